"""The Newton family: Newton with a line search and safeguards, and projected Newton.

Both are one class with different defaults. Newton uses the raw Hessian and a backtracking line search on
the incremental potential; projected Newton the SPD-projected Hessian. Safeguards keep Newton from
blowing up where its raw Hessian is indefinite (contact, compressed springs). Each safeguard that fires
sets a bit of ``SolveStats.safeguards``, which the runner records per step:

- ``line_search`` (bit 1): the line search cut a step below its full length;
- ``projected`` (bit 2): the raw Newton direction was not a descent direction (or its solve failed, or
  its line search found no decrease); that iteration took the SPD-projected Hessian's direction instead;
- ``regularized`` (bit 4): the projected solve failed too; M (or the diagonal) was added, with a factor of
  10 more each time, until the solve gave a descent direction (Nocedal & Wright, "Numerical
  Optimization", sec. 3.4, "modified Newton");
- ``fallback`` (bit 8): set by a FallbackChain when a later solver of the chain took the step over (converged or not: the step's status says which; ``solver_index`` which solver).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse

from .base import LINEAR_FAILURES, NonlinearSolver
from .dofs import FreeDofs
from .lagged import LaggedFactor
from .line_search import has_value, line_search

SPD_PROJECTIONS = ("none", "clamp", "abs", "eigen", "adaptive")
# Whole-matrix eigenvalue clamping keeps eigenvalues >= this fraction of the largest |eigenvalue|:
# the projected matrix then has a condition number <= 1e8, well inside what a double solve resolves.
EIGEN_FLOOR = 1e-8
# safeguard bits of SolveStats.safeguards (the runner records them per step; docs/results-format.md)
SAFEGUARDS = {"line_search": 1, "projected": 2, "regularized": 4, "fallback": 8}
# solver.refactor: every (a new factorisation at every iteration) | adaptive (a lagged one) | preconditioner (a lagged one
# preconditioning PCG on the current matrix): solvers/lagged.py
REFACTOR_MODES = ("every", "adaptive", "preconditioner")
# preconditioner: PCG on the current Newton matrix, preconditioned by the kept factorisation, to this relative
# residual (an inexact Newton direction: Newton then converges linearly at about this rate); a solve that needs more
# than PRECONDITIONED_ITERATIONS iterations refactorises (the kept matrix has drifted too far from the current one)
PRECONDITIONED_TOLERANCE = 1e-3
PRECONDITIONED_ITERATIONS = 15
# adaptive: refactor once an iteration with the lagged matrix cuts the residual by less than this factor: the
# chord iterations' linear rate against the cost of a factorisation (measured on the hanging 32x32 and 64x64 cloth,
# backward Euler, dt = 0.01 s, tolerance 1e-9: 0.5 beat 0.1, 0.25 and 0.7; docs/performance.md)
DEFAULT_REFACTOR_RATE = 0.5
# adaptive projection: the raw Hessian for the next iteration once the last step's actual decrease of E
# was at least this fraction of the decrease its quadratic model predicted (the model is trusted: near
# the solution); the abs-projected Hessian otherwise. 0.75 is the "very successful step" threshold at
# which trust-region methods enlarge their region (Nocedal & Wright, alg. 4.1).
ADAPTIVE_TRUST = 0.75
# modified Newton: the first multiple of M added to a Hessian whose solve failed, and the growth per retry
REGULARIZATION_START, REGULARIZATION_GROWTH, REGULARIZATION_TRIES = 1e-6, 10.0, 16


def project_eigen(matrix: np.ndarray, fixed: np.ndarray, mirror: bool = False) -> np.ndarray:
    """The free block of a symmetric dense matrix with its eigenvalues clamped at EIGEN_FLOOR max |eigenvalue|
    (or, ``mirror``, replaced by max(|eigenvalue|, that floor): the abs projection).

    Only the free rows and columns (the matrix the linear solve sees) are projected; the fixed ones,
    which the solve drops, are left as they are."""
    symmetric = 0.5 * (matrix + matrix.T)
    free = np.setdiff1d(np.arange(symmetric.shape[0]), fixed) if fixed.size else np.arange(symmetric.shape[0])
    block = symmetric[np.ix_(free, free)]
    eigenvalues, eigenvectors = scipy.linalg.eigh(block, check_finite=False)
    floor = EIGEN_FLOOR * float(np.max(np.abs(eigenvalues), initial=0.0))
    if eigenvalues.size == 0 or eigenvalues.min() >= floor:
        return symmetric
    filtered = np.maximum(np.abs(eigenvalues) if mirror else eigenvalues, floor)
    symmetric[np.ix_(free, free)] = (eigenvectors * filtered) @ eigenvectors.T
    return symmetric


@dataclass(slots=True)
class _NewtonState:
    free: FreeDofs
    sparse_hessian: bool = False  # eigen projection: the problem's Hessian turned out sparse (use clamp)
    first: bool = True  # the first direction of this solve (the only one a linear solver's guess is for)
    trusted: bool = False  # adaptive: the last step's quadratic model was trusted (use the raw Hessian)
    safeguards: int = 0  # bits of SAFEGUARDS fired in this solve
    predicted: float = 0.0  # adaptive: the quadratic model's predicted decrease along the last direction
    previous_residual: float | None = None  # refactor adaptive: the residual at the last direction of this solve
    lagged: bool = False  # refactor adaptive: the last direction came from a lagged factorisation


class Newton(NonlinearSolver):
    """Newton's method with a backtracking line search and safeguards: H p = -g, y <- y + a p.

    ``spd_projection`` picks H: ``none`` the raw Hessian (Newton's quadratic convergence near a solution
    with a nonsingular Hessian, Nocedal & Wright thm 3.5); ``clamp`` the problem's own projection (each
    spring's and contact's negative block eigenvalues set to 0); ``abs`` the blocks' eigenvalues mirrored,
    |lambda| (Chen et al., "Trust-region eigenvalue filtering for projected Newton", SIGGRAPH Asia 2024:
    a compressed spring keeps its curvature's size instead of losing it); ``eigen`` whole-matrix
    eigenvalue clamping for dense problems (``clamp`` for sparse ones); ``adaptive`` abs while far from the
    solution and the raw Hessian once the last step's quadratic model predicted its decrease of E well
    (ratio >= ADAPTIVE_TRUST; our reading of that paper's trust-region rule).

    ``line_search``: ``backtracking`` (E(y + a p) <= E(y), a = 1, 1/2, ...), ``armijo`` or ``none`` (full
    steps; the plain Newton of the lectures' first slide). Problems without a value always take full steps.
    With a line search, an iteration whose raw direction is not a descent direction (g^T p >= 0), whose
    solve fails, or whose line search finds no decrease, is redone with the projected Hessian (abs
    where the problem offers it) and, should that fail too, with M added (see the module docstring).
    Checking the residual after an update is not counted as an iteration: a linear problem converges in one.
    """

    name = "newton"
    filters_steps = True  # every step through line_search
    supports_step_test = True
    uses_linear_solver = True

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 line_search: str = "backtracking", spd_projection: str = "none", refactor: str = "every",
                 refactor_rate: float = DEFAULT_REFACTOR_RATE, **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        if spd_projection not in SPD_PROJECTIONS:
            raise ValueError(f"spd_projection must be one of {', '.join(SPD_PROJECTIONS)}, got {spd_projection!r}")
        if refactor not in REFACTOR_MODES:
            raise ValueError(f"refactor must be one of {', '.join(REFACTOR_MODES)}, got {refactor!r}")
        self.line_search = line_search
        self.spd_projection = spd_projection
        self.model_is_spd = spd_projection not in ("none", "adaptive")
        self.refactor = refactor
        self.refactor_rate = refactor_rate
        self._lagged: LaggedFactor | None = None  # refactor adaptive, preconditioner: kept across the solves of a run

    # -- the matrix of an iteration --------------------------------------------------------------
    def _projected(self, problem, y, state, mode: str):
        """The Hessian under projection ``mode`` (clamp | abs | eigen), dense whole-matrix where asked."""
        if mode == "eigen" and not (state is not None and state.sparse_hessian):
            hessian = problem.hessian(y)
            if not scipy.sparse.issparse(hessian):
                return project_eigen(np.array(hessian, dtype=float), np.asarray(problem.fixed_dofs, dtype=np.intp))
            if state is not None:  # sparse: clamp, and skip the raw Hessian for the rest of the solve
                state.sparse_hessian = True
        return problem.hessian(y, project_spd="abs" if mode == "abs" else True)

    def _model_hessian(self, problem, y, state=None):
        mode = self.spd_projection
        if mode == "none" or (mode == "adaptive" and state is not None and state.trusted):
            return problem.hessian(y)
        return self._projected(problem, y, state, "abs" if mode == "adaptive" else mode)

    def _solve(self, matrix, rhs, state, spd, problem, y):
        if self.linear_solver.wants_guess and state.first:
            state.first = False
            guess = problem.direction_guess(y) if hasattr(problem, "direction_guess") else None
            return self.linear_solver.solve(matrix, rhs, state.free, spd=spd, guess=guess)
        return self.linear_solver.solve(matrix, rhs, state.free, spd=spd)

    # -- the contract of NonlinearSolver ---------------------------------------------------------
    def _begin(self, problem, current, free):
        # a convex quadratic problem (``problem.quadratic``: the spring, linear circular motion) needs neither the
        # line search nor the safeguards: its Newton step is its minimiser, and the small systems' steps stay cheap
        if self.line_search != "none" and has_value(problem) and not getattr(problem, "quadratic", False):
            current.energy = problem.value(current.y)
        return _NewtonState(free)

    def _direction(self, problem, current, state):
        if self.refactor == "adaptive" and current.energy is not None:  # a lagged matrix needs the line search's E
            return self._lagged_direction(problem, current, state)
        if self.refactor == "preconditioner" and current.energy is not None:
            return self._preconditioned_direction(problem, current, state)
        return self._fresh_direction(problem, current, state)

    def _preconditioned_direction(self, problem, current, state):
        """Newton-Krylov: the current matrix solved by PCG preconditioned with the kept factorisation (a few
        iterations while the matrix has not moved far from the factored one); the current matrix factorised and kept
        when PCG needs more than PRECONDITIONED_ITERATIONS, fails, or there is no factorisation yet."""
        matrix = self._model_hessian(problem, current.y, state)
        spd = self.model_is_spd and not (self.spd_projection == "adaptive" and state.trusted)
        factor = self._lagged
        if factor is not None and factor.fits(state.free):
            direction, iterations = factor.preconditioned_solve(matrix, -current.gradient, PRECONDITIONED_TOLERANCE,
                                                                PRECONDITIONED_ITERATIONS)
            if direction is not None and np.all(np.isfinite(direction)) and float(current.gradient @ direction) < 0.0:
                return direction, iterations
        return self._factorised_direction(problem, current, state, matrix, spd)

    def _lagged_direction(self, problem, current, state):
        """The direction of the kept factorisation, while the residual falls by at least ``refactor_rate`` per
        iteration and the direction descends; else the matrix at the current iterate, factorised and kept."""
        previous, state.previous_residual = state.previous_residual, current.residual
        slow = previous is not None and current.residual > self.refactor_rate * previous
        factor = self._lagged
        if factor is not None and not slow and factor.fits(state.free):
            direction = factor.solve(-current.gradient)
            if np.all(np.isfinite(direction)) and float(current.gradient @ direction) < 0.0:
                state.lagged = True
                return direction, 1
        state.lagged = False
        matrix = self._model_hessian(problem, current.y, state)
        spd = self.model_is_spd and not (self.spd_projection == "adaptive" and state.trusted)
        return self._factorised_direction(problem, current, state, matrix, spd)

    def _factorised_direction(self, problem, current, state, matrix, spd: bool):
        """The direction of ``matrix`` factorised here, and the factorisation kept for the next iterations; the
        safeguards' direction (nothing kept) where it is singular or its direction does not descend."""
        try:
            factor = LaggedFactor(matrix, state.free, spd, getattr(self.linear_solver, "log", None))
            direction = factor.solve(-current.gradient)
        except (*LINEAR_FAILURES, RuntimeError):
            factor, direction = None, None
        if direction is not None and np.all(np.isfinite(direction)) and float(current.gradient @ direction) < 0.0:
            self._lagged = factor
            return direction, 1
        self._lagged = None
        return self._safeguarded_direction(problem, current, state)

    def _fresh_direction(self, problem, current, state):
        matrix = self._model_hessian(problem, current.y, state)
        spd = self.model_is_spd and not (self.spd_projection == "adaptive" and state.trusted)
        if current.energy is None:  # no value: plain Newton on the residual
            return self._solve(matrix, -current.gradient, state, spd, problem, current.y)
        try:
            direction, cost = self._solve(matrix, -current.gradient, state, spd, problem, current.y)
        except LINEAR_FAILURES:
            if spd:
                raise  # an SPD matrix that cannot be solved: the safeguards would repeat the same solve
            direction, cost = None, 0
        if direction is not None and np.all(np.isfinite(direction)) and float(current.gradient @ direction) < 0.0:
            if self.spd_projection == "adaptive":
                state.predicted = -float(current.gradient @ direction) - 0.5 * float(direction @ (matrix @ direction))
            return direction, cost
        safe, extra = self._safeguarded_direction(problem, current, state)
        return safe, cost + extra

    def _safeguarded_direction(self, problem, current, state):
        """A descent direction where the model Hessian gave none: the projected Hessian's, else with M added."""
        rhs = -current.gradient
        if not self.model_is_spd or self.spd_projection == "adaptive":
            state.safeguards |= SAFEGUARDS["projected"]
            # abs, not clamp: a clamped block keeps no curvature along a climbing direction (a singular matrix
            # where the raw curvature is negative everywhere along it), a mirrored one turns the climb round
            projected = self._projected(problem, current.y, state, "abs")
            try:
                direction, cost = self.linear_solver.solve(projected, rhs, state.free, spd=True)
                if np.all(np.isfinite(direction)) and float(current.gradient @ direction) < 0.0:
                    state.predicted = 0.0
                    return direction, cost
            except LINEAR_FAILURES:
                pass
        state.safeguards |= SAFEGUARDS["regularized"]
        matrix = self._projected(problem, current.y, state, "clamp")
        mass = _mass_of(problem, matrix)
        shift = REGULARIZATION_START
        for _ in range(REGULARIZATION_TRIES):
            try:
                direction, cost = self.linear_solver.solve(_add_diagonal(matrix, shift * mass), rhs, state.free, spd=True)
                if np.all(np.isfinite(direction)) and float(current.gradient @ direction) < 0.0:
                    return direction, cost
            except LINEAR_FAILURES:
                pass
            shift *= REGULARIZATION_GROWTH
        raise np.linalg.LinAlgError("no descent direction: the regularised Newton matrix could not be solved")

    def _advance(self, problem, current, direction, state):
        advance = line_search(problem, state.free, current, direction, self.line_search, within_roundoff=True)
        if not advance.ok and state.lagged:  # the lagged matrix's direction gains nothing: the current matrix's
            state.lagged = False
            matrix = self._model_hessian(problem, current.y, state)
            spd = self.model_is_spd and not (self.spd_projection == "adaptive" and state.trusted)
            fresh, _ = self._factorised_direction(problem, current, state, matrix, spd)
            retried = line_search(problem, state.free, current, fresh, self.line_search, within_roundoff=True)
            retried.line_search_steps += advance.line_search_steps
            advance = retried
        if not advance.ok and current.energy is not None and not self.model_is_spd:
            # a descent direction of the raw Hessian along which E does not decrease: the projected one's
            try:
                safe, _ = self._safeguarded_direction(problem, current, state)
            except LINEAR_FAILURES:
                return advance
            retried = line_search(problem, state.free, current, safe, self.line_search, within_roundoff=True)
            retried.line_search_steps += advance.line_search_steps
            advance = retried
        if advance.line_search_steps:
            state.safeguards |= SAFEGUARDS["line_search"]
        if self.spd_projection == "adaptive" and advance.ok and advance.energy is not None:
            actual = current.energy - advance.energy
            state.trusted = state.predicted > 0.0 and actual >= ADAPTIVE_TRUST * state.predicted
        return advance


class ProjectedNewton(Newton):
    """Newton on the SPD-projected Hessian with a line search (Li et al., "Physics-Based Simulation"
    lecture notes, projected Newton): H+ p = -g gives a descent direction, and E never increases along
    the iterations. The default projection is ``clamp``; every option of ``Newton`` applies."""

    name = "projected_newton"

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 line_search: str = "backtracking", spd_projection: str = "clamp", refactor: str = "every",
                 refactor_rate: float = DEFAULT_REFACTOR_RATE, **options):
        super().__init__(tolerance, max_iterations, linear_solver, line_search=line_search,
                         spd_projection=spd_projection, refactor=refactor, refactor_rate=refactor_rate, **options)


def _mass_of(problem, matrix) -> np.ndarray:
    """The diagonal that modified Newton adds multiples of: the lumped mass, else |diag(H)| (floored at 1)."""
    system = getattr(problem, "system", None)
    if system is not None and getattr(system, "mass", None) is not None:
        return np.asarray(system.mass, dtype=float)
    diagonal = np.abs(np.asarray(matrix.diagonal() if scipy.sparse.issparse(matrix) else np.diag(matrix), dtype=float))
    return np.where(diagonal > 0.0, diagonal, 1.0)


def _add_diagonal(matrix, diagonal: np.ndarray):
    if scipy.sparse.issparse(matrix):
        return matrix + scipy.sparse.diags(diagonal, format=matrix.format)
    result = np.array(matrix, dtype=float)
    result.flat[:: result.shape[0] + 1] += diagonal
    return result
