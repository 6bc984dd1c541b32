"""The compiled parts of vertex block descent's step that do not depend on the potential (solvers/vbd.py has the method):
the incremental potential's inertia and damping at one vertex, the constraint filter, the determinant floor and the
d x d solve, and the change of the inertia and damping when the vertex moves. Each system's colour sweep
(mass_spring/vbd_kernels.py, fem/vbd_kernels.py, fem/shell_vbd_kernels.py) adds its own terms' g_i, H_i and change of P
around these. They are inlined into the sweeps: a call per vertex that takes arrays costs numba their reference counts
(docs/performance.md, "Vertex block descent and XPBD kernels").

With E(y) = 1/2 (y - y~)^T M (y - y~) + s P(y) + w [1/2 (y - a)^T D (y - a)] (w = s/b, D the damping matrix):

    g_i = M_i (y_i - y~_i) + s dP/dy_i + w (D (y - a))_i,    H_i = M_i + s d^2P/dy_i^2 + w D_ii,
    dE_i(u) = u^T M_i (y_i - y~_i + u/2) + s dP_i(u) + w [u^T (D (y - a))_i + u^T D_ii u / 2].
"""

from __future__ import annotations

import math

import numba

from .compiled_cache import keep_fresh
from .constraints import filter_in_place


@numba.njit(cache=True, error_model="numpy")
def filtered_eigenvalue(value, projection):
    """An eigenvalue of a term's block as the projection code asks: as it is (0), clamped at 0 (1), mirrored (2)."""
    if projection == 1:
        return max(value, 0.0)
    if projection == 2:
        return abs(value)
    return value


@numba.njit(cache=True, error_model="numpy", inline="always")
def block_determinant(H, d):
    if d == 1:
        return H[0, 0]
    if d == 2:
        return H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
    return (H[0, 0] * (H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1]) - H[0, 1] * (H[1, 0] * H[2, 2] - H[1, 2] * H[2, 0])
            + H[0, 2] * (H[1, 0] * H[2, 1] - H[1, 1] * H[2, 0]))


@numba.njit(cache=True, error_model="numpy", inline="always")
def solve_block(H, g, u, work, d):
    """u = -H^-1 g by Gaussian elimination with partial pivoting (as LAPACK's); work (d, d + 1) scratch."""
    for r in range(d):
        for c in range(d):
            work[r, c] = H[r, c]
        work[r, d] = -g[r]
    for c in range(d):
        pivot = c
        for r in range(c + 1, d):
            if abs(work[r, c]) > abs(work[pivot, c]):
                pivot = r
        if pivot != c:
            for k in range(d + 1):
                work[c, k], work[pivot, k] = work[pivot, k], work[c, k]
        for r in range(c + 1, d):
            factor = work[r, c] / work[c, c]
            for k in range(c, d + 1):
                work[r, k] -= factor * work[c, k]
    for r in range(d - 1, -1, -1):
        total = work[r, d]
        for k in range(r + 1, d):
            total -= work[r, k] * u[k]
        u[r] = total / work[r, r]


@numba.njit(cache=True, error_model="numpy", inline="always")
def finish_blocks(i, y, d, y_tilde, mass, scale, damping_indptr, damping_indices, damping_data, damping_weight,
                  velocity_origin, g, H, rate, D):
    """g, H hold dP/dy_i and d^2P/dy_i^2 (the potential's, unscaled): made E's, in place; the damping's rates
    (D (y - a))_i and block D_ii into rate, D (what ``inertia_change`` reads)."""
    for a in range(d):
        g[a] = mass[d * i + a] * (y[d * i + a] - y_tilde[d * i + a]) + scale * g[a]
        for b in range(d):
            H[a, b] *= scale
        H[a, a] += mass[d * i + a]
    for a in range(d):
        rate[a] = 0.0
        for b in range(d):
            D[a, b] = 0.0
    if damping_weight != 0.0:
        for a in range(d):
            row = d * i + a
            total = 0.0
            for q in range(damping_indptr[row], damping_indptr[row + 1]):
                column = damping_indices[q]
                total += damping_data[q] * (y[column] - velocity_origin[column])
                if d * i <= column < d * i + d:
                    D[a, column - d * i] = damping_data[q]
            rate[a] = total
            g[a] += damping_weight * total
        for a in range(d):
            for b in range(d):
                H[a, b] += damping_weight * D[a, b]


@numba.njit(cache=True, error_model="numpy", inline="always")
def newton_step(H, g, u, constrained, S, determinant_floor, d, filtered, filtered_vector, work):
    """u = -H^-1 g for one vertex: with a filter S (``constrained``) the minimiser over y_i + range(S) of the quadratic
    model, (S H S + c (I - S)) u = -S g, c H's mean |diagonal|; u = 0 where |det H| <= floor |H|_F^d or anything is
    not finite. H and g are changed. Returns |S g|_inf (inf where g is not finite): the vertex's part of the sweep's
    residual (solvers/vbd.py)."""
    if constrained:
        mean = 0.0
        for a in range(d):
            mean += abs(H[a, a])
        mean /= d
        if not mean > 0.0:
            mean = 1.0
        for a in range(d):
            for b in range(d):
                total = 0.0
                for p in range(d):
                    for q in range(d):
                        total += S[a, p] * H[p, q] * S[q, b]
                filtered[a, b] = total + mean * ((1.0 if a == b else 0.0) - S[a, b])
        for a in range(d):
            for b in range(d):
                H[a, b] = filtered[a, b]
        filter_in_place(S, g, filtered_vector, d)
    determinant = block_determinant(H, d)
    size = 0.0
    finite = True
    gradient_norm = 0.0
    for a in range(d):
        finite = finite and math.isfinite(g[a])
        gradient_norm = max(gradient_norm, abs(g[a]))
        for b in range(d):
            size += H[a, b] * H[a, b]
    size = math.sqrt(size)
    bound = determinant_floor  # floor |H|_F^d multiplied out: a pow per vertex cost a third of the sweep
    for a in range(d):
        bound *= size
    if abs(determinant) > bound and math.isfinite(determinant) and finite:
        solve_block(H, g, u, work, d)
    else:
        for a in range(d):
            u[a] = 0.0
    if constrained:
        filter_in_place(S, u, filtered_vector, d)
    return gradient_norm if finite else math.inf


@numba.njit(cache=True, error_model="numpy", inline="always")
def inertia_change(i, u, y, d, y_tilde, mass):
    """u^T M_i (y_i - y~_i + u/2), the inertia's part of E's change (added first, as the numpy form adds it)."""
    inertia = 0.0
    for a in range(d):
        inertia += mass[d * i + a] * u[a] * (y[d * i + a] - y_tilde[d * i + a] + 0.5 * u[a])
    return inertia


@numba.njit(cache=True, error_model="numpy", inline="always")
def damping_change(u, d, damping_weight, rate, D):
    """w [u^T (D (y - a))_i + u^T D_ii u / 2], the damping's part of E's change (added last)."""
    if damping_weight == 0.0:
        return 0.0
    linear = 0.0
    quadratic = 0.0
    for a in range(d):
        linear += u[a] * rate[a]
        for b in range(d):
            quadratic += u[a] * D[a, b] * u[b]
    return damping_weight * (linear + 0.5 * quadratic)


@numba.njit(cache=True, error_model="numpy", inline="always")
def take_step(y, i, u, d, change):
    """y_i += u where the backtracking accepted u (E's change <= 0); a step whose change stayed above 0 (or NaN) after
    the last halving is dropped."""
    if change <= 0.0:
        for a in range(d):
            y[d * i + a] += u[a]


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
