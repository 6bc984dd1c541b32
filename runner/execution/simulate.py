"""Simulate one run: step the integrator, record samples, decide the outcome. No I/O here."""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from simrun.experiment.config import Run
from simrun.format.run_result import RunResult
from simrun.format.summary import Status, series_summary as _series_summary
from simrun.integrators import State
from simrun.solvers import EXPLICIT_STEP
from simrun.solvers.base import one_blas_thread
from simrun.solvers.linear import RUN_FACTORISATIONS, FactorisationLog, attach_factorisation_log

from .evaluations import EvaluationCounts
from .peers import simulate_peer
from .recording import STEP_ROWS, Recorder, SampleCadence
from .measures import (RELEASE_SLACK, add_outcome, explicit_frequency, final_error, moving_dofs, on_paths, path_power,
                       release, vertex_constraint_kinds)
from .step_control import StepController, StepTooSmall
from .workers import compiled_threads


# the per-step solver counts, in the order simulate binds them
PER_STEP_SOLVER_KEYS = ("newton_iterations", "linear_iterations", "line_search_steps", "residual", "solver_index",
                        "safeguards")


def _controlled_step(controller: StepController, system, state: State, solver, prepare):
    """One accepted step of a step-controlled run: (its state, the statistics of every try it took, its size (s), its
    error estimate (of the tolerance), the tries rejected before it). Raises StepTooSmall below dt_min."""
    cost, rejected = None, 0
    while True:
        size = controller.step_size(system, state)
        new, stats, error = controller.attempt(system, state, size, solver, prepare)
        cost = stats if cost is None else cost.followed_by(stats)
        if controller.judge(size, error, stats.converged):
            return new, cost._replace(residual=stats.residual, converged=stats.converged), size, error, rejected
        rejected += 1


def simulate(run: Run) -> RunResult:
    """Run the integrator for run.step_count steps of run.dt on run.system (or, with step_control, steps it chooses
    to the duration); never raises for a bad run. A peer's run is taken by its own code (peers.py)."""
    if run.integrator.whole_run:
        return simulate_peer(run)
    system = run.system.build()
    integrator = run.integrator
    solver = run.solver.build()
    threads = compiled_threads(run.solver.threads)
    check_every = run.divergence.check_every
    controller = None  # the step controller of a step-controlled run (runner/execution/step_control.py)
    if run.step_control is None:
        step_count, dt = run.step_count, run.dt
        stride = run.record.stride(step_count)
        frame_stride = run.record.frame_stride(step_count)
        error_step = run.record.error_step(dt, step_count, system.capabilities.test_frequency)
        recorder = Recorder(system, step_count // stride + 2, step_count // frame_stride + 2)
    else:
        # the rows grow as the steps come; samples and frames are kept at even times (or every k-th step)
        step_count, dt, error_step = STEP_ROWS, math.nan, 0
        error_time = run.record.error_at(system.capabilities.test_frequency)
        error_time = run.duration if error_time is None else min(error_time, run.duration)
        release_stops = list(system.constraints.release_times) if system.constraints is not None else []
        controller = StepController(run.step_control, integrator, system, [run.duration, error_time, *release_stops])
        cadence = SampleCadence(run.record, run.duration)
        recorder = Recorder(system, cadence.sample_rows, cadence.frame_rows)
    error_state = None  # (t, x, v) at the end of step error_step, where the run's error is measured
    with_frames = not system.records_state_per_sample
    per_step = {
        "newton_iterations": np.zeros(step_count, dtype=np.int32),
        "linear_iterations": np.zeros(step_count, dtype=np.int32),
        "line_search_steps": np.zeros(step_count, dtype=np.int32),
        "residual": np.zeros(step_count),
        "solver_index": np.zeros(step_count, dtype=np.int8),
        "safeguards": np.zeros(step_count, dtype=np.uint8),
    }
    # per step, for a sparse system's direct solves: the furthest path a factorisation took (1 + its index in
    # FACTORISATION_PATHS; 0: none), and per run the count of each
    factorisations = attach_factorisation_log(solver) if system.hessian_pattern is not None else None
    if factorisations is not None:
        per_step["factorisation_path"] = np.zeros(step_count, dtype=np.int8)
    # a step-controlled run counts every factorisation, sparse or dense, its solver's or its method's own (Radau
    # IIA's blocks), as work-precision's currency beside the evaluations (a peer's is scipy's nlu)
    every_factorisation = (factorisations or FactorisationLog()) if controller is not None else None
    with_contact = system.has_contact
    if with_contact:  # per step: the smallest signed contact distance (m), active contacts, friction's loss (J)
        per_step.update(contact_distance=np.zeros(step_count), active_contacts=np.zeros(step_count, dtype=np.int32),
                        friction_work=np.zeros(step_count))
    if controller is not None:  # per accepted step: its size (s), its error estimate (of the tolerance), rejected tries
        per_step.update(dt=np.zeros(step_count), error_estimate=np.zeros(step_count),
                        rejected_attempts=np.zeros(step_count, dtype=np.int16))
    stop_on_not_converged = run.solver.on_not_converged == "stop"
    # a real-time budget: a step that used up max_iterations is what the budget bought, not a failure
    accept_not_converged = run.solver.on_not_converged == "accept"

    state = State(0.0, system.x0.copy(), system.v0.copy())
    if with_contact:  # IPC's barrier stiffness (auto) before anything evaluates the energy
        system.begin_run(dt if controller is None else controller.step_size(system, state), state.x)
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
    newton_iterations, linear_iterations = per_step["newton_iterations"], per_step["linear_iterations"]
    line_search_steps, residuals, solver_index = per_step["line_search_steps"], per_step["residual"], per_step["solver_index"]
    safeguards = per_step["safeguards"]

    record_sample, record_frame, total_energy = recorder.record, recorder.record_frame, system.total_energy
    step = integrator.step

    def prepare(t: float, size: float, x: np.ndarray) -> None:
        """Before each try of a step-controlled run: the colliders move to its end (the system as released so far)."""
        if with_contact:
            system.begin_step(t, size, x)

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
    status, message, t_diverged, not_converged_steps = Status.OK, "", None, 0
    first_not_converged = diverged_step = 0  # 1-based step numbers; 0: none
    steps = 0
    max_wall_time = run.record.max_wall_time
    over_budget = False  # stopped at record.max_wall_time
    # a step-controlled run's evaluations (as wall_time, the set-up left out): fixed-step runs count none, so that a
    # run stepped alone stores what it stores stepped as a lane, where every lane's forces are one call
    evaluations = EvaluationCounts() if controller is not None else None
    if evaluations is not None:
        evaluations.instrument(system)
    # a run whose work is numba's threads (XPBD, VBD): OpenBLAS's threads, woken by a long vector's ddot, would spin
    # against them on the same cores (2-10 ms sweeps instead of 2.4, 30 ms XPBD frames instead of 10, 64 x 64 cloth)
    blas = one_blas_thread() if needs_no_blas_threads(integrator, solver) else contextlib.nullcontext()
    start = time.perf_counter()
    counting = RUN_FACTORISATIONS.set(every_factorisation)
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"), blas:
            state = integrator.start(system, state)
            n = 0
            while n < step_count if controller is None else not controller.done:
                previous = state
                if controller is None:
                    if with_contact:  # colliders move to the step's end; IPC's stiffness is estimated and updated
                        system.begin_step(dt * n, dt, state.x)
                    state, stats = step(system, state, dt, solver)
                    t = dt * (n + 1)  # the loop owns t: no accumulated round-off, whatever state.t says
                else:
                    if n == step_count:  # the rows are full: twice as many
                        per_step = {key: np.concatenate([value, np.zeros_like(value)]) for key, value in per_step.items()}
                        (newton_iterations, linear_iterations, line_search_steps, residuals, solver_index,
                         safeguards) = (per_step[key] for key in PER_STEP_SOLVER_KEYS)
                        step_count *= 2
                    state, stats, dt, error, rejected = _controlled_step(controller, system, state, solver, prepare)
                    per_step["dt"][n], per_step["error_estimate"][n], per_step["rejected_attempts"][n] = dt, error, rejected
                    t = controller.t  # every stop (the duration, the error time, a release) reached exactly
                steps = n + 1
                n = steps
                if factorisations is not None:
                    per_step["factorisation_path"][steps - 1] = factorisations.take_step()
                if with_contact:
                    distance, active, lost = system.contact_record(previous.x, state.x, state.v, dt)
                    per_step["contact_distance"][steps - 1], per_step["active_contacts"][steps - 1] = distance, active
                    per_step["friction_work"][steps - 1] = lost
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
                    if controller is not None:
                        evaluations.instrument(system)
                        controller.changed(system)
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
                    row = steps - 1
                    newton_iterations[row] = stats.iterations
                    linear_iterations[row] = stats.linear_iterations
                    line_search_steps[row] = stats.line_search_steps
                    residuals[row] = stats.residual
                    solver_index[row] = stats.solver_index
                    safeguards[row] = stats.safeguards
                if controller is None:
                    if steps == error_step:
                        error_state = (t, state.x.copy(), state.v.copy())
                    last = steps == step_count
                    sampled = steps % stride == 0 or last
                    framed = with_frames and (steps % frame_stride == 0 or last)
                else:
                    if t == error_time:
                        error_state = (t, state.x.copy(), state.v.copy())
                    last = controller.done
                    sampled = cadence.sample_due(steps, t) or last
                    framed = with_frames and (cadence.frame_due(steps, t) or last)
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
                    # math.isfinite: cheaper than np.isfinite on one float (docs/performance.md)
                    # the work of prescribed paths is energy put in on purpose, not a sign of instability
                    if not math.isfinite(energy) or abs(energy - work - energy0) > energy_bound:
                        status, t_diverged, diverged_step = Status.DIVERGED, t, steps
                        message = f"energy {energy:.3g} J left the bound |E - E0| <= {energy_bound:.3g} J at t = {t:.6g} s"
                        record_stop(t, state, sampled, framed)
                        break
                if stop_on_not_converged and not stats.converged:
                    message = f"step {steps} (t = {t:.6g} s) did not converge: residual {stats.residual:.3g}"
                    record_stop(t, state, sampled, framed)
                    break
                if max_wall_time is not None and not last and time.perf_counter() - start > max_wall_time:
                    over_budget = True
                    of = f" of {step_count}" if controller is None else ""
                    message = (f"stopped at t = {t:.6g} s (step {steps}{of}): {time.perf_counter() - start:.3g} s "
                               f"of wall time, over record.max_wall_time {max_wall_time:g} s")
                    record_stop(t, state, sampled, framed)
                    break
    except StepTooSmall as error:  # the controller's own end: its message says where and why
        status, message = Status.FAILED, str(error)
    except Exception as error:  # a failing run is a result, never the end of the sweep
        status, message = Status.FAILED, f"{type(error).__name__}: {error}"
    finally:
        RUN_FACTORISATIONS.reset(counting)
    wall_time = time.perf_counter() - start
    if status is Status.OK and over_budget:
        status = Status.NOT_CONVERGED
    elif status is Status.OK and not_converged_steps and not accept_not_converged:
        status = Status.NOT_CONVERGED
        if not message:
            limits = "max_iterations" + (" or time_budget" if getattr(run.solver, "time_budget", None) else "")
            message = f"{not_converged_steps} of {steps} steps did not converge within {limits}"
    samples = recorder.result()
    attrs = {"final_error": final_error(system, samples), "not_converged_steps": not_converged_steps,
             "first_not_converged_step": first_not_converged, "diverged_step": diverged_step,
             "safeguard_steps": int(np.count_nonzero(safeguards[:steps])),
             **(_contact_attrs(per_step, steps) if with_contact else {}),
             **({f"factorisations_{path}": count for path, count in factorisations.as_dict().items()}
                if factorisations is not None else {}),
             **(evaluations.as_attrs() if evaluations is not None else {}), **system.capabilities.as_attrs(),
             "threads": threads}
    if controller is not None:  # the stored dt is the mean accepted step; the counts of the controller
        attrs.update(dt=t_reached / steps if (t_reached := controller.t) > 0 and steps else math.nan,
                     planned_steps=steps, accepted_steps=controller.accepted_steps, rejected_steps=controller.rejected_steps,
                     not_converged_attempts=controller.failed_solves, factorisations=every_factorisation.total)
    model = add_outcome(system, samples, attrs, error_state, with_frames, constraint_kinds)
    bound = explicit_frequency(system, integrator)
    if math.isfinite(bound):  # stored where there is one: off the test equation, for the methods with a bound
        attrs["explicit_frequency"] = bound
    result = RunResult(
        run_id=run.run_id, status=status, steps=steps, wall_time=wall_time, samples=samples,
        per_step={key: value[:steps] for key, value in per_step.items()},
        t_diverged=t_diverged, message=message, attrs=attrs, model=model,
    )
    if not run.record.series:  # a map: the summary's numbers as attributes, no series
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
    distances = per_step["contact_distance"][:steps]
    return {"min_contact_distance": float(np.min(distances)) if steps else float("inf"),
            "max_active_contacts": int(np.max(per_step["active_contacts"][:steps])) if steps else 0,
            "friction_work": float(np.sum(per_step["friction_work"][:steps]))}
