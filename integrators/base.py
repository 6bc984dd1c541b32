"""The contract of a time integrator, and the incremental potential that most implicit ones share.

An integrator is a small frozen object: its parameters are pydantic fields (so they double as the
config schema) and its class declares ``name``, ``order``, ``explicit`` and a one-line ``summary``.
It supplies
- ``step(system, state, dt, solver) -> (State, SolveStats)``: one step of size dt (s);
- optionally ``start(system, state) -> State``: fill the method's carried quantities (``State.aux``,
  e.g. the acceleration of Newmark or the previous state of a multistep method) from (x0, v0).

Implicit methods that are the minimisation of an incremental potential (DESIGN.md) build an
``IncrementalPotential`` and hand it to the solver, which knows nothing about integrators. Methods
that sample the force at several points of the step (the average vector field, the BDF2/midpoint
mix) build a ``SegmentPotential`` (integrators/segment.py): its gradient is their residual and its
Hessian their Jacobian, and it still has a value, so line-search solvers can use it too.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.sparse
from pydantic import BaseModel, ConfigDict

from simrun.solvers import SolveStats
from simrun.solvers.base import FLOAT64, INITIAL_GUESSES, SMALL_VECTOR, max_norm
from simrun.systems import System
from simrun.systems.patterns import add_keeping_pattern, diagonal_blocks

from .labels import parameter_text
from .lanes import LaneIncrementalPotential


@dataclass(slots=True)  # not frozen: built once per step, and a frozen __init__ is slower (docs/performance.md)
class State:
    """The changing state: time t (s), positions x (m), velocities v (m/s), and a method's carried arrays.

    Treated as immutable: a step returns a new State and never writes into the one it was given. ``reusable``, no
    part of its value, is what the step that reached it leaves the next (Radau IIA's K and factors, dopri5's slope)."""

    t: float
    x: np.ndarray
    v: np.ndarray
    aux: tuple[np.ndarray, ...] = ()
    reusable: object = None


@dataclass(slots=True)
class StepPlan:
    """An incremental-potential step before its solve: the predictor y~ (m), the scale s = c h^2 (s^2), the velocity
    map v(y) = (y - a)/b (origin a in m, divisor b in s), where D is taken, and the fraction theta of the step at
    which the unknown lies; ``carried``: what the method's ``finish`` needs besides y (Newmark's x^).

    Every array is a linear function of the step's start state without a constant term (gravity is in P, not in
    y~), so a method's ``plan`` and ``finish`` applied to a state's derivative give the derivative of the plan and of
    the next state: the forward sensitivities of integrators/sensitivity.py step through the methods' own code."""

    y_tilde: np.ndarray
    scale: float
    velocity_origin: np.ndarray
    velocity_divisor: float
    damping_at: np.ndarray
    fraction: float = 1.0
    carried: tuple = ()

    def problem(self, system: System, state: State, dt: float) -> "IncrementalPotential":
        if getattr(system, "lane_count", None) is not None:  # many runs stepped together (systems/lanes.py)
            return LaneIncrementalPotential(system, self.y_tilde, self.scale, self.velocity_origin, self.velocity_divisor,
                                            self.damping_at, (state.x, state.v, dt), self.fraction)
        problem = IncrementalPotential(system, self.y_tilde, self.scale, velocity_origin=self.velocity_origin,
                                       velocity_divisor=self.velocity_divisor, damping_at=self.damping_at,
                                       step_start=(state.x, state.v, dt), fraction=self.fraction)
        problem.prescribed = on_paths(system, state, dt, self.fraction)
        return problem


class Integrator(BaseModel):
    """Base of all integrators; see the module docstring for the contract."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: ClassVar[str]
    order: ClassVar[int]
    explicit: ClassVar[bool]
    summary: ClassVar[str]
    # the problem its steps hand the solver: "incremental_potential" (IncrementalPotential), "segment_potential"
    # (SegmentPotential), "newton_step" (one Newton step on an IncrementalPotential, solver.newton_step), or None
    # (no solver); solvers that need one kind refuse the others at config time
    problem_kind: ClassVar[str | None] = None

    # whether one step is a linear map of the state on a linear system (every method here: its amplification matrix
    # is then probed from unit states); False for a method nonlinear by design, whose card is measured from runs
    linear: ClassVar[bool] = True
    # the unit round-off of the arithmetic a step is computed in: float64's, except an engine's that steps in float32;
    # the analysis reads growth of the probed spectral radius only above what that round-off could make
    unit_roundoff: ClassVar[float] = 2.0 ** -53
    # whether this class's step is elementwise arithmetic of the state and the system's acceleration, kick or
    # incremental potential (StepPlan), so that it steps many runs held as lanes of one array (systems/lanes.py) as it
    # steps one; only a class's own declaration counts (``steps_lanes``): a subclass may change the step
    lanes: ClassVar[bool] = False

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        if "name" not in vars(cls):  # a class that names itself nothing is named by its path (a plug-in's label)
            cls.name = f"{cls.__module__}:{cls.__qualname__}"

    @classmethod
    def steps_lanes(cls) -> bool:
        """Whether this class itself declares ``lanes``: its steps take lanes of runs as they take one run."""
        return bool(vars(cls).get("lanes", False))

    def start(self, system: System, state: State) -> State:
        return state

    def prepare(self, system: System, dt: float) -> None:
        """What a run sets up before its stepping time starts (an engine's model of the system, built and compiled for
        steps of dt s); nothing for simrun's own methods."""

    def engine_description(self) -> str:
        """The engine that takes this method's steps, its version, precision and device ("MuJoCo 4.0.0, float64,
        CPU"); "" for simrun's own methods."""
        return ""

    def unused_parameters(self) -> frozenset[str]:
        """The parameters this instance's steps do not read (an option of other variants only): labels leave them
        out."""
        return frozenset()

    # whether the method takes steps of one fixed size only (an engine whose step size is a model option): no step
    # control then
    fixed_steps_only: ClassVar[bool] = False

    @abstractmethod
    def step(self, system: System, state: State, dt: float, solver) -> tuple[State, SolveStats]:
        """Advance ``state`` by dt (s); implicit methods solve with ``solver``."""

    def plan(self, state: State, dt: float) -> StepPlan | None:
        """The incremental potential of the step from ``state`` (``StepPlan``), for the methods whose steps are one;
        None for the others. Such a method's ``step`` is ``potential_step``."""
        return None

    def finish(self, state: State, plan: StepPlan, y: np.ndarray, dt: float) -> State:
        """The state after the step, from the minimiser y of ``plan``'s potential (linear in state and y)."""
        raise TypeError(f"{self.name} takes no incremental-potential steps")

    # what ``start`` puts in State.aux: () (nothing, or a multistep method's history that its first step fills),
    # or ("acceleration",), M^-1 f(x0, v0) (Newmark's family): the forward sensitivities start it too
    started_aux: ClassVar[tuple[str, ...]] = ()

    def potential_step(self, system: System, state: State, dt: float, solver) -> tuple[State, SolveStats]:
        """``plan``, its problem solved from x_n (``solve_step``), then ``finish``."""
        plan = self.plan(state, dt)
        problem = plan.problem(system, state, dt)
        y, stats = solve_step(solver, problem, problem.start_point(state.x))
        return self.finish(state, plan, y, dt), stats

    def refusal(self, system: System) -> str | None:
        """Why this method cannot step ``system``, in one line, or None: the config refuses such a run before any
        starts (XPBD needs the system's springs as compliant constraints). Most methods step every system; contact
        asks more of them (``contact_refusal``)."""
        return contact_refusal(self, system)

    @property
    def unknown_fraction(self) -> float:
        """theta: the unknown of the method's problem is the position at t_n + theta h (1: x_{n+1} itself)."""
        return 1.0

    @property
    def order_of_accuracy(self) -> int:
        """The order with these parameter values; ``order`` is the order at the defaults (Newmark: 1 unless gamma = 1/2)."""
        return self.order

    def closed_form_spectral_radius(self, hw: np.ndarray) -> np.ndarray | None:
        """rho(h w) of the method on the undamped test spring q'' + w^2 q = 0, in closed form, where its author knows
        one; None (the default) where not. ``simrun check-integrator`` holds the measured radius to it."""
        return None

    def limiting_stiffness(self, system: System, x: np.ndarray):
        """The stiffness K whose stiffest frequency w (K v = w^2 M v) bounds this method's stable step on ``system``
        about x, at (h w)* of ``explicit_form`` on the test equation: the Hessian for an explicit method; None for an
        implicit one (no bound) and where no such bound is known (an IMEX pair's own rule: integrators/imex.py)."""
        return system.hessian(x) if self.explicit else None

    def explicit_form(self) -> "Integrator":
        """The method whose test-equation stability limit (h w)* goes with ``limiting_stiffness``: the method itself;
        an IMEX method with nothing implicit."""
        return self

    # what kind of method it is, for work-precision by family: lecture (the lectures' methods), explicit,
    # dirk, radau, bdf, rosenbrock, imex; peers: scipy
    family: ClassVar[str] = "lecture"
    # a peer's run is taken whole by another code (integrators/peers.py), not step by step
    whole_run: ClassVar[bool] = False

    def given_steps(self, duration: float) -> tuple[float, float] | None:
        """(mean step, duration) in s of a run whose times are given rather than chosen (a recorded trajectory, within
        the config's ``duration``): the sweep's dt does not multiply it; None for every method that takes steps."""
        return None
    # a multistep method's State.aux holds its history at its own past steps: a step from the same state at another
    # size (Richardson's two half steps) is not the method's step, so no Richardson estimate is taken of it
    carries_history: ClassVar[bool] = False

    @property
    def error_estimate(self) -> str | None:
        """What its steps' own local error estimate is (``step_with_error``), for adaptive steps; None: it has none."""
        return None

    @property
    def estimate_order(self) -> int:
        """q in: the local error estimate is O(h^q); the step controller's exponent is 1/q."""
        return self.order_of_accuracy + 1

    def estimate_order_from(self, state: State) -> int:
        """q of the estimate of the step from ``state``: ``estimate_order``, or its starter's while a multistep
        method's history is too short (the variable-step BDF starts with TR-BDF2)."""
        return self.estimate_order

    # a multistep method's controller changes the step less often and less at a time than a one-step method's: an
    # accepted step's proposed factor in [step_hold_below, step_hold) keeps the step (Radau IIA's, from 0: a step kept
    # is a factorisation saved), and a step grows at most ``step_growth`` times (the history is interpolated to the
    # new step, each change an error of its own: Shampine & Reichelt 1997, ode15s)
    step_hold: ClassVar[float] = 1.0
    step_hold_below: ClassVar[float] = 1.0
    step_growth: ClassVar[float] = 5.0

    def step_with_error(self, system: System, state: State, dt: float, solver, error_tolerance=None):
        """``step``, and the step's local error estimate as (2, dof_count) rows: positions (m), velocities (m/s).
        ``error_tolerance``: the step control's (rtol, atol), which Radau IIA's own iteration stops at a fraction of."""
        raise TypeError(f"{self.name} has no error estimate of its own")

    @property
    def label(self) -> str:
        """The name, with every parameter that differs from its default: ``generalized_alpha[rho_inf=0]``."""
        changed = [parameter_text(key, value) for key, value in self.model_dump().items()
                   if value != type(self).model_fields[key].default]
        return f"{self.name}[{','.join(changed)}]" if changed else self.name


def solve_step(solver, problem, start: np.ndarray) -> tuple[np.ndarray, SolveStats]:
    """``solver.minimize(problem, start)``, then, where friction asks it (``friction.lag_iterations`` k), k more
    solves from the solution with the friction's normal forces and tangent bases lagged there instead of at the
    step's start (IPC's re-lagging: each brings them closer to the solution's own); the statistics summed."""
    y, stats = solver.minimize(problem, start)
    for _ in range(getattr(problem, "relags", 0)):
        if not stats.converged:
            break
        problem.relag(y)
        y, more = solver.minimize(problem, y)
        stats = stats.followed_by(more)
    return y, stats


def contact_refusal(integrator: Integrator, system: System) -> str | None:
    """Why ``integrator`` cannot step ``system``'s contact, in one line, or None. IPC needs every step filtered so
    that no position crosses a surface: only the incremental-potential methods whose unknown is x_{n+1} itself
    have such steps (a line search cuts them); friction is a dissipative potential of the step's velocity map, which
    only the incremental-potential problems carry."""
    contact = system.contact_form()
    if not contact:
        return None
    kind = integrator.problem_kind
    if contact.needs_step_filter:
        if integrator.explicit or kind is None:
            return ("takes explicit steps, which nothing cuts short of a collision: IPC contact needs an "
                    "incremental-potential method (backward_euler, bdf2, newmark) whose line search CCD filters")
        if kind != "incremental_potential":
            why = ("takes one Newton step without a line search" if kind == "newton_step"
                   else "samples forces at points of the step x_n -> x_{n+1}, which CCD on the solver's steps does not keep apart")
            return f"{why}: IPC contact needs an incremental-potential method (backward_euler, bdf2, newmark)"
        if integrator.unknown_fraction != 1.0:
            return (f"solves for the position at t_n + {integrator.unknown_fraction:g} h and extrapolates x_{{n+1}} from it, "
                    "which CCD cannot keep out of a collider: IPC contact needs a method whose unknown is x_{n+1} "
                    "(backward_euler, bdf2, newmark; generalized_alpha only with rho_inf = 0)")
    if contact.has_friction:
        if kind not in ("incremental_potential", "newton_step"):
            return ("applies no friction: friction is a dissipative potential of the step's velocity map, which only "
                    "the incremental-potential methods carry")
        if integrator.unknown_fraction != 1.0:
            return (f"applies friction at t_n + {integrator.unknown_fraction:g} h, while friction's loss is booked with "
                    "the step's end velocity (the energy budget would not close): friction needs a method whose "
                    "unknown is x_{n+1} (backward_euler, bdf2, newmark, semi_implicit_backward_euler)")
    return None


def add_diagonal(matrix, diagonal: np.ndarray, in_place: bool = False):
    """matrix + diag(diagonal), for a dense array or a scipy sparse matrix.

    ``in_place``: the caller owns ``matrix`` (a temporary), so a dense float array is updated in place."""
    if in_place and type(matrix) is np.ndarray and matrix.dtype is FLOAT64 and matrix.flags.c_contiguous:
        # the diagonal of a C-ordered square array, through its flat view (ravel: cheaper than .flat)
        matrix.ravel()[:: matrix.shape[0] + 1] += diagonal
        return matrix
    if scipy.sparse.issparse(matrix):
        return matrix + scipy.sparse.diags(diagonal, format=matrix.format)
    result = np.array(matrix, dtype=float)
    result.flat[:: result.shape[0] + 1] += diagonal  # the diagonal, whatever the copy's memory order
    return result


def add_mass(matrix, system: System, in_place: bool = False):
    """matrix + M: the system's diagonal mass, and a consistent mass's correction where it has one."""
    matrix = add_diagonal(matrix, system.mass, in_place=in_place)
    if system.mass_correction is not None:
        matrix = matrix + (system.mass_correction if scipy.sparse.issparse(matrix) else system.mass_correction.toarray())
    return matrix


def mass_refusal(name: str, system: System) -> str | None:
    """Why a method that takes M as a diagonal (its inverse per dof, or per vertex) cannot step ``system``, or None."""
    if system.mass_correction is None:
        return None
    return (f"{name} takes M as a diagonal, and the system's mass is a consistent matrix: use mass: lumped, or a "
            "method that takes M whole (the incremental-potential and explicit methods)")


# round-off of M (y - y~): a few ulps of its largest term, and, where that term is subnormal (a motion damped to 1e-300
# m and below), a few of the subnormals' fixed spacing, which is then the round-off (relative digits are gone)
RESIDUAL_ULPS = 64.0 * np.finfo(float).eps
RESIDUAL_SUBNORMALS = 64.0 * np.finfo(float).smallest_subnormal


def residual_floor(mass: np.ndarray, y_tilde: np.ndarray) -> float:
    """The residual below which the inertia term's own round-off hides further progress: 64 eps |M y~|_inf, plus 64
    subnormal spacings."""
    if y_tilde.size <= SMALL_VECTOR and mass.shape == y_tilde.shape:
        # max_norm(mass * y_tilde) over Python floats (the same IEEE products), without the array in between
        largest = 0.0
        for factor, value in zip(mass.ravel().tolist(), y_tilde.ravel().tolist()):
            value = abs(factor * value)
            if value > largest:
                largest = value
            elif value != value:  # NaN, as max_norm propagates it
                return math.nan
        return RESIDUAL_ULPS * largest + RESIDUAL_SUBNORMALS
    return RESIDUAL_ULPS * max_norm(mass * y_tilde) + RESIDUAL_SUBNORMALS


def on_paths(system: System, state: State, dt: float, fraction: float = 1.0) -> np.ndarray | None:
    """The unknown of a step on the dofs of prescribed paths (None without any): where it puts x_{n+1} on the path,
    x_n + theta (p(t + h) - x_n) for an unknown at t_n + theta h. (y~ extrapolates them along their velocity: off a
    curved path by O(h^2), which costs the neighbours' motion and the energy budget an order.)"""
    constraints = system.constraints
    if constraints is None or not constraints.moving_dofs.size:
        return None
    moving = constraints.moving_dofs
    positions, _ = constraints.path(state.t + dt)
    return state.x[moving] + fraction * (positions - state.x[moving])


def constrained_start(system: System, start: np.ndarray, y_tilde: np.ndarray, prescribed: np.ndarray | None = None
                      ) -> np.ndarray:
    """S start + (I - S) y~ on the vertices of prescribed paths (the only ones where y~ and start differ
    on a filtered component: pinned and sliding vertices have no velocity along it); ``prescribed``: the values
    the unknown takes there instead of y~ (the step's problem knows the path: ``StepPlan.problem``)."""
    constraints = system.constraints
    if constraints is None or not constraints.moving_dofs.size:
        return start
    start = start.copy()
    start[constraints.moving_dofs] = y_tilde[constraints.moving_dofs] if prescribed is None else prescribed
    return start


def initial_guess(problem, kind: str, scale: float) -> np.ndarray:
    """Where a solve of one step starts, for the unknown y at t_n + theta h:
    ``start`` x_n; ``inertial`` x_n + theta h v_n (the lecture's "x_n + h v_n" for backward Euler);
    ``predictor`` the method's y~; ``adaptive`` y~ + c h^2 a~, a~ the part of the acceleration at the
    step's start along the external field g, clamped to [0, |g|] per vertex (Chen et al., "Vertex block
    descent", SIGGRAPH 2024, sec. 3.7, with the acceleration at (x_n, v_n) in place of their finite
    difference of the last two velocities); ``predictor`` where the system has no external field."""
    if kind == "predictor":
        return problem.y_tilde
    if problem.step_start is None:
        raise ValueError(f"initial_guess {kind!r}: this problem does not know the state at the start of its step")
    x_start, v_start, dt = problem.step_start
    if kind == "start":
        return x_start
    if kind == "inertial":
        return x_start + (problem.fraction * dt) * v_start
    if kind != "adaptive":
        raise ValueError(f"initial_guess must be one of {', '.join(INITIAL_GUESSES)}, got {kind!r}")
    system = problem.system
    field = system.external_acceleration
    if field is None:
        return problem.y_tilde
    dim = max(system.dim, 1)
    field_blocks = field.reshape(-1, dim)
    strength = np.sqrt(np.square(field_blocks).sum(axis=1))
    direction = field_blocks / np.where(strength > 0.0, strength, 1.0)[:, None]
    acceleration = system.acceleration(x_start, v_start).reshape(-1, dim)
    along = np.clip(np.einsum("ij,ij->i", acceleration, direction), 0.0, strength)
    # filtered as every solver's direction is: pinned vertices stay, sliding ones stay on their planes and lines
    displacement = scale * (along[:, None] * direction).ravel()
    if system.fixed_dofs.size:
        displacement[system.fixed_dofs] = 0.0
    if system.sliding is not None:
        system.sliding.apply(displacement)
    return problem.y_tilde + displacement


class _Identity:
    """Hashable by the identity of the object it holds (a scipy matrix is not hashable); keeps it alive."""

    __slots__ = ("held",)

    def __init__(self, held):
        self.held = held

    def __eq__(self, other) -> bool:
        return isinstance(other, _Identity) and other.held is self.held

    def __hash__(self) -> int:
        return id(self.held)


class IncrementalPotential:
    """E(y) = 1/2 (y - y~)^T M (y - y~) + s [P(y) + 1/(2 b) (y - a)^T D (y - a)],  s = c h^2.

    The minimiser solves M (y - y~) = s f(y, v(y)) with v(y) = (y - a)/b the method's velocity at
    the evaluation point y, so every incremental-potential method is described by its predictor
    y~, scale s, and velocity map (a, b). Damping f_d = -D v enters as a Rayleigh term, with D taken
    at the start of the step (exact for constant D).

    Parameters: system; y_tilde (m), shape (dof_count,); scale s = c h^2 (s^2);
    velocity_origin a (m) and velocity_divisor b (s); damping_at: positions at which D is taken;
    step_start (x_n, v_n, h) and fraction theta: the unknown is the position at t_n + theta h (1 for
    backward Euler, 1/2 for the implicit midpoint rule), which the initial guesses use.
    """

    fresh_gradient = True  # gradient() builds a new float64 array each call (M is float64): no copy needed
    projective = True  # the form projective dynamics minimises (with a system whose projective form is exact)

    def __init__(self, system: System, y_tilde: np.ndarray, scale: float,
                 velocity_origin: np.ndarray | None = None, velocity_divisor: float = 1.0,
                 damping_at: np.ndarray | None = None, step_start: tuple[np.ndarray, np.ndarray, float] | None = None,
                 fraction: float = 1.0):
        self.system = system
        self.y_tilde = y_tilde
        self.scale = scale
        self.velocity_divisor = velocity_divisor
        self.step_start = step_start
        self.fraction = fraction
        # a convex quadratic E (quadratic P, D constant): one full Newton step is its minimiser
        self.quadratic = system.quadratic_potential and (damping_at is None or system.damping_is_constant)
        self.fixed_dofs = system.fixed_dofs
        self.sliding = system.sliding
        damping = None if damping_at is None else system.damping_matrix(damping_at)
        self.damping = damping
        # the system fills one fixed CSR pattern (the cloth), and D, if any, shares it
        self._in_pattern = system.hessian_pattern is not None and (
            damping is None or (scipy.sparse.issparse(damping) and system.in_hessian_pattern(damping)))
        self.velocity_origin = velocity_origin
        self.damping_weight = scale / velocity_divisor
        # the residual M (y - y~) + ... cannot resolve differences below round-off of its largest term
        self.residual_floor = residual_floor(system.mass, y_tilde)
        # friction: a dissipative potential of the velocity map v(y) = (y - a)/b, lagged at the step's start
        self.contact = contact = system.contact_form()
        self.friction = None
        self.relags = 0
        if contact and step_start is not None and velocity_origin is not None:
            self.friction = contact.friction_term(step_start[0], velocity_origin, velocity_divisor)
            self.relags = contact.model.friction_relags if self.friction is not None else 0
        self.quadratic = self.quadratic and self.friction is None and not contact
        self.requires_step_filter = system.requires_step_filter
        self.prescribed = None  # the unknown on the prescribed paths' dofs (StepPlan.problem sets it), else y~ there

    def value(self, y: np.ndarray) -> float:
        offset = y - self.y_tilde
        energy = 0.5 * float(np.dot(self.system.mass_times(offset), offset)) + self.scale * self.system.potential_energy(y)
        if self.damping is not None:
            rate = y - self.velocity_origin
            energy += 0.5 * self.damping_weight * float(rate @ (self.damping @ rate))
        if self.friction is not None:
            energy += self.scale * self.friction.value(y)
        return energy

    def relag(self, y: np.ndarray) -> None:
        """Friction's normal forces and tangent bases taken at y instead, with the colliders where they are at the
        step's end, where y is (``solve_step``)."""
        self.friction = self.contact.friction_term(y, self.velocity_origin, self.velocity_divisor, self.contact.model.time)

    def max_step(self, y: np.ndarray, direction: np.ndarray) -> float:
        """The largest fraction in [0, 1] of the step y -> y + direction that no contact crosses (IPC's filter)."""
        return self.system.max_step(y, direction)

    def value_magnitude(self, y: np.ndarray) -> float:
        """The size of the terms ``value`` sums (kg m^2, E's units), which bounds E's round-off."""
        # the inertia term from y - y~, each difference with an error of about eps |y|
        offset = y - self.y_tilde
        momentum = np.abs(self.system.mass * offset)
        if self.system.mass_correction is not None:
            momentum += abs(self.system.mass_correction) @ np.abs(offset)
        magnitude = float(momentum @ (0.5 * np.abs(offset) + np.abs(y))) + self.scale * self.system.potential_magnitude(y)
        if self.damping is not None:
            rate = y - self.velocity_origin
            magnitude += 0.5 * self.damping_weight * abs(float(rate @ (self.damping @ rate)))
        if self.friction is not None:
            magnitude += self.scale * abs(self.friction.value(y))
        return magnitude

    def gradient(self, y: np.ndarray) -> np.ndarray:
        gradient = self.system.mass_times(y - self.y_tilde) + self.scale * self.system.gradient(y)
        if self.damping is not None:
            gradient += self.damping_weight * (self.damping @ (y - self.velocity_origin))
        if self.friction is not None:
            gradient += self.scale * self.friction.gradient(y)
        if self.fixed_dofs.size:
            gradient[self.fixed_dofs] = 0.0
        if self.sliding is not None:
            self.sliding.apply(gradient)
        return gradient

    def start_point(self, start: np.ndarray) -> np.ndarray:
        """``start`` with the components that a filter removes taken from y~ instead (S start + (I - S) y~).

        Solvers never move a filtered component, so it keeps its start value: y~ is the method's own
        value there, since no force acts on it (a pinned vertex: x_n; a vertex on a prescribed path at
        constant velocity: its exact position)."""
        if self.requires_step_filter:  # IPC: begin where no moving collider has overtaken a vertex
            start = self.contact.start(start) if self.contact else start
        return constrained_start(self.system, start, self.y_tilde, self.prescribed)

    def direction_guess(self, y: np.ndarray) -> np.ndarray:
        """An estimate of the first Newton step from y: the step to the inertial predictor, y~ - y."""
        return self.y_tilde - y

    def initial_guess(self, kind: str) -> np.ndarray:
        """The solve's start (before ``start_point``): see ``initial_guess``."""
        return initial_guess(self, kind, self.scale)

    def rest_hessian(self):
        """M + s K_r + (s/b) D, K_r the rest stiffness of the system's projective form and D this step's damping matrix (taken at
        ``damping_at``, so constant within the step): the matrix of projective dynamics' global step and of
        L-BFGS's rest-shape initial Hessian; None where the system has no rest stiffness. ``rest_key`` names it
        (equal keys, equal matrices) so that a solver keeps one factorisation for every step of a run, or, where
        D depends on x (spring damping), one per step."""
        form = self.system.projective_form()
        if not form:
            return None
        matrix = self.scale * form.rest_stiffness()
        if self.damping is not None:
            matrix = matrix + self.damping_weight * self.damping
        return add_mass(matrix, self.system)

    @property
    def rest_key(self) -> tuple:
        if self.damping is None:
            return (id(self.system), self.scale, None)
        if self.system.damping_is_constant:
            return (id(self.system), self.scale, self.damping_weight)
        # D(x) of this step: the key holds the matrix itself (compared by identity, and kept alive by whoever
        # keeps the key, so that its id cannot be reused by another step's matrix)
        return (id(self.system), self.scale, self.damping_weight, _Identity(self.damping))

    def hessian(self, y: np.ndarray, project_spd: bool = False):
        system = self.system
        extra = []  # terms outside the fixed pattern: mesh contact and its friction (ipctk)
        if self.friction is not None:  # PSD as it is: nothing to project but ipctk's mesh part
            mesh_friction = self.friction.mesh_hessian(y, project_spd)
            if mesh_friction is not None:
                extra.append(self.scale * mesh_friction)
        if self._in_pattern:
            data = self._hessian_data(y, project_spd)
            if self.friction is not None:
                vertices, blocks = self.friction.vertex_blocks(y)
                if vertices.size:
                    self.contact.add_vertex_blocks(data, vertices, self.scale * blocks)
            hessian = system.pattern_matrix(data)
            coupling = self.contact.coupling_hessian(y, project_spd) if self.contact else None  # mesh contact (IPC)
            if coupling is not None:
                extra.append(self.scale * coupling)
        else:
            hessian = self.scale * system.hessian(y, project_spd=project_spd)  # a new array: ours to change
            if self.damping is not None:
                hessian = hessian + self.damping_weight * self.damping
            hessian = add_mass(hessian, system, in_place=True)
            if self.friction is not None:
                extra.append(self.scale * self.friction.point_matrix(y))
        return add_keeping_pattern(hessian, *extra) if extra else hessian

    def _hessian_data(self, y: np.ndarray, project_spd: bool) -> np.ndarray:
        """s K + (s/b) D + M written straight into the system's fixed CSR pattern's data (``System.hessian_data``):
        the same sums as the sparse additions, without building and merging three matrices."""
        system = self.system
        data = system.hessian_data(y, project_spd)
        data *= self.scale
        if self.damping is not None:
            data += self.damping_weight * self.damping.data
        data[system.diagonal_positions] += system.mass
        if system.mass_correction is not None:  # a CSR matrix in the same pattern: its data adds entry for entry
            data += system.mass_correction.data
        return data

    # -- vertex by vertex: what vertex block descent needs (solvers/vbd.py) ------------------------------
    def vertex_colouring(self) -> list[np.ndarray]:
        """The system's colours: no two vertices of a colour share a term of P or of D (D lies in P's pattern)."""
        return self.system.vertex_form().colouring()

    def vertex_blocks(self, y: np.ndarray, vertices: np.ndarray, project_spd=False) -> tuple[np.ndarray, np.ndarray]:
        """E's gradient and Hessian blocks at the vertices i (k,): shapes (k, d) and (k, d, d),

            g_i = M_i (y_i - y~_i) + s dP/dy_i + (s/b) (D (y - a))_i,    H_i = M_i + s d^2P/dy_i^2 + (s/b) D_ii,

        with the system's blocks (``project_spd`` as ``hessian``). Not filtered: the solver applies the fixed
        dofs and sliding filters (E's own ``gradient`` zeroes them)."""
        system, d = self.system, self.system.dim
        vertices = np.asarray(vertices, dtype=np.intp)
        dofs = d * vertices[:, None] + np.arange(d)
        gradient, hessian = system.vertex_form().blocks(y, vertices, project_spd)
        mass = system.mass[dofs]
        gradient = mass * (y[dofs] - self.y_tilde[dofs]) + self.scale * gradient
        hessian = self.scale * hessian
        diagonal = np.arange(d)
        hessian[:, diagonal, diagonal] += mass
        if self.damping is not None:
            rows, damping_blocks = self._damping_rows(vertices, dofs)
            gradient += self.damping_weight * (rows @ (y - self.velocity_origin)).reshape(-1, d)
            hessian += self.damping_weight * damping_blocks
        return gradient, hessian

    def vertex_step_fractions(self, y, vertices, steps):  # the system's step filter per vertex: E adds no bound
        return self.system.vertex_form().step_fractions(y, vertices, steps)

    def vertex_energy_changes(self, y: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The change of E (J), shape (k,), when vertex i moves by u = steps[i] ((k, d), m) and the others stay at y,

            dE_i = u^T M_i (y_i - y~_i + u/2) + s dP_i + (s/b) [u^T (D (y - a))_i + u^T D_ii u / 2],

        dP_i the system's vertex form's ``energy_changes``; each term formed without cancellation, so that the change is
        resolved long after it has dropped below the round-off of E. The vertices must not interact (one colour)."""
        system, d = self.system, self.system.dim
        vertices = np.asarray(vertices, dtype=np.intp)
        dofs = d * vertices[:, None] + np.arange(d)
        changes = np.einsum("ij,ij->i", system.mass[dofs] * steps, y[dofs] - self.y_tilde[dofs] + 0.5 * steps)
        changes += self.scale * system.vertex_form().energy_changes(y, vertices, steps)
        if self.damping is not None:
            rows, damping_blocks = self._damping_rows(vertices, dofs)
            rates = (rows @ (y - self.velocity_origin)).reshape(-1, d)
            changes += self.damping_weight * (np.einsum("ki,ki->k", steps, rates)
                                              + 0.5 * np.einsum("ki,kij,kj->k", steps, damping_blocks, steps))
        return changes

    def _damping_rows(self, vertices: np.ndarray, dofs: np.ndarray):
        """D's rows at the vertices' dofs and its diagonal blocks D_ii (k, d, d), kept per vertex set for this step."""
        kept, key = self.__dict__.setdefault("_damping_parts", {}), vertices.tobytes()
        if key not in kept:
            kept[key] = (self.damping[dofs.ravel()], diagonal_blocks(self.damping, vertices, self.system.dim))
        return kept[key]
