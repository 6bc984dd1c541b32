"""The stable neo-Hookean energy of Smith, de Goes & Kim 2018, less its constant value at rest (docs/fem.md,
"Energies"):

    psi = mu/2 (I_C - d) + lambda/2 ((J - alpha)^2 - (1 - alpha)^2) - mu/2 ln((I_C + 1)/(d + 1)),
    alpha = 1 + mu d / ((d + 1) lambda),    P = (mu - mu / (I_C + 1)) F + lambda (J - alpha) C,

C the cofactor matrix J F^-T; finite for every F, inverted elements included. mu and lambda are the re-parametrised
ones (``lame_parameters``), so that its Hessian at rest is linear elasticity's. In the signed singular values, a pair's
flip and twist eigenvalues are (mu - mu / (I_C + 1)) -+ lambda (J - alpha) sigma_k, sigma_k the third (1 in 2-D). A
shell's membrane is the d = 2 form, f(I_1, J) with alpha = 1 + 2 mu / (3 lambda) (invariant_membrane.py). At one
vertex of a solid (vertex block descent): P n = (mu - mu / (I_C + 1)) w + lambda (J - alpha) c and K = (mu - mu /
(I_C + 1)) |n|^2 I + 2 mu / (I_C + 1)^2 w w^T + lambda c c^T, with w = F n and c = cof(F) n."""

from __future__ import annotations

import math

import numba
import numpy as np

from ...compiled_cache import keep_fresh
from ..linalg import _cofactor, _cofactor_derivative, _determinant, _others
from .invariant_membrane import area_ratio, invariant_changes, stress_and_tangent, vertex_area_ratio, vertex_terms


def lame_parameters(mu: np.ndarray, lam: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The paper's re-parametrisation (sec. 3.4, there for d = 3), which makes the Hessian at rest linear elasticity's
    with Lame mu and lambda (Pa): mu' = mu (d + 1) / d, lambda' = lambda + mu' (d (d + 1) - 2) / (d + 1)^2 (docs/fem.md
    derives it)."""
    mu_snh = mu * (dim + 1.0) / dim
    return mu_snh, lam + mu_snh * (dim * (dim + 1.0) - 2.0) / (dim + 1.0) ** 2


def rest_volume_term(mu: np.ndarray, lam: np.ndarray, dim: int) -> np.ndarray:
    """alpha = 1 + mu d / ((d + 1) lambda) per element, made once for the vertex sweeps (lambda = 0: infinite, as the
    energy's own formula has it)."""
    with np.errstate(divide="ignore"):
        return 1.0 + mu * dim / ((dim + 1.0) * lam)


@numba.njit(cache=True, inline="always")
def energy_terms(F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P into P and with want_tangent A into A (every entry); work[0] holds the cofactor matrix."""
    J = _determinant(F, d)
    C = work[0]
    _cofactor(F, d, C)
    invariant = 0.0
    for i in range(d):
        for j in range(d):
            invariant += F[i, j] * F[i, j]
    alpha = 1.0 + mu * d / ((d + 1.0) * lam)
    # less its value at rest, lambda/2 (1 - alpha)^2 - mu/2 ln(d + 1), so that psi(I) = 0 as for the other energies
    psi = (0.5 * mu * (invariant - d) + 0.5 * lam * ((J - alpha) * (J - alpha) - (1.0 - alpha) * (1.0 - alpha))
           - 0.5 * mu * math.log((invariant + 1.0) / (d + 1.0)))
    shrink = mu / (invariant + 1.0)
    for i in range(d):
        for j in range(d):
            P[i, j] = (mu - shrink) * F[i, j] + lam * (J - alpha) * C[i, j]
    if want_tangent:
        curvature = 2.0 * mu / ((invariant + 1.0) * (invariant + 1.0))
        for i in range(d):
            for j in range(d):
                for k in range(d):
                    for l in range(d):
                        value = (curvature * F[i, j] * F[k, l] + lam * C[i, j] * C[k, l]
                                 + lam * (J - alpha) * _cofactor_derivative(F, d, i, j, k, l))
                        if i == k and j == l:
                            value += mu - shrink
                        A[i * d + j, k * d + l] = value
    return psi


@numba.njit(cache=True, inline="always")
def singular_hessian(sigma, d, J, mu, lam, H):
    """d^2 psi / d sigma^2 into H (d, d); defined everywhere (True)."""
    invariant = 0.0
    for m in range(d):
        invariant += sigma[m] * sigma[m]
    alpha = 1.0 + mu * d / ((d + 1.0) * lam)
    shrink = mu / (invariant + 1.0)
    curvature = 2.0 * mu / ((invariant + 1.0) * (invariant + 1.0))
    for i in range(d):
        for j in range(d):
            if i == j:
                H[i, i] = mu - shrink + curvature * sigma[i] * sigma[i] + lam * _others(sigma, d, i) ** 2
            else:
                third = 1.0 if d == 2 else sigma[3 - i - j]
                H[i, j] = (curvature * sigma[i] * sigma[j]
                           + lam * (_others(sigma, d, i) * _others(sigma, d, j) + (J - alpha) * third))
    return True


@numba.njit(cache=True, inline="always")
def pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam):
    """(flip, twist) of the pair of singular values si, sj; ``third`` the other singular value (1 in 2-D)."""
    invariant = 0.0
    for m in range(d):
        invariant += sigma[m] * sigma[m]
    alpha = 1.0 + mu * d / ((d + 1.0) * lam)
    base = mu - mu / (invariant + 1.0)
    flip = base - lam * (J - alpha) * third
    twist = base + lam * (J - alpha) * third
    return flip, twist


@numba.njit(cache=True)
def membrane_invariants(I1, J, mu, lam):
    """(psi, f_1, f_J, f_11, f_1J, f_JJ) of the membrane's f(I_1, J), the d = 2 form less its value at rest."""
    alpha = 1.0 + 2.0 * mu / (3.0 * lam)
    psi = (0.5 * mu * (I1 - 2.0) + 0.5 * lam * ((J - alpha) * (J - alpha) - (1.0 - alpha) * (1.0 - alpha))
           - 0.5 * mu * math.log((I1 + 1.0) / 3.0))
    return (psi, 0.5 * mu * (1.0 - 1.0 / (I1 + 1.0)), lam * (J - alpha), 0.5 * mu / ((I1 + 1.0) * (I1 + 1.0)), 0.0,
            lam)


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
    """psi(C + dC) - psi(C) without cancellation, from the exact changes of I_1 and J (alpha as
    ``membrane_invariants`` has it)."""
    invariant, invariant_change, J, moved, J_change = invariant_changes(C00, C01, C11, D00, D01, D11)
    alpha = 1.0 + 2.0 * mu / (3.0 * lam)
    return (0.5 * mu * invariant_change + 0.5 * lam * J_change * (2.0 * (J - alpha) + J_change)
            - 0.5 * mu * math.log1p(invariant_change / (invariant + 1.0)))


@numba.njit(cache=True, inline="always")
def vertex_stiffness(F, n, d, squared, mu, lam, A, K, work):
    """K = n^T A n = (mu - mu / (I_C + 1)) |n|^2 I + 2 mu / (I_C + 1)^2 w w^T + lambda c c^T, added into K (zeroed
    by the caller); work[0, 0], work[0, 1] and work[2] hold w, c and cof(F)."""
    w = work[0, 0]
    for i in range(d):
        total = 0.0
        for j in range(d):
            total += F[i, j] * n[j]
        w[i] = total
    C = work[2]
    _cofactor(F, d, C)
    c = work[0, 1]
    for i in range(d):
        total = 0.0
        for j in range(d):
            total += C[i, j] * n[j]
        c[i] = total
    invariant = 0.0
    for i in range(d):
        for j in range(d):
            invariant += F[i, j] * F[i, j]
    shrink = mu / (invariant + 1.0)
    curvature = 2.0 * mu / ((invariant + 1.0) * (invariant + 1.0))
    for i in range(d):
        K[i, i] += (mu - shrink) * squared
        for k in range(d):
            K[i, k] += curvature * w[i] * w[k] + lam * c[i] * c[k]


@numba.njit(cache=True, inline="always")
def invariant_coefficients(J, invariant, mu, lam, alpha):
    """(shear, stretch, spread, volume_stress, kept) of P n = shear w + volume_stress c and K = shear |n|^2 I + stretch
    w w^T + spread c c^T; kept = 1 / (I_C + 1), what the energy's change reads; alpha the element's, made once."""
    kept = 1.0 / (invariant + 1.0)
    return mu - mu * kept, 2.0 * mu * kept * kept, lam, lam * (J - alpha), kept


@numba.njit(cache=True, inline="always")
def invariant_change(J, kept, invariant_change, volume_change, mu, lam, alpha):
    """psi' - psi from the exact changes of I_C and J (kept = 1 / (I_C + 1))."""
    return (0.5 * mu * invariant_change + 0.5 * lam * volume_change * (2.0 * (J - alpha) + volume_change)
            - 0.5 * mu * math.log1p(invariant_change * kept))


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
