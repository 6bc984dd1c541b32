"""Compiled element loops of the finite-element system: deformation gradients, energy densities, stresses, tangents,
their SPD projection, and the scatter into the gradient and into the Hessian's fixed CSR pattern.

Piecewise-linear simplices (triangles in 2-D, tetrahedra in 3-D) with one-point quadrature, which is exact: F is
constant on an element. With the rest shape's edge matrix D_m = [X_1 - X_0, ..., X_d - X_0] and g_a the rows of
D_m^-1 (a = 1..d), g_0 = -sum g_a,

    F = sum_a x_a g_a^T,   dPsi/dx_a = V P g_a,   d^2 Psi / dx_a dx_b = V [A : (g_a, g_b)],

with P = dpsi/dF (first Piola-Kirchhoff stress) and A = d^2 psi / dF^2 (flattened row-major, F_ij -> i d + j).
The SPD projection is of A (d^2 x d^2): B^T A B with B = dF/dx onto F-space is PSD exactly when A is, so the
element Hessian is left unchanged where it is PSD. Energy densities (docs/fem.md), Lame mu and lambda per element:

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
def _rotation(F, d, U, sigma, V):
    """The signed SVD F = U diag(sigma) V^T with U, V rotations (the smallest sigma takes the sign of det F); R = U V^T."""
    u, s, vt = np.linalg.svd(F)
    for i in range(d):
        sigma[i] = s[i]
        for j in range(d):
            U[i, j] = u[i, j]
            V[i, j] = vt[j, i]
    if _determinant(U, d) < 0.0:
        for i in range(d):
            U[i, d - 1] = -U[i, d - 1]
        sigma[d - 1] = -sigma[d - 1]
    if _determinant(V, d) < 0.0:
        for i in range(d):
            V[i, d - 1] = -V[i, d - 1]
        sigma[d - 1] = -sigma[d - 1]


@numba.njit(cache=True)
def material_terms(model, F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P = dpsi/dF into P (d, d), and with want_tangent A = d^2 psi / dF^2 into A (d^2, d^2); work
    (3, d, d) is scratch (the cofactor, Green's strain and its stress), so that an element allocates nothing."""
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
        U = np.empty((d, d))
        V = np.empty((d, d))
        sigma = np.empty(d)
        _rotation(F, d, U, sigma, V)
        R = np.empty((d, d))
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


# A + PSD_SHIFT tr(A)/size I positive definite counts as PSD: its lowest eigenvalue is then above -PSD_SHIFT of the
# mean, a round-off's worth (the rotation-invariant energies' A is singular at rest: rigid rotations cost nothing)
PSD_SHIFT = 1e-12


@numba.njit(cache=True)
def _positive_definite(A, size):
    """Whether A + shift I has a Cholesky factor (the factor is formed in a scratch copy of the lower triangle)."""
    trace = 0.0
    for a in range(size):
        trace += A[a, a]
    if not trace > 0.0:
        return False
    shift = PSD_SHIFT * trace / size
    L = np.empty((size, size))
    for a in range(size):
        for b in range(a + 1):
            total = A[a, b] + (shift if a == b else 0.0)
            for c in range(b):
                total -= L[a, c] * L[b, c]
            if a == b:
                if not total > 0.0:
                    return False
                L[a, a] = math.sqrt(total)
            else:
                L[a, b] = total / L[b, b]
    return True


@numba.njit(cache=True)
def _project(A, size, mode):
    """A's eigenvalues clamped at 0 (mode 1) or mirrored (mode 2), in place; mode 0: as it is."""
    if mode == 0:
        return
    for a in range(size):  # symmetric to round-off: the exact symmetric part goes to LAPACK
        for b in range(a + 1, size):
            mean = 0.5 * (A[a, b] + A[b, a])
            A[a, b] = mean
            A[b, a] = mean
    if _positive_definite(A, size):  # nothing to project: the common case, at a tenth of an eigendecomposition
        return
    values, vectors = np.linalg.eigh(A)
    if mode == 1 and values[0] >= 0.0:
        return
    for a in range(size):
        values[a] = max(values[a], 0.0) if mode == 1 else abs(values[a])
    for a in range(size):
        for b in range(size):
            total = 0.0
            for c in range(size):
                total += vectors[a, c] * values[c] * vectors[b, c]
            A[a, b] = total


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
        work = np.empty((3, d, d))
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
        work = np.empty((3, d, d))
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
        work = np.empty((3, d, d))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], d, F)
            material_terms(model, F, d, mu[e], lam[e], P, A, True, work)
            _project(A, size, projection)
            g = shape_gradients[e]
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
