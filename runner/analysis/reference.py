"""Reference solutions for runs without an exact one (the cloth): what their error is measured against.

``reference_positions`` solves the system, rebuilt from its stored parameters, with scipy's solve_ivp
at a tight tolerance; ``reference_errors`` gives every such run of a results file its error at the
end time, against that solution or against another run of the file (e.g. the smallest dt). Figures,
``simrun plot --reference`` and the report use them; computed only on request, since a reference
costs more than the runs.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np

from simrun.errors import ConfigError

if TYPE_CHECKING:
    from simrun.results import Results, StoredRun

REFERENCE_METHODS = ("DOP853", "Radau", "BDF", "LSODA", "RK45")
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12
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
    import scipy.integrate

    if method not in REFERENCE_METHODS:
        raise ValueError(f"unknown reference method {method!r}; valid: " + ", ".join(REFERENCE_METHODS))
    times = np.asarray(sorted(set(float(t) for t in times)))
    n = system.dof_count
    end = float(times[-1])
    releases = [t for t in (system.constraints.release_times if system.constraints is not None else ()) if t < end]
    # one solve per stretch between releases of prescribed paths: the right-hand side jumps there, and an ODE solver
    # restarts at a discontinuity rather than stepping across it
    positions: dict[float, np.ndarray] = {}
    u = np.concatenate([system.x0, system.v0])
    for begin, finish in zip([0.0, *releases], [*releases, end]):
        inside = times[(times >= begin) & (times <= finish)]
        evaluated = np.union1d(inside, [finish])
        solution = scipy.integrate.solve_ivp(_rate(system), (begin, finish), u, method=method, t_eval=evaluated,
                                             rtol=rtol, atol=atol)
        if not solution.success:
            raise RuntimeError(f"reference solution ({method}) failed: {solution.message}")
        positions.update({float(t): solution.y[:n, column] for column, t in enumerate(solution.t) if t in inside})
        u = solution.y[:, -1]
        system = system.released(finish)
    return positions


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


def reference_errors(results: Results, reference: str, say=None) -> dict[str, float]:
    """run_id -> max |x - x_ref| (m) at the run's error time (``StoredRun.error_time``: the state stored there,
    ``error_positions``; format 1: the last stored state), for runs without an exact solution (NaN error).
    These stand in for ``StoredRun.error`` in the convergence figures and tables.

    ``reference``: a scipy solve_ivp method (dop853 by default: explicit, 8th order; at rtol 1e-10
    it is far more accurate than any run) solved on the system rebuilt from the stored
    ``system_params``, or a run_id of the file whose last state serves as the reference for runs
    of the same system and end time. Runs whose last state is not stored are skipped.
    """
    needing = [run for run in results.runs.values() if not np.isfinite(run.error) and not run.status.stopped]
    if not needing:
        return {}
    finals = {run.run_id: final for run in needing if (final := error_state(run)) is not None}
    errors: dict[str, float] = {}
    if reference in results.runs:  # another run (e.g. the smallest dt) as the reference
        anchor = results.runs[reference]
        anchor_final = error_state(anchor)
        if anchor_final is None:
            raise ConfigError(f"--reference: run {reference!r} has no stored final state to compare with")
        for run in needing:
            if run.run_id == reference or run.run_id not in finals:
                continue
            t_end, x_end = finals[run.run_id]
            if run.system_params == anchor.system_params and math.isclose(t_end, anchor_final[0], rel_tol=1e-9):
                errors[run.run_id] = float(np.max(np.abs(x_end - anchor_final[1])))
        return errors
    from simrun.analysis.oscillator import build_system  # the systems, only when a reference is solved

    method = {name.lower(): name for name in REFERENCE_METHODS}.get(str(reference).lower())
    if method is None:
        raise ConfigError(f"--reference: {reference!r} is neither a method nor a run of this file; valid: {REFERENCE_CHOICES}")
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
        if system.has_contact:
            # IPC's barrier is a potential of the step and friction one of the methods' velocity maps, which no ODE
            # holds; a penalty is a force, but one whose derivative jumps where a vertex touches: an explicit
            # reference crawls through every landing (hours for a stiff penalty cloth), and no method keeps its
            # order across the kink, so a reference there would measure the kink, not the methods
            if say:
                say(f"no reference solution for {system_type} with contact (non-smooth at every touch; IPC and "
                    "friction are no ODE's forces): --reference <run_id> compares with a run of the file instead")
            continue
        if say:
            say(f"reference solution ({method}, rtol {REFERENCE_RTOL:g}) for {system_type} to t = {times[-1]:g} s ...")
        try:
            solution = reference_positions(system, times, method)
        except (RuntimeError, ValueError) as error:
            if say:
                say(f"reference solution failed ({error}); no convergence figure for these runs")
            continue
        for run in runs:
            t_end, x_end = finals[run.run_id]
            reference_x = solution[min(solution, key=lambda t: abs(t - t_end))]
            errors[run.run_id] = float(np.max(np.abs(x_end - reference_x)))
    return errors


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
