"""Newton for many lanes at once (systems/lanes.py): a batched solve of each lane's incremental potential.

Every lane runs the iteration of ``NonlinearSolver._run`` with ``Newton``'s direction on a quadratic problem (its
Newton step is its minimiser, so there is no line search, as ``Newton._begin`` decides for one run): its own
convergence test (tolerance times its starting residual, or the absolute tolerance, never below its residual
floor), the round-off stall test, its own iteration counts, and a mask that takes a lane out as soon as it has
converged or its residual is not finite. The directions are stacked small solves: a division for one dof (what
the dense direct solver does for a 1 x 1 matrix, bit for bit), LAPACK's batched solve for more.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .base import ROUNDOFF_STEP

# the solver options a lane solve reproduces; any other (a fallback chain, an iterative linear solver, step
# tests, other initial guesses, whole-matrix eigenvalue clamping) makes its runs step alone
LANE_SOLVERS = ("newton", "projected_newton")
LANE_LINEAR_SOLVERS = ("direct", "cholesky")
LANE_TOLERANCE_MODES = ("residual", "absolute")


class LaneSolveStats(NamedTuple):
    """SolveStats with one entry per lane (arrays of shape (lanes,))."""

    iterations: np.ndarray
    linear_iterations: np.ndarray
    line_search_steps: np.ndarray
    residual: np.ndarray
    converged: np.ndarray
    solver_index: np.ndarray
    safeguards: np.ndarray


def lane_refusal(params) -> str | None:
    """Why runs with these solver options (a SolverParams) cannot be stepped as lanes, or None."""
    if params.type not in LANE_SOLVERS:
        return f"solver {params.type} (lanes take {', '.join(LANE_SOLVERS)})"
    if params.fallback:
        return "a fallback chain"
    if params.linear_solver not in LANE_LINEAR_SOLVERS:
        return f"linear solver {params.linear_solver}"
    if params.tolerance_mode not in LANE_TOLERANCE_MODES:
        return f"tolerance_mode {params.tolerance_mode}"
    if params.initial_guess != "start":
        return f"initial_guess {params.initial_guess}"
    if getattr(params, "spd_projection", "none") == "eigen":
        return "spd_projection eigen"
    return None


def stacked_solve(blocks: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with blocks[l] x[l] = rhs[l] for every lane: blocks (lanes, n, n), rhs (lanes, n)."""
    if blocks.shape[1] == 1:
        return rhs / blocks[:, :, 0]
    return np.linalg.solve(blocks, rhs[:, :, None])[:, :, 0]


def lane_max_norm(array: np.ndarray) -> np.ndarray:
    """|row|_inf per lane, NaN where a row holds a NaN (as max_norm)."""
    if array.shape[1] == 1:
        return np.abs(array[:, 0])
    return np.max(np.abs(array), axis=1)


class LaneNewton:
    """Newton on every lane of a LaneIncrementalPotential; ``minimize`` returns (y, LaneSolveStats)."""

    def __init__(self, params):
        refusal = lane_refusal(params)
        if refusal is not None:
            raise ValueError(f"lanes cannot reproduce {refusal}")
        self.tolerance = params.tolerance
        self.tolerance_mode = params.tolerance_mode
        self.max_iterations = params.max_iterations

    def _threshold(self, problem, residual: np.ndarray) -> np.ndarray:
        """ConvergenceTest.at_start per lane."""
        threshold = self.tolerance * residual if self.tolerance_mode == "residual" else np.full_like(residual, self.tolerance)
        floor = problem.residual_floor
        return np.where(floor > threshold, floor, threshold)  # Python's max(threshold, floor), NaN included

    def minimize(self, problem, start: np.ndarray):
        y = start  # never written to: every update is a new array
        gradient = problem.gradient(y)
        residual = lane_max_norm(gradient)
        threshold = self._threshold(problem, residual)
        lanes = y.shape[0]
        iterations = np.zeros(lanes, dtype=np.int64)
        linear = np.zeros(lanes, dtype=np.int64)
        converged = residual <= threshold
        active = ~converged & (residual < np.inf)  # (residual < inf: finite, as it is never negative)
        count = 0
        while count < self.max_iterations and active.any():
            everywhere = active.all()  # the common case: every lane iterates, and no mask is applied
            direction = stacked_solve(problem.hessian(y), -gradient)
            linear += active  # a direct solve counts one, also where the direction then ends the lane's solve
            size = lane_max_norm(direction)
            stalled = size <= ROUNDOFF_STEP * lane_max_norm(y)  # a direction below y's last bits: converged
            if stalled.any():
                converged |= active & stalled
                moving = active & ~stalled & (size < np.inf)
            else:
                moving = active & (size < np.inf)
            if everywhere and moving.all():
                y = y + direction
                gradient = problem.gradient(y)
                residual = lane_max_norm(gradient)
                iterations += 1
                count += 1
                met = residual <= threshold  # (False where not finite)
                if met.all():  # the common end: every lane converged in this iteration
                    converged = met
                    break
                finite = residual < np.inf
                converged |= met
                active = finite & ~met
                continue
            else:
                y = np.where(moving[:, None], y + direction, y)
                gradient = np.where(moving[:, None], problem.gradient(y), gradient)
                residual = np.where(moving, lane_max_norm(gradient), residual)
                iterations += moving
            count += 1
            finite = residual < np.inf
            met = moving & finite & (residual <= threshold)
            converged |= met
            active = moving & finite & ~met
        zeros = self._zeros(lanes)
        return y, LaneSolveStats(iterations, linear, zeros, residual, converged, zeros, zeros)

    def _zeros(self, lanes: int) -> np.ndarray:
        """The counts a Newton step of a quadratic problem leaves at zero (line search, fallback, safeguards): one
        read-only array per lane count, which the runner need not copy into its zero-filled records."""
        zeros = self.__dict__.get("zeros")
        if zeros is None or zeros.size != lanes:
            zeros = self.__dict__["zeros"] = np.zeros(lanes, dtype=np.int64)
            zeros.setflags(write=False)
        return zeros

    def newton_step(self, problem, start: np.ndarray):
        """Exactly one Newton iteration per lane (NonlinearSolver.newton_step)."""
        gradient = problem.gradient(start)
        y = start + stacked_solve(problem.hessian(start), -gradient)
        ones, zeros = np.ones(y.shape[0], dtype=np.int64), self._zeros(y.shape[0])
        return y, LaneSolveStats(ones, ones, zeros, lane_max_norm(problem.gradient(y)), np.ones(y.shape[0], dtype=bool),
                                 zeros, zeros)
