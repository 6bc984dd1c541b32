"""The Newton family: plain Newton on the residual, and projected Newton with a line search."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse

from .base import Advance, NonlinearSolver
from .dofs import FreeDofs
from .line_search import has_value, line_search

SPD_PROJECTIONS = ("none", "clamp", "eigen")
# Whole-matrix eigenvalue clamping keeps eigenvalues >= this fraction of the largest |eigenvalue|:
# the projected matrix then has a condition number <= 1e8, well inside what a double solve resolves.
EIGEN_FLOOR = 1e-8


def project_eigen(matrix: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Clamp the eigenvalues of the free block of a symmetric dense matrix at EIGEN_FLOOR max |eigenvalue|.

    Only the free rows and columns (the matrix the linear solve sees) are projected; the fixed ones,
    which the solve drops, are left as they are."""
    symmetric = 0.5 * (matrix + matrix.T)
    free = np.setdiff1d(np.arange(symmetric.shape[0]), fixed) if fixed.size else np.arange(symmetric.shape[0])
    block = symmetric[np.ix_(free, free)]
    eigenvalues, eigenvectors = scipy.linalg.eigh(block, check_finite=False)
    floor = EIGEN_FLOOR * float(np.max(np.abs(eigenvalues), initial=0.0))
    if eigenvalues.size == 0 or eigenvalues.min() >= floor:
        return symmetric
    symmetric[np.ix_(free, free)] = (eigenvectors * np.maximum(eigenvalues, floor)) @ eigenvectors.T
    return symmetric


@dataclass(slots=True)
class _NewtonState:
    free: FreeDofs
    sparse_hessian: bool = False  # eigen projection: the problem's Hessian turned out sparse (use clamp)
    first: bool = True  # the first direction of this solve (the only one a linear solver's guess is for)


class Newton(NonlinearSolver):
    """Newton's method on the residual: H(y_k) p = -g(y_k), y_{k+1} = y_k + p (full steps).

    The raw Hessian (Jacobian) is used as is, so Newton also solves problems without a value and
    converges quadratically near a solution with a nonsingular Jacobian (Nocedal & Wright, thm 3.5);
    far from it, it may overshoot (no line search). Checking the residual after an update is not
    counted as an iteration, so a linear problem converges in exactly one.
    """

    name = "newton"
    supports_step_test = True
    uses_linear_solver = True

    def _begin(self, problem, current, free):
        return _NewtonState(free)

    def _direction(self, problem, current, state):
        matrix = self._model_hessian(problem, current.y, state)
        if self.linear_solver.wants_guess and state.first:
            state.first = False
            guess = problem.direction_guess(current.y) if hasattr(problem, "direction_guess") else None
            return self.linear_solver.solve(matrix, -current.gradient, state.free, spd=self.model_is_spd, guess=guess)
        return self.linear_solver.solve(matrix, -current.gradient, state.free, spd=self.model_is_spd)

    def _advance(self, problem, current, direction, state):
        return Advance(current.y + direction)


class ProjectedNewton(Newton):
    """Newton on the optimisation view: minimise E(y) with the SPD-projected Hessian and a line search.

    H+(y_k) p = -g(y_k) gives a descent direction (H+ is positive definite), and the step length
    alpha = 1, 1/2, 1/4, ... is cut until E(y_k + alpha p) <= E(y_k) (`backtracking`) or
    E(y_k + alpha p) <= E(y_k) + c alpha g^T p (`armijo`), so E never increases along the iterations
    (Li et al., "Physics-Based Simulation" lecture notes, projected Newton). ``spd_projection``:
    ``none`` (raw Hessian; a non-descent direction ends the solve as not converged), ``clamp`` (the
    problem's own projection: per spring for the cloth), ``eigen`` (eigenvalue clamping of the whole
    matrix for dense problems; sparse problems use ``clamp``, which for the cloth is the exact
    eigenvalue clamp of every spring's 3x3 block). Problems without a value take full steps.
    """

    name = "projected_newton"

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 line_search: str = "backtracking", spd_projection: str = "clamp", **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        if spd_projection not in SPD_PROJECTIONS:
            raise ValueError(f"spd_projection must be one of {', '.join(SPD_PROJECTIONS)}, got {spd_projection!r}")
        self.line_search = line_search
        self.spd_projection = spd_projection
        self.model_is_spd = spd_projection != "none"

    def _model_hessian(self, problem, y, state=None):
        if self.spd_projection == "none":
            return problem.hessian(y)
        if self.spd_projection == "eigen" and not (state is not None and state.sparse_hessian):
            hessian = problem.hessian(y)
            if not scipy.sparse.issparse(hessian):
                return project_eigen(np.array(hessian, dtype=float), np.asarray(problem.fixed_dofs, dtype=np.intp))
            if state is not None:  # sparse: clamp, and skip the raw Hessian for the rest of the solve
                state.sparse_hessian = True
        return problem.hessian(y, project_spd=True)

    def _begin(self, problem, current, free):
        if self.line_search != "none" and has_value(problem):
            current.energy = problem.value(current.y)
        return _NewtonState(free)

    def _advance(self, problem, current, direction, state):
        return line_search(problem, state.free, current, direction, self.line_search)
