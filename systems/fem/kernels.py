"""Compiled element loops of the finite-element system: deformation gradients, energy densities, stresses, tangents,
their SPD projection, and the scatter into the gradient and into the Hessian's fixed CSR pattern.

Piecewise-linear simplices (triangles in 2-D, tetrahedra in 3-D) with one-point quadrature, which is exact: F is
constant on an element. With the rest shape's edge matrix D_m = [X_1 - X_0, ..., X_d - X_0] and g_a the rows of
D_m^-1 (a = 1..d), g_0 = -sum g_a,

    F = sum_a x_a g_a^T,   dPsi/dx_a = V P g_a,   d^2 Psi / dx_a dx_b = V [A : (g_a, g_b)],

with P = dpsi/dF (first Piola-Kirchhoff stress) and A = d^2 psi / dF^2 (flattened row-major, F_ij -> i d + j).
The SPD projection is of A (d^2 x d^2): B^T A B with B = dF/dx onto F-space is PSD exactly when A is, so the
element Hessian is left unchanged where it is PSD. A's eigensystem is analytic for these isotropic energies (Smith
et al. 2019): a signed SVD of F from the eigensystem of F^T F, the d x d Hessian in the singular values, and closed
forms for the rest; no LAPACK call per element. Energy densities (docs/fem.md), Lame mu and lambda per element:

- LINEAR:      mu eps:eps + lambda/2 tr(eps)^2, eps = (F + F^T)/2 - I
- COROTATED:   mu ||F - R||^2 + lambda/2 (J - 1)^2 (Stomakhin et al. 2012), R from the polar decomposition
- STVK:        mu E:E + lambda/2 tr(E)^2, E = (F^T F - I)/2
- NEO_HOOKEAN: mu/2 (tr(F^T F) - d) - mu ln J + lambda/2 (ln J)^2 (infinite for J <= 0)
- STABLE_NEO_HOOKEAN: mu/2 (I_C - d) + lambda/2 (J - alpha)^2 - mu/2 ln(I_C + 1), alpha = 1 + mu d / ((d + 1) lambda)
  (Smith, de Goes & Kim 2018), less its constant value at rest; mu and lambda already re-parametrised by the caller
  (materials.py)

Each loop over elements runs in parallel (``prange``): every element writes only its own rows, so the result does
not depend on the thread count; the scatters run serially in element order, so neither does round-off.
"""

from __future__ import annotations

import math

import numba
import numpy as np

LINEAR, COROTATED, STVK, NEO_HOOKEAN, STABLE_NEO_HOOKEAN = range(5)
# the denominators sigma_m + sigma_n of the rotation's derivative are kept at least this far from 0 (a flat element)
ROTATION_FLOOR = 1e-12
# (d, d) scratch matrices of material_terms: cofactor or strain, stress, F F^T; the co-rotated SVD's U, V, R, S, sigma
WORK_SLOTS = 6
# elements per chunk of the parallel loops: the scratch arrays are made once per chunk, not once per element
CHUNK = 256


@numba.njit(cache=True)
def _epsilon2(i, j):
    return 0.0 if i == j else (1.0 if i < j else -1.0)


@numba.njit(cache=True)
def _epsilon3(i, j, k):
    return (i - j) * (j - k) * (k - i) / 2.0


@numba.njit(cache=True)
def _determinant(F, d):
    if d == 2:
        return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))


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


# A + PSD_SHIFT max|lambda| I: eigenvalues above -PSD_SHIFT of the largest count as 0 (round-off: the rotation-invariant
# energies' tangent is singular at rest, where rigid rotations cost nothing), and leave the exact tangent as it is
PSD_SHIFT = 1e-12
# an element whose tangent's lowest eigenvalue, from the closed-form singular values, is above this fraction of the
# largest is PSD whatever their round-off: it skips the SVD (the singular values' error is far below this)
SCREEN_MARGIN = 1e-6
# a column F v_a of the SVD shorter than this fraction of the largest singular value is F's null space: U's column is
# then chosen orthogonal to the others instead of normalising round-off
RANK_FLOOR = 1e-14
@numba.njit(cache=True)
def _plane_eigen(b00, b01, b11):
    """(high, low, c, s): the eigenvalues of the symmetric 2 x 2 matrix [[b00, b01], [b01, b11]], descending, and the
    unit eigenvector (c, s) of the high one ((-s, c) is the low one's), without cancellation in either."""
    mean, half = 0.5 * (b00 + b11), 0.5 * (b00 - b11)
    radius = math.hypot(half, b01)
    if radius == 0.0:
        return mean, mean, 1.0, 0.0
    if half >= 0.0:
        c, s = half + radius, b01
    else:
        c, s = b01, radius - half
    norm = math.hypot(c, s)
    return mean + radius, mean - radius, c / norm, s / norm


@numba.njit(cache=True)
def _symmetric_eigen(S, d, values, vectors):
    """S = vectors diag(values) vectors^T for a symmetric d x d matrix (d <= 3), values descending; S is overwritten.
    The eigenvalues in closed form (``_closed_form_eigenvalues``); in 3-D the eigenvector of the one farther from the
    others from the largest cross product of two rows of S - lambda I, then the other two from the exact 2 x 2
    problem in the plane normal to it (Eberly, "A robust eigensolver for 3 x 3 symmetric matrices", 2014). An
    eigenvector's error is round-off over the gap to the next eigenvalue, so V diag(values) V^T equals S to
    round-off of |S| even where eigenvalues nearly coincide."""
    if d == 2:
        values[0], values[1], c, s = _plane_eigen(S[0, 0], S[0, 1], S[1, 1])
        vectors[0, 0], vectors[1, 0], vectors[0, 1], vectors[1, 1] = c, s, -s, c
        return
    a00, a01, a02, a11, a12, a22 = S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2]
    _closed_form_eigenvalues(S, 3, values)
    first = 0 if values[0] - values[1] >= values[1] - values[2] else 2
    shift = values[first]
    r0x, r0y, r0z = a00 - shift, a01, a02
    r1x, r1y, r1z = a01, a11 - shift, a12
    r2x, r2y, r2z = a02, a12, a22 - shift
    best, vx, vy, vz = -1.0, 1.0, 0.0, 0.0
    for pair in range(3):
        if pair == 0:
            cx, cy, cz = r0y * r1z - r0z * r1y, r0z * r1x - r0x * r1z, r0x * r1y - r0y * r1x
        elif pair == 1:
            cx, cy, cz = r0y * r2z - r0z * r2y, r0z * r2x - r0x * r2z, r0x * r2y - r0y * r2x
        else:
            cx, cy, cz = r1y * r2z - r1z * r2y, r1z * r2x - r1x * r2z, r1x * r2y - r1y * r2x
        norm = cx * cx + cy * cy + cz * cz
        if norm > best:
            best, vx, vy, vz = norm, cx, cy, cz
    if not best > 0.0:  # S - lambda I of rank 1 or 0 (two or three equal eigenvalues): any axis will do to start
        vx, vy, vz = 1.0, 0.0, 0.0
        best = 1.0
        if first == 2:  # the double eigenvalue is the top one: the single one's vector is S's range direction
            rows = (r0x * r0x + r0y * r0y + r0z * r0z, r1x * r1x + r1y * r1y + r1z * r1z, r2x * r2x + r2y * r2y + r2z * r2z)
            pick = 0 if rows[0] >= rows[1] and rows[0] >= rows[2] else (1 if rows[1] >= rows[2] else 2)
            if rows[pick] > 0.0:
                vx, vy, vz = (r0x, r0y, r0z) if pick == 0 else ((r1x, r1y, r1z) if pick == 1 else (r2x, r2y, r2z))
                best = rows[pick]
    scale = 1.0 / math.sqrt(best)
    vx, vy, vz = vx * scale, vy * scale, vz * scale
    # an orthonormal basis (u, w) of the plane normal to v
    if abs(vx) > abs(vy):
        scale = 1.0 / math.sqrt(vx * vx + vz * vz)
        ux, uy, uz = -vz * scale, 0.0, vx * scale
    else:
        scale = 1.0 / math.sqrt(vy * vy + vz * vz)
        ux, uy, uz = 0.0, vz * scale, -vy * scale
    wx, wy, wz = vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux
    # S restricted to the plane: [u w]^T S [u w]
    sux, suy, suz = a00 * ux + a01 * uy + a02 * uz, a01 * ux + a11 * uy + a12 * uz, a02 * ux + a12 * uy + a22 * uz
    swx, swy, swz = a00 * wx + a01 * wy + a02 * wz, a01 * wx + a11 * wy + a12 * wz, a02 * wx + a12 * wy + a22 * wz
    b00 = ux * sux + uy * suy + uz * suz
    b01 = wx * sux + wy * suy + wz * suz
    b11 = wx * swx + wy * swy + wz * swz
    high, low, c, s = _plane_eigen(b00, b01, b11)
    vectors[0, first], vectors[1, first], vectors[2, first] = vx, vy, vz
    values[first] = vx * (a00 * vx + a01 * vy + a02 * vz) + vy * (a01 * vx + a11 * vy + a12 * vz) + vz * (a02 * vx + a12 * vy + a22 * vz)
    others = (1, 2) if first == 0 else (0, 1)
    for column in range(2):
        target = others[column]
        p, q = (c, s) if column == 0 else (-s, c)
        vectors[0, target], vectors[1, target], vectors[2, target] = p * ux + q * wx, p * uy + q * wy, p * uz + q * wz
        values[target] = high if column == 0 else low


@numba.njit(cache=True)
def _closed_form_eigenvalues(S, d, values):
    """The eigenvalues of the symmetric d x d (d <= 3) matrix S, descending, in closed form (the trigonometric
    solution of the characteristic cubic in 3-D), accurate to round-off of |S|; S is overwritten."""
    if d == 2:
        mean, half = 0.5 * (S[0, 0] + S[1, 1]), math.hypot(0.5 * (S[0, 0] - S[1, 1]), S[0, 1])
        values[0], values[1] = mean + half, mean - half
        return
    mean = (S[0, 0] + S[1, 1] + S[2, 2]) / 3.0
    off = S[0, 1] ** 2 + S[0, 2] ** 2 + S[1, 2] ** 2
    spread = math.sqrt(((S[0, 0] - mean) ** 2 + (S[1, 1] - mean) ** 2 + (S[2, 2] - mean) ** 2 + 2.0 * off) / 6.0)
    if spread == 0.0:
        values[0] = values[1] = values[2] = mean
        return
    for i in range(3):
        S[i, i] -= mean
    angle = math.acos(max(-1.0, min(1.0, _determinant(S, 3) / (2.0 * spread ** 3)))) / 3.0
    values[0] = mean + 2.0 * spread * math.cos(angle)
    values[2] = mean + 2.0 * spread * math.cos(angle + 2.0 * math.pi / 3.0)
    values[1] = 3.0 * mean - values[0] - values[2]


@numba.njit(cache=True)
def _gram(F, d, S):
    """S = F^T F (d, d)."""
    for i in range(d):
        for j in range(d):
            value = 0.0
            for m in range(d):
                value += F[m, i] * F[m, j]
            S[i, j] = value


@numba.njit(cache=True)
def _singular_values(F, d, S, sigma):
    """The signed singular values of F (descending, the last with the sign of det F) from the closed-form eigenvalues
    of F^T F: accurate to round-off of |F|^2 in sigma^2, which is what the projection's screening needs (the
    full SVD costs three times more). S (d, d) is scratch."""
    _gram(F, d, S)
    _closed_form_eigenvalues(S, d, sigma)
    for i in range(d):
        sigma[i] = math.sqrt(max(sigma[i], 0.0))
    if _determinant(F, d) < 0.0:
        sigma[d - 1] = -sigma[d - 1]


@numba.njit(cache=True)
def _positive_definite_small(H, d):
    """Whether the symmetric d x d (d <= 3) matrix H is positive definite, by its leading principal minors."""
    if not H[0, 0] > 0.0:
        return False
    minor = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
    if not minor > 0.0:
        return False
    return d == 2 or _determinant(H, 3) > 0.0


@numba.njit(cache=True)
def _signed_svd(F, d, U, sigma, V, S):
    """F = U diag(sigma) V^T with U and V rotations, sigma descending but for the last, which takes the sign of det F
    (the rotation-variant SVD of Irving et al. 2004). V and sigma^2 from the eigensystem of F^T F; U's columns
    F v_i / sigma_i, the last one the cross product of the others, so that U is a rotation even for a flat element.
    S (d, d) is scratch."""
    _gram(F, d, S)
    _symmetric_eigen(S, d, sigma, V)
    if _determinant(V, d) < 0.0:
        for i in range(d):
            V[i, d - 1] = -V[i, d - 1]
    floor = RANK_FLOOR * math.sqrt(max(sigma[0], 0.0))  # sigma holds sigma^2 here
    for a in range(d - 1):
        for i in range(d):
            value = 0.0
            for j in range(d):
                value += F[i, j] * V[j, a]
            U[i, a] = value
        for b in range(a):  # Gram-Schmidt against the columns before: round-off of F^T F's eigenvectors
            overlap = 0.0
            for i in range(d):
                overlap += U[i, a] * U[i, b]
            for i in range(d):
                U[i, a] -= overlap * U[i, b]
        norm = 0.0
        for i in range(d):
            norm += U[i, a] * U[i, a]
        norm = math.sqrt(norm)
        if norm > floor and norm > 0.0:
            for i in range(d):
                U[i, a] /= norm
        elif a == 0:  # F = 0: any direction
            for i in range(d):
                U[i, 0] = 1.0 if i == 0 else 0.0
        else:  # 3-D, F of rank 1: a unit vector orthogonal to the first column, from the axis least along it
            axis = 0
            for k in range(1, 3):
                if abs(U[k, 0]) < abs(U[axis, 0]):
                    axis = k
            U[0, 1] = (U[1, 0] if axis == 2 else 0.0) - (U[2, 0] if axis == 1 else 0.0)
            U[1, 1] = (U[2, 0] if axis == 0 else 0.0) - (U[0, 0] if axis == 2 else 0.0)
            U[2, 1] = (U[0, 0] if axis == 1 else 0.0) - (U[1, 0] if axis == 0 else 0.0)
            norm = math.sqrt(U[0, 1] ** 2 + U[1, 1] ** 2 + U[2, 1] ** 2)
            for i in range(3):
                U[i, 1] /= norm
    if d == 2:
        U[0, 1], U[1, 1] = -U[1, 0], U[0, 0]
    else:
        U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
        U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
        U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]
    for a in range(d):
        value = 0.0
        for i in range(d):
            for j in range(d):
                value += U[i, a] * F[i, j] * V[j, a]
        sigma[a] = value


@numba.njit(cache=True)
def projection_scratch(d):
    """The arrays one element's projection works in, made once per chunk: U, V, S (d, d) of the SVD, sigma (d,), H
    and its eigenvectors (d, d), their eigenvalues (d,), the pairs' flip and twist eigenvalues (3, 2), the tangent's
    eigenvalues (d^2,) and one eigenvector (d^2,)."""
    return (np.empty((d, d)), np.empty((d, d)), np.empty((d, d)), np.empty(d), np.empty((d, d)), np.empty((d, d)),
            np.empty(d), np.empty((3, 2)), np.empty(d * d), np.empty(d * d))


@numba.njit(cache=True)
def _others(sigma, d, i):
    """J / sigma_i, as the product of the other singular values (defined at sigma_i = 0)."""
    value = 1.0
    for m in range(d):
        if m != i:
            value *= sigma[m]
    return value


@numba.njit(cache=True)
def _singular_terms(model, sigma, d, mu, lam, H, pairs):
    """psi as a function of the signed singular values: H = d^2 psi / d sigma^2 into H (d, d), and per pair (i, j),
    i < j in the order (0, 1), (0, 2), (1, 2), the tangent's two eigenvalues on the pair's "flip" (symmetric,
    (psi_i - psi_j) / (sigma_i - sigma_j)) and "twist" (antisymmetric, (psi_i + psi_j) / (sigma_i + sigma_j)) modes
    into pairs (pair, 2), each quotient written out per energy so that it has no cancellation at sigma_i = sigma_j
    (Smith, de Goes & Kim 2019, "Analytic eigensystems for isotropic distortion energies"). False for an
    element where the energy is undefined (neo-Hookean at J <= 0)."""
    J = 1.0
    for m in range(d):
        J *= sigma[m]
    if model == NEO_HOOKEAN:
        if not J > 0.0:
            return False
        log_J = math.log(J)
        for i in range(d):
            for j in range(d):
                if i == j:
                    H[i, i] = mu + (mu + lam * (1.0 - log_J)) / (sigma[i] * sigma[i])
                else:
                    H[i, j] = lam / (sigma[i] * sigma[j])
    elif model == STABLE_NEO_HOOKEAN:
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
    elif model == COROTATED:
        for i in range(d):
            for j in range(d):
                if i == j:
                    H[i, i] = 2.0 * mu + lam * _others(sigma, d, i) ** 2
                else:
                    third = 1.0 if d == 2 else sigma[3 - i - j]
                    H[i, j] = lam * (_others(sigma, d, i) * _others(sigma, d, j) + (J - 1.0) * third)
    else:  # STVK
        trace = 0.0
        for m in range(d):
            trace += 0.5 * (sigma[m] * sigma[m] - 1.0)
        for i in range(d):
            for j in range(d):
                if i == j:
                    H[i, i] = (2.0 * mu * (sigma[i] * sigma[i] + 0.5 * (sigma[i] * sigma[i] - 1.0))
                               + lam * (sigma[i] * sigma[i] + trace))
                else:
                    H[i, j] = lam * sigma[i] * sigma[j]
    pair = 0
    for i in range(d):
        for j in range(i + 1, d):
            third = 1.0 if d == 2 else sigma[3 - i - j]
            si, sj = sigma[i], sigma[j]
            if model == NEO_HOOKEAN:
                flip = mu + (mu - lam * math.log(J)) / (si * sj)
                twist = mu + (lam * math.log(J) - mu) / (si * sj)
            elif model == STABLE_NEO_HOOKEAN:
                invariant = 0.0
                for m in range(d):
                    invariant += sigma[m] * sigma[m]
                alpha = 1.0 + mu * d / ((d + 1.0) * lam)
                base = mu - mu / (invariant + 1.0)
                flip = base - lam * (J - alpha) * third
                twist = base + lam * (J - alpha) * third
            elif model == COROTATED:
                total = si + sj
                if abs(total) < ROTATION_FLOOR:
                    total = ROTATION_FLOOR if total >= 0.0 else -ROTATION_FLOOR
                flip = 2.0 * mu - lam * (J - 1.0) * third
                twist = 2.0 * mu - 4.0 * mu / total + lam * (J - 1.0) * third
            else:
                trace = 0.0
                for m in range(d):
                    trace += 0.5 * (sigma[m] * sigma[m] - 1.0)
                flip = mu * (si * si + si * sj + sj * sj - 1.0) + lam * trace
                twist = mu * (si * si - si * sj + sj * sj - 1.0) + lam * trace
            pairs[pair, 0], pairs[pair, 1] = flip, twist
            pair += 1
    return True


@numba.njit(cache=True)
def project_tangent(model, F, d, mu, lam, A, mode, scratch):
    """The exact tangent A = d^2 psi / dF^2 at F made PSD in place, its negative eigenvalues clamped to 0 (mode 1) or
    mirrored (mode 2); True where it had any below -PSD_SHIFT of the largest, False where it was left as it is.
    From the analytic eigensystem of an isotropic energy: with F = U diag(sigma) V^T, d scaling modes U diag(z) V^T
    (z the eigenvectors of d^2 psi / d sigma^2) and per pair of singular values a flip and a twist mode,
    U (e_i e_j^T +- e_j e_i^T) V^T / sqrt 2 (``_singular_terms``). Only the negative modes' eigenvectors are formed,
    as a low-rank update A + (lambda' - lambda) q q^T of each. Mode 0 and the linear energy (whose constant tangent is
    PSD for every nu in (-1, 0.5)) never project."""
    if mode == 0 or model == LINEAR:
        return False
    U, V, S, sigma, H, Z, curvatures, pairs, values, vector = scratch
    # screening: the eigenvalues need the singular values alone, which the closed form gives at a fraction of the
    # SVD's cost; an element clearly PSD by them (the lowest above SCREEN_MARGIN of the largest) is left as it is
    _singular_values(F, d, S, sigma)
    if not _singular_terms(model, sigma, d, mu, lam, H, pairs):
        return False
    _closed_form_eigenvalues(H, d, curvatures)
    lowest, largest = curvatures[d - 1], max(abs(curvatures[0]), abs(curvatures[d - 1]))
    for pair in range(d * (d - 1) // 2):
        lowest = min(lowest, pairs[pair, 0], pairs[pair, 1])
        largest = max(largest, abs(pairs[pair, 0]), abs(pairs[pair, 1]))
    if lowest > SCREEN_MARGIN * largest:
        return False
    _signed_svd(F, d, U, sigma, V, S)
    _singular_terms(model, sigma, d, mu, lam, H, pairs)
    if _positive_definite_small(H, d):  # no scaling mode to project: no eigenvectors; the trace bounds the largest
        trace = 0.0
        for k in range(d):
            trace += H[k, k]
        for k in range(d):
            curvatures[k] = trace
    else:
        _symmetric_eigen(H, d, curvatures, Z)
    size = d * d
    for k in range(d):
        values[k] = curvatures[k]
    for pair in range(d * (d - 1) // 2):
        values[d + 2 * pair], values[d + 2 * pair + 1] = pairs[pair, 0], pairs[pair, 1]
    largest = 0.0
    for k in range(size):
        largest = max(largest, abs(values[k]))
    changed = False
    for k in range(size):
        if values[k] >= -PSD_SHIFT * largest:
            continue
        changed = True
        # the mode's eigenvector, flattened as A is (F_ij -> i d + j)
        if k < d:
            for i in range(d):
                for j in range(d):
                    value = 0.0
                    for m in range(d):
                        value += Z[m, k] * U[i, m] * V[j, m]
                    vector[i * d + j] = value
        else:
            pair, sign = (k - d) // 2, (1.0 if (k - d) % 2 == 0 else -1.0)
            a, b = (0, 1) if pair == 0 else ((0, 2) if pair == 1 else (1, 2))
            for i in range(d):
                for j in range(d):
                    vector[i * d + j] = math.sqrt(0.5) * (U[i, a] * V[j, b] + sign * U[i, b] * V[j, a])
        change = -values[k] if mode == 1 else -2.0 * values[k]  # to 0, or to -lambda
        for row in range(size):
            scaled = change * vector[row]
            for column in range(size):
                A[row, column] += scaled * vector[column]
    return changed


@numba.njit(cache=True)
def _deformation_gradient(x, element, gradients, d, F):
    """F = sum_a x_a g_a^T of one element; x flat (n d,), gradients (d + 1, d) the g_a."""
    for i in range(d):
        for j in range(d):
            value = 0.0
            for a in range(d + 1):
                value += x[d * element[a] + i] * gradients[a, j]
            F[i, j] = value


@numba.njit(cache=True, parallel=True)
def element_energies(x, elements, shape_gradients, volumes, mu, lam, model):
    """V psi(F) of every element (J), shape (elements,)."""
    count, d = elements.shape[0], shape_gradients.shape[2]
    energies = np.empty(count)
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        F = np.empty((d, d))
        P = np.empty((d, d))
        A = np.empty((1, 1))
        work = np.empty((WORK_SLOTS, d, d))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], d, F)
            energies[e] = volumes[e] * material_terms(model, F, d, mu[e], lam[e], P, A, False, work)
    return energies


@numba.njit(cache=True, parallel=True)
def _element_forces(x, elements, shape_gradients, volumes, mu, lam, model, forces):
    """forces[e, a] = V P g_a, the gradient of element e's energy at its vertex a (N)."""
    count, d = elements.shape[0], shape_gradients.shape[2]
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        F = np.empty((d, d))
        P = np.empty((d, d))
        A = np.empty((1, 1))
        work = np.empty((WORK_SLOTS, d, d))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], d, F)
            material_terms(model, F, d, mu[e], lam[e], P, A, False, work)
            for a in range(d + 1):
                for i in range(d):
                    value = 0.0
                    for j in range(d):
                        value += P[i, j] * shape_gradients[e, a, j]
                    forces[e, a, i] = volumes[e] * value


@numba.njit(cache=True)
def elastic_gradient(x, elements, shape_gradients, volumes, mu, lam, model):
    """dPsi/dx of all elements (N), flat (n d,)."""
    count, d = elements.shape[0], shape_gradients.shape[2]
    forces = np.empty((count, d + 1, d))
    _element_forces(x, elements, shape_gradients, volumes, mu, lam, model, forces)
    gradient = np.zeros(x.size)
    for e in range(count):  # serial: the sum's order, and so its round-off, is the elements' order
        for a in range(d + 1):
            for i in range(d):
                gradient[d * elements[e, a] + i] += forces[e, a, i]
    return gradient


@numba.njit(cache=True)
def _tetrahedron_block(A, g, volume, AB, block):
    """block = V B^T A B of one tetrahedron (12 x 12), as in ``_element_hessians`` with the sizes written out, so that
    the compiler unrolls the short sums (a third of the general loop's time)."""
    for row in range(9):
        for b in range(4):
            for k in range(3):
                AB[row, 3 * b + k] = A[row, 3 * k] * g[b, 0] + A[row, 3 * k + 1] * g[b, 1] + A[row, 3 * k + 2] * g[b, 2]
    for a in range(4):
        for i in range(3):
            for column in range(12):
                block[3 * a + i, column] = volume * (g[a, 0] * AB[3 * i, column] + g[a, 1] * AB[3 * i + 1, column]
                                                     + g[a, 2] * AB[3 * i + 2, column])


@numba.njit(cache=True, parallel=True)
def _element_hessians(x, elements, shape_gradients, volumes, mu, lam, model, projection, blocks):
    """blocks[e] = V B^T A B, element e's Hessian ((d + 1) d square, vertex-major), A projected as asked."""
    count, d = elements.shape[0], shape_gradients.shape[2]
    size = d * d
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        F = np.empty((d, d))
        P = np.empty((d, d))
        A = np.empty((size, size))
        AB = np.empty((size, (d + 1) * d))
        work = np.empty((WORK_SLOTS, d, d))
        scratch = projection_scratch(d)
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], d, F)
            material_terms(model, F, d, mu[e], lam[e], P, A, True, work)
            project_tangent(model, F, d, mu[e], lam[e], A, projection, scratch)
            g = shape_gradients[e]
            if d == 3:
                _tetrahedron_block(A, g, volumes[e], AB, blocks[e])
                continue
            # AB[(i, j), (b, k)] = sum_l A[(i, j), (k, l)] g_b,l, then H[(a, i), (b, k)] = V sum_j g_a,j AB[(i, j), (b, k)]
            for row in range(size):
                for b in range(d + 1):
                    for k in range(d):
                        value = 0.0
                        for l in range(d):
                            value += A[row, k * d + l] * g[b, l]
                        AB[row, b * d + k] = value
            for a in range(d + 1):
                for i in range(d):
                    for column in range((d + 1) * d):
                        value = 0.0
                        for j in range(d):
                            value += g[a, j] * AB[i * d + j, column]
                        blocks[e, a * d + i, column] = volumes[e] * value


@numba.njit(cache=True)
def elastic_hessian_data(x, elements, shape_gradients, volumes, mu, lam, model, projection, positions, nnz, blocks):
    """The elastic Hessian's values in the fixed CSR pattern (N/m): positions (elements, k, k) map each entry of an
    element block (k = (d + 1) d) to its place in the pattern's data array of length nnz; blocks (elements, k, k) is
    the caller's scratch, kept from call to call."""
    count, d = elements.shape[0], shape_gradients.shape[2]
    k = (d + 1) * d
    _element_hessians(x, elements, shape_gradients, volumes, mu, lam, model, projection, blocks)
    data = np.zeros(nnz)
    for e in range(count):  # serial, in element order (as the gradient)
        for row in range(k):
            for column in range(k):
                data[positions[e, row, column]] += blocks[e, row, column]
    return data


@numba.njit(cache=True, parallel=True)
def volume_ratios(x, elements, shape_gradients):
    """J = det F of every element: its volume (area) over its rest volume."""
    count, d = elements.shape[0], shape_gradients.shape[2]
    ratios = np.empty(count)
    for e in numba.prange(count):
        F = np.empty((d, d))
        _deformation_gradient(x, elements[e], shape_gradients[e], d, F)
        ratios[e] = _determinant(F, d)
    return ratios


@numba.njit(cache=True)
def _first_root(c0, c1, c2, c3):
    """The smallest t in (0, 1] with c0 + c1 t + c2 t^2 + c3 t^3 = 0 (c0 > 0), or 2.0 if there is none: the cubic is
    monotone between the roots of its derivative, so each such interval holds at most one root, found by bisection."""
    cuts = [0.0]
    a, b, c = 3.0 * c3, 2.0 * c2, c1  # the derivative a t^2 + b t + c
    if a != 0.0:
        discriminant = b * b - 4.0 * a * c
        if discriminant >= 0.0:
            root = math.sqrt(discriminant)
            for t in sorted([(-b - root) / (2.0 * a), (-b + root) / (2.0 * a)]):
                if 0.0 < t < 1.0:
                    cuts.append(t)
    elif b != 0.0 and 0.0 < -c / b < 1.0:
        cuts.append(-c / b)
    cuts.append(1.0)
    for number in range(len(cuts) - 1):
        low, high = cuts[number], cuts[number + 1]
        value_high = c0 + high * (c1 + high * (c2 + high * c3))
        if value_high > 0.0:
            continue
        for _ in range(60):
            middle = 0.5 * (low + high)
            if c0 + middle * (c1 + middle * (c2 + middle * c3)) > 0.0:
                low = middle
            else:
                high = middle
        return low
    return 2.0


@numba.njit(cache=True, parallel=True)
def inversion_free_step(x, direction, elements, fraction):
    """The largest step t <= 1 along ``direction`` at which every element keeps ``fraction`` of its volume at x:
    det(D_s + t D_p) = fraction det(D_s) first, per element (D_s, D_p the edge matrices of x and of the direction).
    det(D_s + t D_p) = det D_s + t cof(D_s) : D_p + t^2 cof(D_p) : D_s + t^3 det D_p in 3-D (the t^2 term is
    det D_p and there is no t^3 term in 2-D), cof the cofactor matrix. Elements already at or below zero volume at x
    are not cut (nothing keeps them positive)."""
    count, d = elements.shape[0], elements.shape[1] - 1
    limits = np.empty(count)
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        Ds = np.empty((d, d))
        Dp = np.empty((d, d))
        C = np.empty((d, d))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            for a in range(d):
                for i in range(d):
                    Ds[i, a] = x[d * elements[e, a + 1] + i] - x[d * elements[e, 0] + i]
                    Dp[i, a] = direction[d * elements[e, a + 1] + i] - direction[d * elements[e, 0] + i]
            volume = _determinant(Ds, d)
            if not volume > 0.0:
                limits[e] = 2.0
                continue
            _cofactor(Ds, d, C)
            first = 0.0
            for i in range(d):
                for j in range(d):
                    first += C[i, j] * Dp[i, j]
            if d == 2:
                second, third = _determinant(Dp, d), 0.0
            else:
                _cofactor(Dp, d, C)
                second = 0.0
                for i in range(d):
                    for j in range(d):
                        second += C[i, j] * Ds[i, j]
                third = _determinant(Dp, d)
            limits[e] = _first_root(1.0 - fraction, first / volume, second / volume, third / volume)
    smallest = 1.0
    for e in range(count):
        smallest = min(smallest, limits[e])
    return smallest
