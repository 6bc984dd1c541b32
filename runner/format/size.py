"""How many bytes a run's rows take before compression: what the writer admits against ``--max-size-gb`` and what
cuts runs stepped as lanes into chunks."""

from __future__ import annotations

from simrun.experiment.config import Run

# bytes per step of the per-step datasets (int32 x 3, float64, int8) and per sample scalar
PER_STEP_BYTES = 3 * 4 + 8 + 1
SAMPLE_SCALARS = 12  # t, energies, dissipated energy, momentum, angular momentum, radius, energy parts
SCALARS_BYTES = 1024  # a run's attributes and summary row, about


def estimate_run_parts(run: Run) -> dict[str, int]:
    """What one run holds in memory and writes to the file (uncompressed), in bytes, by what sets it:
    ``per_step`` (solver counts of every step: steps = duration / dt), ``samples`` (the recorded
    series: record.every or record.max_samples) and ``frames`` (vertex positions of the systems that
    keep frames: record.frames_every or record.max_frames)."""
    if not run.record.series:  # the summary row and the run's scalars only
        return {"per_step": 0, "samples": SCALARS_BYTES, "frames": 0}
    steps = run.step_count
    dof = run.system.dof_count
    samples = steps // run.record.stride(steps) + 2
    per_sample = SAMPLE_SCALARS
    frames = 0
    if run.system.system_class.records_state_per_sample:
        per_sample += 2 * dof
    else:  # frames of the vertex positions, at their own cadence
        frames = (steps // run.record.frame_stride(steps) + 2) * dof * 8
    return {"per_step": steps * PER_STEP_BYTES, "samples": samples * per_sample * 8, "frames": frames}


def estimate_run_bytes(run: Run) -> int:
    """An upper bound of what one run holds in memory and writes to the file (uncompressed), in bytes."""
    return sum(estimate_run_parts(run).values())
