"""The energy densities of the finite-element materials, compiled with numba: psi(F), the stress P = dpsi/dF and the
tangent A = d^2 psi / dF^2 (flattened row-major, F_ij -> i d + j) of one element, Lame mu and lambda given. The
formulas are in docs/fem.md:

- LINEAR:      mu eps:eps + lambda/2 tr(eps)^2, eps = (F + F^T)/2 - I
- COROTATED:   mu ||F - R||^2 + lambda/2 (J - 1)^2 (Stomakhin et al. 2012), R from the polar decomposition
- STVK:        mu E:E + lambda/2 tr(E)^2, E = (F^T F - I)/2
- NEO_HOOKEAN: mu/2 (tr(F^T F) - d) - mu ln J + lambda/2 (ln J)^2 (infinite for J <= 0)
- STABLE_NEO_HOOKEAN: mu/2 (I_C - d) + lambda/2 (J - alpha)^2 - mu/2 ln(I_C + 1), alpha = 1 + mu d / ((d + 1) lambda)
  (Smith, de Goes & Kim 2018), less its constant value at rest; mu and lambda already re-parametrised by the caller
  (materials.py)
"""

from __future__ import annotations

import math

import numba

from ..compiled_cache import keep_fresh
from .linalg import _determinant, _signed_svd

LINEAR, COROTATED, STVK, NEO_HOOKEAN, STABLE_NEO_HOOKEAN = range(5)
# the denominators sigma_m + sigma_n of the rotation's derivative are kept at least this far from 0 (a flat element)
ROTATION_FLOOR = 1e-12
# (d, d) scratch matrices of material_terms: cofactor or strain, stress, F F^T; the co-rotated SVD's U, V, R, S, sigma
WORK_SLOTS = 6

@numba.njit(cache=True)
def _epsilon2(i, j):
    return 0.0 if i == j else (1.0 if i < j else -1.0)


@numba.njit(cache=True)
def _epsilon3(i, j, k):
    return (i - j) * (j - k) * (k - i) / 2.0


@numba.njit(cache=True)
def _cofactor(F, d, C):
    """C = det(F) F^-T, written without the inverse (defined for every F)."""
    if d == 2:
        C[0, 0], C[0, 1], C[1, 0], C[1, 1] = F[1, 1], -F[1, 0], -F[0, 1], F[0, 0]
        return
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            C[i, j] = F[i1, j1] * F[i2, j2] - F[i1, j2] * F[i2, j1]


@numba.njit(cache=True)
def _cofactor_derivative(F, d, i, j, k, l):
    """dC_ij / dF_kl: eps_ik eps_jl in 2-D; eps_ikm eps_jln F_mn in 3-D, whose only term is m, n the third indices of
    (i, k) and (j, l)."""
    if d == 2:
        return _epsilon2(i, k) * _epsilon2(j, l)
    if i == k or j == l:
        return 0.0
    m, n = 3 - i - k, 3 - j - l
    return _epsilon3(i, k, m) * _epsilon3(j, l, n) * F[m, n]


@numba.njit(cache=True)
def material_terms(model, F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P = dpsi/dF into P (d, d), and with want_tangent A = d^2 psi / dF^2 into A (d^2, d^2); work
    (WORK_SLOTS, d, d) is scratch (the cofactor, Green's strain and its stress, the SVD), so that an element
    allocates nothing."""
    for i in range(d):
        for j in range(d):
            P[i, j] = 0.0
    if want_tangent:
        for a in range(d * d):
            for b in range(d * d):
                A[a, b] = 0.0
    if model == LINEAR:
        trace = 0.0
        for i in range(d):
            trace += F[i, i] - 1.0
        psi = 0.5 * lam * trace * trace
        for i in range(d):
            for j in range(d):
                strain = 0.5 * (F[i, j] + F[j, i]) - (1.0 if i == j else 0.0)
                psi += mu * strain * strain
                P[i, j] = 2.0 * mu * strain + (lam * trace if i == j else 0.0)
        if want_tangent:
            for i in range(d):
                for j in range(d):
                    A[i * d + j, i * d + j] += mu
                    A[i * d + j, j * d + i] += mu
                    if i == j:
                        for k in range(d):
                            A[i * d + i, k * d + k] += lam
        return psi
    if model == STVK:
        E = work[0]
        for i in range(d):
            for j in range(d):
                value = 0.0
                for p in range(d):
                    value += F[p, i] * F[p, j]
                E[i, j] = 0.5 * (value - (1.0 if i == j else 0.0))
        trace = 0.0
        for i in range(d):
            trace += E[i, i]
        psi = 0.5 * lam * trace * trace
        S = work[1]
        for i in range(d):
            for j in range(d):
                psi += mu * E[i, j] * E[i, j]
                S[i, j] = 2.0 * mu * E[i, j] + (lam * trace if i == j else 0.0)
        for i in range(d):
            for j in range(d):
                value = 0.0
                for m in range(d):
                    value += F[i, m] * S[m, j]
                P[i, j] = value
        if want_tangent:
            FFt = work[2]
            for i in range(d):
                for k in range(d):
                    value = 0.0
                    for m in range(d):
                        value += F[i, m] * F[k, m]
                    FFt[i, k] = value
            # dP_ij/dF_kl = delta_ik S_lj + mu (F_il F_kj + (F F^T)_ik delta_lj) + lambda F_ij F_kl
            for i in range(d):
                for j in range(d):
                    for k in range(d):
                        for l in range(d):
                            value = mu * F[i, l] * F[k, j] + lam * F[i, j] * F[k, l]
                            if i == k:
                                value += S[l, j]
                            if l == j:
                                value += mu * FFt[i, k]
                            A[i * d + j, k * d + l] = value
        return psi
    if model == NEO_HOOKEAN:
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
    if model == COROTATED:
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
    # STABLE_NEO_HOOKEAN
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


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
