"""Compiled spring loops: the springs' geometry and gradient at one state (every solver's, and projective dynamics'
local step and right-hand side), and the gradient at several states at once (Radau IIA's stages,
``MassSpring.gradients``).

At one state: one pass over the springs for delta = x_i - x_j, L = |delta|, L - l0 and k (L - l0)
(``spring_geometry``), one over the vertices gathering c_e delta_e in the incidence matrix's row order
(``gather_spring_gradient``), single-threaded (why: at the kernels). They reproduce the numpy forms bit for bit
(tests/test_mass_spring_kernels.py).

At several states: one pass over the springs per state, the law's factor c_e(L) (dW_e/dx_i = c_e delta) scattered
into the gradient in spring order. The numpy path makes the same numbers with a dozen array operations
and two transposing copies, each a pass over memory where this loop makes one in all; its
incidence product sums each vertex's springs in spring order too, so the two agree to round-off. A law enters the loop
as its code (``LAW_CODES``): numba's cache does not keep a kernel that takes a compiled function as an argument (every
process compiled it again, into a new cache entry).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..compiled_cache import keep_fresh


# the spring laws' codes in the compiled loops (the finite elements' materials are numbered the same way)
HOOKEAN, SQUARED_LENGTH = 0, 1
LAW_CODES = {"hookean": HOOKEAN, "squared_length": SQUARED_LENGTH}


@numba.njit(cache=True, error_model="numpy")
def gradient_factor(law, stiffness, length, rest_length, rest_length_squared):
    """c_e of the law, in the order of operations of its numpy form (laws.py): k (L - l0) / L (HookeanLaw),
    2 k (L^2 / l0^2 - 1) (SquaredLengthLaw)."""
    if law == SQUARED_LENGTH:
        return 2.0 * stiffness * (length * length / rest_length_squared - 1.0)
    return stiffness * (length - rest_length) / length


@numba.njit(cache=True, error_model="numpy")
def spring_gradients(X, first, second, stiffness, rest_length, rest_length_squared, dim, law, out):
    """out[r] = sum_e c_e(L_e) (e_i - e_j) kron delta_e at the state X[r], for every row r; out is overwritten."""
    rows = X.shape[0]
    delta = np.empty(dim)
    out[:] = 0.0
    for r in range(rows):
        for e in range(first.size):
            i, j = first[e] * dim, second[e] * dim
            squared = 0.0
            for c in range(dim):
                delta[c] = X[r, i + c] - X[r, j + c]
                squared += delta[c] * delta[c]
            scale = gradient_factor(law, stiffness[e], math.sqrt(squared), rest_length[e], rest_length_squared[e])
            for c in range(dim):
                value = delta[c] * scale
                out[r, i + c] += value
                out[r, j + c] -= value
    return out


# The springs at one state, for every solver (projective dynamics' local step and right-hand side are these): one
# pass over the springs for the geometry, one over the vertices for the gradient, which gathers each vertex's springs
# in the order of the incidence matrix's row (what scipy's sparse product does): the numpy path's numbers bit for bit.
# Single-threaded on purpose: a pass is too short to pay for waking two parallel regions' threads, and numba's OpenMP
# threads left spinning after it slow the energy's BLAS dot that follows (OpenBLAS's threads on the same cores;
# docs/performance.md, "Projective dynamics and L-BFGS").
@numba.njit(cache=True, error_model="numpy")
def spring_geometry(x, first, second, stiffness, rest_length, dim, delta, length, stretch, tension):
    """delta_e = x_i - x_j, L_e = |delta_e|, L_e - l0_e and k_e (L_e - l0_e), written into the four arrays."""
    for e in range(first.size):
        i, j = first[e] * dim, second[e] * dim
        squared = 0.0
        for c in range(dim):
            component = x[i + c] - x[j + c]
            delta[e, c] = component
            squared += component * component
        length[e] = math.sqrt(squared)
        stretch[e] = length[e] - rest_length[e]
        tension[e] = stiffness[e] * stretch[e]


@numba.njit(cache=True, error_model="numpy")
def gather_spring_gradient(indptr, springs, signs, delta, factor, dim, out):
    """out[d v + c] = sum over the springs e of vertex v (incidence row v, in its order) of sign * delta_e[c] c_e;
    out is overwritten. dim is 2 or 3: the components are summed side by side, each in the row's order."""
    for v in range(indptr.size - 1):
        x_total, y_total, z_total = 0.0, 0.0, 0.0
        for k in range(indptr[v], indptr[v + 1]):
            e = springs[k]
            scale = factor[e]
            x_total += signs[k] * (delta[e, 0] * scale)
            y_total += signs[k] * (delta[e, 1] * scale)
            if dim == 3:
                z_total += signs[k] * (delta[e, 2] * scale)
        out[dim * v] = x_total
        out[dim * v + 1] = y_total
        if dim == 3:
            out[dim * v + 2] = z_total
    return out


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
