"""Simulate one run: step the integrator, record samples, decide the outcome. No I/O here."""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from simrun.experiment.config import Run
from simrun.format.record import (CONTACT_STEP_COLUMNS, FACTORISATION_STEP_COLUMNS, SOLVER_STEP_COLUMNS, decide_status,
                                  not_converged_message)
from simrun.format.run_result import RunResult
from simrun.format.summary import Status, series_summary as _series_summary
from simrun.integrators import State
from simrun.solvers import EXPLICIT_STEP
from simrun.solvers.base import one_blas_thread
from simrun.solvers.linear import RUN_FACTORISATIONS, attach_factorisation_log

from .evaluations import EvaluationCounts
from .measures import (RELEASE_SLACK, add_outcome, explicit_frequency, final_error, moving_dofs, on_paths, path_power,
                       release, vertex_constraint_kinds)
from .peers import simulate_peer
from .recorded import simulate_recorded
from .recording import Recorder
from .schedule import schedule_of
from .step_control import StepTooSmall
from .step_log import StepLog
from .workers import compiled_threads


# the integrators whose whole run another code takes (integrators/peers.py, integrators/recorded.py), by name
WHOLE_RUNS = {"solve_ivp": simulate_peer, "recorded": simulate_recorded}


def simulate(run: Run) -> RunResult:
    """Run the integrator on run.system over its schedule (fixed steps of run.dt, or the steps its step controller
    chooses to the duration); never raises for a bad run. A peer's run is taken by its own code (peers.py), a recorded
    trajectory's is read (recorded.py)."""
    if run.integrator.whole_run:
        return kept_as_recorded(WHOLE_RUNS[run.integrator.name](run), run.record)
    system = run.system.build()
    integrator = run.integrator
    solver = run.solver.build()
    threads = compiled_threads(run.solver.threads)
    check_every = run.divergence.check_every
    schedule = schedule_of(run, system, integrator)
    recorder = Recorder(system, schedule.sample_rows, schedule.frame_rows)
    error_state = None  # (t, x, v) at the end of the step where the run's error is measured
    with_frames = not system.records_state_per_sample
    with_contact = bool(system.contact_form())
    # per step, for a sparse system's direct solves: the furthest path a factorisation took (1 + its index in
    # FACTORISATION_PATHS; 0: none), and per run the count of each
    factorisations = attach_factorisation_log(solver) if system.hessian_pattern is not None else None
    if schedule.controlled and factorisations is not None:  # one log counts every factorisation, by path too
        schedule.factorisations = factorisations
    columns = [*SOLVER_STEP_COLUMNS, *(FACTORISATION_STEP_COLUMNS if factorisations is not None else ()),
               *(CONTACT_STEP_COLUMNS if with_contact else ()), *schedule.log_columns]
    log = StepLog(columns, schedule.log_rows)
    stop_on_not_converged = run.solver.on_not_converged == "stop"

    state = State(0.0, system.x0.copy(), system.v0.copy())
    if with_contact:  # IPC's barrier stiffness (auto) before anything evaluates the energy
        system.contact_form().begin_run(schedule.first_size(system, state), state.x)
    energy0 = system.total_energy(state.x, state.v)
    energy_bound = run.divergence.energy_factor * system.energy_scale()
    dissipated = 0.0  # work of the physical damping forces so far (J), for the energy budget
    work = 0.0  # work done on the system by the vertices on prescribed paths so far (J), for the energy budget
    friction = 0.0  # energy friction took out so far (J), for the energy budget
    moving = moving_dofs(system)
    # paths that end (``until``): released at the end of the first step that reaches the time
    release_times = list(system.constraints.release_times) if system.constraints is not None else []
    constraint_kinds = vertex_constraint_kinds(system)  # as the run starts: the paths' vertices before any release
    damped = system.is_damped

    record_sample, record_frame, total_energy = recorder.record, recorder.record_frame, system.total_energy
    step = integrator.step

    def record_stop(t: float, state: State, sampled: bool, framed: bool) -> None:
        """The sample (and frame) of the step a run stops at, unless the regular cadence took them already."""
        if not sampled:
            record_sample(t, state.x, state.v, dissipated, work, friction)
        if with_frames and not framed:
            record_frame(t, state.x)

    record_sample(0.0, state.x, state.v, dissipated, work, friction)
    if with_frames:
        record_frame(0.0, state.x)
    # W: the drivers' power at the start of each step (the trapezoidal rule's first point)
    step_start_power = path_power(system, moving, state.x, state.v, 0.0) if moving.size else 0.0
    failed = diverged = over_budget = False
    message, t_diverged, not_converged_steps = "", None, 0
    first_not_converged = diverged_step = 0  # 1-based step numbers; 0: none
    steps = solver_iterations = 0
    # a step-controlled run's evaluations (as wall_time, the set-up left out): fixed-step runs count none, so that a
    # run stepped alone stores what it stores stepped as a lane, where every lane's forces are one call
    evaluations = EvaluationCounts() if schedule.controlled else None
    if evaluations is not None:
        evaluations.instrument(system)
    # a run whose work is numba's threads (XPBD, VBD): OpenBLAS's threads, woken by a long vector's dot product,
    # would spin against them on the same cores
    blas = one_blas_thread() if needs_no_blas_threads(integrator, solver) else contextlib.nullcontext()
    if not schedule.controlled:
        integrator.prepare(system, run.dt)  # an engine's model, built before the stepping time starts
    start = time.perf_counter()
    counting = RUN_FACTORISATIONS.set(schedule.factorisations)
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"), blas:
            state = integrator.start(system, state)
            while not schedule.done:
                previous = state
                state, stats = schedule.next_step(system, state, step, solver, log)
                steps, t, dt = schedule.steps, schedule.t, schedule.dt
                row = steps - 1
                if factorisations is not None:
                    log.put(row, factorisation_path=factorisations.take_step())
                if with_contact:
                    distance, active, lost = system.contact_form().record(previous.x, state.x, state.v, dt)
                    log.put(row, contact_distance=distance, active_contacts=active, friction_work=lost)
                    friction += lost
                if moving.size:  # the prescribed vertices where their paths are at t, and the work they did
                    state = on_paths(system.constraints, moving, state, t)
                    power = path_power(system, moving, state.x, state.v, t)
                    work += 0.5 * dt * (step_start_power + power)  # the trapezoidal rule: second order
                    step_start_power = power
                if release_times and t >= release_times[0] - RELEASE_SLACK * dt:
                    # the vertices of the paths that end here go free, at their paths' positions and velocities; the
                    # method goes on with what it carries (a multistep history of every dof stays valid: x and v
                    # are continuous at the release, only the acceleration jumps)
                    system, moving = release(system, release_times, t, dt)
                    total_energy = system.total_energy
                    if evaluations is not None:
                        evaluations.instrument(system)
                    schedule.changed(system)
                    step_start_power = path_power(system, moving, state.x, state.v, t) if moving.size else 0.0
                if damped:
                    # h v_bar^T D(x_bar) v_bar with the step's mean velocity and D at its mean position: the
                    # exact discrete balance of implicit midpoint for quadratic energies, a second-order
                    # estimate for the others (D at the step's start would make it first order when D
                    # depends on x, as spring damping does)
                    damping = system.damping_matrix(0.5 * (previous.x + state.x))
                    mean_velocity = 0.5 * (previous.v + state.v)
                    dissipated += dt * float(mean_velocity @ (damping @ mean_velocity))
                if stats is not EXPLICIT_STEP:  # the per-step arrays start at zero, what an explicit step reports
                    log.record(row, stats)
                    solver_iterations += int(stats.iterations)
                if schedule.at_error_time():
                    error_state = (t, state.x.copy(), state.v.copy())
                last = schedule.done
                sampled = schedule.sample_due()
                framed = with_frames and schedule.frame_due()
                # a sample's row carries the energy, so the check below needs no second evaluation
                energy = record_sample(t, state.x, state.v, dissipated, work, friction) if sampled else None
                if framed:
                    record_frame(t, state.x)
                if not stats.converged:  # counted first: a step can fail to converge and diverge at once
                    not_converged_steps += 1
                    first_not_converged = first_not_converged or steps
                # a step that stops the run for not converging is checked for divergence first: a run
                # whose energy left the bound is diverged, whatever else went wrong in the step
                if steps % check_every == 0 or last or (stop_on_not_converged and not stats.converged):
                    if energy is None:
                        energy = total_energy(state.x, state.v)
                    # math.isfinite: cheaper than np.isfinite on one float
                    # the work of prescribed paths is energy put in on purpose, not a sign of instability
                    if not math.isfinite(energy) or abs(energy - work - energy0) > energy_bound:
                        diverged, t_diverged, diverged_step = True, t, steps
                        message = f"energy {energy:.3g} J left the bound |E - E0| <= {energy_bound:.3g} J at t = {t:.6g} s"
                        record_stop(t, state, sampled, framed)
                        break
                if stop_on_not_converged and not stats.converged:
                    message = f"step {steps} (t = {t:.6g} s) did not converge: residual {stats.residual:.3g}"
                    record_stop(t, state, sampled, framed)
                    break
                if last:
                    continue
                used_up = run.record.used_up(steps, solver_iterations, time.perf_counter() - start)
                if used_up is not None:
                    over_budget = True
                    message = f"stopped at t = {t:.6g} s ({schedule.where()}): {used_up}"
                    record_stop(t, state, sampled, framed)
                    break
    except StepTooSmall as error:  # the controller's own end: its message says where and why
        failed, message = True, str(error)
    except Exception as error:  # a failing run is a result, never the end of the sweep
        failed, message = True, f"{type(error).__name__}: {error}"
    finally:
        RUN_FACTORISATIONS.reset(counting)
    wall_time = time.perf_counter() - start
    accept_not_converged = run.solver.on_not_converged == "accept"
    status = decide_status(failed=failed, diverged=diverged, over_budget=over_budget,
                           not_converged_steps=not_converged_steps, accept_not_converged=accept_not_converged)
    if status is Status.NOT_CONVERGED and not message:
        message = not_converged_message(not_converged_steps, steps, bool(getattr(run.solver, "time_budget", None)))
    samples = recorder.result()
    per_step = log.result(steps)
    attrs = {"final_error": final_error(system, samples), "not_converged_steps": not_converged_steps,
             "first_not_converged_step": first_not_converged, "diverged_step": diverged_step,
             "safeguard_steps": int(np.count_nonzero(per_step["safeguards"])),
             **(_contact_attrs(per_step, steps) if with_contact else {}),
             **({f"factorisations_{path}": count for path, count in factorisations.as_dict().items()}
                if factorisations is not None else {}),
             **(evaluations.as_attrs() if evaluations is not None else {}), **system.capabilities.as_attrs(),
             "threads": threads, **schedule.attrs()}
    model = add_outcome(system, samples, attrs, error_state, with_frames, constraint_kinds)
    bound = explicit_frequency(system, integrator)
    if math.isfinite(bound):  # stored where there is one: off the test equation, for the methods with a bound
        attrs["explicit_frequency"] = bound
    engine = integrator.engine_description()
    if engine:  # another code took the steps: which, in what precision, on what device
        attrs["engine"] = engine
    result = RunResult(
        run_id=run.run_id, status=status, steps=steps, wall_time=wall_time, samples=samples, per_step=per_step,
        t_diverged=t_diverged, message=message, attrs=attrs, model=model,
    )
    return kept_as_recorded(result, run.record)


def kept_as_recorded(result: RunResult, record) -> RunResult:
    """The run as ``record`` keeps it: with ``series: false`` (a map) the summary's numbers as attributes, no series."""
    if not record.series:
        result.attrs.update(series_summary(result))
        result.samples, result.per_step = {}, {}
    return result


def needs_no_blas_threads(integrator, solver) -> bool:
    """Whether a run's work gains nothing from BLAS threads: an explicit method's own (those that declare
    ``needs_no_blas_threads``: XPBD), or its solver's (every solver of a fallback chain)."""
    if integrator.explicit:
        return getattr(integrator, "needs_no_blas_threads", False)
    return bool(getattr(solver, "needs_no_blas_threads", False))


def series_summary(result: RunResult) -> dict[str, float]:
    """The summary's numbers that come from the run's series (results.SERIES_SUMMARY_KEYS), from its RunResult."""
    empty = np.empty(0)
    return _series_summary(result.attrs, lambda key: result.samples.get(key, result.per_step.get(key, empty)))


def _contact_attrs(per_step: dict[str, np.ndarray], steps: int) -> dict[str, float]:
    """The run's contact in numbers: the smallest signed distance over its steps (m; negative: a penetration),
    the most contacts acting at once, and friction's total loss (J)."""
    distances = per_step["contact_distance"]
    return {"min_contact_distance": float(np.min(distances)) if steps else float("inf"),
            "max_active_contacts": int(np.max(per_step["active_contacts"])) if steps else 0,
            "friction_work": float(np.sum(per_step["friction_work"]))}
