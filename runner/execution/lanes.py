"""Lockstep lanes: runs of one small system, one integrator and one step count, stepped together.

``simulate_lanes(runs)`` is ``simulate`` for many runs at once: the state is an array with one row per run (a
lane; systems/lanes.py), each lane with its own parameters, initial state and dt, stepped by the integrator's own
code and, for implicit methods, the batched Newton of solvers/lanes.py. Everything ``simulate`` decides per run is
decided per lane: samples on the run's stride, the divergence check, the status, the first step that did not
converge, the error at the error time. Lanes that stop (diverged, or a step that did not converge under
``on_not_converged: stop``) keep being stepped with the others, unrecorded: taking them out would cost more than
their arithmetic. Every lane's recorded data is its run's stepped alone, bit for bit (tests/test_lanes.py).

``lane_key(run)`` says which runs may share lanes (None: the run is stepped alone), ``lane_chunks`` groups a
sweep's pending runs into chunks for the executors. A chunk whose stepping raises is run again run by run, so a
failure stays one run's result.
"""

from __future__ import annotations

import math
import time

import numpy as np

from simrun.execution.lane_recording import LaneSeries, LaneSummary, lane_decays, lane_errors, lane_final_error
from simrun.execution.simulate import simulate
from simrun.execution.workers import compiled_threads
from simrun.experiment.config import Run
from simrun.format.record import decide_status, not_converged_message
from simrun.format.run_result import LaneBatch, lane_summary, lane_table
from simrun.format.size import estimate_run_bytes
from simrun.format.summary import Status
from simrun.integrators import INTEGRATORS, State
from simrun.solvers import EXPLICIT_STEP
from simrun.solvers.lanes import LaneNewton, lane_refusal

# the registry's methods that step lanes as they step one run (Integrator.lanes); the others (segment potentials, the
# exponential method's matrix functions, XPBD's constraint projections) step each run alone
LANE_INTEGRATORS = tuple(name for name, method in INTEGRATORS.items() if method.steps_lanes())
# lanes pay off from this many runs of one kind (below it a chunk's fixed costs outweigh the runs' own)
MIN_LANES = 16
# a chunk holds at most this many bytes of recorded data (``simrun.format.size.estimate_run_bytes``) while it is stepped
CHUNK_BYTES = 64 * 2**20
MAX_CHUNK_LANES = 4096


def lane_key(run: Run):
    """What runs must share to be lanes of one chunk (system type, integrator, solver, step count, recording and
    divergence settings), or None when this run is stepped alone (its system or method has no lane form, or its
    solver options are ones the batched Newton does not reproduce)."""
    system_class = run.system.system_class
    # declared by the class itself: a subclass (a plug-in's nonlinear spring) has physics its parent's lanes lack
    lanes_class = vars(system_class).get("lanes_class")
    if lanes_class is None or not type(run.integrator).steps_lanes():
        return None
    if run.record.budgeted:  # a budget per run: lanes step together, so each is stepped alone
        return None
    if run.step_control is not None:  # each run chooses its own steps
        return None
    if not run.integrator.explicit and lane_refusal(run.solver) is not None:
        return None
    solver = "" if run.integrator.explicit else run.solver.model_dump_json()
    return (run.system.type, lanes_class.lane_kind(run.system), run.integrator_label,
            run.integrator.model_dump_json(), solver, run.step_count, run.record.model_dump_json(),
            run.divergence.model_dump_json())


def lane_chunks(runs: list[Run], jobs: int = 1) -> tuple[list[list[Run]], list[Run]]:
    """(chunks of runs to step as lanes, runs to step alone). Runs of one key form chunks when there are at least
    MIN_LANES of them: at most CHUNK_BYTES of recorded data each, and at least ``jobs`` chunks per key when the runs
    allow, so that every worker gets a share."""
    groups: dict = {}
    alone = []
    for run in runs:
        key = lane_key(run)
        if key is None:
            alone.append(run)
        else:
            groups.setdefault(key, []).append(run)
    chunks = []
    for members in groups.values():
        if len(members) < MIN_LANES:
            alone.extend(members)
            continue
        per_chunk = max(1, min(MAX_CHUNK_LANES, CHUNK_BYTES // max(1, estimate_run_bytes(members[0]))))
        count = max(math.ceil(len(members) / per_chunk), min(jobs, len(members) // MIN_LANES))
        size = math.ceil(len(members) / count)
        chunks.extend(members[start:start + size] for start in range(0, len(members), size))
    alone.sort(key=lambda run: run.index)
    return chunks, alone


def simulate_lanes(runs: list[Run]) -> LaneBatch:
    """Step ``runs`` (one lane_key) together; never raises for a bad run (a chunk that raises is run run by run)."""
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return _simulate_lanes(runs)
    except Exception:  # noqa: BLE001 - a lane failure must not cost its neighbours their runs
        alone = [simulate(run) for run in runs]
        return LaneBatch(runs=runs, status=[result.status for result in alone], steps=np.array([r.steps for r in alone]),
                         wall_time=np.array([r.wall_time for r in alone]), t_diverged=np.full(len(runs), math.nan),
                         message=[r.message for r in alone], attrs=[r.attrs for r in alone], results_alone=alone)


def _simulate_lanes(runs: list[Run]) -> LaneBatch:
    first = runs[0]
    singles = [run.system.build() for run in runs]
    system = type(singles[0]).lanes_class(singles)
    integrator = first.integrator
    solver = None if integrator.explicit else LaneNewton(first.solver)
    lanes, step_count = len(runs), first.step_count
    dt = np.array([run.dt for run in runs]).reshape(-1, 1)
    dt_flat = dt.ravel()
    record, check_every = first.record, first.divergence.check_every
    stride = record.stride(step_count)
    capabilities = system.capability_columns()
    frequencies = capabilities["test_frequency"]
    error_steps = np.array([run.record.error_step(run.dt, step_count, None if math.isnan(frequency) else frequency)
                            for run, frequency in zip(runs, frequencies.tolist())])
    error_step_set = set(error_steps.tolist())
    stop_on_not_converged = first.solver.on_not_converged == "stop"
    accept_not_converged = first.solver.on_not_converged == "accept"
    exact = getattr(system, "exact_states", None)  # the error norms' exact solution, where the system has one
    if record.series:  # simulate.Recorder's columns, one array per key
        layout = dict(system.observable_layout)
        layout.update(t=(), dissipated_energy=(), positions=(system.dof_count,), velocities=(system.dof_count,))
        recorder = LaneSeries(layout, step_count // stride + 2, lanes, step_count, system.modal_energy,
                              capabilities["energy_scale"], exact)
    else:
        recorder = LaneSummary(capabilities["energy_scale"], lanes, system.dof_count, system.modal_energy, exact)

    state = State(0.0, system.x0.copy(), system.v0.copy())
    energy0 = system.total_energy(state.x, state.v)
    energy_bound = np.array([run.divergence.energy_factor for run in runs]) * capabilities["energy_scale"]
    dissipated = np.zeros(lanes)
    damped = system.is_damped
    running = stopped = None  # the lanes still running, and the others; None: all of them, none
    stopped_at = np.full(lanes, step_count, dtype=np.int64)  # steps taken
    diverged = np.zeros(lanes, dtype=bool)
    t_diverged = np.full(lanes, math.nan)
    not_converged_steps = np.zeros(lanes, dtype=np.int64)
    first_not_converged = np.zeros(lanes, dtype=np.int64)
    messages = [""] * lanes
    error_positions = np.full((lanes, system.dof_count), math.nan)
    error_velocities = np.full((lanes, system.dof_count), math.nan)
    error_times = np.full(lanes, math.nan)

    recorder.sample(system.observables(state.x, state.v), 0.0, dissipated, state.x, state.v, None)
    step = integrator.step
    start = time.perf_counter()
    state = integrator.start(system, state)
    for n in range(step_count):
        previous = state
        state, stats = step(system, state, dt, solver)
        steps = n + 1
        if damped:  # simulate's energy budget: h v_bar^T D v_bar with the step's mean velocity
            dissipated += dt_flat * system.dissipation(0.5 * (previous.v + state.v))
        failing = None
        if stats is not EXPLICIT_STEP:
            recorder.solver_step(n, stats, running)
            if not stats.converged.all():
                failing = ~stats.converged if running is None else running & ~stats.converged
                if failing.any():
                    not_converged_steps += failing
                    first_not_converged[failing & (first_not_converged == 0)] = steps
                else:
                    failing = None
        if steps in error_step_set:
            at_error = error_steps == steps if running is None else (error_steps == steps) & running
            error_times[at_error] = dt_flat[at_error] * steps
            error_positions[at_error], error_velocities[at_error] = state.x[at_error], state.v[at_error]
        last = steps == step_count
        sampled = steps % stride == 0 or last
        energy = None
        if sampled:
            observed = system.observables(state.x, state.v)
            recorder.sample(observed, dt_flat * steps, dissipated, state.x, state.v, running)
            energy = observed["energy"]
        regular_check = steps % check_every == 0 or last
        stopping = None
        if regular_check or (stop_on_not_converged and failing is not None):
            if energy is None:
                energy = system.total_energy(state.x, state.v)
            # simulate's test, E not finite or |E - E0| > bound, as one comparison that NaN fails
            change = np.subtract(energy, energy0)
            within = np.abs(change, out=change) <= energy_bound
            checked = running if regular_check else failing
            unchecked = None if checked is None else (stopped if checked is running else ~checked)
            if not (within.all() if unchecked is None else (within | unchecked).all()):  # (all(where=): far slower)
                escaped = ~within if checked is None else checked & ~within
                t = dt_flat * steps
                for lane in np.flatnonzero(escaped).tolist():
                    messages[lane] = (f"energy {energy[lane]:.3g} J left the bound |E - E0| <= {energy_bound[lane]:.3g} J "
                                      f"at t = {t[lane]:.6g} s")
                diverged[escaped], t_diverged[escaped] = True, t[escaped]
                stopping = escaped
        if stop_on_not_converged and failing is not None:
            halted = failing if stopping is None else failing & ~stopping
            if halted.any():
                t = dt_flat * steps
                for lane in np.flatnonzero(halted).tolist():
                    messages[lane] = f"step {steps} (t = {t[lane]:.6g} s) did not converge: residual {stats.residual[lane]:.3g}"
                stopping = halted if stopping is None else stopping | halted
        if stopping is not None:
            stopped_at[stopping] = steps
            if not sampled:  # simulate's record_stop: a sample of its own at the step where the run stopped
                recorder.stop_sample(stopping, system.observables(state.x, state.v), dt_flat * steps, dissipated,
                                     state.x, state.v)
            running = ~stopping if running is None else running & ~stopping
            stopped = ~running
            if not running.any():
                break
    wall_time = (time.perf_counter() - start) / lanes
    kept = recorder.finish(stopped_at)

    # the run's scalars (simulate's attrs), for all lanes at once
    final_error = lane_final_error(system, kept["last_t"], kept["last_positions"])
    errors = lane_errors(system, error_times, error_positions, error_velocities, frequencies)
    shared = {**singles[0].capabilities.as_attrs(), "threads": compiled_threads(first.solver.threads)}
    columns = {"final_error": final_error, "not_converged_steps": not_converged_steps,
               "first_not_converged_step": first_not_converged, "diverged_step": np.where(diverged, stopped_at, 0),
               "safeguard_steps": kept["safeguard_steps"]}
    columns = {key: values.tolist() for key, values in columns.items()}
    columns["decay_per_period"] = lane_decays(kept["decay_energies"], capabilities["natural_frequency"])
    norms = {key: values.tolist() for key, values in kept["error_norms"].items()}  # measures.error_norms per lane
    capability_lists = {key: values.tolist() for key, values in capabilities.items()}
    summary = {key: values.tolist() for key, values in kept["series_summary"].items()} if not record.series else {}
    statuses, attrs = [], []
    for lane in range(lanes):
        lane_status = decide_status(failed=False, diverged=bool(diverged[lane]), over_budget=False,
                                    not_converged_steps=columns["not_converged_steps"][lane],
                                    accept_not_converged=accept_not_converged)
        if lane_status is Status.NOT_CONVERGED and not messages[lane]:
            messages[lane] = not_converged_message(columns["not_converged_steps"][lane], int(stopped_at[lane]))
        statuses.append(lane_status)
        lane_attrs = {key: values[lane] for key, values in columns.items()}
        lane_attrs.update(shared)
        lane_attrs.update({key: values[lane] for key, values in capability_lists.items()})
        lane_attrs.update({key: value for key, values in norms.items() if not math.isnan(value := values[lane])})
        if not math.isnan(error_times[lane]):
            lane_attrs["error_time"] = float(error_times[lane])
            lane_attrs["error"] = float(errors[lane])
        lane_attrs.update({key: values[lane] for key, values in summary.items()})
        attrs.append(lane_attrs)
    batch = LaneBatch(runs=runs, status=statuses, steps=stopped_at, wall_time=np.full(lanes, wall_time),
                      t_diverged=t_diverged, message=messages, attrs=attrs, samples=kept["samples"],
                      sample_count=kept["sample_count"], per_step=kept["per_step"],
                      error_positions=error_positions if record.series else None)
    # what the writer stores, made here (in the worker, beside the other chunks) rather than by the one writer
    batch.table, batch.summary = lane_table(runs, batch), lane_summary(runs, batch, kept["series_summary"])
    return batch
