"""The Newton family: plain Newton on the residual, and projected Newton with a line search."""

from __future__ import annotations

import numpy as np

from .base import NonlinearProblem, SolveStats
from .linear import LINEAR_SOLVERS

# A Newton step this small relative to |y| changes y only in its last bits: the iterate is as good
# as floating point allows, whatever the residual's own round-off says.
ROUNDOFF_STEP = 16 * np.finfo(float).eps
# Armijo's sufficient-decrease constant; 1e-4 is the customary choice (Nocedal & Wright, sec. 3.1).
ARMIJO_C = 1e-4


class Newton:
    """Newton's method: H(y_k) p = -g(y_k), y_{k+1} = y_k + p, until |g|_inf <= tol |g(y_0)|_inf.

    The test is relative to the starting residual, so it needs no units. Two round-off limits also
    end the iteration as converged: the residual below the problem's ``residual_floor``, or a Newton
    step that no longer changes y beyond its last bits. Checking the residual after an update is not
    counted as an iteration, so a linear problem converges in exactly one.
    """

    project_spd = False

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
        line_search_steps = 0
        while residual > threshold and not stalled and np.isfinite(residual) and iterations < self.max_iterations:
            direction, cost = self.linear_solve(self._hessian(problem, y), -gradient, problem.fixed_dofs)
            step, reductions = self._step_length(problem, y, direction, gradient)
            direction *= step
            y += direction
            iterations += 1
            linear_iterations += cost
            line_search_steps += reductions
            gradient = problem.gradient(y)
            residual = float(np.max(np.abs(gradient)))
            stalled = float(np.max(np.abs(direction))) <= ROUNDOFF_STEP * float(np.max(np.abs(y)))
        converged = bool(residual <= threshold or (stalled and np.isfinite(residual)))
        return y, SolveStats(iterations, linear_iterations, line_search_steps, residual, converged)

    def _hessian(self, problem, y):
        return problem.hessian(y, project_spd=True) if self.project_spd else problem.hessian(y)

    def _step_length(self, problem, y, direction, gradient) -> tuple[float, int]:
        """Plain Newton takes the full step."""
        return 1.0, 0

    def newton_step(self, problem: NonlinearProblem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        """Exactly one Newton iteration from ``start`` (the semi-implicit methods): no convergence test."""
        direction, cost = self.linear_solve(self._hessian(problem, start), -problem.gradient(start), problem.fixed_dofs)
        y = start + direction
        # the residual left at the result says how far one iteration is from the implicit solution
        residual = float(np.max(np.abs(problem.gradient(y))))
        return y, SolveStats(1, cost, 0, residual, True)


class ProjectedNewton(Newton):
    """Newton on the optimisation view: minimise E(y) with the SPD-projected Hessian and a line search.

    H+(y_k) p = -g(y_k) gives a descent direction (H+ is positive definite), and the step length
    alpha = 1, 1/2, 1/4, ... is cut until E(y_k + alpha p) <= E(y_k) (`backtracking`) or
    E(y_k + alpha p) <= E(y_k) + c alpha g^T p (`armijo`), so E never increases along the iterations
    (Li et al., "Physics-Based Simulation" lecture notes, projected Newton). Problems without a value
    (a residual and its Jacobian only) take full steps.
    """

    project_spd = True

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver: str = "direct",
                 line_search: str = "backtracking", max_line_search: int = 40):
        super().__init__(tolerance, max_iterations, linear_solver)
        self.line_search = line_search
        self.max_line_search = max_line_search

    def _step_length(self, problem, y, direction, gradient) -> tuple[float, int]:
        if self.line_search == "none" or not hasattr(problem, "value"):
            return 1.0, 0
        energy = problem.value(y)
        slope = float(np.dot(gradient, direction))
        sufficient = ARMIJO_C * slope if self.line_search == "armijo" else 0.0
        step = 1.0
        for reductions in range(self.max_line_search):
            if problem.value(y + step * direction) <= energy + step * sufficient:
                return step, reductions
            step *= 0.5
        return step, self.max_line_search
