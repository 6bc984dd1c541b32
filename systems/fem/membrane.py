"""The membrane of a shell: the finite-element energies of each triangle's 3 x 2 deformation gradient, compiled with
numba (docs/fem.md, "Shells").

A triangle of a surface in 3-D has, at rest, a 2-D frame in its own plane (t_1 along its first edge, t_2 = n x t_1);
D_m holds its edges in that frame, and g_a are the rows of D_m^-1 as for a 2-D solid, so that F = sum_a x_a g_a^T is
3 x 2 and maps the rest plane onto the deformed triangle. C = F^T F (2 x 2) is all a membrane energy sees, which makes
it invariant to rotations of the deformed triangle, turning it over included. Each material's membrane form is in its
module (materials/): St. Venant-Kirchhoff's in Green's strain E = (C - I)/2, the others' as f(I_1, J) with I_1 = tr C
and J = sqrt(det C), the area ratio (materials/invariant_membrane.py derives P and A of those). A flattens F_ij
(i < 3, j < 2) to 2 i + j.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..compiled_cache import keep_fresh
from .kernels import cubic_crossings
from .linalg import project_dense
from .materials.dispatch import membrane_terms as material_membrane_terms

# an eigenvalue of the tangent above -PSD_SHIFT of the largest counts as 0 (as the solids' projection has it)
PSD_SHIFT = 1e-12
CHUNK = 256


@numba.njit(cache=True)
def membrane_terms(model, F, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3) of a 3 x 2 F, P = dpsi/dF into P (3, 2), and with want_tangent A = d^2 psi / dF^2 into A (6, 6);
    work (4, 3, 3) is scratch (C and the material's: S, or adj C, H, Q)."""
    C = work[0]
    for i in range(2):
        for j in range(2):
            value = 0.0
            for p in range(3):
                value += F[p, i] * F[p, j]
            C[i, j] = value
    I1 = C[0, 0] + C[1, 1]
    return material_membrane_terms(model, F, C, I1, mu, lam, P, A, want_tangent, work)


@numba.njit(cache=True)
def _deformation_gradient(x, element, gradients, F):
    """F = sum_a x_a g_a^T (3 x 2) of one triangle; x flat (3 n,), gradients (3, 2)."""
    for i in range(3):
        for j in range(2):
            F[i, j] = (x[3 * element[0] + i] * gradients[0, j] + x[3 * element[1] + i] * gradients[1, j]
                       + x[3 * element[2] + i] * gradients[2, j])


@numba.njit(cache=True, parallel=True)
def element_energies(x, elements, shape_gradients, weights, mu, lam, model):
    """w psi(F) of every triangle (J), w its rest area times the thickness."""
    count = elements.shape[0]
    energies = np.empty(count)
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        F, P, A, work = np.empty((3, 2)), np.empty((3, 2)), np.empty((1, 1)), np.empty((4, 3, 3))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], F)
            energies[e] = weights[e] * membrane_terms(model, F, mu[e], lam[e], P, A, False, work)
    return energies


@numba.njit(cache=True, parallel=True)
def element_forces(x, elements, shape_gradients, weights, mu, lam, model, forces):
    """forces[e, a] = w P g_a (N), the gradient of triangle e's energy at its vertex a."""
    count = elements.shape[0]
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        F, P, A, work = np.empty((3, 2)), np.empty((3, 2)), np.empty((1, 1)), np.empty((4, 3, 3))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], F)
            membrane_terms(model, F, mu[e], lam[e], P, A, False, work)
            for a in range(3):
                for i in range(3):
                    forces[e, a, i] = weights[e] * (P[i, 0] * shape_gradients[e, a, 0]
                                                    + P[i, 1] * shape_gradients[e, a, 1])


@numba.njit(cache=True, parallel=True)
def element_hessians(x, elements, shape_gradients, weights, mu, lam, model, projection, blocks):
    """blocks[e] = w B^T A B (9 x 9, vertex-major), A projected to PSD as asked (0 none, 1 clamp, 2 abs) by its own
    eigensystem: B = dF/dx maps the triangle's 9 coordinates onto all 3 x 2 matrices, so B^T A B is PSD exactly
    when A is."""
    count = elements.shape[0]
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        F, P, A, work = np.empty((3, 2)), np.empty((3, 2)), np.empty((6, 6)), np.empty((4, 3, 3))
        scratch, vectors, values = np.empty((6, 6)), np.empty((6, 6)), np.empty(12)
        AB = np.empty((6, 9))
        for e in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _deformation_gradient(x, elements[e], shape_gradients[e], F)
            membrane_terms(model, F, mu[e], lam[e], P, A, True, work)
            project_dense(A, 6, projection, PSD_SHIFT, scratch, values, vectors)
            g = shape_gradients[e]
            # AB[(i, j), (b, k)] = sum_l A[(i, j), (k, l)] g_b,l; H[(a, i), (b, k)] = w sum_j g_a,j AB[(i, j), (b, k)]
            for row in range(6):
                for b in range(3):
                    for k in range(3):
                        AB[row, 3 * b + k] = A[row, 2 * k] * g[b, 0] + A[row, 2 * k + 1] * g[b, 1]
            for a in range(3):
                for i in range(3):
                    for column in range(9):
                        blocks[e, 3 * a + i, column] = weights[e] * (g[a, 0] * AB[2 * i, column]
                                                                     + g[a, 1] * AB[2 * i + 1, column])


@numba.njit(cache=True, parallel=True)
def area_ratios(x, elements, shape_gradients):
    """J = sqrt(det F^T F) of every triangle: its area over its rest area."""
    count = elements.shape[0]
    ratios = np.empty(count)
    for e in numba.prange(count):
        F = np.empty((3, 2))
        _deformation_gradient(x, elements[e], shape_gradients[e], F)
        c00 = F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0]
        c01 = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
        c11 = F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1]
        ratios[e] = math.sqrt(max(c00 * c11 - c01 * c01, 0.0))
    return ratios


@numba.njit(cache=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def _first_crossing(q0, q1, q2, q3, q4):
    """The smallest t in (0, 1] where the quartic q0 + q1 t + ... + q4 t^4 (q0 > 0) reaches 0 (its last point above),
    or 2.0 if it stays positive: its derivative's roots (a cubic's, kernels.cubic_crossings) split [0, 1] into
    pieces on which it is monotone, and each piece is bisected for a sign change."""
    cuts = [0.0]
    for t in cubic_crossings(q1, 2.0 * q2, 3.0 * q3, 4.0 * q4):
        cuts.append(t)
    cuts.append(1.0)
    for number in range(len(cuts) - 1):
        low, high = cuts[number], cuts[number + 1]
        if q0 + high * (q1 + high * (q2 + high * (q3 + high * q4))) > 0.0:
            continue
        for _ in range(60):
            middle = 0.5 * (low + high)
            if q0 + middle * (q1 + middle * (q2 + middle * (q3 + middle * q4))) > 0.0:
                low = middle
            else:
                high = middle
        return low
    return 2.0


@numba.njit(cache=True, parallel=True)
def area_keeping_step(x, direction, elements, fraction):
    """The largest step t <= 1 along ``direction`` at which every triangle keeps ``fraction`` of its area at x: its
    normal N(t) = (e_1 + t p_1) x (e_2 + t p_2) = N + t (e_1 x p_2 + p_1 x e_2) + t^2 p_1 x p_2 is quadratic in t,
    so |N(t)|^2 - fraction^2 |N|^2 is a quartic, whose first root in (0, 1] is the limit. Triangles of no area at x
    are not cut."""
    count = elements.shape[0]
    limits = np.empty(count)
    for e in numba.prange(count):
        v0, v1, v2 = elements[e, 0], elements[e, 1], elements[e, 2]
        e1 = (x[3 * v1] - x[3 * v0], x[3 * v1 + 1] - x[3 * v0 + 1], x[3 * v1 + 2] - x[3 * v0 + 2])
        e2 = (x[3 * v2] - x[3 * v0], x[3 * v2 + 1] - x[3 * v0 + 1], x[3 * v2 + 2] - x[3 * v0 + 2])
        p1 = (direction[3 * v1] - direction[3 * v0], direction[3 * v1 + 1] - direction[3 * v0 + 1],
              direction[3 * v1 + 2] - direction[3 * v0 + 2])
        p2 = (direction[3 * v2] - direction[3 * v0], direction[3 * v2 + 1] - direction[3 * v0 + 1],
              direction[3 * v2 + 2] - direction[3 * v0 + 2])
        n0 = _cross(e1[0], e1[1], e1[2], e2[0], e2[1], e2[2])
        a = _cross(e1[0], e1[1], e1[2], p2[0], p2[1], p2[2])
        b = _cross(p1[0], p1[1], p1[2], e2[0], e2[1], e2[2])
        n1 = (a[0] + b[0], a[1] + b[1], a[2] + b[2])
        n2 = _cross(p1[0], p1[1], p1[2], p2[0], p2[1], p2[2])
        squared = n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]
        if not squared > 0.0:
            limits[e] = 2.0
            continue
        q1 = 2.0 * (n0[0] * n1[0] + n0[1] * n1[1] + n0[2] * n1[2])
        q2 = (n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]) + 2.0 * (n0[0] * n2[0] + n0[1] * n2[1] + n0[2] * n2[2])
        q3 = 2.0 * (n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2])
        q4 = n2[0] * n2[0] + n2[1] * n2[1] + n2[2] * n2[2]
        limits[e] = _first_crossing(1.0 - fraction * fraction, q1 / squared, q2 / squared, q3 / squared, q4 / squared)
    smallest = 1.0
    for e in range(count):
        smallest = min(smallest, limits[e])
    return smallest


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
