"""The co-rotated energy: psi = mu ||F - R||^2 + lambda/2 (J - 1)^2, R the rotation of F's polar decomposition (the
fixed co-rotated energy of Stomakhin et al. 2012; docs/fem.md, "Energies"). With the signed SVD F = U diag(sigma) V^T
(linalg.py; U, V rotations, so that R = U V^T stays a rotation for inverted elements) and the cofactor matrix C:

    P = 2 mu (F - R) + lambda (J - 1) C,
    dR_ij/dF_kl = sum_{m<n} (U_im V_jn - U_in V_jm)(U_km V_ln - U_kn V_lm) / (sigma_m + sigma_n).

With lambda = 0 it is the as-rigid-as-possible energy, projective dynamics' element constraint (system.py). A
shell's membrane is f(I_1, J) = mu (I_1 - 2 (sigma_1 + sigma_2) + 2) + lambda/2 (J - 1)^2 with sigma_1 + sigma_2 =
sqrt(I_1 + 2 J) (invariant_membrane.py). At one vertex of a solid (vertex block descent) its K is its exact tangent
contracted with n, and its energy change the difference of the element's energies."""

from __future__ import annotations

import math

import numba

from ...compiled_cache import keep_fresh
from ..linalg import _cofactor, _cofactor_derivative, _determinant, _others, _signed_svd
from .invariant_membrane import (AREA_FLOOR, area_ratio, invariant_changes, stress_and_tangent, vertex_area_ratio,
                                 vertex_terms)

# the denominators sigma_m + sigma_n of the rotation's derivative are kept at least this far from 0 (a flat element)
ROTATION_FLOOR = 1e-12


@numba.njit(cache=True, inline="always")
def energy_terms(F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P into P and with want_tangent A into A (every entry); work[0] holds the cofactor matrix,
    work[1:5] and work[5, 0] the SVD's U, V, R, its scratch and sigma."""
    U, V, R, sigma = work[1], work[2], work[3], work[5, 0]
    _signed_svd(F, d, U, sigma, V, work[4])
    for i in range(d):
        for j in range(d):
            value = 0.0
            for m in range(d):
                value += U[i, m] * V[j, m]
            R[i, j] = value
    J = _determinant(F, d)
    C = work[0]
    _cofactor(F, d, C)
    psi = 0.5 * lam * (J - 1.0) * (J - 1.0)
    for i in range(d):
        psi += mu * (sigma[i] - 1.0) * (sigma[i] - 1.0)
    for i in range(d):
        for j in range(d):
            P[i, j] = 2.0 * mu * (F[i, j] - R[i, j]) + lam * (J - 1.0) * C[i, j]
    if want_tangent:
        for i in range(d):
            for j in range(d):
                for k in range(d):
                    for l in range(d):
                        # dR_ij/dF_kl = sum_{m<n} (U_im V_jn - U_in V_jm)(U_km V_ln - U_kn V_lm) / (sigma_m + sigma_n)
                        rotation = 0.0
                        for m in range(d):
                            for n in range(m + 1, d):
                                total = sigma[m] + sigma[n]
                                if abs(total) < ROTATION_FLOOR:
                                    total = ROTATION_FLOOR if total >= 0.0 else -ROTATION_FLOOR
                                rotation += ((U[i, m] * V[j, n] - U[i, n] * V[j, m])
                                             * (U[k, m] * V[l, n] - U[k, n] * V[l, m]) / total)
                        value = -2.0 * mu * rotation + lam * (C[k, l] * C[i, j]
                                                              + (J - 1.0) * _cofactor_derivative(F, d, i, j, k, l))
                        if i == k and j == l:
                            value += 2.0 * mu
                        A[i * d + j, k * d + l] = value
    return psi


@numba.njit(cache=True, inline="always")
def singular_hessian(sigma, d, J, mu, lam, H):
    """d^2 psi / d sigma^2 into H (d, d); defined everywhere (True)."""
    for i in range(d):
        for j in range(d):
            if i == j:
                H[i, i] = 2.0 * mu + lam * _others(sigma, d, i) ** 2
            else:
                third = 1.0 if d == 2 else sigma[3 - i - j]
                H[i, j] = lam * (_others(sigma, d, i) * _others(sigma, d, j) + (J - 1.0) * third)
    return True


@numba.njit(cache=True, inline="always")
def pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam):
    """(flip, twist) of the pair of singular values si, sj; the twist's 1 / (si + sj) floored as the tangent's is."""
    total = si + sj
    if abs(total) < ROTATION_FLOOR:
        total = ROTATION_FLOOR if total >= 0.0 else -ROTATION_FLOOR
    flip = 2.0 * mu - lam * (J - 1.0) * third
    twist = 2.0 * mu - 4.0 * mu / total + lam * (J - 1.0) * third
    return flip, twist


@numba.njit(cache=True)
def membrane_invariants(I1, J, mu, lam):
    """(psi, f_1, f_J, f_11, f_1J, f_JJ) of the membrane's f(I_1, J), sigma_1 + sigma_2 floored at a collapsed
    triangle."""
    total = math.sqrt(max(I1 + 2.0 * J, AREA_FLOOR))  # sigma_1 + sigma_2
    psi = mu * (I1 - 2.0 * total + 2.0) + 0.5 * lam * (J - 1.0) * (J - 1.0)
    cube = total * total * total
    return (psi, mu * (1.0 - 1.0 / total), -2.0 * mu / total + lam * (J - 1.0), 0.5 * mu / cube, mu / cube,
            2.0 * mu / cube + lam)


@numba.njit(cache=True, inline="always")
def membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work):
    """psi of a 3 x 2 F (C = F^T F, I_1 given), P into P (3, 2) and with want_tangent A into A (6, 6)."""
    J = area_ratio(C)
    psi, f1, fJ, f11, f1J, fJJ = membrane_invariants(I1, J, mu, lam)
    stress_and_tangent(F, C, J, f1, fJ, f11, f1J, fJJ, P, A, want_tangent, work)
    return psi


@numba.njit(cache=True, inline="always")
def membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K):
    """P n into stress and K = n^T A n into K at a triangle's corner (invariant_membrane.py)."""
    J = vertex_area_ratio(C00, C01, C11)
    _, f1, fJ, f11, f1J, fJJ = membrane_invariants(C00 + C11, J, mu, lam)
    vertex_terms(F, n0, n1, squared, C00, C01, C11, J, f1, fJ, f11, f1J, fJJ, stress, K)


@numba.njit(cache=True, inline="always")
def membrane_change(C00, C01, C11, D00, D01, D11, mu, lam):
    """psi(C + dC) - psi(C) without cancellation, from the exact changes of I_1 and J; sigma_1 + sigma_2 =
    sqrt(I_1 + 2 J), floored as ``membrane_invariants`` floors it."""
    invariant, invariant_change, J, moved, J_change = invariant_changes(C00, C01, C11, D00, D01, D11)
    before, after = invariant + 2.0 * J, invariant + invariant_change + 2.0 * (J + J_change)
    if before >= AREA_FLOOR and after >= AREA_FLOOR:
        total_change = (invariant_change + 2.0 * J_change) / (math.sqrt(before) + math.sqrt(after))
    else:
        total_change = math.sqrt(max(after, AREA_FLOOR)) - math.sqrt(max(before, AREA_FLOOR))
    return mu * (invariant_change - 2.0 * total_change) + 0.5 * lam * J_change * (2.0 * (J - 1.0) + J_change)


@numba.njit(cache=True, inline="always")
def vertex_stiffness(F, n, d, squared, mu, lam, A, K, work):
    """K = n^T A n from the exact tangent A at F, which the caller has computed (``energy_terms`` with want_tangent):
    the rotation's derivative has no short closed form at one vertex."""
    for i in range(d):
        for k in range(d):
            total = 0.0
            for j in range(d):
                for m in range(d):
                    total += n[j] * A[i * d + j, k * d + m] * n[m]
            K[i, k] = total


@numba.njit(cache=True, inline="always")
def vertex_energy_change(F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work):
    """psi(F + u n^T) - psi(F), the difference of the element's energies (moved holds F + u n^T)."""
    for i in range(d):
        for j in range(d):
            moved[i, j] = F[i, j] + u[i] * n[j]
    return (energy_terms(moved, d, mu, lam, P, A, False, work)
            - energy_terms(F, d, mu, lam, P, A, False, work))


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
