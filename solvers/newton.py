"""Newton's method on the residual of a nonlinear problem."""

from __future__ import annotations

import numpy as np

from .base import NonlinearProblem, SolveStats
from .linear import LINEAR_SOLVERS

# A Newton step this small relative to |y| changes y only in its last bits: the iterate is as good
# as floating point allows, whatever the residual's own round-off says.
ROUNDOFF_STEP = 16 * np.finfo(float).eps


class Newton:
    """Newton's method: H(y_k) p = -g(y_k), y_{k+1} = y_k + p, until |g|_inf <= tol |g(y_0)|_inf.

    The test is relative to the starting residual, so it needs no units. Two round-off limits also
    end the iteration as converged: the residual below the problem's ``residual_floor``, or a Newton
    step that no longer changes y beyond its last bits. Checking the residual after an update is not counted as an iteration, so a linear
    problem converges in exactly one.
    """

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver: str = "direct"):
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.linear_solve = LINEAR_SOLVERS[linear_solver]

    def minimize(self, problem: NonlinearProblem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        y = start.copy()
        gradient = problem.gradient(y)
        residual = float(np.max(np.abs(gradient))) if gradient.size else 0.0
        threshold = max(self.tolerance * residual, problem.residual_floor)
        iterations = linear_iterations = 0
        stalled = False
        while residual > threshold and not stalled and np.isfinite(residual) and iterations < self.max_iterations:
            direction, cost = self.linear_solve(problem.hessian(y), -gradient, problem.fixed_dofs)
            y += direction
            iterations += 1
            linear_iterations += cost
            gradient = problem.gradient(y)
            residual = float(np.max(np.abs(gradient)))
            stalled = float(np.max(np.abs(direction))) <= ROUNDOFF_STEP * float(np.max(np.abs(y)))
        converged = bool(residual <= threshold or (stalled and np.isfinite(residual)))
        return y, SolveStats(iterations, linear_iterations, 0, residual, converged)

    def newton_step(self, problem: NonlinearProblem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        """Exactly one Newton iteration from ``start`` (the semi-implicit methods): no convergence test."""
        direction, cost = self.linear_solve(problem.hessian(start), -problem.gradient(start), problem.fixed_dofs)
        y = start + direction
        # the residual left at the result says how far one iteration is from the implicit solution
        residual = float(np.max(np.abs(problem.gradient(y))))
        return y, SolveStats(1, cost, 0, residual, True)
