"""What a solver sees and what it returns.

A solver gets a nonlinear problem and knows nothing about integrators or time steps. A problem offers
- ``gradient(y)``: the residual, shape (n,) (the gradient of ``value`` where a value exists);
- ``hessian(y)``: its Jacobian, a dense (n, n) array or a scipy sparse matrix;
- ``value(y)``: the objective, where the problem is a minimisation (optional);
- ``fixed_dofs``: indices that the solver must leave unchanged;
- ``residual_floor``: the residual below which round-off makes further progress meaningless.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


class NonlinearProblem(Protocol):
    fixed_dofs: np.ndarray
    residual_floor: float

    def gradient(self, y: np.ndarray) -> np.ndarray: ...

    def hessian(self, y: np.ndarray): ...


@dataclass(frozen=True, slots=True)
class SolveStats:
    """What one nonlinear solve cost and how it ended."""

    iterations: int = 0  # nonlinear (Newton) iterations; the final residual check is not one
    linear_iterations: int = 0  # summed over the solve; a direct factor-and-solve counts as one
    line_search_steps: int = 0
    residual: float = 0.0  # |gradient|_inf at the returned point
    converged: bool = True
    solver_index: int = 0  # which solver of the fallback chain finished the step (0: the main one)


EXPLICIT_STEP = SolveStats()  # what an explicit step reports: nothing solved
