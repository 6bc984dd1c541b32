"""A peer's run: scipy's ``solve_ivp`` method on the system, stepped by scipy itself (integrators/peers.py).

The solver object (``scipy.integrate.Radau``, ``BDF``, ``LSODA``, ...) is stepped here rather than through
``solve_ivp``, so that each accepted step's size is recorded. The samples and frames are kept at step ends at the cadence of
a step-controlled run of simrun's; the state at the error time comes from the step's dense output. The solve restarts at
the releases of prescribed paths, where the right-hand side jumps. The counts are scipy's own: ``nfev`` force
evaluations (those of its finite-difference Jacobians included), ``njev`` Jacobians and ``nlu`` LU factorisations.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.integrate
import scipy.sparse

from simrun.experiment.config import Run
from simrun.format.record import decide_status
from simrun.format.run_result import RunResult
from simrun.integrators.peers import IMPLICIT_PEERS

from .measures import add_outcome, final_error, moving_dofs, path_power, vertex_constraint_kinds
from .recording import STEP_ROWS, Recorder, SampleCadence
from .step_log import StepLog

SOLVERS = {"Radau": scipy.integrate.Radau, "BDF": scipy.integrate.BDF, "LSODA": scipy.integrate.LSODA,
           "RK45": scipy.integrate.RK45, "DOP853": scipy.integrate.DOP853}


def first_order_form(system, dense_jacobian: bool = False):
    """(F, J) of u' = F(u) = (v, M^-1 f(x, v)) for scipy: the prescribed dofs accelerate with their paths, the pinned
    ones not at all; J = [[0, I], [-M^-1 K, -M^-1 D]] (sparse, or dense for LSODA), with the held dofs' rows zero. With
    damping D(x) it leaves out dD/dx v, as simrun's own Newton matrices do."""
    n = system.dof_count
    constraints = system.constraints
    moving = moving_dofs(system)
    held = np.union1d(np.asarray(system.fixed_dofs, dtype=np.intp), moving)
    keep = np.ones(n)
    keep[held] = 0.0
    inverse_mass = keep / system.mass

    def rate(t, u):
        acceleration = system.acceleration(u[:n], u[n:])
        if moving.size:
            acceleration[moving] = constraints.path_accelerations(t)
        return np.concatenate([u[n:], acceleration])

    def jacobian(t, u):
        x = u[:n]
        stiffness = scipy.sparse.csr_array(system.hessian(x))
        scaled = scipy.sparse.diags_array(-inverse_mass) @ stiffness
        blocks = [[None, scipy.sparse.identity(n, format="csr")], [scaled, None]]
        if system.is_damped:
            blocks[1][1] = scipy.sparse.diags_array(-inverse_mass) @ scipy.sparse.csr_array(system.damping_matrix(x))
        matrix = scipy.sparse.block_array(blocks, format="csc")
        return matrix.toarray() if dense_jacobian else matrix

    return rate, jacobian


def simulate_peer(run: Run) -> RunResult:
    """The run by scipy's solver: samples at even times, per-step sizes, its counts; never raises for a bad run."""
    system = run.system.build()
    peer, control = run.integrator, run.step_control
    n = system.dof_count
    cadence = SampleCadence(run.record, run.duration)
    recorder = Recorder(system, cadence.sample_rows, cadence.frame_rows)
    with_frames = not system.records_state_per_sample
    error_time = run.record.error_at(system.capabilities.test_frequency)
    error_time = run.duration if error_time is None else min(error_time, run.duration)
    releases = [t for t in (system.constraints.release_times if system.constraints is not None else ()) if t < run.duration]
    energy0 = system.total_energy(system.x0, system.v0)
    energy_bound = run.divergence.energy_factor * system.energy_scale()
    constraint_kinds = vertex_constraint_kinds(system)
    log = StepLog(["dt"], STEP_ROWS)  # each accepted step's size
    steps = 0
    counts = {"function_evaluations": 0, "jacobian_evaluations": 0, "factorisations": 0}
    state = np.concatenate([system.x0, system.v0])
    dissipated = work = 0.0
    recorder.record(0.0, state[:n], state[n:], 0.0, 0.0)
    if with_frames:
        recorder.record_frame(0.0, state[:n])
    failed = diverged = over_budget = False
    message, t_diverged, error_state = "", None, None
    options = {"rtol": control.tolerance, "atol": control.atol}
    if control.dt_max is not None:
        options["max_step"] = control.dt_max
    if control.dt_initial != "auto":
        options["first_step"] = control.dt_initial
    rate, jacobian = first_order_form(system)
    rate(0.0, state), jacobian(0.0, state)  # the first calls' imports and caches are set-up, as simrun's system build is
    start = time.perf_counter()
    try:
        for begin, end in zip([0.0, *releases], [*releases, run.duration]):
            moving = moving_dofs(system)
            rate, jacobian = first_order_form(system, dense_jacobian=peer.method == "LSODA")
            if peer.method in IMPLICIT_PEERS and peer.jacobian:
                options["jac"] = jacobian
            solver = SOLVERS[peer.method](rate, begin, state, end, **options)
            power = path_power(system, moving, state[:n], state[n:], begin) if moving.size else 0.0
            while solver.status == "running":
                previous_t, previous = solver.t, solver.y
                message = solver.step()
                if solver.status == "failed":
                    break
                t, state = solver.t, solver.y
                size = t - previous_t
                log.grow_to(steps + 1)
                log.put(steps, dt=size)
                steps += 1
                if system.is_damped:  # as simulate books it: the step's mean velocity, D at its mean position
                    mean_v = 0.5 * (previous[n:] + state[n:])
                    dissipated += size * float(mean_v @ (system.damping_matrix(0.5 * (previous[:n] + state[:n])) @ mean_v))
                if moving.size:
                    now = path_power(system, moving, state[:n], state[n:], t)
                    work += 0.5 * size * (power + now)
                    power = now
                if previous_t < error_time <= t:  # the error at its exact time, from the step's dense output
                    u = state if error_time == t else solver.dense_output()(error_time)
                    error_state = (error_time, u[:n].copy(), u[n:].copy())
                last = t >= run.duration
                # samples and frames at step ends, at the cadence of simrun's step-controlled runs
                if cadence.sample_due(steps, t) or last:
                    energy = recorder.record(t, state[:n], state[n:], dissipated, work)
                    if not math.isfinite(energy) or abs(energy - work - energy0) > energy_bound:
                        diverged, t_diverged = True, t
                        message = f"energy {energy:.3g} J left the bound |E - E0| <= {energy_bound:.3g} J at t = {t:.6g} s"
                        break
                if with_frames and (cadence.frame_due(steps, t) or last):
                    recorder.record_frame(t, state[:n])
                if last:
                    continue
                used_up = run.record.used_up(steps, elapsed=time.perf_counter() - start)
                if used_up is not None:
                    over_budget = True
                    message = f"stopped at t = {t:.6g} s: {used_up}"
                    break
            counts["function_evaluations"] += solver.nfev
            counts["jacobian_evaluations"] += getattr(solver, "njev", 0)
            counts["factorisations"] += getattr(solver, "nlu", 0)
            if solver.status == "failed":
                failed, message = True, f"scipy's {peer.method}: {message}"
            if failed or diverged or over_budget:
                break
            system = system.released(end)
        else:
            message = ""
    except Exception as error:  # a failing run is a result, never the end of the sweep
        failed, message = True, f"{type(error).__name__}: {error}"
    wall_time = time.perf_counter() - start
    status = decide_status(failed=failed, diverged=diverged, over_budget=over_budget, not_converged_steps=0,
                           accept_not_converged=False)
    samples = recorder.result()
    per_step = log.result(steps)
    attrs = {"final_error": final_error(system, samples), "not_converged_steps": 0, "first_not_converged_step": 0,
             "diverged_step": 0, "safeguard_steps": 0, "accepted_steps": steps, "planned_steps": steps,
             "dt": sum(per_step["dt"].tolist()) / steps if steps else math.nan, **counts,
             **system.capabilities.as_attrs()}
    model = add_outcome(system, samples, attrs, error_state, with_frames, constraint_kinds)
    return RunResult(run_id=run.run_id, status=status, steps=steps, wall_time=wall_time, samples=samples,
                     per_step=per_step, t_diverged=t_diverged, message=message, attrs=attrs, model=model)
