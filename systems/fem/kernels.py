"""Compiled element loops of the finite-element system: deformation gradients, the elements' energies, forces and
Hessian blocks, their scatter into the gradient and into the Hessian's fixed CSR pattern, volume ratios and the step
filter. The energy densities are in energies.py (each material's in materials/), the SPD projection in projection.py,
the small dense algebra in linalg.py.

Piecewise-linear simplices (triangles in 2-D, tetrahedra in 3-D) with one-point quadrature, which is exact: F is
constant on an element. With the rest shape's edge matrix D_m = [X_1 - X_0, ..., X_d - X_0] and g_a the rows of
D_m^-1 (a = 1..d), g_0 = -sum g_a,

    F = sum_a x_a g_a^T,   dPsi/dx_a = V P g_a,   d^2 Psi / dx_a dx_b = V [A : (g_a, g_b)],

with P = dpsi/dF (first Piola-Kirchhoff stress) and A = d^2 psi / dF^2. The SPD projection is of A (d^2 x d^2):
B^T A B with B = dF/dx onto F-space is PSD exactly when A is, so the element Hessian is left unchanged where it is
PSD.

Each loop over elements runs in parallel (``prange``): every element writes only its own rows, so the result does
not depend on the thread count; the scatters run serially in element order, so neither does round-off. The same
scatters take the shells' membrane triangles (membrane.py) and hinges (bending.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..compiled_cache import keep_fresh
from .energies import WORK_SLOTS, material_terms
from .linalg import _cofactor, _determinant
from .projection import project_tangent, projection_scratch

# elements per chunk of the parallel loops: the scratch arrays are made once per chunk, not once per element
CHUNK = 256


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
def element_forces(x, elements, shape_gradients, volumes, mu, lam, model, forces):
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
def scatter_forces(forces, elements, gradient):
    """gradient[d v + i] += forces[e, a, i] for each element e's vertex v = elements[e, a]: serial, in element order,
    so that the sum's order, and so its round-off, does not depend on the threads that made the forces."""
    count, corners, d = forces.shape
    for e in range(count):
        for a in range(corners):
            for i in range(d):
                gradient[d * elements[e, a] + i] += forces[e, a, i]


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
def element_hessians(x, elements, shape_gradients, volumes, mu, lam, model, projection, blocks):
    """blocks[e] = V B^T A B, element e's Hessian ((d + 1) d square, vertex-major), A projected as asked (0 none, 1
    clamp, 2 abs)."""
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
def scatter_blocks(blocks, positions, data):
    """data[positions[e, r, c]] += blocks[e, r, c]: the element blocks into the fixed CSR pattern's data array (positions
    from the pattern, made once), serial in element order (as the gradient)."""
    count, size = blocks.shape[0], blocks.shape[1]
    for e in range(count):
        for row in range(size):
            for column in range(size):
                data[positions[e, row, column]] += blocks[e, row, column]


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
def _critical_cuts(a, b, c):
    """[0, the roots of a t^2 + b t + c in (0, 1) ascending, 1]: the pieces of [0, 1] on which a polynomial whose
    derivative this is stays monotone."""
    cuts = [0.0]
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
    return cuts


@numba.njit(cache=True)
def cubic_crossings(c0, c1, c2, c3):
    """Where c0 + c1 t + c2 t^2 + c3 t^3 passes from > 0 to <= 0 or back in (0, 1], ascending: one per monotone
    piece at most (``_critical_cuts`` of its derivative), found by bisection; each the end of its bracket on the
    side of the piece's start."""
    cuts = _critical_cuts(3.0 * c3, 2.0 * c2, c1)
    crossings = [0.0 for _ in range(0)]
    for number in range(len(cuts) - 1):
        low, high = cuts[number], cuts[number + 1]
        start = c0 + low * (c1 + low * (c2 + low * c3)) > 0.0
        if (c0 + high * (c1 + high * (c2 + high * c3)) > 0.0) == start:
            continue
        for _ in range(60):
            middle = 0.5 * (low + high)
            if (c0 + middle * (c1 + middle * (c2 + middle * c3)) > 0.0) == start:
                low = middle
            else:
                high = middle
        crossings.append(low)
    return crossings


@numba.njit(cache=True)
def _first_root(c0, c1, c2, c3):
    """The smallest t in (0, 1] with c0 + c1 t + c2 t^2 + c3 t^3 <= 0 (c0 > 0), or 2.0 if there is none (its last
    point above 0: a step cut there keeps the element above the fraction). On [0, 1] the cubic is at least
    c0 + min(c1, 0) + min(c2, 0) + min(c3, 0): where that is above 0 (every element under a small step) there is no
    crossing, and the search's lists, which cost more than the rest of the filter, are not made."""
    if c0 + min(c1, 0.0) + min(c2, 0.0) + min(c3, 0.0) > 0.0:
        return 2.0
    crossings = cubic_crossings(c0, c1, c2, c3)
    return crossings[0] if len(crossings) else 2.0


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


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
