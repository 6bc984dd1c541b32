"""The results file: one HDF5 file per experiment (layout documented in docs/results-format.md).

Each finished run is committed at once (group written, summary row appended, file flushed), so the
file always opens and holds every run that finished.
"""

from __future__ import annotations

import datetime
import json
import platform
from importlib import metadata
from pathlib import Path

import h5py
import numpy as np

from simrun import __version__
from simrun.config import Run
from simrun.simulate import RunResult

FORMAT_VERSION = 1
RESULTS_NAME = "results.h5"
# per-step arrays are mostly constant (0 or 1 iteration): gzip shrinks them by orders of magnitude
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}

SUMMARY_DTYPE = np.dtype([
    ("run_id", h5py.string_dtype()),
    ("integrator", h5py.string_dtype()),
    ("dt", "f8"),
    ("status", h5py.string_dtype()),
    ("steps", "i8"),
    ("max_rel_energy_drift", "f8"),
    ("final_rel_energy_drift", "f8"),
    ("final_error", "f8"),
    ("mean_newton_iterations", "f8"),
    ("mean_linear_iterations", "f8"),
    ("wall_time", "f8"),
])


# bytes per step of the per-step datasets (int32 x 3, float64, int8) and per sample scalar
PER_STEP_BYTES = 3 * 4 + 8 + 1
SAMPLE_SCALARS = 12  # t, energies, dissipated energy, momentum, angular momentum, radius, energy parts


def estimate_run_bytes(run: Run) -> int:
    """An upper bound of what one run holds in memory and writes to the file (uncompressed), in bytes."""
    steps = run.step_count
    dof = run.system.dof_count
    samples = steps // run.record.stride(steps) + 2
    per_sample = SAMPLE_SCALARS
    total = steps * PER_STEP_BYTES
    if run.system.type == "cloth":
        total += (steps // run.record.frame_stride(steps) + 2) * dof * 8
    else:
        per_sample += 2 * dof
    return total + samples * per_sample * 8


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in ("numpy", "scipy", "h5py", "matplotlib", "pydantic", "pyyaml"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def energy_drift(energy: np.ndarray, scale: float) -> tuple[float, float]:
    """(max |E - E0|, final E - E0), both relative to the energy scale (|E0|, or |KE0| + |PE0| when E0 = 0)."""
    if energy.size == 0:
        return float("nan"), float("nan")
    drift = (energy - energy[0]) / scale
    return float(np.max(np.abs(drift))), float(drift[-1])


def drift_scale(samples: dict[str, np.ndarray]) -> float:
    energy0 = abs(float(samples["energy"][0]))
    if energy0 > 0:
        return energy0
    scale = abs(float(samples["kinetic_energy"][0])) + abs(float(samples["potential_energy"][0]))
    return scale if scale > 0 else 1.0


class ResultsFileError(Exception):
    """An existing results file that cannot be resumed (another config, or unreadable)."""


def stored_config_hash(path: Path) -> str | None:
    """The config hash of an existing results file; raises ResultsFileError if it cannot be read."""
    try:
        with h5py.File(path, "r") as file:
            return str(file.attrs.get("config_hash", "")) or None
    except OSError as error:
        raise ResultsFileError(f"cannot be opened ({error.__class__.__name__}); start over with --force") from None


class ResultsWriter:
    """Writes one experiment's results file; the only place that writes HDF5.

    A run is committed in one go: its group (attributes, then datasets, then ``complete = True``
    last), its summary row, then a flush. A group without ``complete`` is the trace of a write that
    was killed midway: ``resume`` removes it, so the run is simply run again.
    """

    def __init__(self, file: h5py.File):
        self.file = file
        self.path = Path(file.filename)

    @classmethod
    def create(cls, path: Path, config_text: str, config_hash: str, name: str) -> "ResultsWriter":
        file = h5py.File(path, "w")
        attrs = file.attrs
        attrs["format_version"] = FORMAT_VERSION
        attrs["simrun_version"] = __version__
        attrs["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        attrs["name"] = name
        attrs["config"] = config_text
        attrs["config_hash"] = config_hash
        attrs["package_versions"] = json.dumps(package_versions())
        file.create_group("runs")
        file.create_dataset("summary", shape=(0,), maxshape=(None,), dtype=SUMMARY_DTYPE, chunks=True)
        file.flush()
        return cls(file)

    @classmethod
    def resume(cls, path: Path) -> "ResultsWriter":
        """Open an existing file for more runs: drop incomplete groups, rebuild the summary from the rest."""
        writer = cls(h5py.File(path, "a"))
        runs = writer.file["runs"]
        for run_id in [run_id for run_id, group in runs.items() if not group.attrs.get("complete", False)]:
            del runs[run_id]
        rows = [_summary_row(run_id, runs[run_id]) for run_id in sorted(runs, key=lambda key: runs[key].attrs["index"])]
        del writer.file["summary"]
        writer.file.create_dataset("summary", data=np.array(rows, dtype=SUMMARY_DTYPE), maxshape=(None,), chunks=True)
        writer.file.flush()
        return writer

    def completed_runs(self) -> set[str]:
        return set(self.file["runs"])

    def write_run(self, run: Run, result: RunResult) -> None:
        group = self.file["runs"].create_group(run.run_id)
        attrs = group.attrs
        attrs["index"] = run.index
        attrs["system"] = run.system.type
        attrs["system_params"] = json.dumps(run.system.model_dump(mode="json"))
        attrs["integrator"] = run.integrator.name
        attrs["integrator_label"] = run.integrator.label
        attrs["order"] = run.integrator.order
        attrs["explicit"] = run.integrator.explicit
        attrs["solver"] = json.dumps(run.solver.model_dump(mode="json"))
        attrs["dt"] = run.dt
        attrs["duration"] = run.duration
        attrs["status"] = result.status
        attrs["steps"] = result.steps
        attrs["planned_steps"] = run.step_count
        attrs["wall_time"] = result.wall_time
        attrs["params"] = json.dumps(run.params)
        attrs["message"] = result.message
        if result.t_diverged is not None:
            attrs["t_diverged"] = result.t_diverged
        for key, value in result.attrs.items():
            attrs[key] = value
        for key, array in result.samples.items():
            group.create_dataset(key, data=array)
        for key, array in result.per_step.items():
            group.create_dataset(key, data=array, **(COMPRESSION if array.size > 1024 else {}))
        attrs["complete"] = True
        summary = self.file["summary"]
        summary.resize((summary.shape[0] + 1,))
        summary[-1] = np.array([_summary_row(run.run_id, group)], dtype=SUMMARY_DTYPE)[0]
        self.file.flush()

    def close(self) -> None:
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _summary_row(run_id: str, group: h5py.Group) -> tuple:
    """One summary row, computed from the run's group alone (so a resumed file can rebuild it)."""
    attrs = group.attrs
    if "energy" in group and group["energy"].shape[0]:
        samples = {key: group[key][()] for key in ("energy", "kinetic_energy", "potential_energy")}
        max_drift, final_drift = energy_drift(samples["energy"], drift_scale(samples))
    else:
        max_drift = final_drift = float("nan")
    newton = group["newton_iterations"][()]
    linear = group["linear_iterations"][()]
    return (
        run_id, str(attrs["integrator_label"]), float(attrs["dt"]), str(attrs["status"]), int(attrs["steps"]),
        max_drift, final_drift, float(attrs.get("final_error", float("nan"))),
        float(newton.mean()) if newton.size else 0.0, float(linear.mean()) if linear.size else 0.0,
        float(attrs["wall_time"]),
    )


def load_summary(path: str | Path) -> np.ndarray:
    """The summary table, one row per run, as a numpy structured array with str fields decoded."""
    with h5py.File(path, "r") as file:
        table = file["summary"][()]
    decoded = np.empty(table.shape, dtype=[(name, object if table.dtype[name].kind == "O" else table.dtype[name])
                                           for name in table.dtype.names])
    for name in table.dtype.names:
        column = table[name]
        decoded[name] = [item.decode() if isinstance(item, bytes) else item for item in column] if column.dtype.kind == "O" else column
    return decoded
