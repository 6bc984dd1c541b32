"""XPBD's distance-constraint projection, compiled: one colour of springs (no shared vertex) in parallel.

Per spring of the group, at x = x_n + displacement (integrators/xpbd.py has the method, MMC 2016 eqs. 18 and 26):

    delta = (x_i,n - x_j,n) + (u_i - u_j),  L = |delta|,  n = delta / L  (no direction at L = 0: no move),
    Delta lambda = (-k h^2 (L - l0) - lambda - beta h (u_i - u_j) . n) / ((k h^2 + beta h) (W_i n + W_j n) . n + 1),
    lambda += Delta lambda,  u_i += W_i n Delta lambda,  u_j -= W_j n Delta lambda,

with W the inverse mass through each end's filter (S W at a sliding end) and an anchored spring's second end fixed at
its anchor. Springs of one group share no vertex, so each writes only its own ends: ``prange`` over chunks of the
group, and the result does not depend on the thread count.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from simrun.systems.compiled_cache import keep_fresh
from simrun.systems.constraints import filter_in_place

# springs per chunk of the parallel loop: the scratch arrays are made once per chunk, not per spring
CHUNK = 256


@numba.njit(cache=True)
def _project_chunk(first_spring, last_spring, d, start, moves, multiplier, first, second, anchor, rest_length,
                   stiffness_h2, damping_h, first_weight, second_weight, first_slides, first_projector, second_slides,
                   second_projector, damped):
    moved = np.empty(d)
    delta = np.empty(d)
    direction = np.empty(d)
    first_gradient = np.empty(d)
    second_gradient = np.empty(d)
    filtered = np.empty(d)
    for r in range(first_spring, last_spring):
        i, j = first[r], second[r]
        squared = 0.0
        for a in range(d):
            other_move = moves[j, a] if j >= 0 else 0.0
            other_start = start[j, a] if j >= 0 else anchor[r, a]
            moved[a] = moves[i, a] - other_move
            delta[a] = (start[i, a] - other_start) + moved[a]
            squared += delta[a] * delta[a]
        length = math.sqrt(squared)
        divisor = length if length > 0.0 else math.inf
        for a in range(d):
            direction[a] = delta[a] / divisor
            first_gradient[a] = first_weight[r, a] * direction[a]
            second_gradient[a] = second_weight[r, a] * direction[a]
        if first_slides[r]:
            filter_in_place(first_projector[r], first_gradient, filtered, d)
        if second_slides[r]:
            filter_in_place(second_projector[r], second_gradient, filtered, d)
        weight = 0.0
        for a in range(d):
            weight += (first_gradient[a] + second_gradient[a]) * direction[a]
        numerator = -stiffness_h2[r] * (length - rest_length[r]) - multiplier[r]
        if damped:
            along = 0.0
            for a in range(d):
                along += moved[a] * direction[a]
            numerator -= damping_h[r] * along
        change = numerator / ((stiffness_h2[r] + damping_h[r]) * weight + 1.0)
        multiplier[r] += change
        for a in range(d):
            moves[i, a] += first_gradient[a] * change
            if j >= 0:
                moves[j, a] -= second_gradient[a] * change


@numba.njit(parallel=True, cache=True)
def project_distance(start, moves, multiplier, first, second, anchor, rest_length, stiffness_h2, damping_h,
                     first_weight, second_weight, first_slides, first_projector, second_slides, second_projector,
                     damped):
    """One XPBD update of every distance constraint of a group, in place on ``moves`` (n, d) and ``multiplier``;
    start (n, d): x_n; second[r] = -1 for a spring anchored at anchor[r]; *_slides[r]: that end's filter is
    *_projector[r]; damped: any beta h of the group is nonzero."""
    d = first_weight.shape[1]
    count = first.size
    chunks = (count + CHUNK - 1) // CHUNK
    for chunk in prange(chunks):
        first_spring, last_spring = chunk * CHUNK, min(count, chunk * CHUNK + CHUNK)
        if d == 3:
            _project_chunk(first_spring, last_spring, 3, start, moves, multiplier, first, second, anchor, rest_length,
                           stiffness_h2, damping_h, first_weight, second_weight, first_slides, first_projector,
                           second_slides, second_projector, damped)
        else:
            _project_chunk(first_spring, last_spring, 2, start, moves, multiplier, first, second, anchor, rest_length,
                           stiffness_h2, damping_h, first_weight, second_weight, first_slides, first_projector,
                           second_slides, second_projector, damped)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
