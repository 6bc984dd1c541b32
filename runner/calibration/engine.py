"""One fit: min over theta of sum_k |x(t_k; theta) - x_obs(t_k)|^2 for one integrator and step, with
``scipy.optimize.least_squares`` (trust region reflective, bounds), and what it found.

A residual evaluation is one simulation (``step_run``): the run's own integrator, solver and step, from the system
built with the trial values, recording the observed dofs at every step; the recorded motion is read at the
observation times by cubic Hermite interpolation in each step (``scipy.interpolate.CubicHermiteSpline`` on x and
v), which is exact at the steps themselves. The Jacobian is the exact forward sensitivity where the method and the
parameter have one (integrators/sensitivity.py), finite differences otherwise. A trial that diverges gives a large
finite residual (the trust region then shrinks); a start that diverges is the fit's result, ``diverged``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.interpolate
import scipy.optimize

from simrun.calibration.keys import system_at
from simrun.execution.measures import RELEASE_SLACK, moving_dofs, on_paths, release
from simrun.integrators import Integrator, State
from simrun.integrators.sensitivity import ForwardSensitivity, exact_refusal

# a diverged trial's residual: this many times the observed motion's largest value, at every observation
DIVERGED_RESIDUAL = 1e3
# a finite-difference step: sqrt(eps) relative (forward differences balance truncation and round-off there)
DIFFERENCE_STEP = math.sqrt(np.finfo(float).eps)
# the config-value change that finds how a parameter enters the system (exact for the selections it makes)
SELECTION_CHANGE = 1.0
# an observation time within this fraction of dt of a step is at that step (compare: steps)
ON_STEP_TOLERANCE = 1e-6


class Status:
    CONVERGED, NOT_CONVERGED, DIVERGED, FAILED = "converged", "not_converged", "diverged", "failed"


@dataclass
class FitTask:
    """One fit, self-contained (sent to a worker): which run (integrator None: the system's exact solution),
    which parameters, what was observed and how to weigh it."""

    fit_id: str
    index: int
    label: str
    integrator: Integrator | None
    solver: object  # the run's SolverParams
    dt: float
    duration: float
    system: object  # the run's SystemParams (the fitted keys are set on it)
    keys: list[str]
    start: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    observations: object  # Observations
    weights: str = "position"
    compare: str = "steps"
    sensitivities: str = "auto"
    max_evaluations: int = 100
    tolerance: float = 1e-10


@dataclass
class FitOutcome:
    fit_id: str
    status: str
    message: str
    values: np.ndarray
    standard_errors: np.ndarray
    residual_norm: float  # |r| at the result (m, with velocities scaled to m)
    rms_residual: float  # |r| / sqrt(len r)
    evaluations: int  # residual evaluations of the least-squares solver
    iterations: int  # its Jacobian evaluations (one per accepted trust-region step, about)
    simulations: int  # every simulation, finite-difference ones included
    wall_time: float
    jacobian: str  # exact | finite_differences | mixed | none
    fitted_positions: np.ndarray  # (observations, observed dofs) at the result
    fitted_velocities: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


@dataclass
class Trajectory:
    """The observed dofs at every step (steps + 1, q), their tangents (steps + 1, q, p) when asked, and the step at
    which the run stopped being finite (0: never)."""

    x: np.ndarray
    v: np.ndarray
    dx: np.ndarray | None = None
    dv: np.ndarray | None = None
    diverged_step: int = 0


def step_run(system, integrator: Integrator, solver, dt: float, steps: int, dofs: np.ndarray,
             sensitivity: ForwardSensitivity | None = None) -> Trajectory:
    """Step ``integrator`` ``steps`` times from the system's initial state, keeping ``dofs`` of x and v (and of the
    tangents with ``sensitivity``); constraints, contact and prescribed paths as ``simrun.execution.simulate`` applies them."""
    q = dofs.size
    xs, vs = np.full((steps + 1, q), np.nan), np.full((steps + 1, q), np.nan)
    dxs = dvs = None
    state = State(0.0, system.x0.copy(), system.v0.copy())
    with_contact = bool(system.contact_form())
    if with_contact:
        system.contact_form().begin_run(dt, state.x)
    moving = moving_dofs(system)
    release_times = list(system.constraints.release_times) if system.constraints is not None else []
    state = integrator.start(system, state)
    tangent = None
    if sensitivity is not None:
        tangent = sensitivity.start(state)
        dxs, dvs = np.full((steps + 1, q, sensitivity.count), np.nan), np.full((steps + 1, q, sensitivity.count), np.nan)
        dxs[0], dvs[0] = tangent.x[dofs], tangent.v[dofs]
    xs[0], vs[0] = state.x[dofs], state.v[dofs]
    diverged = 0
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for n in range(steps):
            if with_contact:  # the system as released so far
                system.contact_form().begin_step(dt * n, dt, state.x)
            if sensitivity is None:
                state, _ = integrator.step(system, state, dt, solver)
            else:
                state, tangent, _ = sensitivity.step(state, tangent, dt, solver)
            if moving.size:
                state = on_paths(system.constraints, moving, state, dt * (n + 1))
            if release_times and dt * (n + 1) >= release_times[0] - RELEASE_SLACK * dt:  # as simulate releases them
                system, moving = release(system, release_times, dt * (n + 1), dt)
                if sensitivity is not None:
                    sensitivity = sensitivity.released(system)
            # one float: inf or NaN in any entry (or entries past 1e154, as good as diverged) makes it non-finite
            if not math.isfinite(float(state.x.dot(state.x) + state.v.dot(state.v))):
                diverged = n + 1
                break
            np.take(state.x, dofs, out=xs[n + 1])
            np.take(state.v, dofs, out=vs[n + 1])
            if tangent is not None:
                np.take(tangent.x, dofs, axis=0, out=dxs[n + 1])
                np.take(tangent.v, dofs, axis=0, out=dvs[n + 1])
    return Trajectory(xs, vs, dxs, dvs, diverged)


def at_times(trajectory: Trajectory, dt: float, times: np.ndarray, tangents: bool = False):
    """(x, v) of the trajectory at ``times`` (cubic Hermite in each step; exact at the steps), or of its tangents."""
    steps = trajectory.x.shape[0]
    grid = dt * np.arange(steps)
    values = trajectory.dx if tangents else trajectory.x
    rates = trajectory.dv if tangents else trajectory.v
    shape = values.shape[1:]
    spline = scipy.interpolate.CubicHermiteSpline(grid, values.reshape(steps, -1), rates.reshape(steps, -1), axis=0)
    return spline(times).reshape((times.size,) + shape), spline(times, 1).reshape((times.size,) + shape)


def steps_covering(duration: float, dt: float, last_time: float) -> int:
    """The run's steps (those of dt in the duration), and more if an observation lies past the last of them (by less
    than dt): a run is never read past its last step, where the interpolant would extrapolate."""
    steps = max(1, math.floor(duration / dt + 1e-9))
    return max(steps, math.ceil(last_time / dt - ON_STEP_TOLERANCE))


def on_steps(times: np.ndarray, dt: float) -> np.ndarray:
    """The observations whose times are steps of dt (to ON_STEP_TOLERANCE dt): a mask."""
    ratio = times / dt
    return np.abs(ratio - np.round(ratio)) <= ON_STEP_TOLERANCE


class Model:
    """theta -> the simulated observations and their residual, for one task; counts its simulations.

    With ``compare: steps`` only the observations at the run's steps enter the residual, read from the steps
    themselves (a method has no motion between its steps; interpolating one would bias the fit at large steps);
    ``interpolated`` uses every observation, through cubic Hermite interpolation in each step."""

    def __init__(self, task: FitTask):
        self.task = task
        observations = task.observations
        self.dofs = observations.dofs
        self.used = np.ones(observations.t.size, dtype=bool)
        self.step_index = None
        if task.integrator is not None and task.compare == "steps":
            self.used = on_steps(observations.t, task.dt)
            self.step_index = np.round(observations.t[self.used] / task.dt).astype(np.intp)
        self.times = observations.t[self.used]
        self.with_velocity = task.weights == "position_and_velocity"
        self.velocity_scale = observations.velocity_scale if self.with_velocity else 0.0
        self.steps = 0 if task.integrator is None else steps_covering(task.duration, task.dt, observations.t[-1])
        self.simulations = 0
        observed = [observations.positions[self.used].ravel()]
        if self.with_velocity:
            observed.append(self.velocity_scale * observations.velocities[self.used].ravel())
        self.observed = np.concatenate(observed)
        self.penalty = DIVERGED_RESIDUAL * (float(np.max(np.abs(self.observed))) + 1.0)
        self.last_diverged = 0

    def system(self, values: np.ndarray):
        return system_at(self.task.system, self.task.keys, values).build()

    def motion(self, values: np.ndarray, with_jacobian: bool = False, times: np.ndarray | None = None):
        """(x, v) at the compared observation times (``times``: at these instead, interpolated), and d(x, v)/dtheta
        (observations, q, p) by forward sensitivities for the parameters that have them (None where none); None
        for a run that diverged."""
        task = self.task
        try:
            system = self.system(values)
        except ValueError:  # a trial the model refuses (past a bound of its own: k <= 0): as bad as a divergence
            self.last_diverged = 0
            return None
        self.simulations += 1
        if task.integrator is None:  # the exact solution
            with np.errstate(over="ignore", invalid="ignore"):
                exact = system.exact_solution(self.times if times is None else times)
            x, v = exact[0][:, self.dofs], exact[1][:, self.dofs]
            if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
                return None
            return x, v, None
        sensitivity, columns = None, []
        if with_jacobian:
            sensitivity, columns = self.sensitivity(system, values)
        trajectory = step_run(system, task.integrator, task.solver.build(), task.dt, self.steps, self.dofs, sensitivity)
        self.last_diverged = trajectory.diverged_step
        if trajectory.diverged_step:
            return None
        if times is not None:
            return (*at_times(trajectory, task.dt, times), None)
        if self.step_index is not None:
            x, v = trajectory.x[self.step_index], trajectory.v[self.step_index]
        else:
            x, v = at_times(trajectory, task.dt, self.times)
        tangents = None
        if sensitivity is not None:
            if self.step_index is not None:
                dx, dv = trajectory.dx[self.step_index], trajectory.dv[self.step_index]
            else:
                dx, dv = at_times(trajectory, task.dt, self.times, tangents=True)
            tangents = (columns, dx, dv)
        return x, v, tangents

    def sensitivity(self, system, values: np.ndarray):
        """The forward sensitivity of the parameters that enter the system linearly, and their columns."""
        task = self.task
        if task.sensitivities == "finite_differences" or exact_refusal(system, task.integrator) is not None:
            return None, []
        derivatives, columns = [], []
        for column in range(len(task.keys)):
            moved = values.copy()
            moved[column] += SELECTION_CHANGE
            change = moved[column] - values[column]  # the change as stored, so that the selection divides exactly
            try:
                changed = self.system(moved)
            except ValueError:  # the moved value is not allowed (a bound of the model's own)
                continue
            derivative = system.parameter_derivative(changed, change)
            if derivative is not None:
                derivatives.append(derivative)
                columns.append(column)
        if not derivatives:
            return None, []
        return ForwardSensitivity(system, task.integrator, derivatives), columns

    def residual_of(self, motion) -> np.ndarray:
        if motion is None:
            return np.full(self.observed.size, self.penalty)
        x, v, _ = motion
        parts = [x.ravel()]
        if self.with_velocity:
            parts.append(self.velocity_scale * v.ravel())
        return np.concatenate(parts) - self.observed

    def jacobian_of(self, motion, values: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, str]:
        """d r/d theta: exact columns from the motion's tangents, forward differences for the rest."""
        count = len(self.task.keys)
        jacobian = np.empty((residual.size, count))
        exact_columns = []
        if motion is not None and motion[2] is not None:
            columns, dx, dv = motion[2]
            for slot, column in enumerate(columns):
                parts = [dx[:, :, slot].ravel()]
                if self.with_velocity:
                    parts.append(self.velocity_scale * dv[:, :, slot].ravel())
                jacobian[:, column] = np.concatenate(parts)
            exact_columns = list(columns)
        for column in range(count):
            if column in exact_columns:
                continue
            step = DIFFERENCE_STEP * max(1.0, abs(values[column]))
            moved = values.copy()
            moved[column] += step if values[column] + step <= self.task.upper[column] else -step
            change = moved[column] - values[column]
            jacobian[:, column] = (self.residual_of(self.motion(moved)) - residual) / change
        kind = ("exact" if len(exact_columns) == count else "finite_differences" if not exact_columns else "mixed")
        return jacobian, kind


def fit_one(task: FitTask) -> FitOutcome:
    """The least-squares fit of one task; never raises for a fit that goes wrong (its status says what happened)."""
    start_time = time.perf_counter()
    model = Model(task)
    count = len(task.keys)
    cache: dict = {}
    kinds: set[str] = set()

    def evaluate(values: np.ndarray):
        key = values.tobytes()
        if key not in cache:
            cache.clear()
            motion = model.motion(values, with_jacobian=True)
            residual = model.residual_of(motion)
            cache[key] = (motion, residual, None)
        return cache[key]

    def residual(values):
        return evaluate(np.asarray(values, dtype=float))[1]

    def jacobian(values):
        values = np.asarray(values, dtype=float)
        motion, value, matrix = evaluate(values)
        if matrix is None:
            matrix, kind = model.jacobian_of(motion, values, value)
            kinds.add(kind)
            cache[values.tobytes()] = (motion, value, matrix)
        return matrix

    nan = np.full(count, np.nan)
    try:
        first = model.motion(task.start)
        if first is None:
            return _outcome(task, model, Status.DIVERGED, f"the start diverged at step {model.last_diverged}", nan, nan,
                            None, start_time, "none", 0, 0)
        if task.integrator is None:  # the exact solution: no sensitivities, finite differences throughout
            with np.errstate(over="ignore", invalid="ignore"):
                result = scipy.optimize.least_squares(
                    lambda values: model.residual_of(model.motion(np.asarray(values, dtype=float))), task.start,
                    bounds=(task.lower, task.upper), method="trf", x_scale="jac", ftol=task.tolerance, xtol=task.tolerance,
                    gtol=task.tolerance, max_nfev=task.max_evaluations)
            kinds.add("finite_differences")
        else:
            result = scipy.optimize.least_squares(
                residual, task.start, jac=jacobian, bounds=(task.lower, task.upper), method="trf", x_scale="jac",
                ftol=task.tolerance, xtol=task.tolerance, gtol=task.tolerance, max_nfev=task.max_evaluations)
        values = result.x
        errors = standard_errors(result.jac, result.fun)
        final = model.motion(values)
        shown = model.motion(values, times=task.observations.t) if final is not None else None
    except Exception as error:  # a solver or model failure is a result, not the end of the calibration
        return _outcome(task, model, Status.FAILED, f"{type(error).__name__}: {error}", nan, nan, None, start_time,
                        "none", 0, 0)
    if final is None:
        status, message = Status.DIVERGED, f"the result diverged at step {model.last_diverged}"
    elif result.status == 0:
        status, message = Status.NOT_CONVERGED, f"stopped after {result.nfev} evaluations (max_evaluations): {result.message}"
    else:
        status, message = Status.CONVERGED, result.message
    kind = kinds.pop() if len(kinds) == 1 else ("mixed" if kinds else "none")
    return _outcome(task, model, status, message, values, errors, final, start_time, kind, result.nfev, result.njev or 0,
                    shown)


def standard_errors(jacobian: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """sqrt(diag(s^2 (J^T J)^-1)), s^2 = |r|^2 / (m - p): the parameters' standard errors for independent
    residuals of equal variance, estimated from the residual itself (NaN when m <= p)."""
    rows, count = jacobian.shape
    if rows <= count:
        return np.full(count, np.nan)
    variance = float(residual @ residual) / (rows - count)
    covariance = variance * np.linalg.pinv(jacobian.T @ jacobian)
    return np.sqrt(np.clip(np.diag(covariance), 0.0, None))


def _outcome(task, model, status, message, values, errors, motion, start_time, kind, evaluations, iterations,
             shown=None) -> FitOutcome:
    """The outcome; ``motion``: the compared motion at the result (its residual), ``shown``: the motion at every
    observation time (what is stored and drawn)."""
    shape = task.observations.positions.shape
    if motion is None:
        positions, velocities, residual = np.full(shape, np.nan), None, np.full(1, np.nan)
    else:
        positions, velocities = shown[0], shown[1]
        residual = model.residual_of(motion)
    norm = float(np.linalg.norm(residual))
    return FitOutcome(
        fit_id=task.fit_id, status=status, message=str(message), values=np.asarray(values, dtype=float),
        standard_errors=np.asarray(errors, dtype=float), residual_norm=norm, rms_residual=norm / math.sqrt(residual.size),
        evaluations=int(evaluations), iterations=int(iterations), simulations=model.simulations,
        wall_time=time.perf_counter() - start_time, jacobian=kind, fitted_positions=np.asarray(positions, dtype=float),
        fitted_velocities=None if velocities is None else np.asarray(velocities, dtype=float))


__all__ = ["FitOutcome", "FitTask", "Status", "at_times", "fit_one", "standard_errors", "step_run"]
