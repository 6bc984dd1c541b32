"""A tetrahedron's neo-Hookean terms at one vertex, from the invariants, for vertex block descent (vbd_kernels.py, whose
docstring derives them): P n and K = d^2 psi / dx_i^2 straight from J, I_C, w = F n and c = cof(F) n, with no tangent
and no full P (``invariant_terms``); the same for a tetrahedron written out in scalars, with K's projection in closed
form (``invariant_terms_3d``), and a vertex's sum over its tetrahedra kept in registers (``invariant_elements_3d``);
the energy's change when the vertex alone moves, from the exact changes of I_C and J (``invariant_change_3d``). Each
material's own coefficients and change are in its module (materials/), through the dispatch's
``invariant_coefficients`` and ``invariant_change``. All but ``invariant_terms`` are inlined into the sweep."""

from __future__ import annotations

import numba

from ..compiled_cache import keep_fresh
from .linalg import _cofactor, _determinant
from .materials.dispatch import invariant_change, invariant_coefficients


@numba.njit(cache=True, error_model="numpy")
def invariant_terms(model, F, n, d, mu, lam, alpha, C, w, c, stress, K):
    """The neo-Hookean energies' P n (into stress) and K straight from the invariants (w = F n and c = cof(F) n into
    w, c; C scratch): no tangent, no full P. Returns J and what ``invariant_blocks`` returns."""
    J = _determinant(F, d)
    _cofactor(F, d, C)
    invariant, squared = 0.0, 0.0
    for i in range(d):
        squared += n[i] * n[i]
        along, volume = 0.0, 0.0
        for j in range(d):
            invariant += F[i, j] * F[i, j]
            along += F[i, j] * n[j]
            volume += C[i, j] * n[j]
        w[i], c[i] = along, volume
    return J, invariant_blocks(model, J, invariant, squared, d, mu, lam, alpha, w, c, stress, K)


@numba.njit(cache=True, error_model="numpy", inline="always")
def invariant_terms_3d(y, elements, shape_gradients, p, model, mu, lam, alpha, projection):
    """``invariant_terms`` of row p's tetrahedron (its corner 0 the vertex) written out in scalars (F's columns f_j,
    cof(F) = [f1 x f2, f2 x f0, f0 x f1]), with K's projection in closed form where it has one: the same numbers to
    round-off at a third of the cost of the loops over d. Returns (J, the kept value, w = F n, c = cof(F) n, and the
    coefficients of P n = shear w + volume_stress c and K = diagonal I + stretch w w^T + spread c c^T: shear,
    volume_stress, diagonal, stretch, spread)."""
    v0, v1, v2, v3 = 3 * elements[p, 0], 3 * elements[p, 1], 3 * elements[p, 2], 3 * elements[p, 3]
    g00, g01, g02 = shape_gradients[p, 0, 0], shape_gradients[p, 0, 1], shape_gradients[p, 0, 2]
    g10, g11, g12 = shape_gradients[p, 1, 0], shape_gradients[p, 1, 1], shape_gradients[p, 1, 2]
    g20, g21, g22 = shape_gradients[p, 2, 0], shape_gradients[p, 2, 1], shape_gradients[p, 2, 2]
    g30, g31, g32 = shape_gradients[p, 3, 0], shape_gradients[p, 3, 1], shape_gradients[p, 3, 2]
    x0, x1, x2, x3 = y[v0], y[v1], y[v2], y[v3]
    f00 = x0 * g00 + x1 * g10 + x2 * g20 + x3 * g30
    f01 = x0 * g01 + x1 * g11 + x2 * g21 + x3 * g31
    f02 = x0 * g02 + x1 * g12 + x2 * g22 + x3 * g32
    x0, x1, x2, x3 = y[v0 + 1], y[v1 + 1], y[v2 + 1], y[v3 + 1]
    f10 = x0 * g00 + x1 * g10 + x2 * g20 + x3 * g30
    f11 = x0 * g01 + x1 * g11 + x2 * g21 + x3 * g31
    f12 = x0 * g02 + x1 * g12 + x2 * g22 + x3 * g32
    x0, x1, x2, x3 = y[v0 + 2], y[v1 + 2], y[v2 + 2], y[v3 + 2]
    f20 = x0 * g00 + x1 * g10 + x2 * g20 + x3 * g30
    f21 = x0 * g01 + x1 * g11 + x2 * g21 + x3 * g31
    f22 = x0 * g02 + x1 * g12 + x2 * g22 + x3 * g32
    n0, n1, n2 = g00, g01, g02  # the vertex's own shape gradient
    # cofactor columns: C[:, 0] = f1 x f2, C[:, 1] = f2 x f0, C[:, 2] = f0 x f1 (f_j = F[:, j])
    c00, c10, c20 = f11 * f22 - f21 * f12, f21 * f02 - f01 * f22, f01 * f12 - f11 * f02
    c01, c11, c21 = f12 * f20 - f22 * f10, f22 * f00 - f02 * f20, f02 * f10 - f12 * f00
    c02, c12, c22 = f10 * f21 - f20 * f11, f20 * f01 - f00 * f21, f00 * f11 - f10 * f01
    J = f00 * c00 + f10 * c10 + f20 * c20
    invariant = (f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12 + f20 * f20 + f21 * f21
                 + f22 * f22)
    w0, w1, w2 = f00 * n0 + f01 * n1 + f02 * n2, f10 * n0 + f11 * n1 + f12 * n2, f20 * n0 + f21 * n1 + f22 * n2
    a0, a1, a2 = c00 * n0 + c01 * n1 + c02 * n2, c10 * n0 + c11 * n1 + c12 * n2, c20 * n0 + c21 * n1 + c22 * n2
    squared = n0 * n0 + n1 * n1 + n2 * n2
    shear, stretch, spread, volume_stress, kept = invariant_coefficients(model, J, invariant, mu, lam, alpha)
    diagonal = shear * squared
    if projection != 0 and spread < 0.0:
        # K = shear |n|^2 I + stretch w w^T + spread c c^T with shear, stretch >= 0. Only the neo-Hookean K (stretch 0)
        # gets here: its eigenvalue along c is shear |n|^2 + spread |c|^2 (across c: shear |n|^2), so the projection
        # moves that one. The stable neo-Hookean spread is its lambda, above 0 for every nu > -1
        # (materials/stable_neo_hookean.py).
        along = a0 * a0 + a1 * a1 + a2 * a2
        lowest = diagonal + spread * along
        if lowest < 0.0:
            spread = ((0.0 if projection == 1 else -lowest) - diagonal) / along
    return J, kept, w0, w1, w2, a0, a1, a2, shear, volume_stress, diagonal, stretch, spread


@numba.njit(cache=True, error_model="numpy", inline="always")
def invariant_elements_3d(i, y, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, projection, ws, cs,
                           Js, kept):
    """The real-time case, the neo-Hookean energies on tetrahedra, in scalars: (dP_el/dy_i, the upper triangle of the
    sum of the elements' projected K: h00, h01, h02, h11, h12, h22); each element's w, c, J and kept value into ws,
    cs, Js and kept. The sums stay in registers: summed in arrays, each element's blocks were stored and loaded again
    (numba cannot tell those arrays from y): nearly twice the cost of the vertex blocks."""
    g0 = g1 = g2 = 0.0
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        slot = p - indptr[i]
        J, value, w0, w1, w2, a0, a1, a2, shear, volume_stress, diagonal, stretch, spread = invariant_terms_3d(
            y, elements, shape_gradients, p, model, mu[p], lam[p], alpha[p], projection)
        ws[slot, 0], ws[slot, 1], ws[slot, 2] = w0, w1, w2
        cs[slot, 0], cs[slot, 1], cs[slot, 2] = a0, a1, a2
        Js[slot], kept[slot] = J, value
        volume = volumes[p]
        g0 += volume * (shear * w0 + volume_stress * a0)
        g1 += volume * (shear * w1 + volume_stress * a1)
        g2 += volume * (shear * w2 + volume_stress * a2)
        h00 += volume * (diagonal + stretch * w0 * w0 + spread * a0 * a0)
        h11 += volume * (diagonal + stretch * w1 * w1 + spread * a1 * a1)
        h22 += volume * (diagonal + stretch * w2 * w2 + spread * a2 * a2)
        h01 += volume * (stretch * w0 * w1 + spread * a0 * a1)
        h02 += volume * (stretch * w0 * w2 + spread * a0 * a2)
        h12 += volume * (stretch * w1 * w2 + spread * a1 * a2)
    return g0, g1, g2, h00, h01, h02, h11, h12, h22


@numba.njit(cache=True, error_model="numpy", inline="always")
def set_blocks(g, H, g0, g1, g2, h00, h01, h02, h11, h12, h22):
    """g = (g0, g1, g2) and the symmetric H of its upper triangle."""
    g[0], g[1], g[2] = g0, g1, g2
    H[0, 0], H[1, 1], H[2, 2] = h00, h11, h22
    H[0, 1] = H[1, 0] = h01
    H[0, 2] = H[2, 0] = h02
    H[1, 2] = H[2, 1] = h12


@numba.njit(cache=True, error_model="numpy", inline="always")
def invariant_blocks(model, J, invariant, squared, d, mu, lam, alpha, w, c, stress, K):
    """P n (into stress) and K of the neo-Hookean energies from J, I_C, |n|^2, w and c; returns the kept value
    (the dispatch's ``invariant_coefficients``)."""
    shear, stretch, spread, volume_stress, kept = invariant_coefficients(model, J, invariant, mu, lam, alpha)
    diagonal = shear * squared
    for i in range(d):
        stress[i] = shear * w[i] + volume_stress * c[i]
        for k in range(d):
            K[i, k] = stretch * w[i] * w[k] + spread * c[i] * c[k]
        K[i, i] += diagonal
    return kept


@numba.njit(cache=True, error_model="numpy", inline="always")
def invariant_change_3d(i, u0, u1, u2, indptr, shape_gradients, volumes, mu, lam, alpha, model, ws, cs, Js, kept):
    """``_elastic_change`` of the neo-Hookean energies on tetrahedra, from what ``invariant_elements_3d`` kept."""
    squared_u = u0 * u0 + u1 * u1 + u2 * u2
    total = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        slot = p - indptr[i]
        n0, n1, n2 = shape_gradients[p, 0, 0], shape_gradients[p, 0, 1], shape_gradients[p, 0, 2]
        total += volumes[p] * invariant_change(
            model, Js[slot], kept[slot], 2.0 * (u0 * ws[slot, 0] + u1 * ws[slot, 1] + u2 * ws[slot, 2])
            + squared_u * (n0 * n0 + n1 * n1 + n2 * n2), u0 * cs[slot, 0] + u1 * cs[slot, 1] + u2 * cs[slot, 2],
            mu[p], lam[p], alpha[p])
    return total


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
