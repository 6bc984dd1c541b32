"""The writing half of the results file (layout in docs/results-format.md; ``simrun.results`` reads it).

Each finished run is committed at once (group written, summary row appended, file flushed), so the
file always opens and holds every run that finished. The policies around the writer live here too:
whether a sweep may write where it is asked to, whether it fits, and whether an existing file is
resumed or refused.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shutil
import tempfile
from importlib import metadata
from pathlib import Path

import h5py
import numpy as np

from simrun import __version__
from simrun.config import Run
from simrun.errors import ConfigError, ResultsFileError
from simrun.results import FORMAT_VERSION, SUMMARY_DTYPE, summary_row
from simrun.results import load_summary  # noqa: F401  (deprecated alias, one version: simrun.load(path).summary)
from simrun.simulate import RunResult

# per-step arrays are mostly constant (0 or 1 iteration): gzip shrinks them by orders of magnitude
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
DEFAULT_MAX_SIZE_GB = 50.0


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
    if run.system.system_class.records_state_per_sample:
        per_sample += 2 * dof
    else:  # frames of the vertex positions, at their own cadence
        total += (steps // run.record.frame_stride(steps) + 2) * dof * 8
    return total + samples * per_sample * 8


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in ("numpy", "scipy", "h5py", "matplotlib", "pydantic", "pyyaml", "pandas"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


# -- before a sweep starts: may it write there, does it fit, is it a resume? ----------------------
def check_writable(output: Path) -> None:
    """Refuse an output folder we cannot write before any run starts (and before creating anything)."""
    existing = _existing_ancestor(output)
    if not existing.is_dir():
        raise ConfigError(f"output: {str(existing)!r} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError:
        raise ConfigError(f"output: cannot write in {str(existing)!r}; choose another --output") from None


def admit_size(runs: list[Run], output: Path, jobs: int, max_size_gb: float = DEFAULT_MAX_SIZE_GB) -> None:
    """Refuse a sweep whose results would not fit on the disk, under the limit, or (jobs at once) in memory."""
    sizes = [estimate_run_bytes(run) for run in runs]
    total = sum(sizes)
    free = shutil.disk_usage(_existing_ancestor(output)).free
    limit = min(max_size_gb * 1e9, free)
    if total > limit:
        reason = f"the --max-size limit of {max_size_gb:g} GB" if max_size_gb * 1e9 <= free else f"the {free / 1e9:.3g} GB free"
        raise ConfigError(f"sweep: the results would take about {total / 1e9:.3g} GB, more than {reason}; "
                          "record fewer samples (record.max_samples, record.max_frames) or shorten the sweep")
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    in_flight = sum(sorted(sizes)[-jobs:])
    if in_flight > 0.8 * memory:
        raise ConfigError(f"sweep: {jobs} runs at once would hold about {in_flight / 1e9:.3g} GB in memory, "
                          f"more than 80 % of the {memory / 1e9:.3g} GB here; use fewer --jobs or record fewer samples")


def _existing_ancestor(path: Path) -> Path:
    while not path.exists():
        path = path.parent
    return path


def open_writer(path: Path, config_text: str, digest: str, name: str, force: bool) -> "ResultsWriter":
    """The resume policy: a new file; the existing one when it holds the same config (resume); else a refusal.

    ``force`` starts over whatever the file holds."""
    if path.exists() and not force:
        try:
            with h5py.File(path, "r") as file:
                existing = str(file.attrs.get("config_hash", "")) or None
        except OSError as error:
            raise ResultsFileError(f"output: {str(path)!r} cannot be opened ({error.__class__.__name__}); "
                                   "start over with --force") from None
        if existing != digest:
            raise ConfigError(f"output: {str(path)!r} holds the results of a different config; "
                              "start over with --force, or choose another --output")
        return ResultsWriter.resume(path)
    return ResultsWriter.create(path, config_text, digest, name)


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
        rows = [summary_row(run_id, runs[run_id]) for run_id in sorted(runs, key=lambda key: runs[key].attrs["index"])]
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
        attrs["status"] = str(result.status)
        attrs["steps"] = result.steps
        attrs["planned_steps"] = run.step_count
        attrs["wall_time"] = result.wall_time
        attrs["params"] = json.dumps(run.params)
        attrs["message"] = result.message
        if result.t_diverged is not None:
            attrs["t_diverged"] = result.t_diverged
        for key, value in result.attrs.items():  # final error, solver counts, the system's capabilities
            attrs[key] = value
        for key, array in result.samples.items():
            group.create_dataset(key, data=array)
        for key, array in result.per_step.items():
            group.create_dataset(key, data=array, **(COMPRESSION if array.size > 1024 else {}))
        attrs["complete"] = True
        summary = self.file["summary"]
        summary.resize((summary.shape[0] + 1,))
        summary[-1] = np.array([summary_row(run.run_id, group)], dtype=SUMMARY_DTYPE)[0]
        self.file.flush()

    def close(self) -> None:
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
