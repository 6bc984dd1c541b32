"""A fallback chain: when a solver does not converge on a step, the next one of the chain tries.

As PolyFEM's solver fallbacks: ``fallback: [lbfgs, gradient_descent]`` behind the main solver.
"""

from __future__ import annotations

import numpy as np

from .base import LINEAR_FAILURES, NonlinearSolver, SolveStats
from .newton import SAFEGUARDS


class FallbackChain:
    """Solvers tried in turn on a step until one converges.

    A fallback restarts from the best iterate of the attempt before it (the one with the smallest
    |residual|_inf, the start itself when nothing improved on it), with the convergence test fixed
    at the step's start: the threshold stays tolerance times the residual at the original start,
    so a rescued step meets the same criterion as one the main solver finished. The statistics sum
    the iterations (nonlinear, linear, line search) over all attempts; ``solver_index`` says which
    solver finished the step (0: the main one, 1: the first fallback, ...) and ``converged`` whether
    it converged. ``newton_step`` (the semi-implicit methods' single iteration) is the main solver's,
    or, when its linear solve fails (an indefinite matrix for MPCG or Cholesky, a singular one), the first
    solver's of the chain whose Newton matrix the solve takes (projected Newton's SPD one).
    """

    def __init__(self, solvers: list[NonlinearSolver]):
        if not solvers:
            raise ValueError("a fallback chain needs at least one solver")
        self.solvers = list(solvers)

    @property
    def main(self) -> NonlinearSolver:
        return self.solvers[0]

    @property
    def needs_no_blas_threads(self) -> bool:
        """Whether no solver of the chain gains from BLAS threads (``NonlinearSolver.needs_no_blas_threads``)."""
        return all(solver.needs_no_blas_threads for solver in self.solvers)

    def minimize(self, problem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        first = self.main.starting_point(problem, start)
        outcome = self.main.solve(problem, first, self.main.test_from(problem, start, first))
        iterations, linear, line_search = (outcome.stats.iterations, outcome.stats.linear_iterations,
                                           outcome.stats.line_search_steps)
        safeguards = outcome.stats.safeguards
        index = 0
        while not outcome.stats.converged and index + 1 < len(self.solvers):
            index += 1
            outcome = self.solvers[index].solve(problem, outcome.best, test=outcome.test)
            iterations += outcome.stats.iterations
            linear += outcome.stats.linear_iterations
            line_search += outcome.stats.line_search_steps
            safeguards |= outcome.stats.safeguards | SAFEGUARDS["fallback"]
        return outcome.y, SolveStats(iterations, linear, line_search, outcome.stats.residual,
                                     outcome.stats.converged, index, safeguards)

    def newton_step(self, problem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        for index, solver in enumerate(self.solvers):
            try:
                y, stats = solver.newton_step(problem, start)
            except LINEAR_FAILURES:
                if index + 1 == len(self.solvers):
                    raise
                continue
            return y, stats._replace(solver_index=index)
        raise AssertionError("unreachable: the chain has at least one solver")
