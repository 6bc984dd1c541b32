"""Reference solutions for runs without an exact one (the cloth): what their error is measured against.

``reference_states`` solves the system, rebuilt from its stored parameters, with scipy's solve_ivp
at a tight tolerance (``reference_positions``: its x alone); ``reference_errors`` gives every such run of a results
file its error at the error time, against that solution or against another run of the file (e.g. the smallest dt).
A solved reference's own accuracy is estimated by a second one of another tolerance (and, unless the reference is
DOP853 itself, another method), solved at the same times: max |x_ref - x_check| there, stated with the errors
(``ReferenceErrors.statement``). Figures, ``simrun plot --reference`` and the report use them; computed only on
request, since a reference costs more than the runs.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np

from simrun.errors import ConfigError

if TYPE_CHECKING:
    from simrun.results import Results, StoredRun

REFERENCE_METHODS = ("DOP853", "Radau", "BDF", "LSODA", "RK45")
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12
# the second reference, which estimates the first's accuracy: DOP853 (8th order) a thousand times tighter, so that its
# own error is a small part of their difference; an explicit eighth-order pair stays affordable at that tolerance
# where scipy's Radau does not (on the work_precision cloth it takes minutes)
CHECK_METHOD = "DOP853"
CHECK_RTOL = 1e-13
CHECK_ATOL = 1e-15
REFERENCE_CHOICES = ("auto, none, " + ", ".join(name.lower() for name in REFERENCE_METHODS)
                     + ", or a run_id of the file")
# ``auto``: a file that studies convergence (one method at this many time steps or more) without an exact solution
# gets DOP853's reference; any other file none (a reference costs more than the runs)
CONVERGENCE_DTS = 3


def automatic_reference(results: "Results") -> str | None:
    """The reference ``auto`` stands for: "DOP853" where the runs without an exact solution study convergence (a
    method at CONVERGENCE_DTS time steps or more) on a smooth system (no contact: IPC's barrier and friction are no
    ODE's forces), else None."""
    needing = [run for run in results.runs.values() if not np.isfinite(run.error) and not run.status.stopped]
    if not needing or any(run.attrs.get("max_active_contacts") is not None for run in needing):
        return None
    steps: dict[str, set[float]] = {}
    for run in needing:
        steps.setdefault(run.label, set()).add(run.dt)
    return "DOP853" if max(len(dts) for dts in steps.values()) >= CONVERGENCE_DTS else None


def reference_positions(system, times, method: str = "DOP853", rtol: float = REFERENCE_RTOL,
                        atol: float = REFERENCE_ATOL) -> dict[float, np.ndarray]:
    """x(t) (m, shape (dof_count,)) at each of the given times (s), from scipy's solve_ivp on u = (x, v), u' = (v, M^-1 f(x, v))."""
    return {t: x for t, (x, _) in reference_states(system, times, method, rtol, atol).items()}


def reference_states(system, times, method: str = "DOP853", rtol: float = REFERENCE_RTOL,
                     atol: float = REFERENCE_ATOL) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """(x (m), v (m/s)), each of shape (dof_count,), at each of the given times (s), from scipy's solve_ivp on
    u = (x, v), u' = (v, M^-1 f(x, v))."""
    import scipy.integrate

    if method not in REFERENCE_METHODS:
        raise ValueError(f"unknown reference method {method!r}; valid: " + ", ".join(REFERENCE_METHODS))
    times = np.asarray(sorted(set(float(t) for t in times)))
    n = system.dof_count
    end = float(times[-1])
    releases = [t for t in (system.constraints.release_times if system.constraints is not None else ()) if t < end]
    # one solve per stretch between releases of prescribed paths: the right-hand side jumps there, and an ODE solver
    # restarts at a discontinuity rather than stepping across it
    states: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    u = np.concatenate([system.x0, system.v0])
    for begin, finish in zip([0.0, *releases], [*releases, end]):
        inside = times[(times >= begin) & (times <= finish)]
        evaluated = np.union1d(inside, [finish])
        solution = scipy.integrate.solve_ivp(_rate(system), (begin, finish), u, method=method, t_eval=evaluated,
                                             rtol=rtol, atol=atol)
        if not solution.success:
            raise RuntimeError(f"reference solution ({method}) failed: {solution.message}")
        states.update({float(t): (solution.y[:n, column], solution.y[n:, column])
                       for column, t in enumerate(solution.t) if t in inside})
        u = solution.y[:, -1]
        system = system.released(finish)
    return states


def _rate(system):
    """u' = (v, M^-1 f(x, v)) of the system, with its prescribed paths' own accelerations on their dofs."""
    n = system.dof_count
    constraints = system.constraints
    moving = constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp)

    def rate(t, u):
        acceleration = system.acceleration(u[:n], u[n:])
        if moving.size:  # the vertices on prescribed paths accelerate with their paths (centripetal for a rotation)
            acceleration[moving] = constraints.path_accelerations(t)
        return np.concatenate([u[n:], acceleration])

    return rate


class ReferenceErrors(dict):
    """run_id -> max |x - x_ref| (m) at the run's error time, and what that reference is and how well it is known.

    A dict, so that it stands in for the runs' errors wherever those are taken (figures, tables). Beside the errors:
    ``source`` (what the reference is), ``check`` (the second reference, "" where none was solved), ``accuracy``
    (run_id -> m: max |x_ref - x_check| over the error times of the run's system, the reference's estimated accuracy),
    ``velocity_errors`` (run_id -> max |v - v_ref| (m/s) at the error time, for runs that stored their velocities
    there), ``velocity_accuracy`` (run_id -> m/s) and ``coinciding`` (labels of compared runs that used the
    reference's own method and tolerance: their errors against it are not independent of it)."""

    def __init__(self, errors: Iterable = (), source: str = "", check: str = "", accuracy: dict | None = None,
                 velocity_errors: dict | None = None, velocity_accuracy: dict | None = None,
                 coinciding: list[str] | None = None):
        super().__init__(errors)
        self.source, self.check = source, check
        self.accuracy: dict[str, float] = accuracy or {}
        self.velocity_errors: dict[str, float] = velocity_errors or {}
        self.velocity_accuracy: dict[str, float] = velocity_accuracy or {}
        self.coinciding: list[str] = coinciding or []

    def accuracy_of(self, run_ids: Iterable[str]) -> float:
        """m: the largest estimated accuracy of the references of these runs (NaN where none was estimated)."""
        return _largest(self.accuracy, run_ids)

    def below_accuracy(self, run_ids: Iterable[str] | None = None) -> list[str]:
        """The runs (of ``run_ids``, default all) whose error is at or below their reference's estimated accuracy: there
        the difference measures the reference, not the run."""
        return [run_id for run_id in (self if run_ids is None else run_ids)
                if run_id in self and run_id in self.accuracy and self[run_id] <= self.accuracy[run_id]]

    def statement(self) -> str:
        """What the errors are measured against and how well it is known, as one clause (no final full stop)."""
        if not self.accuracy:
            return self.source + (" (its accuracy not estimated)" if self.source.startswith("scipy") else "")
        accuracy, velocity = _largest(self.accuracy), _largest(self.velocity_accuracy)
        moving = f", {velocity:.2g} m/s in v" if np.isfinite(velocity) else ""
        said = (f"{self.source}, whose own accuracy, estimated by a second reference ({self.check}) at the same times, "
                f"is max |x_ref − x_check| = {accuracy:.2g} m{moving}: errors at or below it measure the reference, not the run")
        if self.coinciding:
            said += (f"; the reference's method and tolerance are those of {', '.join(self.coinciding)}, whose errors "
                     "against it are not independent")
        return said


def _largest(values: dict[str, float], run_ids: Iterable[str] | None = None) -> float:
    """The largest of ``values`` (of ``run_ids``, default all); NaN where there is none."""
    chosen = [values[run_id] for run_id in (values if run_ids is None else run_ids) if run_id in values]
    return max(chosen) if chosen else math.nan


def reference_errors(results: Results, reference: str, say=None) -> ReferenceErrors:
    """run_id -> max |x - x_ref| (m) at the run's error time (``StoredRun.error_time``: the state stored there,
    ``error_positions``; format 1: the last stored state), for runs without an exact solution (NaN error).
    These stand in for ``StoredRun.error`` in the convergence and work-precision figures and tables.

    ``reference``: a scipy solve_ivp method (dop853 by default: explicit, 8th order; at rtol 1e-10
    it is far more accurate than any run) solved on the system rebuilt from the stored
    ``system_params``, or a run_id of the file whose last state serves as the reference for runs
    of the same system and end time. Runs whose last state is not stored are skipped. A solved reference is
    checked against a second one (CHECK_METHOD at CHECK_RTOL; ``ReferenceErrors.accuracy``), and compared runs that
    took its own method at its own tolerance are named (``ReferenceErrors.coinciding``).
    """
    needing = [run for run in results.runs.values() if not np.isfinite(run.error) and not run.status.stopped]
    if not needing:
        return ReferenceErrors()
    finals = {run.run_id: final for run in needing if (final := error_state(run)) is not None}
    if reference in results.runs:  # another run (e.g. the smallest dt) as the reference
        anchor = results.runs[reference]
        anchor_final = error_state(anchor)
        if anchor_final is None:
            raise ConfigError(f"--reference: run {reference!r} has no stored final state to compare with")
        errors = {}
        for run in needing:
            if run.run_id == reference or run.run_id not in finals:
                continue
            t_end, x_end = finals[run.run_id]
            if run.system_params == anchor.system_params and math.isclose(t_end, anchor_final[0], rel_tol=1e-9):
                errors[run.run_id] = float(np.max(np.abs(x_end - anchor_final[1])))
        return ReferenceErrors(errors, source=f"run {reference}")
    from simrun.analysis.oscillator import build_system  # the systems, only when a reference is solved

    method = {name.lower(): name for name in REFERENCE_METHODS}.get(str(reference).lower())
    if method is None:
        raise ConfigError(f"--reference: {reference!r} is neither a method nor a run of this file; valid: {REFERENCE_CHOICES}")
    errors = ReferenceErrors(source=f"scipy solve_ivp ({method}, rtol {REFERENCE_RTOL:g}, atol {REFERENCE_ATOL:g})",
                             check=f"{CHECK_METHOD}, rtol {CHECK_RTOL:g}, atol {CHECK_ATOL:g}",
                             coinciding=coinciding_runs(results, method, REFERENCE_RTOL))
    systems: dict[str, list[StoredRun]] = {}
    for run in needing:
        if run.run_id in finals:
            systems.setdefault(json.dumps([run.system, run.system_params], sort_keys=True), []).append(run)
    for key, runs in systems.items():
        system_type, params = json.loads(key)
        times = sorted({finals[run.run_id][0] for run in runs})
        try:
            system = build_system(system_type, params)
        except (RuntimeError, ValueError) as error:
            if say:
                say(f"reference solution failed ({error}); no convergence figure for these runs")
            continue
        if system.contact_form():
            # IPC's barrier is a potential of the step and friction one of the methods' velocity maps, which no ODE
            # holds; a penalty is a force, but one whose derivative jumps where a vertex touches: an explicit
            # reference crawls through every landing (hours for a stiff penalty cloth), and no method keeps its
            # order across the kink, so a reference there would measure the kink, not the methods
            if say:
                say(f"no reference solution for {system_type} with contact (non-smooth at every touch; IPC and "
                    "friction are no ODE's forces): --reference <run_id> compares with a run of the file instead")
            continue
        if say:
            say(f"reference solution ({method}, rtol {REFERENCE_RTOL:g}) for {system_type} to t = {times[-1]:g} s, and its "
                f"check ({CHECK_METHOD}, rtol {CHECK_RTOL:g}) ...")
        try:
            solution = reference_states(system, times, method)
            check = reference_states(system, times, CHECK_METHOD, CHECK_RTOL, CHECK_ATOL)
        except (RuntimeError, ValueError) as error:
            if say:
                say(f"reference solution failed ({error}); no convergence figure for these runs")
            continue
        # the reference's own accuracy: its distance from the check at every time a run's error is measured at
        accuracy = max(float(np.max(np.abs(solution[t][0] - check[t][0]))) for t in times)
        velocity_accuracy = max(float(np.max(np.abs(solution[t][1] - check[t][1]))) for t in times)
        for run in runs:
            t_end, x_end = finals[run.run_id]
            nearest = min(solution, key=lambda t: abs(t - t_end))
            reference_x, reference_v = solution[nearest]
            errors[run.run_id] = float(np.max(np.abs(x_end - reference_x)))
            errors.accuracy[run.run_id] = accuracy
            errors.velocity_accuracy[run.run_id] = velocity_accuracy
            if "error_velocities" in run:
                v_end = np.asarray(run["error_velocities"], dtype=float).ravel()
                errors.velocity_errors[run.run_id] = float(np.max(np.abs(v_end - reference_v)))
    return errors


def coinciding_runs(results: Results, method: str, rtol: float) -> list[str]:
    """The labels of the file's runs of scipy's ``method`` (solve_ivp peers) at the tolerance ``rtol``: a reference of
    that method and tolerance is the same computation as theirs, no independent measure of their error."""
    default = (results.config.get("step_control") or {}).get("tolerance")
    labels = []
    for run in results.runs.values():
        tolerance = run.params.get("step_control.tolerance", default)
        if (run.integrator == "solve_ivp" and str(run.integrator_params.get("method", "Radau")).lower() == method.lower()
                and tolerance is not None and math.isclose(float(tolerance), rtol, rel_tol=1e-9)):
            labels.append(run.label)
    return list(dict.fromkeys(labels))


def error_state(run: StoredRun) -> tuple[float, np.ndarray] | None:
    """(t, x) where the run's error is measured: the state stored at its error time; format 1 (which stored
    none): its last frame, or its last positions sample. None when the run has neither."""
    if "error_positions" in run:
        return run.error_time, np.asarray(run["error_positions"], dtype=float).ravel()
    if run.format_version >= 2:  # it stopped before its error time
        return None
    if "frames" in run and run["frames"].shape[0]:
        return float(run["frame_t"][-1]), np.asarray(run["frames"][-1], dtype=float).ravel()
    if "positions" in run and run["positions"].shape[0]:
        return float(run["t"][-1]), np.asarray(run["positions"][-1], dtype=float).ravel()
    return None
