"""A recorded trajectory's run: the states another code computed (integrators/recorded.py), measured on the config's
system as simrun's own runs are.

Nothing is stepped. Each kept state is handed to the same ``Recorder`` that simulate.py fills, so the energies, momenta
and observables are the system's own; samples and frames are kept at the cadence of a fixed-step run of the same
steps (at even times where the trajectory's steps are uneven). The physical damping's loss and the prescribed paths'
work are integrated over the trajectory's steps by the trapezoidal rule, with D at the step's mean position, as
simrun books its own steps; the energy bound marks a trajectory that blew up as diverged, where it left it. The
error is measured at the recorded state nearest the error time. Its wall time is the trajectory's own, where the file
says it (a ``wall_time`` entry, s, prorated to the states within the duration), else NaN: simrun's reading is not
what the other code spent.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from simrun.experiment.config import Run
from simrun.format.record import decide_status
from simrun.format.run_result import RunResult

from .measures import add_outcome, final_error, moving_dofs, path_power, vertex_constraint_kinds
from .recording import Recorder, SampleCadence
from .step_log import StepLog

# steps within this fraction of their mean are even: the trajectory is sampled as a fixed-step run of that step
EVEN_STEPS = 1e-9
# the metadata kept in the results file: at most this many entries, each text at most this many characters (an HDF5
# attribute holds 64 KiB; a code's whole config may be among the free text)
MAX_METADATA_ENTRIES = 200
MAX_METADATA_TEXT = 2_000


def simulate_recorded(run: Run) -> RunResult:
    """The trajectory's states measured on ``run.system``; never raises for a bad run."""
    try:
        return _measure(run)
    except Exception as error:  # a failing run is a result, never the end of the sweep
        return RunResult(run_id=run.run_id, status=decide_status(failed=True, diverged=False, over_budget=False,
                                                                  not_converged_steps=0, accept_not_converged=False),
                         steps=0, wall_time=math.nan, samples={}, per_step={}, t_diverged=None,
                         message=f"{type(error).__name__}: {error}", attrs={}, model={})


def _measure(run: Run) -> RunResult:
    system = run.system.build()
    recorded = run.integrator.read()
    kept = int(np.count_nonzero(recorded.t <= run.duration * (1.0 + 1e-12)))
    t, x, v = recorded.t[:kept], recorded.x[:kept], recorded.velocities[:kept]
    steps = kept - 1
    sizes = np.diff(t)
    even = bool(np.all(np.abs(sizes - run.dt) <= EVEN_STEPS * run.dt))
    cadence = SampleCadence(run.record, run.duration)
    stride, frame_stride = run.record.stride(steps), run.record.frame_stride(steps)
    sample_rows = steps // stride + 2 if even else cadence.sample_rows
    frame_rows = steps // frame_stride + 2 if even else cadence.frame_rows
    recorder = Recorder(system, sample_rows, frame_rows)
    with_frames = not system.records_state_per_sample

    def sample_due(step: int) -> bool:
        return step % stride == 0 if even else cadence.sample_due(step, float(t[step]))

    def frame_due(step: int) -> bool:
        return step % frame_stride == 0 if even else cadence.frame_due(step, float(t[step]))

    test_frequency = system.capabilities.test_frequency
    error_time = run.record.error_at(test_frequency)
    error_index = steps if error_time is None else int(np.argmin(np.abs(t - min(error_time, t[-1]))))
    releases = [time for time in (system.constraints.release_times if system.constraints is not None else ())
                if time < t[-1]]
    energy0 = system.total_energy(x[0], v[0])
    energy_bound = run.divergence.energy_factor * system.energy_scale()
    constraint_kinds = vertex_constraint_kinds(system)
    moving = moving_dofs(system)
    power = path_power(system, moving, x[0], v[0], 0.0) if moving.size else 0.0
    dissipated = work = 0.0
    diverged, t_diverged, message = False, None, ""
    recorder.record(0.0, x[0], v[0], 0.0, 0.0)
    if with_frames:
        recorder.record_frame(0.0, x[0])
    for step in range(1, kept):
        size = float(sizes[step - 1])
        if system.is_damped:  # as simulate books a step: its mean velocity, D at its mean position
            mean_v = 0.5 * (v[step - 1] + v[step])
            dissipated += size * float(mean_v @ (system.damping_matrix(0.5 * (x[step - 1] + x[step])) @ mean_v))
        if moving.size:
            now = path_power(system, moving, x[step], v[step], float(t[step]))
            work += 0.5 * size * (power + now)
            power = now
        last = step == steps
        if sample_due(step) or last:
            energy = recorder.record(float(t[step]), x[step], v[step], dissipated, work)
            if not math.isfinite(energy) or abs(energy - work - energy0) > energy_bound:
                diverged, t_diverged = True, float(t[step])
                message = (f"energy {energy:.3g} J left the bound |E - E0| <= {energy_bound:.3g} J at "
                           f"t = {t[step]:.6g} s")
                break
        if with_frames and (frame_due(step) or last):
            recorder.record_frame(float(t[step]), x[step])
        while releases and t[step] >= releases[0]:  # the paths that end here hold their vertices no longer
            system = system.released(releases.pop(0))
            moving = moving_dofs(system)
            power = path_power(system, moving, x[step], v[step], float(t[step])) if moving.size else 0.0
    taken = step if diverged else steps
    error_state = None
    if error_index <= taken:
        error_state = (float(t[error_index]), x[error_index].copy(), v[error_index].copy())
    samples = recorder.result()
    log = StepLog(["dt"], max(taken, 1))
    log.grow_to(taken)
    for index in range(taken):
        log.put(index, dt=float(sizes[index]))
    attrs = {"final_error": final_error(system, samples), "not_converged_steps": 0, "first_not_converged_step": 0,
             "diverged_step": taken if diverged else 0, "safeguard_steps": 0, "dt": run.dt,
             **system.capabilities.as_attrs()}
    entries = file_metadata(Path(run.integrator.trajectory))
    if entries:
        attrs["trajectory_metadata"] = json.dumps(entries, default=str)
    model = add_outcome(system, samples, attrs, error_state, with_frames, constraint_kinds)
    status = decide_status(failed=False, diverged=diverged, over_budget=False, not_converged_steps=0,
                           accept_not_converged=False)
    # the other code's time for the states kept, its whole trajectory's prorated by steps
    wall_time = recorded_wall_time(entries) * taken / (recorded.t.size - 1)
    return RunResult(run_id=run.run_id, status=status, steps=taken, wall_time=wall_time, samples=samples,
                     per_step=log.result(taken), t_diverged=t_diverged, message=message, attrs=attrs, model=model)


def _scalars(path: Path) -> dict:
    """The trajectory file's entries besides t, x and v that are scalars or short texts (npz arrays of one value;
    HDF5 root attributes and scalar datasets), as JSON types."""
    entries = {}
    if path.suffix.lower() == ".npz":
        with np.load(path, allow_pickle=False) as file:
            items = [(key, file[key]) for key in file.files if key not in ("t", "x", "v")]
    else:
        import h5py

        with h5py.File(path, "r") as file:
            items = list(file.attrs.items()) + [(key, file[key][()]) for key in file
                                                if key not in ("t", "x", "v") and isinstance(file[key], h5py.Dataset)
                                                and file[key].size <= 16]
    for key, value in items:
        value = np.asarray(value)
        if value.size > 16:
            continue
        if value.dtype.kind in "SO":
            value = np.char.decode(value.astype(bytes), "utf-8", "replace") if value.dtype.kind == "S" else value.astype(str)
        entries[str(key)] = value.item() if value.ndim == 0 else value.tolist()
    return entries


def file_metadata(path: Path) -> dict:
    """The file's free-form metadata (empty when it has none): its first MAX_METADATA_ENTRIES entries by name, texts
    cut at MAX_METADATA_TEXT characters."""
    return {key: value[:MAX_METADATA_TEXT] if isinstance(value, str) else value
            for key, value in sorted(_scalars(path).items())[:MAX_METADATA_ENTRIES]}


def recorded_wall_time(metadata: dict) -> float:
    """The other code's wall time for the whole trajectory (its ``wall_time`` entry, s), NaN where the file does not
    say."""
    value = metadata.get("wall_time")
    try:
        value = float(value)
    except (TypeError, ValueError):
        return math.nan
    return value if math.isfinite(value) and value >= 0 else math.nan
