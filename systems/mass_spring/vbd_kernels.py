"""Vertex block descent's colour sweep of a mass-spring incremental potential, compiled.

E(y) = 1/2 (y - y~)^T M (y - y~) + s P(y) + (s/b) [damping], P the springs and gravity (solvers/vbd.py has the method,
systems/mass_spring/blocks.py the numpy form of the blocks this reproduces). For each vertex i of one colour, in
parallel (``prange`` over chunks of the colour; no two vertices of a colour share a spring, so each reads its
neighbours, which belong to other colours, and writes only its own dofs):

    g_i = M_i (y_i - y~_i) + s (sum_{e at i} c_e (y_i - y_j) - m_i g) + w (D (y - a))_i,
    H_i = M_i + s sum_{e at i} B_e + w D_ii,

the filter of a constrained vertex (S H S + c (I - S), S g), the determinant floor, u = -H^-1 g (Gaussian elimination
with partial pivoting, as LAPACK's), and the per-vertex backtracking: u halved until the change of E it causes,
formed without cancellation, is <= 0, dropped after ``max_halvings``. The result does not depend on the thread
count: every vertex's numbers are its own, in a fixed order. The inertia, damping, filter and solve are the shared
ones of systems/vertex_kernels.py, the colliders' terms those of systems/contact/point_kernels.py; the springs' blocks
and changes are this module's.

The incidences of a vertex are in the order of the numpy form (the springs at which it is the first end, then those
at which it is the second, each in spring order), so the sums match it to round-off.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from ..compiled_cache import keep_fresh
from ..contact.point_kernels import (add_vertex_terms, beyond_reach, may_reach, point_scratch, vertex_change,
                                     vertex_impact_fraction)
from ..vertex_kernels import (damping_change, filtered_eigenvalue, finish_blocks, inertia_change, newton_step,
                              take_step)
from .kernels import SQUARED_LENGTH, gradient_factor

# vertices per chunk of the parallel loop: the scratch arrays are made once per chunk, not per vertex
CHUNK = 64


@numba.njit(cache=True, error_model="numpy")
def _energy_change(law, stiffness, rest_length, rest_length_squared, length, moved_length, squared_change):
    """W(L') - W(L) of one spring without cancellation (laws.py ``energy_changes``)."""
    if law == SQUARED_LENGTH:
        ratios = (moved_length * moved_length + length * length) / rest_length_squared
        return 0.5 * stiffness * squared_change * (ratios - 2.0)
    return 0.5 * stiffness * squared_change / (moved_length + length) * (moved_length + length - 2.0 * rest_length)


@numba.njit(cache=True, error_model="numpy")
def _springs(i, y, d, indptr, other, springs, stiffness, rest_length, rest_length_squared, law, projection, g, H,
             deltas, lengths):
    """sum_{e at i} c_e (y_i - y_j) into g and sum_e B_e into H; each spring's delta and length into deltas, lengths."""
    for a in range(d):
        g[a] = 0.0
        for b in range(d):
            H[a, b] = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        j, e, slot = other[p], springs[p], p - indptr[i]
        squared = 0.0
        for a in range(d):
            deltas[slot, a] = y[d * i + a] - y[d * j + a]
            squared += deltas[slot, a] * deltas[slot, a]
        length = math.sqrt(squared)
        lengths[slot] = length
        factor = gradient_factor(law, stiffness[e], length, rest_length[e], rest_length_squared[e])
        if law == SQUARED_LENGTH:
            ratio = length * length / rest_length_squared[e]
            along = 2.0 * stiffness[e] * filtered_eigenvalue(3.0 * ratio - 1.0, projection)
            transverse = 2.0 * stiffness[e] * filtered_eigenvalue(ratio - 1.0, projection)
        else:
            along = stiffness[e]
            transverse = stiffness[e] * filtered_eigenvalue(1.0 - rest_length[e] / length, projection)
        # B_e = along u u^T + transverse (I - u u^T) = (along - transverse) u u^T + transverse I, with u = delta / L
        outer_scale = (along - transverse) / squared
        for a in range(d):
            g[a] += factor * deltas[slot, a]
            H[a, a] += transverse
            for b in range(d):
                H[a, b] += outer_scale * deltas[slot, a] * deltas[slot, b]


@numba.njit(cache=True, error_model="numpy")
def _change(i, u, y, d, y_tilde, mass, scale, indptr, springs, stiffness, rest_length, rest_length_squared, law,
            gravity_force, damping_weight, rate, D, deltas, lengths, contact_change):
    """The change of E when vertex i alone moves by u, each term formed without cancellation, from the incident
    springs' deltas and lengths at y (``_springs``); contact_change: the colliders' (J, unscaled)."""
    potential = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        e, slot = springs[p], p - indptr[i]
        moved = 0.0
        squared_change = 0.0
        for a in range(d):
            shifted = deltas[slot, a] + u[a]
            moved += shifted * shifted
            squared_change += u[a] * (deltas[slot, a] + deltas[slot, a] + u[a])
        potential += _energy_change(law, stiffness[e], rest_length[e], rest_length_squared[e], lengths[slot],
                                    math.sqrt(moved), squared_change)
    for a in range(d):
        potential -= gravity_force[i, a] * u[a]
    potential += contact_change
    change = inertia_change(i, u, y, d, y_tilde, mass) + scale * potential
    return change + damping_change(u, d, damping_weight, rate, D)


@numba.njit(cache=True, error_model="numpy")
def _chunk(first_vertex, last_vertex, d, max_degree, y, vertices, constrained, projectors, y_tilde, mass, scale, indptr, other,
           springs, stiffness, rest_length, rest_length_squared, law, gravity_force, damping_indptr, damping_indices,
           damping_data, damping_weight, velocity_origin, colliders, projection, determinant_floor, max_halvings, halvings,
           gradient_norms):
    """The vertices first_vertex:last_vertex of one colour; d a constant at each call site, so that the d x d loops
    unroll. Each vertex: g_i and H_i of E at y, the damping's rates (D (y - a))_i and block D_ii, and each incident
    spring's y_i - y_j and length (what ``_change`` reads), the Newton step and its backtracking. The colliders'
    functions are called only where there are colliders, their change only for a step that reaches one, and from
    here, not from ``_change``: passing their two tuples of arrays to a function called per vertex and halving cost
    as much as the springs."""
    g = np.empty(d)
    H = np.empty((d, d))
    rate = np.empty(d)
    D = np.empty((d, d))
    filtered_vector = np.empty(d)
    u = np.empty(d)
    work = np.empty((d, d + 1))
    filtered = np.empty((d, d))
    deltas = np.empty((max_degree, d))
    lengths = np.empty(max_degree)
    contact = point_scratch(d, colliders)
    touching = colliders[0].size > 0
    for k in range(first_vertex, last_vertex):
        i = vertices[k]
        _springs(i, y, d, indptr, other, springs, stiffness, rest_length, rest_length_squared, law, projection, g, H,
                 deltas, lengths)
        for a in range(d):
            g[a] -= gravity_force[i, a]
        clearance = add_vertex_terms(i, y, d, colliders, projection, g, H, contact) if touching else math.inf
        finish_blocks(i, y, d, y_tilde, mass, scale, damping_indptr, damping_indices, damping_data, damping_weight,
                      velocity_origin, g, H, rate, D)
        gradient_norms[k] = newton_step(H, g, u, constrained[k], projectors[k], determinant_floor, d, filtered,
                                        filtered_vector, work)
        if touching and may_reach(u, d, colliders, clearance):  # IPC: the step stops short of the first collider
            fraction = vertex_impact_fraction(u, d, colliders, contact)
            if fraction < 1.0:
                for a in range(d):
                    u[a] *= fraction
        rounds = 0
        while True:
            contact_change = 0.0 if beyond_reach(u, d, clearance) else vertex_change(u, d, colliders, contact)
            change = _change(i, u, y, d, y_tilde, mass, scale, indptr, springs, stiffness, rest_length,
                             rest_length_squared, law, gravity_force, damping_weight, rate, D, deltas, lengths,
                             contact_change)
            if change <= 0.0 or rounds >= max_halvings:  # NaN halves too
                break
            for a in range(d):
                u[a] *= 0.5
            rounds += 1
        take_step(y, i, u, d, change)
        halvings[k] = rounds


@numba.njit(parallel=True, cache=True, error_model="numpy")
def sweep_colour(y, vertices, constrained, projectors, y_tilde, mass, scale, indptr, other, springs, max_degree,
                 stiffness, rest_length, rest_length_squared, law, gravity_force, damping_indptr, damping_indices,
                 damping_data, damping_weight, velocity_origin, colliders, projection, determinant_floor, max_halvings,
                 halvings, gradient_norms):
    """One colour's vertex steps, taken in place in y; halvings[k]: the halvings vertex k's step took (max_halvings
    for a step dropped); gradient_norms[k]: |g_k|_inf of E where vertex k met it (filtered; the sweep's residual).
    ``constrained[k]``: vertex k's filter is projectors[k] (fixed dofs or sliding); colliders: contact/point_kernels.py
    ``colliders_of``."""
    dim = projectors.shape[1]
    count = vertices.size
    chunks = (count + CHUNK - 1) // CHUNK
    for chunk in prange(chunks):
        first_vertex, last_vertex = chunk * CHUNK, min(count, chunk * CHUNK + CHUNK)
        if dim == 3:
            _chunk(first_vertex, last_vertex, 3, max_degree, y, vertices, constrained, projectors, y_tilde, mass, scale, indptr,
                   other, springs, stiffness, rest_length, rest_length_squared, law, gravity_force, damping_indptr,
                   damping_indices, damping_data, damping_weight, velocity_origin, colliders, projection,
                   determinant_floor, max_halvings, halvings, gradient_norms)
        else:
            _chunk(first_vertex, last_vertex, 2, max_degree, y, vertices, constrained, projectors, y_tilde, mass, scale, indptr,
                   other, springs, stiffness, rest_length, rest_length_squared, law, gravity_force, damping_indptr,
                   damping_indices, damping_data, damping_weight, velocity_origin, colliders, projection,
                   determinant_floor, max_halvings, halvings, gradient_norms)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
