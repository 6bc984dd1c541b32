"""Newton's method on the residual of a nonlinear problem."""

from __future__ import annotations

import numpy as np

from .base import NonlinearProblem, SolveStats
from .linear import LINEAR_SOLVERS


class Newton:
    """Newton's method: H(y_k) p = -g(y_k), y_{k+1} = y_k + p, until |g|_inf <= tol |g(y_0)|_inf.

    The test is relative to the starting residual, so it needs no units; the problem's
    ``residual_floor`` (round-off of the residual itself) ends the iteration when the residual can no
    longer shrink. Checking the residual after an update is not counted as an iteration, so a linear
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
        while residual > threshold and np.isfinite(residual) and iterations < self.max_iterations:
            direction, cost = self.linear_solve(problem.hessian(y), -gradient, problem.fixed_dofs)
            y += direction
            iterations += 1
            linear_iterations += cost
            gradient = problem.gradient(y)
            residual = float(np.max(np.abs(gradient)))
        converged = bool(residual <= threshold)
        return y, SolveStats(iterations, linear_iterations, 0, residual, converged)

    def newton_step(self, problem: NonlinearProblem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        """Exactly one Newton iteration from ``start`` (the semi-implicit methods): no convergence test."""
        direction, cost = self.linear_solve(problem.hessian(start), -problem.gradient(start), problem.fixed_dofs)
        y = start + direction
        # the residual left at the result says how far one iteration is from the implicit solution
        residual = float(np.max(np.abs(problem.gradient(y))))
        return y, SolveStats(1, cost, 0, residual, True)
