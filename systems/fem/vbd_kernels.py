"""Vertex block descent on a finite-element solid, compiled: each vertex's gradient and d x d Hessian
block from the elements around it, the change of the elastic energy when the vertex alone moves, the fraction of its
step that keeps those elements' volumes, and one colour's sweep (solvers/vbd.py has the method).

Vertex i is corner a of element e with shape gradient n = g_a (kernels.py). Moving the vertex alone by u changes the
element's deformation gradient by a rank-one term, F' = F + u n^T, so

    dPsi_e/dx_i = V P n,    d^2 Psi_e / dx_i^2 = V K,  K_ik = sum_jl n_j A_(ij)(kl) n_l  (A = d^2 psi / dF^2).

K has a closed form for the invariant-based energies (docs/fem.md, "Vertex block descent"; each material's module has
its own); with w = F n, c = cof(F) n
(cof(F) = J F^-T), |n|^2 = n . n, and the cofactor's derivative contracted with n n vanishing (eps_jkl n_j n_k = 0):

- LINEAR:             mu |n|^2 I + (mu + lambda) n n^T
- STVK:               (n^T S n) I + (mu + lambda) w w^T + mu |n|^2 F F^T,   S = 2 mu E + lambda tr(E) I
- NEO_HOOKEAN:        mu |n|^2 I + (mu + lambda (1 - ln J)) / J^2 c c^T
- STABLE_NEO_HOOKEAN: (mu - mu / (I_C + 1)) |n|^2 I + 2 mu / (I_C + 1)^2 w w^T + lambda c c^T
- COROTATED:          the contraction of its exact tangent A, which needs the SVD's rotation derivative.

Each element's K is projected to SPD on its own (clamp or mirror its negative eigenvalues), as the springs' blocks are
in the mass-spring sweep (Chen et al., "Vertex block descent", 2024: the vertex's Hessian is the sum of its elements'
blocks): the diagonal block of the element's projected 12 x 12 Hessian would cost an eigensystem of A per element and
vertex, four times per sweep.

The energy change is formed without cancellation from the exact changes of the invariants, I_C' - I_C = 2 u . w +
|u|^2 |n|^2 and J' - J = c . u (the matrix determinant lemma: exact, J is linear in u), and for St. Venant-Kirchhoff
and linear elasticity from the strain's change; the co-rotated energy's is the difference of the element's energies.
J' = J + t c . u also gives the exact largest fraction t of the step that keeps every element at the vertex above
``kept_volume`` of its volume (the step filter, systems/fem/system.py ``max_step``).

The colliders' terms (penalty or IPC barrier) are those of systems/contact/point_kernels.py, added at each vertex with
its elements' before the step. The parallel loops run over chunks of vertices (one colour's, or the asked ones); every vertex's numbers are its own,
in a fixed order, so the result does not depend on the thread count.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from ..compiled_cache import keep_fresh
from ..contact.point_kernels import (add_vertex_terms, beyond_reach, may_reach, point_scratch, vertex_change,
                                     vertex_impact_fraction)
from ..vertex_kernels import damping_change, finish_blocks, inertia_change, newton_step, take_step
from .energies import WORK_SLOTS, material_terms
from .linalg import _cofactor, _determinant, _symmetric_eigen
from .materials.dispatch import (invariant_change, vertex_energy_change, vertex_stiffness_needs_tangent,
                                 vertex_terms_from_invariants)
from .materials.dispatch import vertex_stiffness as material_vertex_stiffness
from .tet_terms import invariant_change_3d, invariant_elements_3d, invariant_terms, set_blocks

# vertices per chunk of the parallel loops: the scratch arrays are made once per chunk, not per vertex (their 30-odd
# allocations cost as much as several vertices' terms)
CHUNK = 64


@numba.njit(cache=True, error_model="numpy")
def _scratch(d, max_degree):
    """One chunk's arrays: each incident element's F, w = F n, c = cof(F) n, J and its energy's kept value (ln J or
    1 / (I_C + 1), ``invariant_blocks``); P, A, the material's work, K
    and its eigensystem, a moved F (the co-rotated change), P n; one element's F, n, w and c.

    The loops index these whole arrays and copy one element's values in and out: a view per element (``Fs[slot]``)
    costs numba two atomic reference counts, which had been most of the sweep's time."""
    return (np.empty((max_degree, d, d)), np.empty((max_degree, d)), np.empty((max_degree, d)), np.empty(max_degree),
            np.empty(max_degree), np.empty((d, d)), np.empty((d * d, d * d)), np.empty((WORK_SLOTS, d, d)),
            np.empty((d, d)), np.empty((d, d)), np.empty(d), np.empty((d, d)), np.empty((d, d)), np.empty(d),
            np.empty((d, d)), np.empty(d), np.empty(d), np.empty(d))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _element_gradient(x, elements, shape_gradients, e, d, F):
    """F = sum_a x_a g_a^T of element e (kernels.py's, indexing the whole arrays)."""
    for i in range(d):
        for j in range(d):
            value = 0.0
            for a in range(d + 1):
                value += x[d * elements[e, a] + i] * shape_gradients[e, a, j]
            F[i, j] = value


@numba.njit(cache=True, error_model="numpy")
def vertex_stiffness(model, F, n, d, mu, lam, A, K, work):
    """K = n^T A n (d, d) at F, in closed form but where the material contracts its exact tangent A (the co-rotated
    energy's: ``vertex_stiffness_needs_tangent``), which the caller has computed."""
    squared = 0.0
    for j in range(d):
        squared += n[j] * n[j]
    for i in range(d):
        for k in range(d):
            K[i, k] = 0.0
    material_vertex_stiffness(model, F, n, d, squared, mu, lam, A, K, work)


@numba.njit(cache=True, error_model="numpy", inline="always")
def project_block(K, d, projection, copy, values, vectors):
    """K made SPD in place: its negative eigenvalues clamped to 0 (projection 1) or mirrored (2); left as it is where
    it is positive definite or projection is 0."""
    if projection == 0:
        return
    # positive definite by its leading minors (linalg's _positive_definite_small, here inlined: a call per element
    # costs more than the test)
    if K[0, 0] > 0.0:
        minor = K[0, 0] * K[1, 1] - K[0, 1] * K[1, 0]
        if minor > 0.0 and (d == 2 or (K[0, 0] * (K[1, 1] * K[2, 2] - K[1, 2] * K[2, 1])
                                       - K[0, 1] * (K[1, 0] * K[2, 2] - K[1, 2] * K[2, 0])
                                       + K[0, 2] * (K[1, 0] * K[2, 1] - K[1, 1] * K[2, 0])) > 0.0):
            return
    for i in range(d):
        for k in range(d):
            copy[i, k] = K[i, k]
    _symmetric_eigen(copy, d, values, vectors)
    for m in range(d):
        if values[m] < 0.0:
            values[m] = 0.0 if projection == 1 else -values[m]
    for i in range(d):
        for k in range(d):
            total = 0.0
            for m in range(d):
                total += vectors[i, m] * values[m] * vectors[k, m]
            K[i, k] = total


@numba.njit(cache=True, error_model="numpy")
def _elements_at(i, y, d, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, projection,
                 g, H, scratch):
    """dP_el/dy_i into g and the projected sum of the elements' K into H; each incident element's F, w, c, J and kept
    value into the scratch (what ``_elastic_change`` and ``_kept_fraction`` read). Incidence p is vertex i's element
    with vertex i as its corner 0 (vertex.py)."""
    Fs, ws, cs, Js, kept, P, A, work, K, copy, values, vectors, _, stress, F, n, w, c = scratch
    invariant_based = vertex_terms_from_invariants(model)
    if invariant_based and d == 3:  # the real-time case in a loop of its own, in scalars: F itself is not kept
        g0, g1, g2, h00, h01, h02, h11, h12, h22 = invariant_elements_3d(
            i, y, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, projection, ws, cs, Js, kept)
        set_blocks(g, H, g0, g1, g2, h00, h01, h02, h11, h12, h22)
        return
    for a in range(d):
        g[a] = 0.0
        for b in range(d):
            H[a, b] = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        e, slot = p, p - indptr[i]  # row p holds the element's corners and constants (vertex.py)
        _element_gradient(y, elements, shape_gradients, e, d, F)
        for a in range(d):
            n[a] = shape_gradients[e, 0, a]
            for b in range(d):
                Fs[slot, a, b] = F[a, b]
        if invariant_based:
            J, value = invariant_terms(model, F, n, d, mu[e], lam[e], alpha[e], copy, w, c, stress, K)
        else:
            material_terms(model, F, d, mu[e], lam[e], P, A, vertex_stiffness_needs_tangent(model), work)
            vertex_stiffness(model, F, n, d, mu[e], lam[e], A, K, work)
            _cofactor(F, d, copy)
            J, value = _determinant(F, d), 0.0
            for a in range(d):
                total, cofactor = 0.0, 0.0
                for b in range(d):
                    total += P[a, b] * n[b]
                    cofactor += copy[a, b] * n[b]
                stress[a] = total
                c[a] = cofactor
        Js[slot], kept[slot] = J, value
        for a in range(d):
            ws[slot, a], cs[slot, a] = w[a], c[a]
        project_block(K, d, projection, copy, values, vectors)
        volume = volumes[e]
        for a in range(d):
            g[a] += volume * stress[a]
            for b in range(d):
                H[a, b] += volume * K[a, b]


@numba.njit(cache=True, error_model="numpy")
def _density_change(model, F, n, w, c, J, kept, u, d, mu, lam, alpha, moved, P, A, work):
    """psi(F + u n^T) - psi(F) without cancellation (see the module docstring); w = F n and kept (the neo-Hookean
    energies', ``invariant_blocks``), c = cof(F) n, J = det F."""
    squared_n, squared_u, turned, volume_change = 0.0, 0.0, 0.0, 0.0  # |n|^2, |u|^2, u . n, c . u
    for j in range(d):
        squared_n += n[j] * n[j]
        squared_u += u[j] * u[j]
        turned += u[j] * n[j]
        volume_change += c[j] * u[j]
    if vertex_terms_from_invariants(model):
        along = 0.0
        for j in range(d):
            along += u[j] * w[j]
        return invariant_change(model, J, kept, 2.0 * along + squared_u * squared_n, volume_change, mu, lam, alpha)
    return vertex_energy_change(model, F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work)


@numba.njit(cache=True, error_model="numpy")
def _elastic_change(i, u, d, indptr, shape_gradients, volumes, mu, lam, alpha, model, scratch):
    """The change of the elements' energy when vertex i alone moves by u, from the scratch ``_elements_at`` filled."""
    Fs, ws, cs, Js, kept, P, A, work, _, _, _, _, moved, _, F, n, w, c = scratch
    invariant_based = vertex_terms_from_invariants(model)
    total = 0.0
    if invariant_based and d == 3:  # the real-time case in a loop of its own, in scalars
        return invariant_change_3d(i, u[0], u[1], u[2], indptr, shape_gradients, volumes, mu, lam, alpha, model, ws,
                                    cs, Js, kept)
    for p in range(indptr[i], indptr[i + 1]):
        slot = p - indptr[i]
        for a in range(d):
            n[a], w[a], c[a] = shape_gradients[p, 0, a], ws[slot, a], cs[slot, a]
            if not invariant_based:
                for b in range(d):
                    F[a, b] = Fs[slot, a, b]
        total += volumes[p] * _density_change(model, F, n, w, c, Js[slot], kept[slot], u, d, mu[p], lam[p], alpha[p],
                                              moved, P, A, work)
    return total


@numba.njit(cache=True, error_model="numpy", inline="always")
def _kept_fraction(i, u, d, indptr, kept_volume, scratch):
    """The largest t <= 1 at which every element at vertex i keeps ``kept_volume`` of its volume, J + t c . u >=
    kept_volume J (elements at or below zero volume are not cut: nothing keeps them positive)."""
    cs, Js = scratch[2], scratch[3]
    fraction = 1.0
    for p in range(indptr[i], indptr[i + 1]):
        slot = p - indptr[i]
        rate = 0.0
        for a in range(d):
            rate += cs[slot, a] * u[a]
        if Js[slot] > 0.0 and rate < 0.0:
            fraction = min(fraction, (1.0 - kept_volume) * Js[slot] / -rate)
    return fraction


@numba.njit(cache=True, error_model="numpy")
def _chunk(first_vertex, last_vertex, d, max_degree, y, vertices, constrained, projectors, y_tilde, mass, scale, indptr,
           elements, shape_gradients, volumes, mu, lam, alpha, model, gravity_force, kept_volume, damping_indptr,
           damping_indices, damping_data, damping_weight, velocity_origin, colliders, projection, determinant_floor,
           max_halvings, halvings, gradient_norms):
    """The vertices first_vertex:last_vertex of one colour; d a constant at each call site."""
    scratch = _scratch(d, max_degree)
    contact = point_scratch(d, colliders)
    touching = colliders[0].size > 0  # the colliders' functions only where there are any: their tuples cost a call
    g = np.empty(d)
    H = np.empty((d, d))
    rate = np.empty(d)
    D = np.empty((d, d))
    filtered_vector = np.empty(d)
    u = np.empty(d)
    work = np.empty((d, d + 1))
    filtered = np.empty((d, d))
    # the real-time case's terms inlined here: a call that takes the scratch tuple costs numba the reference counts of
    # its arrays, per vertex and per backtracking round
    tetrahedra_in_scalars = d == 3 and vertex_terms_from_invariants(model)
    ws, cs, Js, kept = scratch[1], scratch[2], scratch[3], scratch[4]
    for k in range(first_vertex, last_vertex):
        i = vertices[k]
        if tetrahedra_in_scalars:
            g0, g1, g2, h00, h01, h02, h11, h12, h22 = invariant_elements_3d(
                i, y, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, projection, ws, cs, Js, kept)
            set_blocks(g, H, g0, g1, g2, h00, h01, h02, h11, h12, h22)
        else:
            _elements_at(i, y, d, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, projection,
                         g, H, scratch)
        for a in range(d):
            g[a] -= gravity_force[i, a]
        clearance = add_vertex_terms(i, y, d, colliders, projection, g, H, contact) if touching else math.inf
        finish_blocks(i, y, d, y_tilde, mass, scale, damping_indptr, damping_indices, damping_data, damping_weight,
                      velocity_origin, g, H, rate, D)
        gradient_norms[k] = newton_step(H, g, u, constrained[k], projectors[k], determinant_floor, d, filtered,
                                        filtered_vector, work)
        fraction = _kept_fraction(i, u, d, indptr, kept_volume, scratch)
        if touching and may_reach(u, d, colliders, clearance):  # IPC: the step stops short of the first collider
            fraction = min(fraction, vertex_impact_fraction(u, d, colliders, contact))
        if fraction < 1.0:
            for a in range(d):
                u[a] *= fraction
        rounds = 0
        while True:
            if tetrahedra_in_scalars:
                potential = invariant_change_3d(i, u[0], u[1], u[2], indptr, shape_gradients, volumes, mu, lam, alpha,
                                                 model, ws, cs, Js, kept)
            else:
                potential = _elastic_change(i, u, d, indptr, shape_gradients, volumes, mu, lam, alpha, model, scratch)
            for a in range(d):
                potential -= gravity_force[i, a] * u[a]
            if not beyond_reach(u, d, clearance):  # a step that reaches a collider
                potential += vertex_change(u, d, colliders, contact)
            change = inertia_change(i, u, y, d, y_tilde, mass) + scale * potential
            change += damping_change(u, d, damping_weight, rate, D)
            if change <= 0.0 or rounds >= max_halvings:  # NaN halves too
                break
            for a in range(d):
                u[a] *= 0.5
            rounds += 1
        take_step(y, i, u, d, change)
        halvings[k] = rounds


@numba.njit(parallel=True, cache=True, error_model="numpy")
def sweep_colour(y, vertices, constrained, projectors, y_tilde, mass, scale, indptr, max_degree,
                 elements, shape_gradients, volumes, mu, lam, alpha, model, gravity_force, kept_volume, damping_indptr,
                 damping_indices, damping_data, damping_weight, velocity_origin, colliders, projection, determinant_floor,
                 max_halvings, halvings, gradient_norms):
    """One colour's vertex steps, taken in place in y; halvings[k]: the halvings vertex k's step took (max_halvings
    for a step dropped); gradient_norms[k]: |g_k|_inf of E where vertex k met it (filtered; the sweep's residual).
    ``constrained[k]``: vertex k's filter is projectors[k] (fixed dofs or sliding); colliders: contact/point_kernels.py
    ``colliders_of``."""
    dim = projectors.shape[1]
    count = vertices.size
    for chunk in prange((count + CHUNK - 1) // CHUNK):
        _chunk(chunk * CHUNK, min(count, chunk * CHUNK + CHUNK), dim, max_degree, y, vertices, constrained, projectors,
               y_tilde, mass, scale, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, gravity_force,
               kept_volume, damping_indptr, damping_indices, damping_data, damping_weight, velocity_origin, colliders,
               projection, determinant_floor, max_halvings, halvings, gradient_norms)


# -- the same terms for given vertices, each at x with the others held (what the numpy sweep and contact take) --------
@numba.njit(parallel=True, cache=True, error_model="numpy")
def vertex_blocks(x, vertices, indptr, max_degree, elements, shape_gradients, volumes, mu, lam, alpha, model,
                  projection, gradient, hessian):
    """gradient[k] = dP_el/dx_i (N) and hessian[k] the projected sum of the elements' blocks (N/m) of vertex
    i = vertices[k]: the elements' energy only (the caller adds gravity and contact)."""
    d = shape_gradients.shape[2]
    count = vertices.size
    for chunk in prange((count + CHUNK - 1) // CHUNK):
        scratch = _scratch(d, max_degree)
        for k in range(chunk * CHUNK, min(count, chunk * CHUNK + CHUNK)):
            _elements_at(vertices[k], x, d, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model,
                         projection, gradient[k], hessian[k], scratch)


@numba.njit(parallel=True, cache=True, error_model="numpy")
def vertex_changes(x, vertices, steps, indptr, max_degree, elements, shape_gradients, volumes, mu,
                   lam, alpha, model, kept_volume, changes, fractions):
    """changes[k]: the change of the elements' energy (J) when vertex i = vertices[k] alone moves by steps[k];
    fractions[k]: the largest fraction of that step that keeps its elements above ``kept_volume`` of their volume."""
    d = shape_gradients.shape[2]
    count = vertices.size
    for chunk in prange((count + CHUNK - 1) // CHUNK):
        scratch = _scratch(d, max_degree)
        g = np.empty(d)
        H = np.empty((d, d))
        for k in range(chunk * CHUNK, min(count, chunk * CHUNK + CHUNK)):
            i = vertices[k]
            _elements_at(i, x, d, indptr, elements, shape_gradients, volumes, mu, lam, alpha, model, 0, g, H,
                         scratch)
            changes[k] = _elastic_change(i, steps[k], d, indptr, shape_gradients, volumes, mu, lam, alpha, model,
                                         scratch)
            fractions[k] = _kept_fraction(i, steps[k], d, indptr, kept_volume, scratch)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
