"""The writing half of the results file (layout in docs/results-format.md; ``simrun.results`` reads it).

Each finished run is committed at once (group written, summary row appended, file flushed), so the
file always opens and holds every run that finished. The policies around the writer live here too:
whether a sweep fits, and whether an existing file is resumed or refused (whether it may write where
it is asked to: ``simrun.results.lock.check_writable``). The root attributes carry the provenance: versions,
host, cpu, the command line, the config's git commit and the resolved config.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shutil
import socket
import subprocess
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from simrun.errors import ConfigError, ResultsFileError
from simrun.integrators import plugins as integrator_plugins
from simrun.experiment.config import RecordParams, Run
from simrun.format.layout import FORMAT_VERSION, LANES_GROUP, LANE_TABLE, OPTIONAL_LANE_COLUMNS
from simrun.format.record import check_record
from simrun.format.run_result import RunResult
from simrun.format.size import estimate_run_parts
from simrun.format.summary import SUMMARY_DTYPE, as_text, summary_row
from simrun.results.lock import existing_ancestor
from simrun.results.reader import unreadable_reason
from simrun.version import __version__

if TYPE_CHECKING:
    from simrun.format.run_result import LaneBatch

# per-step arrays are mostly constant (0 or 1 iteration): gzip shrinks them by orders of magnitude
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
DEFAULT_MAX_SIZE_GB = 50.0


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in ("numpy", "scipy", "h5py", "matplotlib", "pydantic", "pyyaml", "pandas"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def cpu_description() -> str:
    """The processor's model name and the number of logical cores, e.g. "AMD EPYC 7B13 (8 cores)"."""
    model = ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as stream:
            model = next((line.split(":", 1)[1].strip() for line in stream if line.startswith("model name")), "")
    except OSError:
        pass
    model = model or platform.processor() or platform.machine() or "unknown"
    return f"{model} ({os.cpu_count()} cores)"


GIT_TIMEOUT = 10.0  # s; a hung git (a network file system) must not hold the sweep up


def git_commit(config_path: Path) -> str:
    """The commit checked out in the config file's folder, plus "+dirty" when git sees the file changed
    (or untracked); empty when the folder is not in a git work tree or git is not available."""
    config_path = Path(config_path)
    folder = config_path.parent

    def git(*arguments: str) -> str:
        done = subprocess.run(["git", "-C", str(folder), *arguments], capture_output=True, text=True,
                              timeout=GIT_TIMEOUT, check=True)
        return done.stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        changed = git("status", "--porcelain", "--", config_path.name)
    except (OSError, subprocess.SubprocessError):
        return ""
    return commit + ("+dirty" if changed else "")


# -- before a sweep starts: does it fit, is it a resume? ------------------------------------------
def admit_size(runs: list[Run], output: Path, jobs: int, max_size_gb: float = DEFAULT_MAX_SIZE_GB) -> None:
    """Refuse a sweep whose results would not fit on the disk, under the limit, or (jobs at once) in memory."""
    parts = [estimate_run_parts(run) for run in runs]
    sizes = [sum(part.values()) for part in parts]
    total = sum(sizes)
    free = shutil.disk_usage(existing_ancestor(output)).free
    limit = min(max_size_gb * 1e9, free)
    if total > limit:
        reason = f"the --max-size limit of {max_size_gb:g} GB" if max_size_gb * 1e9 <= free else f"the {free / 1e9:.3g} GB free"
        raise ConfigError(f"sweep: the results would take about {total / 1e9:.3g} GB, more than {reason}; "
                          + size_advice(runs, parts))
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    largest = sorted(range(len(runs)), key=sizes.__getitem__)[-jobs:]
    in_flight = sum(sizes[index] for index in largest)
    if in_flight > 0.8 * memory:
        raise ConfigError(f"sweep: {jobs} runs at once would hold about {in_flight / 1e9:.3g} GB in memory, "
                          f"more than 80 % of the {memory / 1e9:.3g} GB here; use fewer --jobs, or "
                          + size_advice([runs[index] for index in largest], [parts[index] for index in largest]))


def size_advice(runs: list[Run], parts: list[dict[str, int]]) -> str:
    """What to change to shrink these runs' estimate: the part that dominates it, named by its config key."""
    totals = {key: sum(part[key] for part in parts) for key in parts[0]}
    dominant = max(totals, key=totals.get)
    share = f"{totals[dominant] / max(1, sum(totals.values())):.0%} of the estimate"
    longest = max(runs, key=lambda run: run.step_count)
    if dominant == "per_step":
        return (f"the per-step arrays dominate ({share}; {longest.step_count:,} steps in the longest run): "
                "shorten duration or use a larger dt, or sweep fewer runs")
    if dominant == "frames":
        if any(run.record.frames_every is not None for run in runs):
            return (f"the frames dominate ({share}): use a larger record.frames_every, or drop it and "
                    f"keep at most record.max_frames frames (default {RecordParams.model_fields['max_frames'].default})")
        return f"the frames dominate ({share}): lower record.max_frames"
    if any(run.record.every is not None for run in runs):
        return (f"the recorded samples dominate ({share}): use a larger record.every, or drop it and "
                f"keep at most record.max_samples samples (default {RecordParams.model_fields['max_samples'].default})")
    return f"the recorded samples dominate ({share}): lower record.max_samples"


def open_writer(path: Path, config_text: str, digest: str, name: str, force: bool, **provenance) -> "ResultsWriter":
    """The resume policy: a new file; the existing one when it holds the same config (resume); else a refusal.

    ``force`` starts over whatever the file holds. ``provenance``: the keywords of ``ResultsWriter.create``
    (a resumed file keeps the provenance of its creation)."""
    if path.exists() and not force:
        try:
            with h5py.File(path, "r") as file:
                existing = str(file.attrs.get("config_hash", "")) or None
        except OSError as error:
            raise ResultsFileError(f"output: {str(path)!r} {unreadable_reason(path, error)}: start over with --force "
                                   "(what it holds is lost), or choose another --output") from None
        if existing != digest:
            raise ConfigError(f"output: {str(path)!r} holds the results of a different config; "
                              "start over with --force, or choose another --output")
        return ResultsWriter.resume(path)
    return ResultsWriter.create(path, config_text, digest, name, **provenance)


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
    def create(cls, path: Path, config_text: str, config_hash: str, name: str, *, command_line: str = "",
               config_path: Path | None = None, resolved_config: str = "") -> "ResultsWriter":
        """A new file with the root attributes (docs/results-format.md), provenance included: host, cpu,
        ``command_line`` (what started the sweep), the git commit of ``config_path`` (the config file,
        None when the config was not a file) and ``resolved_config`` (the validated experiment as YAML)."""
        file = h5py.File(path, "w")
        attrs = file.attrs
        attrs["format_version"] = FORMAT_VERSION
        attrs["simrun_version"] = __version__
        attrs["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        attrs["name"] = name
        attrs["config"] = config_text
        attrs["config_hash"] = config_hash
        attrs["package_versions"] = json.dumps(package_versions())
        attrs["host"] = socket.gethostname()
        attrs["cpu"] = cpu_description()
        attrs["command_line"] = command_line
        attrs["config_git_commit"] = git_commit(config_path) if config_path is not None else ""
        attrs["resolved_config"] = resolved_config
        file.create_group("runs")
        file.create_dataset("summary", shape=(0,), maxshape=(None,), dtype=SUMMARY_DTYPE, chunks=True)
        file.flush()
        return cls(file)

    @classmethod
    def resume(cls, path: Path) -> "ResultsWriter":
        """Open an existing file for more runs: drop incomplete groups and lane chunks, rebuild the summary from the rest."""
        writer = cls(h5py.File(path, "a"))
        runs = writer.file["runs"]
        for run_id in [run_id for run_id, group in runs.items() if not group.attrs.get("complete", False)]:
            del runs[run_id]
        chunks = writer.file.get(LANES_GROUP)
        if chunks is not None:
            for name in [name for name, chunk in chunks.items() if not chunk.attrs.get("complete", False)]:
                del chunks[name]
        writer._rebuild_summary()
        return writer

    def remove_runs(self, run_ids: list[str]) -> None:
        """Delete these runs' groups and rebuild the summary without them (a calibration refitting them)."""
        runs = self.file["runs"]
        for run_id in run_ids:
            del runs[run_id]
        self._rebuild_summary()

    def _rebuild_summary(self) -> None:
        """/summary from the runs' groups and the lane chunks' own rows, in sweep order."""
        runs = self.file["runs"]
        rows = [(int(runs[run_id].attrs["index"]), summary_row(run_id, runs[run_id])) for run_id in runs]
        for chunk in self.file.get(LANES_GROUP, {}).values():
            rows += zip(chunk[LANE_TABLE]["index"].tolist(), _in_summary_columns(chunk["summary"][()]).tolist())
        rows.sort(key=lambda item: item[0])
        del self.file["summary"]
        self.file.create_dataset("summary", data=np.array([row for _, row in rows], dtype=SUMMARY_DTYPE),
                                 maxshape=(None,), chunks=True)
        self.file.flush()

    def completed_runs(self) -> set[str]:
        done = set(self.file["runs"])
        for chunk in self.file.get(LANES_GROUP, {}).values():
            if chunk.attrs.get("complete", False):  # (a write interrupted by Ctrl-C left the others)
                done.update(as_text(run_id) for run_id in chunk[LANE_TABLE]["run_id"].tolist())
        return done

    def write_run(self, run: Run, result: RunResult) -> None:
        check_record(result.attrs)
        group = self.file["runs"].create_group(run.run_id)
        attrs = group.attrs
        attrs["index"] = run.index
        attrs["system"] = run.system.type
        attrs["system_params"] = json.dumps(run.system.model_dump(mode="json"))
        attrs["integrator"] = run.integrator.name
        attrs["integrator_label"] = run.integrator_label
        attrs.update(integrator_plugins.provenance(type(run.integrator)))
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
        for key, array in result.model.items():  # the topology that pictures draw: springs, triangles
            group.create_dataset(key, data=array, **(COMPRESSION if array.size > 1024 else {}))
        for key, array in result.per_step.items():
            group.create_dataset(key, data=array, **(COMPRESSION if array.size > 1024 else {}))
        attrs["complete"] = True
        summary = self.file["summary"]
        summary.resize((summary.shape[0] + 1,))
        summary[-1] = np.array([summary_row(run.run_id, group)], dtype=SUMMARY_DTYPE)[0]
        self.file.flush()

    def write_lanes(self, runs: list[Run], batch: "LaneBatch") -> None:
        """A chunk of runs stepped together (runner/execution/lanes.py), committed in one go as one group of /lanes with a column
        per attribute and a dataset per series, each with a run axis (docs/results-format.md, "Lane chunks"); a
        chunk that was stepped run by run (it failed as lanes) is written as runs."""
        if batch.results_alone is not None:
            for run, result in zip(runs, batch.results_alone):
                self.write_run(run, result)
            return
        first = runs[0]
        group = self.file.require_group(LANES_GROUP).create_group(f"{first.index:06d}+{len(runs)}")
        shared, table = batch.table
        columns = table.dtype.names
        check_record({**shared, **dict.fromkeys(column for column in columns if column != "run_id")})
        for key, value in shared.items():
            group.attrs[key] = value
        group.create_dataset(LANE_TABLE, data=table)
        group.attrs["optional_columns"] = [key for key in OPTIONAL_LANE_COLUMNS if key in columns]
        group.attrs["per_step_keys"] = list(batch.per_step)
        series = group.create_group("series")
        for key, array in {**batch.samples, **batch.per_step}.items():
            series.create_dataset(key, data=array, **(COMPRESSION if array.size > 1024 else {}))
        if batch.sample_count is not None:
            group.create_dataset("sample_count", data=batch.sample_count)
        if batch.error_positions is not None:
            series.create_dataset("error_positions", data=batch.error_positions)
        rows = batch.summary
        group.create_dataset("summary", data=rows)
        group.attrs["complete"] = True
        summary = self.file["summary"]
        summary.resize((summary.shape[0] + len(rows),))
        summary[-len(rows):] = rows
        self.file.flush()

    def close(self) -> None:
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _in_summary_columns(stored: np.ndarray) -> np.ndarray:
    """A lane chunk's summary rows in this simrun's columns (SUMMARY_DTYPE): a column that a chunk written by an older
    simrun lacks (the error norms over the run) is NaN, as its runs' attributes read."""
    rows = np.empty(stored.shape, dtype=SUMMARY_DTYPE)
    for name in SUMMARY_DTYPE.names:
        rows[name] = stored[name] if name in stored.dtype.names else np.nan
    return rows
