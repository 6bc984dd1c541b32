"""What a solver sees, what it returns, and the iteration that every nonlinear solver shares.

A solver gets a nonlinear problem and knows nothing about integrators or time steps. A problem offers
- ``gradient(y)``: the residual, shape (n,) (the gradient of ``value`` where a value exists);
- ``hessian(y, project_spd=False)``: its Jacobian, a dense (n, n) array or a scipy sparse matrix;
  with ``project_spd=True`` the problem's own cheap SPD projection (the cloth clamps each spring's
  transverse eigenvalue at 0);
- ``value(y)``: the objective, where the problem is a minimisation (optional; every incremental
  potential has one);
- ``fixed_dofs``: indices that the solver must leave unchanged;
- ``residual_floor``: the residual below which round-off makes further progress meaningless;
- ``fresh_gradient`` (optional, default False): True when ``gradient`` returns a new float64 array
  on every call, which the solver may then keep without a copy.

Writing a solver (the contract, written once here): subclass ``NonlinearSolver`` and supply
- ``_begin(problem, iterate, free) -> state``: per-solve state (memory, step lengths), kept off ``self``
  so that one solver object serves every step of a run;
- ``_direction(problem, iterate, state) -> (p, linear_iterations)``: the search direction at the
  current iterate, zero on fixed degrees of freedom;
- ``_advance(problem, iterate, p, state) -> Advance``: the next iterate (a line search, a full step,
  a Chebyshev update), with its gradient and energy where it computed them.
Iterates are new arrays, never written to in place: the solve keeps the best one by reference.
``solve`` does the bookkeeping: the shared convergence test, iteration counts, the best iterate,
and the optional ``callback(y, gradient)`` after the start and every iteration.
"""

from __future__ import annotations

import functools
import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, ClassVar, NamedTuple, Protocol

import numpy as np

from .dofs import FreeDofs, free_dofs
from .linear import FLOAT64, LINEAR_SOLVERS, LinearSolver

# A search direction this small relative to |y| changes y only in its last bits: the iterate is as
# good as floating point allows, whatever the residual's own round-off says.
ROUNDOFF_STEP = 16 * np.finfo(float).eps
# Up to this many entries, |v|_inf is taken over Python floats (one particle in 3-D has 3 dofs).
SMALL_VECTOR = 8
# A failing linear solve (exactly singular factor, non-finite matrix) ends the nonlinear solve as not converged.
LINEAR_FAILURES = (np.linalg.LinAlgError, RuntimeError, ValueError, FloatingPointError)
# A factorisation at a solve's start that fails ends it as not converged; a ValueError there is a refusal
# (one line: the problem is not one the solver takes), which propagates.
FACTORISATION_FAILURES = (np.linalg.LinAlgError, RuntimeError, FloatingPointError)
TOLERANCE_MODES = ("residual", "absolute", "step", "velocity")
STEP_MODES = ("step", "velocity")  # the modes that test the Newton direction (Newton-type solvers only)
# where a solve starts: the kinds of a problem's initial_guess (integrators/base.py: initial_guess)
INITIAL_GUESSES = ("start", "inertial", "predictor", "adaptive")


@functools.cache
def _blas_libraries():
    """threadpoolctl's view of the loaded BLAS libraries (numpy's and scipy's, loaded by the time a solve runs), made
    once: making it scans the process's libraries."""
    import threadpoolctl

    return threadpoolctl.ThreadpoolController()


def one_blas_thread():
    """A context in which BLAS runs on one thread. OpenBLAS's threads, once woken by a call on long vectors (above
    about 10,000 entries), spin waiting for the next: on a machine's every core they take the time of whatever runs
    between the calls (docs/performance.md, "Threads and BLAS").
    - L-BFGS's two-loop recursion is 4 x history ddot and daxpy calls, each of which wakes them. The factor solves
      between the two loops keep the threads they were given: CHOLMOD's supernodal solve gains from them on large
      problems.
    - Vertex block descent's compiled sweeps and XPBD's projections run on numba's threads between the energies' BLAS
      calls, on the cores where OpenBLAS's woken threads spin, so that a sweep's time varies several-fold from call to
      call. Such a run holds BLAS at one thread throughout (runner/execution/simulate.py): limited within each solve
      only, the threads woken between solves keep spinning."""
    return _blas_libraries().limit(limits=1, user_api="blas")


class NonlinearProblem(Protocol):
    fixed_dofs: np.ndarray
    residual_floor: float

    def gradient(self, y: np.ndarray) -> np.ndarray: ...

    def hessian(self, y: np.ndarray, project_spd: bool = False): ...


class SolveStats(NamedTuple):
    """What one nonlinear solve cost and how it ended.

    Immutable (EXPLICIT_STEP is shared by every explicit step); a NamedTuple rather than a frozen
    dataclass because it is built once per implicit step, and a frozen dataclass's __init__ (one
    object.__setattr__ per field) costs more (docs/performance.md)."""

    iterations: int = 0  # nonlinear (Newton) iterations; the final residual check is not one
    linear_iterations: int = 0  # summed over the solve; a direct factor-and-solve counts as one
    line_search_steps: int = 0
    residual: float = 0.0  # |gradient|_inf at the returned point
    converged: bool = True
    solver_index: int = 0  # which solver of the fallback chain finished the step (0: the main one)
    safeguards: int = 0  # bits of the safeguards that fired (solvers/newton.py SAFEGUARDS; 0: none)

    def followed_by(self, later: "SolveStats") -> "SolveStats":
        """Two solves' statistics summed: the counts added, the residual and convergence of the later one (converged
        only if both were), the worse solver index, the safeguards of both."""
        return SolveStats(self.iterations + later.iterations, self.linear_iterations + later.linear_iterations,
                          self.line_search_steps + later.line_search_steps, later.residual,
                          self.converged and later.converged, max(self.solver_index, later.solver_index),
                          self.safeguards | later.safeguards)


EXPLICIT_STEP = SolveStats()  # what an explicit step reports: nothing solved


def max_norm(vector: np.ndarray) -> float:
    """|vector|_inf (NaN if any entry is NaN), 0 for an empty vector: the ufunc itself, not np.max's wrappers."""
    size = vector.size
    if size <= SMALL_VECTOR:  # the small systems: Python floats cost a fraction of any array reduction
        largest = 0.0
        for value in vector.ravel().tolist():
            value = abs(value)
            if value > largest:
                largest = value
            elif value != value:  # NaN, which np.max propagates too
                return math.nan
        return float(largest)
    # the ufunc's reduce on the flat view: cheaper than np.max with its wrappers and axis=None (docs/performance.md)
    return float(np.maximum.reduce(abs(vector.ravel())))


def _own_copy(array) -> np.ndarray:
    """np.array(array, dtype=float): a float64 copy the solver owns; ndarray.copy() where it already is one."""
    if type(array) is np.ndarray and array.dtype is FLOAT64:
        return array.copy()  # the same values, without np.array's argument parsing
    return np.array(array, dtype=float)


def free_dofs_of(problem, size: int) -> FreeDofs:
    """The FreeDofs of ``problem`` (its fixed dofs and sliding filters)."""
    return _free_dofs(size, problem.fixed_dofs, getattr(problem, "sliding", None))


_ALL_FREE: dict[int, FreeDofs] = {}  # size -> FreeDofs without fixed dofs (most problems of the small systems)


def _free_dofs(size: int, fixed_dofs, sliding=None) -> FreeDofs:
    """``free_dofs``, with the common case of no fixed dofs answered from a dict (no hashing of index bytes)."""
    if sliding is not None:
        return free_dofs(size, fixed_dofs, sliding)
    if fixed_dofs is None or len(fixed_dofs) == 0:
        free = _ALL_FREE.get(size)
        if free is None:
            free = _ALL_FREE[size] = free_dofs(size, ())
        return free
    return free_dofs(size, fixed_dofs)


# ------------------------------------------------------------------------------------------------
# The convergence test, shared by every nonlinear solver
# ------------------------------------------------------------------------------------------------
@dataclass(slots=True)  # slots: the small objects of every solve are built a little faster
class ConvergenceTest:
    """When a nonlinear solve has converged; fixed at the start point of the step.

    ``residual`` mode: |g(y_k)|_inf <= tolerance |g(y_0)|_inf, relative to the starting residual so
    that it needs no units. ``absolute``: |g(y_k)|_inf <= tolerance, in the residual's own units (kg m
    for an incremental potential: M (y - y~) + c h^2 dP/dy). ``step`` mode (Newton-type solvers):
    |p_k|_inf <= tolerance |p_0|_inf with p the (unscaled) Newton direction; near the solution p_k
    estimates the error y_k - y*, so this is the error-oriented test of Deuflhard ("Newton Methods for
    Nonlinear Problems", sec. 2.1). ``velocity`` (Newton-type solvers): the lectures' own rule,
    |p_k|_inf / b <= tolerance in m/s, b the problem's ``velocity_divisor`` (h for backward Euler: the
    course code's |p|_inf / h < 1e-2; h/2 for the implicit midpoint rule, whose unknown is x_{n+1/2}),
    so the solver needs no time step. In the step modes the direction that meets the test is applied
    before the solve ends (as both lectures do: x <- x + a p, then test). In every mode two round-off
    limits end the iteration as converged: the residual below the problem's ``residual_floor``, or a
    direction that no longer changes y beyond its last bits.
    """

    tolerance: float
    mode: str  # "residual" | "absolute" | "step" | "velocity"
    threshold: float  # the residual at which the solve has converged
    first_direction: float | None = None  # |p_0|_inf, set by the first direction (step mode)
    step_limit: float = 0.0  # velocity mode: the largest |p|_inf that meets the test, tolerance * b (m)

    @classmethod
    def at_start(cls, tolerance: float, mode: str, problem, residual: float) -> "ConvergenceTest":
        floor = float(getattr(problem, "residual_floor", 0.0))
        threshold = tolerance * residual if mode == "residual" else tolerance if mode == "absolute" else 0.0
        test = cls(tolerance, mode, max(threshold, floor))
        if mode == "velocity":
            divisor = getattr(problem, "velocity_divisor", None)
            if divisor is None:
                raise ValueError("tolerance_mode velocity: this problem has no velocity_divisor (the b in v(y) = (y - a)/b)")
            test.step_limit = tolerance * float(divisor)
        return test

    def residual_met(self, residual: float) -> bool:
        return residual <= self.threshold

    @property
    def tests_steps(self) -> bool:
        return self.mode == "step" or self.mode == "velocity"

    def step_met(self, direction_norm: float) -> bool:
        """Step modes: the direction is small enough (step mode: the first direction only sets the reference)."""
        if self.mode == "velocity":
            return direction_norm <= self.step_limit
        if self.mode != "step":
            return False
        if self.first_direction is None:
            self.first_direction = direction_norm
            return direction_norm == 0.0
        return direction_norm <= self.tolerance * self.first_direction

    @staticmethod
    def stalled(direction_norm: float, y: np.ndarray) -> bool:
        return direction_norm <= ROUNDOFF_STEP * max_norm(y)


def chebyshev_weight(position: int, previous_weight: float, rho: float) -> float:
    """omega at ``position`` of the Chebyshev semi-iterative sequence (Wang 2015, eq. 12):
    omega_1 = 1, omega_2 = 2 / (2 - rho^2), omega_k = 4 / (4 - rho^2 omega_{k-1})."""
    if position <= 1:
        return 1.0
    if position == 2:
        return 2.0 / (2.0 - rho * rho)
    return 4.0 / (4.0 - rho * rho * previous_weight)


# ------------------------------------------------------------------------------------------------
# The shared iteration
# ------------------------------------------------------------------------------------------------
@dataclass(slots=True)
class Iterate:
    """The current point of a solve: y, its gradient (zero on fixed dofs), |gradient|_inf, E(y) if known. The gradient
    is None where the loop left it for later (``Advance.residual_estimate``): residual is then the estimate."""

    y: np.ndarray
    gradient: np.ndarray | None
    residual: float
    energy: float | None = None


@dataclass(slots=True)
class Advance:
    """What ``_advance`` produced: the next y, with its gradient and energy where already computed.

    residual_estimate: what the step itself saw of the residual, where it sees one without a full gradient (vertex
    block descent: the largest |g_i|_inf where its sweep met vertex i). Above the threshold, the loop takes it as not
    converged and leaves the full gradient for later: for an iterate whose estimate meets the threshold, and for the
    solve's last iterate, whose residual is what the solve reports. So an estimate decides no convergence, only when to
    check it; the check may come one iteration after a full gradient would have met it."""

    y: np.ndarray
    gradient: np.ndarray | None = None
    energy: float | None = None
    line_search_steps: int = 0
    ok: bool = True  # False: no acceptable step was found (the solve stops, not converged)
    residual_estimate: float | None = None


@dataclass(slots=True)
class Outcome:
    """A finished solve: the result, its statistics, the best iterate seen and the convergence test used."""

    y: np.ndarray
    stats: SolveStats
    best: np.ndarray
    test: ConvergenceTest


class FrameClock:
    """A solve's time budget, as a real-time frame's: the solve stops before an iteration that would end past it, the
    next iteration's length taken as the last one's. The first iteration is always taken (its length is timed from the
    end of the solve's start, whose factorisations the budget includes but whose length is not an iteration's)."""

    __slots__ = ("deadline", "mark")

    def __init__(self, budget: float):
        self.mark = time.perf_counter()
        self.deadline = self.mark + budget

    def start_iterations(self) -> None:
        self.mark = time.perf_counter()

    def spent(self) -> bool:
        """After an iteration: whether one more as long would end past the budget."""
        now = time.perf_counter()
        length, self.mark = now - self.mark, now
        return now + length > self.deadline


class NonlinearSolver(ABC):
    """Base of the nonlinear solvers: the loop, the counts and the convergence test (see the module docstring).

    Parameters: tolerance (see ``ConvergenceTest``); max_iterations per solve;
    linear_solver: a name of LINEAR_SOLVERS or a LinearSolver (Newton directions, and the one Newton
    step of ``newton_step`` for every solver); tolerance_mode ``residual``, ``absolute``, ``step`` or
    ``velocity``; initial_guess: where ``minimize`` starts (``start``: the point the integrator gives,
    x_n; ``inertial``, ``predictor``, ``adaptive``: the problem's ``initial_guess(kind)``, see
    integrators/base.py); callback(y, gradient), called after the start and every iteration (tests
    record histories with it); time_budget: seconds of wall time per solve (its start, factorisations
    included): the solve stops unconverged before an iteration that would end past it (``FrameClock``; None: no
    limit; real-time practice: a frame's budget, see ``on_not_converged: accept``).
    """

    name: ClassVar[str]
    supports_step_test: ClassVar[bool] = False  # does |p_k| estimate the error (Newton-type directions)?
    # is the one Newton step of ``newton_step`` (semi_implicit_backward_euler) a step of this solver? Not for the
    # solvers whose iteration is not Newton's (projective dynamics, VBD): a run would carry a solver it never uses
    takes_newton_step: ClassVar[bool] = True
    uses_linear_solver: ClassVar[bool] = False  # are its directions linear solves (else only newton_step uses one)?
    # does every step go through line_search (which cuts it to the collision-free fraction IPC contact asks for)?
    filters_steps: ClassVar[bool] = False
    # is its work numba's compiled loops and vector operations, with no BLAS call that gains from threads? A run of it
    # then holds BLAS at one thread (one_blas_thread), whose woken threads would spin against numba's on the cores
    needs_no_blas_threads: ClassVar[bool] = False

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver: str | LinearSolver = "direct",
                 *, tolerance_mode: str = "residual", initial_guess: str = "start", callback: Callable | None = None,
                 time_budget: float | None = None):
        if tolerance_mode not in TOLERANCE_MODES:
            raise ValueError(f"tolerance_mode must be one of {', '.join(TOLERANCE_MODES)}, got {tolerance_mode!r}")
        if tolerance_mode in STEP_MODES and not self.supports_step_test:
            raise ValueError(f"tolerance_mode {tolerance_mode!r} needs a Newton-type solver; {self.name} steps do not estimate the error")
        self.initial_guess = initial_guess
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.linear_solver = LINEAR_SOLVERS[linear_solver]() if isinstance(linear_solver, str) else linear_solver
        self.tolerance_mode = tolerance_mode
        self.callback = callback
        if time_budget is not None and not time_budget > 0.0:
            raise ValueError(f"time_budget must be a positive number of seconds, got {time_budget!r}")
        self.time_budget = time_budget

    # -- public ------------------------------------------------------------------------------
    def minimize(self, problem: NonlinearProblem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        """Minimise (or zero the residual of) ``problem`` from ``start`` (or from the configured initial
        guess); returns (y, SolveStats)."""
        first = self.starting_point(problem, start)
        y, stats, _, _ = self._run(problem, first, self.test_from(problem, start, first))
        return y, stats

    def test_from(self, problem, start: np.ndarray, first: np.ndarray) -> ConvergenceTest | None:
        """The convergence test of a solve that begins at ``first`` instead of the integrator's ``start``
        (x_n): relative to the residual at x_n, so that every initial guess is held to the same threshold
        (None where they are the same point: the solve takes its own)."""
        if first is start:
            return None
        gradient = free_dofs_of(problem, start.size).zero_fixed(np.array(problem.gradient(start), dtype=float))
        return ConvergenceTest.at_start(self.tolerance, self.tolerance_mode, problem, max_norm(gradient))

    def starting_point(self, problem, start: np.ndarray) -> np.ndarray:
        """``start``, or the problem's initial guess of the configured kind (with its filtered components
        taken from y~, as ``start_point`` does for x_n)."""
        if self.initial_guess == "start":
            return start
        guess = getattr(problem, "initial_guess", None)
        if guess is None:
            raise ValueError(f"initial_guess {self.initial_guess!r}: this problem offers no initial guesses")
        point = guess(self.initial_guess)
        point = problem.start_point(point) if hasattr(problem, "start_point") else point
        if getattr(problem, "requires_step_filter", False):  # IPC: no further along x_n -> guess than contact allows
            step = point - start
            fraction = problem.max_step(start, step)
            if fraction < 1.0:
                point = start + fraction * step
        return point

    def solve(self, problem: NonlinearProblem, start: np.ndarray, test: ConvergenceTest | None = None) -> Outcome:
        """``minimize`` with everything a fallback chain needs; ``test`` carries the chain's first start."""
        return Outcome(*self._run(problem, start, test))

    def _run(self, problem, start: np.ndarray, test: ConvergenceTest | None):
        """The iteration: (y, SolveStats, best y, test), what ``Outcome`` holds (``minimize`` needs no Outcome)."""
        clock = None if self.time_budget is None else FrameClock(self.time_budget)
        free = _free_dofs(start.size, problem.fixed_dofs, getattr(problem, "sliding", None))
        callback = self.callback
        y = _own_copy(start)
        fresh_gradient = getattr(problem, "fresh_gradient", False)
        gradient = problem.gradient(y)
        gradient = free.zero_fixed(gradient if fresh_gradient else _own_copy(gradient))
        current = Iterate(y, gradient, max_norm(gradient))
        if test is None:
            test = ConvergenceTest.at_start(self.tolerance, self.tolerance_mode, problem, current.residual)
        best_residual, best = current.residual, y  # iterates are never changed in place: no copies
        iterations = linear_iterations = line_search_steps = 0
        converged = current.residual <= test.threshold  # test.residual_met, inlined
        if callback is not None:
            callback(current.y, current.gradient)
        state = None
        if not converged and math.isfinite(current.residual):
            began = True
            try:
                state = self._begin(problem, current, free)
            except FACTORISATION_FAILURES:  # a factorisation at the start (PD's, L-BFGS's H_0) failed: not converged
                began = False
            if clock is not None:
                clock.start_iterations()
            step_mode = test.tests_steps
            while began and iterations < self.max_iterations:
                try:
                    direction, cost = self._direction(problem, current, state)
                except LINEAR_FAILURES:
                    break
                if free.sliding is not None:  # every solver's direction moves sliding vertices along their filters only
                    direction = free.zero_fixed(direction)
                linear_iterations += cost
                size = max_norm(direction)
                if not math.isfinite(size):
                    break
                # test.stalled, inlined: a direction below y's last bits changes nothing
                if size <= ROUNDOFF_STEP * max_norm(current.y):
                    converged = True
                    break
                # step modes: the direction that meets the test is applied, then the solve ends
                final = step_mode and test.step_met(size)
                advance = self._advance(problem, current, direction, state)
                iterations += 1
                line_search_steps += advance.line_search_steps
                if not advance.ok:
                    converged = final  # a step below the tolerance that E cannot resolve: met all the same
                    break
                estimate = advance.residual_estimate
                if estimate is not None and callback is None and not final and not estimate <= test.threshold:
                    # not converged by the step's own estimate: the full gradient waits (a callback gets every one)
                    current = Iterate(advance.y, None, estimate, advance.energy)
                    if not math.isfinite(estimate):
                        break
                    if clock is not None and clock.spent():
                        break
                    continue
                gradient = advance.gradient
                if gradient is None:
                    gradient = problem.gradient(advance.y)
                    gradient = free.zero_fixed(gradient if fresh_gradient else _own_copy(gradient))
                residual = max_norm(gradient)
                current = Iterate(advance.y, gradient, residual, advance.energy)
                if callback is not None:
                    callback(current.y, current.gradient)
                if residual < best_residual:
                    best_residual, best = residual, current.y
                if not math.isfinite(residual):
                    break
                if residual <= test.threshold or final:  # test.residual_met, or the step test met
                    converged = True
                    break
                if clock is not None and clock.spent():  # the frame's time would be overrun by one more
                    break
        if current.gradient is None:  # the last iterate's residual was an estimate: the solve reports the true one
            gradient = problem.gradient(current.y)
            gradient = free.zero_fixed(gradient if fresh_gradient else _own_copy(gradient))
            current = Iterate(current.y, gradient, max_norm(gradient), current.energy)
            if current.residual < best_residual:
                best_residual, best = current.residual, current.y
            converged = converged or current.residual <= test.threshold  # as the loop would have tested it
        stats = SolveStats(iterations, linear_iterations, line_search_steps, current.residual, bool(converged),
                           0, self._safeguards(state))
        return current.y, stats, best, test

    def newton_step(self, problem: NonlinearProblem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
        """Exactly one Newton iteration from ``start`` (the semi-implicit methods), or from the configured
        ``initial_guess`` where it is not ``start`` (``starting_point``): no convergence test.

        Uses the solver's linear solver and Hessian (projected for projected Newton, raw otherwise)."""
        start = self.starting_point(problem, start)
        free = _free_dofs(start.size, problem.fixed_dofs, getattr(problem, "sliding", None))
        gradient = free.zero_fixed(np.array(problem.gradient(start), dtype=float))
        guess = {}
        if self.linear_solver.wants_guess and hasattr(problem, "direction_guess"):  # MPCG's filtered start
            guess["guess"] = problem.direction_guess(start)
        direction, cost = self.linear_solver.solve(self._model_hessian(problem, start), -gradient, free,
                                                   spd=self.model_is_spd, **guess)
        if free.sliding is not None:
            direction = free.zero_fixed(direction)
        y = start + direction
        # the residual left at the result says how far one iteration is from the implicit solution
        residual = max_norm(free.zero_fixed(np.array(problem.gradient(y), dtype=float)))
        return y, SolveStats(1, cost, 0, residual, True)

    # -- for subclasses --------------------------------------------------------------------------
    model_is_spd = False  # is _model_hessian SPD (the direct solver then factors without pivoting)?

    def _model_hessian(self, problem, y, state=None):
        return problem.hessian(y)

    def _begin(self, problem, current: Iterate, free: FreeDofs):
        return None

    def refusal(self, system, problem_kind: str) -> str | None:
        """Why this solver cannot solve the ``problem_kind`` problems (``Integrator.problem_kind``) of ``system``,
        in one line, or None: the config refuses such a run before any starts. Most solvers take every problem."""
        return None

    def _safeguards(self, state) -> int:
        """The SAFEGUARDS bits that fired in a solve (solvers with safeguards keep them in their state)."""
        return getattr(state, "safeguards", 0) if state is not None else 0

    @abstractmethod
    def _direction(self, problem, current: Iterate, state) -> tuple[np.ndarray, int]:
        """The search direction at the current iterate, and the linear iterations it cost."""

    @abstractmethod
    def _advance(self, problem, current: Iterate, direction: np.ndarray, state) -> Advance:
        """The step along ``direction`` (line search or full step) and the new iterate."""
