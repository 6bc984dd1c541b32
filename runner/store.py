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


class ResultsWriter:
    """Writes one experiment's results file; the only place that writes HDF5."""

    def __init__(self, path: Path, config_text: str, config_hash: str, name: str):
        self.path = Path(path)
        self.file = h5py.File(self.path, "w")
        attrs = self.file.attrs
        attrs["format_version"] = FORMAT_VERSION
        attrs["simrun_version"] = __version__
        attrs["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        attrs["name"] = name
        attrs["config"] = config_text
        attrs["config_hash"] = config_hash
        attrs["package_versions"] = json.dumps(package_versions())
        self.file.create_group("runs")
        self.file.create_dataset("summary", shape=(0,), maxshape=(None,), dtype=SUMMARY_DTYPE, chunks=True)
        self.file.flush()

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
        self._append_summary(run, result)
        self.file.flush()

    def _append_summary(self, run: Run, result: RunResult) -> None:
        samples = result.samples
        if "energy" in samples and samples["energy"].size:
            max_drift, final_drift = energy_drift(samples["energy"], drift_scale(samples))
        else:
            max_drift = final_drift = float("nan")
        newton = result.per_step["newton_iterations"]
        linear = result.per_step["linear_iterations"]
        row = np.array([(
            run.run_id, run.integrator.label, run.dt, result.status, result.steps, max_drift, final_drift,
            result.attrs.get("final_error", float("nan")),
            float(newton.mean()) if newton.size else 0.0, float(linear.mean()) if linear.size else 0.0,
            result.wall_time,
        )], dtype=SUMMARY_DTYPE)
        summary = self.file["summary"]
        summary.resize((summary.shape[0] + 1,))
        summary[-1] = row[0]

    def close(self) -> None:
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


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
