"""The neo-Hookean energy: psi = mu/2 (I_C - d) - mu ln J + lambda/2 (ln J)^2, I_C = tr(F^T F), J = det F, infinite for
J <= 0 (the course code's; docs/fem.md, "Energies"). With G = F^-T and the cofactor matrix C = J G:

    P = mu (F - G) + lambda ln J G,
    dP_ij/dF_kl = mu delta_ik delta_jl + (mu - lambda ln J) G_il G_kj + lambda G_ij G_kl.

In the signed singular values, its scaling Hessian is mu I + (mu + lambda (1 - ln J)) / sigma_i^2 on the diagonal and
lambda / (sigma_i sigma_j) off it; a pair's flip and twist eigenvalues are mu +- (mu - lambda ln J) / (sigma_i sigma_j).
A shell's membrane is f(I_1, J) = mu/2 (I_1 - 2) - mu ln J + lambda/2 (ln J)^2 (invariant_membrane.py). At one vertex
of a solid (vertex block descent, vbd_kernels.py): P n = mu w + (lambda ln J - mu) / J c and K = mu |n|^2 I + (mu +
lambda (1 - ln J)) / J^2 c c^T, with w = F n and c = cof(F) n. Every element or vertex where J <= 0 gets psi = inf
and a NaN stress: no line search accepts it, and no step is taken to it."""

from __future__ import annotations

import math

import numba

from ...compiled_cache import keep_fresh
from ..linalg import _cofactor, _determinant
from .invariant_membrane import area_ratio, invariant_changes, stress_and_tangent, vertex_area_ratio, vertex_terms


@numba.njit(cache=True, inline="always")
def energy_terms(F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P into P and with want_tangent A into A (every entry); work[0] holds the cofactor matrix."""
    J = _determinant(F, d)
    if not J > 0.0:
        for i in range(d):
            for j in range(d):
                P[i, j] = math.nan
        return math.inf  # undefined for an inverted or flat element: no line search accepts it
    C = work[0]
    _cofactor(F, d, C)
    log_J = math.log(J)
    squared = 0.0
    for i in range(d):
        for j in range(d):
            squared += F[i, j] * F[i, j]
    psi = 0.5 * mu * (squared - d) - mu * log_J + 0.5 * lam * log_J * log_J
    for i in range(d):
        for j in range(d):
            G = C[i, j] / J  # F^-T
            P[i, j] = mu * (F[i, j] - G) + lam * log_J * G
    if want_tangent:
        # dP_ij/dF_kl = mu delta_ik delta_jl + (mu - lambda ln J) G_il G_kj + lambda G_ij G_kl, G = F^-T
        for i in range(d):
            for j in range(d):
                for k in range(d):
                    for l in range(d):
                        value = ((mu - lam * log_J) * C[i, l] * C[k, j] + lam * C[i, j] * C[k, l]) / (J * J)
                        if i == k and j == l:
                            value += mu
                        A[i * d + j, k * d + l] = value
    return psi


@numba.njit(cache=True, inline="always")
def singular_hessian(sigma, d, J, mu, lam, H):
    """d^2 psi / d sigma^2 into H (d, d); False where J <= 0 (undefined), H then left as it was."""
    if not J > 0.0:
        return False
    log_J = math.log(J)
    for i in range(d):
        for j in range(d):
            if i == j:
                H[i, i] = mu + (mu + lam * (1.0 - log_J)) / (sigma[i] * sigma[i])
            else:
                H[i, j] = lam / (sigma[i] * sigma[j])
    return True


@numba.njit(cache=True, inline="always")
def pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam):
    """(flip, twist) of the pair of singular values si, sj."""
    flip = mu + (mu - lam * math.log(J)) / (si * sj)
    twist = mu + (lam * math.log(J) - mu) / (si * sj)
    return flip, twist


@numba.njit(cache=True)
def membrane_invariants(I1, J, mu, lam):
    """(psi, f_1, f_J, f_11, f_1J, f_JJ) of the membrane's f(I_1, J); psi = inf and NaN derivatives at J <= 0."""
    if not J > 0.0:
        return math.inf, math.nan, math.nan, math.nan, math.nan, math.nan
    log_J = math.log(J)
    psi = 0.5 * mu * (I1 - 2.0) - mu * log_J + 0.5 * lam * log_J * log_J
    return psi, 0.5 * mu, (lam * log_J - mu) / J, 0.0, 0.0, (mu + lam * (1.0 - log_J)) / (J * J)


@numba.njit(cache=True, inline="always")
def membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work):
    """psi of a 3 x 2 F (C = F^T F, I_1 given), P into P (3, 2) and with want_tangent A into A (6, 6); a collapsed
    triangle (J = 0) has psi = inf and a NaN stress, and leaves A as it was."""
    J = area_ratio(C)
    if not J > 0.0:
        for i in range(3):
            for j in range(2):
                P[i, j] = math.nan
        return math.inf
    psi, f1, fJ, f11, f1J, fJJ = membrane_invariants(I1, J, mu, lam)
    stress_and_tangent(F, C, J, f1, fJ, f11, f1J, fJJ, P, A, want_tangent, work)
    return psi


@numba.njit(cache=True, inline="always")
def membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K):
    """P n into stress and K = n^T A n into K at a triangle's corner (invariant_membrane.py); NaN for a collapsed
    triangle: infinite energy, no force to take."""
    J = vertex_area_ratio(C00, C01, C11)
    if not J > 0.0:
        for i in range(3):
            stress[i] = math.nan
            for k in range(3):
                K[i, k] = math.nan
        return
    _, f1, fJ, f11, f1J, fJJ = membrane_invariants(C00 + C11, J, mu, lam)
    vertex_terms(F, n0, n1, squared, C00, C01, C11, J, f1, fJ, f11, f1J, fJJ, stress, K)


@numba.njit(cache=True, inline="always")
def membrane_change(C00, C01, C11, D00, D01, D11, mu, lam):
    """psi(C + dC) - psi(C) without cancellation, from the exact changes of I_1 and J; inf where the triangle is
    collapsed before or after (the energy is infinite there)."""
    invariant, invariant_change, J, moved, J_change = invariant_changes(C00, C01, C11, D00, D01, D11)
    if not (J > 0.0 and moved > 0.0):
        return math.inf
    log_ratio = math.log1p(J_change / J)
    return (0.5 * mu * invariant_change - mu * log_ratio
            + 0.5 * lam * log_ratio * (2.0 * math.log(J) + log_ratio))


@numba.njit(cache=True, inline="always")
def vertex_stiffness(F, n, d, squared, mu, lam, A, K, work):
    """K = n^T A n = mu |n|^2 I + (mu + lambda (1 - ln J)) / J^2 c c^T (c = cof(F) n), added into K (zeroed by the
    caller); NaN where J <= 0. work[2] holds cof(F), work[0, 1] c."""
    C = work[2]
    _cofactor(F, d, C)
    c = work[0, 1]
    for i in range(d):
        total = 0.0
        for j in range(d):
            total += C[i, j] * n[j]
        c[i] = total
    J = _determinant(F, d)
    factor = (mu + lam * (1.0 - math.log(J))) / (J * J) if J > 0.0 else math.nan
    for i in range(d):
        K[i, i] += mu * squared
        for k in range(d):
            K[i, k] += factor * c[i] * c[k]


@numba.njit(cache=True, inline="always")
def invariant_coefficients(J, invariant, mu, lam, alpha):
    """(shear, stretch, spread, volume_stress, kept) of P n = shear w + volume_stress c and K = shear |n|^2 I + stretch
    w w^T + spread c c^T: P n = mu w + (lambda ln J - mu) / J c; kept = ln J, what the energy's change reads."""
    log_J = math.log(J) if J > 0.0 else math.nan
    inverse = 1.0 / J
    return mu, 0.0, (mu + lam * (1.0 - log_J)) * inverse * inverse, (lam * log_J - mu) * inverse, log_J


@numba.njit(cache=True, inline="always")
def invariant_change(J, kept, invariant_change, volume_change, mu, lam, alpha):
    """psi' - psi from the exact changes of I_C and J (kept = ln J); inf where the element is inverted or flat before
    or after: the energy is infinite there, and no step is taken to it."""
    if not (J > 0.0 and J + volume_change > 0.0):
        return math.inf
    log_ratio = math.log1p(volume_change / J)
    return 0.5 * mu * invariant_change - mu * log_ratio + 0.5 * lam * log_ratio * (2.0 * kept + log_ratio)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
