"""Vertex block descent on a shell, compiled: each vertex's gradient and 3 x 3 Hessian block from its
membrane triangles (membrane.py) and its discrete-shell hinges (bending.py), the change of their energy when the vertex
alone moves, the fraction of its step that keeps its triangles' areas, and one colour's sweep (solvers/vbd.py has the
method; fem/vbd_kernels.py is the same for solids).

Membrane. Vertex i is corner a of triangle e with shape gradient n = g_a (2,). Moving it alone by u changes the 3 x 2
deformation gradient by u n^T, so dPsi_e/dx_i = w P n and its block is w K, K_ik = sum_jl n_j A_(ij)(kl) n_l, with P
and A = d^2 psi / dF^2 those of membrane.py's ``membrane_terms``, contracted in closed form (shell_terms.py's
``membrane_vertex_terms``). The energy change is formed without cancellation from
the exact change of C = F^T F,

    C' - C = n v^T + v n^T + |u|^2 n n^T  (v = F^T u),

whose trace is I_1's change and whose determinant change is tr(adj(C) dC) + det(dC) (2 x 2), so that J' - J =
(det C' - det C) / (J' + J); each energy's change then follows from those of I_1 and J as a solid's does from I_C and
J (St. Venant-Kirchhoff's from E's change dC / 2).

Hinges. The hinge h = (x0, x1, x2, x3) has the angle theta = atan2(s, c) between its triangles' normals N_1 = e x w_1
and N_2 = w_2 x e (e = x1 - x0, w_a = x_(a+1) - x0; bending.py), and E = k_h (theta - theta_rest)^2, whose gradient in
vertex a is 2 k_h (theta - theta_rest) theta_a and whose block is 2 k_h (theta_a theta_a^T + (theta - theta_rest)
theta_aa). theta_a and theta_aa in one vertex have short closed forms (shell_terms.py's ``hinge_angle_block``), where
bending.py's chain through (e, w_1, w_2) takes 9 x 9 products; they equal its blocks. The change is k_h (theta' - theta)
(theta' + theta - 2 theta_rest), theta' the angle at the moved vertex.

Each triangle's and each hinge's block at the vertex is projected to SPD on its own (clamp or mirror its negative
eigenvalues), as a solid's elements' and the springs' are: without projection the vertex's block is the diagonal block
of the full Hessian, exactly.

Moving one corner alone changes a triangle's normal linearly, N(t) = N + t (x2 - x1) x u (x1, x2 the other two
corners in turn), so |N(t)|^2 = kept^2 |N|^2 is a quadratic whose first root in (0, 1] is the exact largest step that
keeps ``kept_area`` of the triangle's area: the step filter of membrane.py's ``area_keeping_step`` for one vertex.

The colliders' terms are those of systems/contact/point_kernels.py. The parallel loops run over chunks of vertices;
every vertex's numbers are its own, in a fixed order, so the result does not depend on the thread count.
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
from .materials.dispatch import membrane_change
from .shell_terms import _hinge_angle, _wing_block, hinge_angle_block, membrane_vertex_terms, project_block_3

# vertices per chunk of the parallel loops: the scratch arrays are made once per chunk, not per vertex
CHUNK = 32


@numba.njit(cache=True, error_model="numpy")
def _scratch(max_degree, max_hinges):
    """One chunk's arrays: each incident triangle's F, each incident hinge's angle; P n; K and its projection's copy,
    eigenvalues and vectors; one triangle's F; ``hinge_angle_block``'s points and vectors; the vertex's theta_a and
    theta_aa."""
    return (np.empty((max_degree, 3, 2)), np.empty(max(max_hinges, 1)), np.empty(3), np.empty((3, 3)),
            np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty((3, 2)), np.empty((10, 3)), np.empty(3),
            np.empty((3, 3)))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _membrane_at(i, y, indptr, elements, shape_gradients, weights, mu, lam, model, projection, g, H, scratch):
    """Adds vertex i's triangles' w P n to g and their projected blocks w K to H; each triangle's F into the scratch
    (what ``_membrane_change`` reads). Incidence p is vertex i's triangle with vertex i as its corner 0 (vertex.py)."""
    Fs, _, stress, K, copy, values, vectors, F, _, _, _ = scratch
    for p in range(indptr[i], indptr[i + 1]):
        slot = p - indptr[i]
        v0, v1, v2 = 3 * elements[p, 0], 3 * elements[p, 1], 3 * elements[p, 2]
        for r in range(3):
            for j in range(2):
                F[r, j] = (y[v0 + r] * shape_gradients[p, 0, j] + y[v1 + r] * shape_gradients[p, 1, j]
                           + y[v2 + r] * shape_gradients[p, 2, j])
                Fs[slot, r, j] = F[r, j]
        membrane_vertex_terms(model, F, shape_gradients[p, 0, 0], shape_gradients[p, 0, 1], mu[p], lam[p], stress, K)
        project_block_3(K, projection, copy, values, vectors)
        weight = weights[p]
        for r in range(3):
            g[r] += weight * stress[r]
            for k in range(3):
                H[r, k] += weight * K[r, k]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _hinges_at(i, y, hinge_indptr, hinges, corners, stiffness, rest_angles, projection, g, H, scratch):
    """Adds vertex i's hinges' gradients to g and their projected blocks to H; each hinge's angle into the scratch (what
    ``_hinge_change`` reads). Hinge row q holds its four vertices in the hinge's own order and vertex i's corner."""
    _, thetas, _, K, copy, values, vectors, _, points, along, curvature = scratch
    for q in range(hinge_indptr[i], hinge_indptr[i + 1]):
        theta = _hinge_angle(y, hinges, q, 0, 0.0, 0.0, 0.0)  # as the energy has it: its change differences this one
        thetas[q - hinge_indptr[i]] = theta
        corner = corners[q]
        hinge_angle_block(y, hinges, q, corner, along, curvature, points)
        scale, change = 2.0 * stiffness[q], theta - rest_angles[q]
        for r in range(3):
            g[r] += scale * change * along[r]
        if corner >= 2 and projection != 0:
            _wing_block(K, scale, change, projection, points)
        else:
            for r in range(3):
                for k in range(r, 3):
                    K[r, k] = K[k, r] = scale * (along[r] * along[k] + change * curvature[r, k])
            project_block_3(K, projection, copy, values, vectors)
        for r in range(3):
            for k in range(3):
                H[r, k] += K[r, k]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _membrane_change(i, u, indptr, shape_gradients, weights, mu, lam, model, scratch):
    """The change of vertex i's triangles' energy when it alone moves by u, from the F ``_membrane_at`` kept."""
    Fs = scratch[0]
    squared_u = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    total = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        slot = p - indptr[i]
        n0, n1 = shape_gradients[p, 0, 0], shape_gradients[p, 0, 1]
        v0 = Fs[slot, 0, 0] * u[0] + Fs[slot, 1, 0] * u[1] + Fs[slot, 2, 0] * u[2]
        v1 = Fs[slot, 0, 1] * u[0] + Fs[slot, 1, 1] * u[1] + Fs[slot, 2, 1] * u[2]
        C00 = Fs[slot, 0, 0] * Fs[slot, 0, 0] + Fs[slot, 1, 0] * Fs[slot, 1, 0] + Fs[slot, 2, 0] * Fs[slot, 2, 0]
        C01 = Fs[slot, 0, 0] * Fs[slot, 0, 1] + Fs[slot, 1, 0] * Fs[slot, 1, 1] + Fs[slot, 2, 0] * Fs[slot, 2, 1]
        C11 = Fs[slot, 0, 1] * Fs[slot, 0, 1] + Fs[slot, 1, 1] * Fs[slot, 1, 1] + Fs[slot, 2, 1] * Fs[slot, 2, 1]
        D00 = 2.0 * n0 * v0 + squared_u * n0 * n0
        D01 = n0 * v1 + n1 * v0 + squared_u * n0 * n1
        D11 = 2.0 * n1 * v1 + squared_u * n1 * n1
        total += weights[p] * membrane_change(model, C00, C01, C11, D00, D01, D11, mu[p], lam[p])
    return total


@numba.njit(cache=True, error_model="numpy", inline="always")
def _hinge_change(i, u, y, hinge_indptr, hinges, corners, stiffness, rest_angles, scratch):
    """The change of vertex i's hinges' energy when it alone moves by u, from the angles ``_hinges_at`` kept."""
    thetas = scratch[1]
    total = 0.0
    for q in range(hinge_indptr[i], hinge_indptr[i + 1]):
        theta, moved = thetas[q - hinge_indptr[i]], _hinge_angle(y, hinges, q, corners[q], u[0], u[1], u[2])
        total += stiffness[q] * (moved - theta) * (moved + theta - 2.0 * rest_angles[q])
    return total


@numba.njit(cache=True, error_model="numpy", inline="always")
def _kept_fraction(i, u, y, indptr, elements, kept_area):
    """The largest t <= 1 at which every triangle at vertex i keeps ``kept_area`` of its area, |N + t m|^2 >=
    kept_area^2 |N|^2 with m = (x2 - x1) x u (the module docstring); triangles of no area are not cut."""
    fraction = 1.0
    for p in range(indptr[i], indptr[i + 1]):
        v0, v1, v2 = 3 * elements[p, 0], 3 * elements[p, 1], 3 * elements[p, 2]
        a0, a1, a2 = y[v1] - y[v0], y[v1 + 1] - y[v0 + 1], y[v1 + 2] - y[v0 + 2]
        b0, b1, b2 = y[v2] - y[v0], y[v2 + 1] - y[v0 + 1], y[v2 + 2] - y[v0 + 2]
        N0, N1, N2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        s0, s1, s2 = y[v2] - y[v1], y[v2 + 1] - y[v1 + 1], y[v2 + 2] - y[v1 + 2]
        m0, m1, m2 = s1 * u[2] - s2 * u[1], s2 * u[0] - s0 * u[2], s0 * u[1] - s1 * u[0]
        area = N0 * N0 + N1 * N1 + N2 * N2
        if not area > 0.0:
            continue
        quadratic = m0 * m0 + m1 * m1 + m2 * m2
        linear = 2.0 * (N0 * m0 + N1 * m1 + N2 * m2)
        constant = (1.0 - kept_area * kept_area) * area
        if not linear < 0.0:  # |N(t)| grows at 0, and a convex quadratic with q(0) > 0 has no positive root then
            continue
        discriminant = linear * linear - 4.0 * quadratic * constant
        if discriminant < 0.0:
            continue
        fraction = min(fraction, 2.0 * constant / (-linear + math.sqrt(discriminant)))  # the smaller root, stably
    return fraction


@numba.njit(cache=True, error_model="numpy", inline="always")
def _shell_at(i, y, indptr, elements, shape_gradients, weights, mu, lam, model, membrane, hinge_indptr, hinges,
              corners, stiffness, rest_angles, projection, g, H, scratch):
    """dP/dy_i of the membrane and the hinges into g, their projected blocks into H (zeroed first)."""
    for a in range(3):
        g[a] = 0.0
        for b in range(3):
            H[a, b] = 0.0
    if membrane:
        _membrane_at(i, y, indptr, elements, shape_gradients, weights, mu, lam, model, projection, g, H, scratch)
    _hinges_at(i, y, hinge_indptr, hinges, corners, stiffness, rest_angles, projection, g, H, scratch)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _shell_change(i, u, y, indptr, shape_gradients, weights, mu, lam, model, membrane, hinge_indptr, hinges, corners,
                  stiffness, rest_angles, scratch):
    change = 0.0
    if membrane:
        change += _membrane_change(i, u, indptr, shape_gradients, weights, mu, lam, model, scratch)
    return change + _hinge_change(i, u, y, hinge_indptr, hinges, corners, stiffness, rest_angles, scratch)


@numba.njit(cache=True, error_model="numpy")
def _chunk(first_vertex, last_vertex, max_degree, max_hinges, y, vertices, constrained, projectors, y_tilde, mass,
           scale, indptr, elements, shape_gradients, weights, mu, lam, model, membrane, hinge_indptr, hinges, corners,
           stiffness, rest_angles, gravity_force, kept_area, damping_indptr, damping_indices, damping_data,
           damping_weight, velocity_origin, colliders, projection, determinant_floor, max_halvings, halvings,
           gradient_norms):
    """The vertices first_vertex:last_vertex of one colour (fem/vbd_kernels.py's ``_chunk`` with the shell's terms)."""
    d = 3
    scratch = _scratch(max_degree, max_hinges)
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
    for k in range(first_vertex, last_vertex):
        i = vertices[k]
        _shell_at(i, y, indptr, elements, shape_gradients, weights, mu, lam, model, membrane, hinge_indptr, hinges,
                  corners, stiffness, rest_angles, projection, g, H, scratch)
        for a in range(d):
            g[a] -= gravity_force[i, a]
        clearance = add_vertex_terms(i, y, d, colliders, projection, g, H, contact) if touching else math.inf
        finish_blocks(i, y, d, y_tilde, mass, scale, damping_indptr, damping_indices, damping_data, damping_weight,
                      velocity_origin, g, H, rate, D)
        gradient_norms[k] = newton_step(H, g, u, constrained[k], projectors[k], determinant_floor, d, filtered,
                                        filtered_vector, work)
        fraction = _kept_fraction(i, u, y, indptr, elements, kept_area)
        if touching and may_reach(u, d, colliders, clearance):  # IPC: the step stops short of the first collider
            fraction = min(fraction, vertex_impact_fraction(u, d, colliders, contact))
        if fraction < 1.0:
            for a in range(d):
                u[a] *= fraction
        rounds = 0
        while True:
            potential = _shell_change(i, u, y, indptr, shape_gradients, weights, mu, lam, model, membrane,
                                      hinge_indptr, hinges, corners, stiffness, rest_angles, scratch)
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
def sweep_colour(y, vertices, constrained, projectors, y_tilde, mass, scale, indptr, max_degree, elements,
                 shape_gradients, weights, mu, lam, model, membrane, hinge_indptr, max_hinges, hinges, corners,
                 stiffness, rest_angles, gravity_force, kept_area, damping_indptr, damping_indices, damping_data,
                 damping_weight, velocity_origin, colliders, projection, determinant_floor, max_halvings, halvings,
                 gradient_norms):
    """One colour's vertex steps, taken in place in y; halvings[k]: the halvings vertex k's step took (max_halvings
    for a step dropped); gradient_norms[k]: |g_k|_inf of E where vertex k met it (filtered; the sweep's residual).
    ``constrained[k]``: vertex k's filter is projectors[k] (fixed dofs or sliding); colliders: contact/point_kernels.py
    ``colliders_of``."""
    count = vertices.size
    for chunk in prange((count + CHUNK - 1) // CHUNK):
        _chunk(chunk * CHUNK, min(count, chunk * CHUNK + CHUNK), max_degree, max_hinges, y, vertices, constrained,
               projectors, y_tilde, mass, scale, indptr, elements, shape_gradients, weights, mu, lam, model, membrane,
               hinge_indptr, hinges, corners, stiffness, rest_angles, gravity_force, kept_area, damping_indptr,
               damping_indices, damping_data, damping_weight, velocity_origin, colliders, projection,
               determinant_floor, max_halvings, halvings, gradient_norms)


# -- the same terms for given vertices, each at x with the others held (what the numpy sweep and contact take) --------
@numba.njit(parallel=True, cache=True, error_model="numpy")
def vertex_blocks(x, vertices, indptr, max_degree, elements, shape_gradients, weights, mu, lam, model, membrane,
                  hinge_indptr, max_hinges, hinges, corners, stiffness, rest_angles, projection, gradient, hessian):
    """gradient[k] = dP/dx_i (N) and hessian[k] the projected sum of the triangles' and hinges' blocks (N/m) of vertex
    i = vertices[k]: the shell's elastic energy only (the caller adds gravity and contact)."""
    count = vertices.size
    for chunk in prange((count + CHUNK - 1) // CHUNK):
        scratch = _scratch(max_degree, max_hinges)
        for k in range(chunk * CHUNK, min(count, chunk * CHUNK + CHUNK)):
            _shell_at(vertices[k], x, indptr, elements, shape_gradients, weights, mu, lam, model, membrane,
                      hinge_indptr, hinges, corners, stiffness, rest_angles, projection, gradient[k], hessian[k],
                      scratch)


@numba.njit(parallel=True, cache=True, error_model="numpy")
def vertex_changes(x, vertices, steps, indptr, max_degree, elements, shape_gradients, weights, mu, lam, model, membrane,
                   hinge_indptr, max_hinges, hinges, corners, stiffness, rest_angles, kept_area, changes, fractions):
    """changes[k]: the change of the shell's elastic energy (J) when vertex i = vertices[k] alone moves by steps[k];
    fractions[k]: the largest fraction of that step that keeps its triangles above ``kept_area`` of their areas."""
    count = vertices.size
    for chunk in prange((count + CHUNK - 1) // CHUNK):
        scratch = _scratch(max_degree, max_hinges)
        g = np.empty(3)
        H = np.empty((3, 3))
        for k in range(chunk * CHUNK, min(count, chunk * CHUNK + CHUNK)):
            i = vertices[k]
            _shell_at(i, x, indptr, elements, shape_gradients, weights, mu, lam, model, membrane, hinge_indptr, hinges,
                      corners, stiffness, rest_angles, 0, g, H, scratch)
            changes[k] = _shell_change(i, steps[k], x, indptr, shape_gradients, weights, mu, lam, model, membrane,
                                       hinge_indptr, hinges, corners, stiffness, rest_angles, scratch)
            fractions[k] = _kept_fraction(i, steps[k], x, indptr, elements, kept_area)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
