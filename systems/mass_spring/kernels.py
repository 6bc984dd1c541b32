"""Compiled spring loops: the springs' gradient at several states at once (Radau IIA's stages, ``MassSpring.gradients``).

One pass over the springs per state: delta = x_i - x_j, L = |delta|, the law's factor c_e(L) (dW_e/dx_i = c_e delta),
scattered into the gradient in spring order. The numpy path makes the same numbers with a dozen array operations
and two transposing copies (about 100 us for three states of the 16 x 16 cloth against 40 us here); its
incidence product sums each vertex's springs in spring order too, so the two agree to round-off. A law enters the loop
as its code (``LAW_CODES``): numba's cache does not keep a kernel that takes a compiled function as an argument (every
process compiled it again, into a new cache entry).
"""

from __future__ import annotations

import math

import numba
import numpy as np


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
