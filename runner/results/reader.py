"""The one reader of a results file (layout in docs/results-format.md); ``simrun.load`` and ``simrun.results.load``.

    results = simrun.load("results/quickstart/results.h5")
    results.summary                   # pandas DataFrame, one row per run
    run = results.runs["0000-forward_euler-dt=0.001"]
    run.status, run.dt, run.attrs     # the run's attributes
    run["energy"]                     # a recorded dataset, read on first use

Figures, the report, ``simrun show`` and a resumed file's summary rows all read through this module. It imports
h5py and numpy only (pandas and yaml when a table or the config is asked for), and of simrun only the format
and the other readers of this folder, never the config, the simulation or the library packages, so that results
can be read where simrun's simulation could not even be imported. What older files did not store is restated in
``simrun.results.compat``, imported when an older file asks for it.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import re
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np

from simrun.format.record import run_attribute
from simrun.errors import ResultsFileError
from simrun.format.layout import LANES_GROUP, READABLE_VERSIONS, RESULTS_NAME
from simrun.format.summary import (SUMMARY_COLUMNS, SUMMARY_DTYPE, Status, as_text, attribute_value, energy_reference,
                                   real_time_factor, series_summary, summary_row, wall_time_per_frame)
from simrun.results.fits import read_fits
from simrun.results.parameters import parameter_columns, typed_series
from simrun.results.lanes import lane_runs

# the params that set a run's steps: its fixed dt, or the tolerance its step control chooses them by
STEP_KEYS = ("dt", "step_control.tolerance")

# -- one run ----------------------------------------------------------------------------------------
class StoredRun:
    """One run of a results file: its attributes (decoded) and its datasets, each read on first use.

    ``run["energy"]`` is the recorded dataset as a numpy array (cached); ``"frames" in run`` tells
    whether it was recorded. The properties name the attributes every run has.
    """

    def __init__(self, results: "Results", run_id: str, attrs: dict, datasets: tuple[str, ...],
                 lane=None):
        self._results = results
        self.run_id = run_id
        self.attrs = attrs
        self.datasets = datasets
        self.lane = lane  # where a run stepped as a lane keeps its series: a row of its chunk's datasets
        self._cache: dict[str, np.ndarray] = {}

    def __repr__(self) -> str:
        return f"<StoredRun {self.run_id}: {self.status}>"

    def __contains__(self, key: str) -> bool:
        return key in self.datasets

    @property
    def format_version(self) -> int:
        """The format of the file that holds the run (docs/results-format.md)."""
        return self._results.format_version

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in self._cache:
            if key not in self.datasets:
                raise KeyError(f"run {self.run_id!r} has no dataset {key!r}; it has: {', '.join(self.datasets)}")
            with self._results.opened() as file:
                self._cache[key] = file["runs"][self.run_id][key][()] if self.lane is None else self.lane.read(file, key)
        return self._cache[key]

    def get(self, key: str, default=None):
        return self[key] if key in self.datasets else default

    def series(self, key: str) -> np.ndarray:
        """A dataset as floats, or an empty array when the run did not record it."""
        return np.asarray(self[key], dtype=float) if key in self.datasets else np.empty(0)

    # -- what the run was -----------------------------------------------------------------------
    @property
    def index(self) -> int:
        return int(self.attrs.get("index", 0))

    @property
    def label(self) -> str:
        """The integrator's name with its non-default parameters: tells lines apart."""
        return str(self.attrs.get("integrator_label", self.attrs.get("integrator", self.run_id)))

    @property
    def integrator(self) -> str:
        return str(self.attrs.get("integrator", ""))

    @property
    def integrator_class(self) -> str:
        """The method's class as ``package.module:ClassName`` ("" in files that predate it)."""
        return str(self.attrs.get("integrator_class", ""))

    @property
    def integrator_source_sha256(self) -> str:
        """The sha256 of the file that defined the method's class when the run was made ("" where not recorded)."""
        return str(self.attrs.get("integrator_source_sha256", ""))

    @functools.cached_property
    def params(self) -> dict:
        """Every swept and method parameter: dt, the swept keys, integrator.<param> (parsed once; do not change it)."""
        return self._json("params")

    @property
    def integrator_params(self) -> dict:
        return {key.removeprefix("integrator."): value for key, value in self.params.items() if key.startswith("integrator.")}

    @functools.cached_property
    def swept(self) -> dict:
        """The swept parameters other than the step (dt, or step_control.tolerance, which chooses the steps) and the
        integrator's own (what tells groups of runs apart)."""
        return {key: value for key, value in self.params.items()
                if key not in STEP_KEYS and not key.startswith("integrator.")}

    @property
    def system(self) -> str:
        return str(self.attrs.get("system", ""))

    @property
    def system_params(self) -> dict:
        return self._json("system_params")

    @property
    def solver(self) -> dict:
        return self._json("solver")

    @property
    def dt(self) -> float:
        return float(self.attrs.get("dt", self.params.get("dt", math.nan)))

    @property
    def order(self) -> int:
        return int(self.attrs.get("order", 0))

    @property
    def explicit(self) -> bool:
        return bool(self.attrs.get("explicit", False))

    # -- how it ended ---------------------------------------------------------------------------
    @property
    def status(self) -> Status:
        return Status(str(self.attrs.get("status", "ok")))

    @property
    def message(self) -> str:
        return str(self.attrs.get("message", ""))

    @property
    def steps(self) -> int:
        return int(self.attrs.get("steps", 0))

    @property
    def wall_time(self) -> float:
        return float(self.attrs.get("wall_time", math.nan))

    @property
    def real_time_factor(self) -> float:
        """Simulated time (steps dt) over wall time: > 1 runs faster than real time."""
        return real_time_factor(self.steps, self.dt, self.wall_time)

    @property
    def wall_time_per_frame(self) -> float:
        """s of wall time per 1/60 s of simulated time (an animation frame)."""
        return wall_time_per_frame(self.steps, self.dt, self.wall_time)

    @functools.cached_property
    def _series_summary(self) -> dict[str, float]:
        return series_summary(self.attrs, self.series)

    @property
    def max_rel_energy_remainder(self) -> float:
        """The integrator's own share of the energy budget: max |E + E_dissipated - W - E0| / E_ref
        (summary.energy_remainder), computed from the series for a file whose summary lacks it."""
        return self._series_summary["max_rel_energy_remainder"]

    @property
    def final_rel_dissipated_energy(self) -> float:
        """The energy damping and friction took out by the end, over E_ref (summary.energy_remainder)."""
        return self._series_summary["final_rel_dissipated_energy"]

    @property
    def final_error(self) -> float:
        """m: max |x - x_exact| at the last sample (NaN without an exact solution)."""
        return float(run_attribute(self.attrs, "final_error"))

    @property
    def final_velocity_error(self) -> float:
        """m/s: max |v - v_exact| at the last sample (NaN without an exact solution, and in files before it)."""
        return float(run_attribute(self.attrs, "final_velocity_error"))

    @property
    def max_error(self) -> float:
        """m: max |x - x_exact| over every stored sample and dof (NaN without an exact solution, and in files before it)."""
        return float(run_attribute(self.attrs, "max_error"))

    @property
    def max_velocity_error(self) -> float:
        """m/s: max |v - v_exact| over every stored sample and dof (NaN without an exact solution, and in files before it)."""
        return float(run_attribute(self.attrs, "max_velocity_error"))

    @property
    def error_time(self) -> float:
        """s: when the run's error was measured (record.error_time, at its nearest step); NaN for a run that
        stopped before it. Format 1 measured at the last sample."""
        if self.format_version == 1:
            t = self.series("t")
            return float(t[-1]) if t.size else math.nan
        return float(run_attribute(self.attrs, "error_time"))

    @property
    def error(self) -> float:
        """m: the distance from the exact solution at error_time (in phase space (x, v/w) on the test equation,
        else max |x - x_exact|); NaN without an exact solution or before error_time. Format 1: final_error."""
        if self.format_version == 1:
            return self.final_error
        return float(run_attribute(self.attrs, "error"))

    # -- what its system declared (format 2; restated for format 1) ------------------------------
    @property
    def test_frequency(self) -> float | None:
        """w (rad/s) when the run is the undamped test equation (or uncoupled copies), else None."""
        value = float(self._capability("test_frequency"))
        return value if math.isfinite(value) else None

    @property
    def explicit_frequency(self) -> float | None:
        """rad/s: the frequency that bounds the run's stable step at (h w)*/w, at the start shape (an explicit
        method's stiffest, IMEX Euler's of K_E - K_I; 0: no bound); None for an implicit method, on the test
        equation, and in files written before it was stored."""
        value = float(run_attribute(self.attrs, "explicit_frequency"))
        return value if math.isfinite(value) else None

    @property
    def length_scale(self) -> float:
        """m: max |x0| (1 when x0 = 0), the scale of position errors."""
        if "length_scale" in self.attrs:
            return float(self.attrs["length_scale"])
        start = self.series("positions")[:1] if "positions" in self else self.series("frames")[:1]
        start = np.abs(start[np.isfinite(start)])
        return float(start.max()) if start.size and start.max() > 0 else 1.0

    @property
    def energy_reference(self) -> float:
        """E_ref (J): what every drift and energy figure of this run is relative to (``energy_reference``)."""
        return self._energy_reference[0]

    @property
    def energy_reference_name(self) -> str:
        """What E_ref is, e.g. "E0 (initial energy)" or "max(M |g| L, |KE0| + |PE0|)"."""
        return self._energy_reference[1]

    energy_scale = energy_reference  # the capability's name in the file

    @functools.cached_property
    def _energy_reference(self) -> tuple[float, str]:
        return energy_reference(self.attrs, *(self.series(key) for key in ("energy", "kinetic_energy", "potential_energy")))

    @property
    def frame_shape(self) -> tuple[int, ...] | None:
        """The vertex grid of one frame, e.g. (rows, columns) of the cloth; None when the run keeps no frames."""
        shape = tuple(int(size) for size in np.atleast_1d(self._capability("frame_shape")))
        return shape or None

    @functools.cached_property
    def vertex_dim(self) -> int:
        """Coordinates per vertex of the run's frames (2 or 3); 0 when the run keeps no frames.

        From the attribute ``vertex_dim``; files written before it (cloth frames) hold (frames, vertices, 3)."""
        if "frames" not in self.datasets:
            return 0
        if int(run_attribute(self.attrs, "vertex_dim")) > 0:
            return int(self.attrs["vertex_dim"])
        if "frames" in self._cache:
            return int(self._cache["frames"].shape[-1])
        with self._results.opened() as file:
            return int(file["runs"][self.run_id]["frames"].shape[-1])

    @functools.cached_property
    def model_edges(self) -> np.ndarray | None:
        """(m, 2) vertex indices of the model's springs (dataset ``model_edges``); for files written before it, the
        row and column neighbours of the frame_shape grid; None for runs without frames or a model to draw."""
        if "model_edges" in self.datasets:
            return np.asarray(self["model_edges"], dtype=np.int32).reshape(-1, 2)
        return _compat().grid_model(self)[0]

    @functools.cached_property
    def model_triangles(self) -> np.ndarray | None:
        """(t, 3) vertex indices of the model's triangles (dataset ``model_triangles``, stored for models that have
        them); for files written before ``model_edges``, two per cell of the frame_shape grid; None for models
        without triangles (a rope)."""
        if "model_triangles" in self.datasets:
            return np.asarray(self["model_triangles"], dtype=np.int32).reshape(-1, 3)
        return None if "model_edges" in self.datasets else _compat().grid_model(self)[1]

    @functools.cached_property
    def model_constraints(self) -> np.ndarray | None:
        """(vertices,) int8: what each vertex is held to (``simrun.format.layout.VERTEX_KINDS``: pinned, on a
        prescribed path, sliding; 0 free), for runs with frames whose model has any; None for files written before it
        (the figures then mark the vertices that never move) and for models without constraints."""
        if "model_constraints" in self.datasets:
            return np.asarray(self["model_constraints"], dtype=np.int8).ravel()
        return None

    @property
    def dof_count(self) -> int:
        """Degrees of freedom of the run's system."""
        if "dof_count" in self.attrs:
            return int(self.attrs["dof_count"])
        positions = self.get("positions")
        return int(positions.shape[1]) if positions is not None else int(np.prod(self["frames"].shape[1:]))

    @property
    def planar(self) -> bool:
        """One body moving in the x-y plane: its trajectory is an orbit."""
        return bool(self._capability("planar"))

    def _capability(self, key: str):
        return self.attrs[key] if key in self.attrs else _compat().format1_capability(self, key)

    def _json(self, key: str) -> dict:
        return json.loads(self.attrs.get(key) or "{}")


# -- the file ---------------------------------------------------------------------------------------
class Results:
    """A results file: ``summary`` (DataFrame), ``runs`` (run id -> StoredRun, in sweep order),
    ``config`` (the resolved config), ``provenance`` (who wrote it, when, with what)."""

    def __init__(self, path: Path, attrs: dict, runs: dict[str, StoredRun] | None = None,
                 summary_table: np.ndarray | None = None):
        self.path = path
        self.attrs = attrs
        self.runs: dict[str, StoredRun] = runs or {}
        self._summary_table = summary_table
        self._file: h5py.File | None = None
        # set by simrun.run: the figure files it drew, and status -> count of the runs it simulated
        self.figure_files: list[Path] = []
        self.ran: dict[str, int] = {}

    def __repr__(self) -> str:
        return f"<Results {self.name}: {len(self.runs)} runs in {self.path}>"

    @property
    def name(self) -> str:
        return str(self.attrs.get("name", self.path.parent.name))

    @property
    def format_version(self) -> int:
        return int(self.attrs.get("format_version", 0))

    @property
    def provenance(self) -> dict:
        """Root attributes but the config: format and simrun version, creation time, config hash, package versions."""
        provenance = {key: value for key, value in self.attrs.items() if key != "config"}
        if isinstance(provenance.get("package_versions"), str):
            try:
                provenance["package_versions"] = json.loads(provenance["package_versions"])
            except ValueError:
                pass
        return provenance

    @property
    def config_text(self) -> str:
        """The config as YAML text, after --set overrides."""
        return str(self.attrs.get("config", ""))

    @property
    def config(self) -> dict:
        """The resolved config as a dict (parsed from the stored YAML)."""
        import yaml

        return yaml.safe_load(self.config_text) or {}

    @property
    def summary(self):
        """One row per run in sweep order (pandas DataFrame): the columns SUMMARY_COLUMNS, then one per swept key and
        method parameter (``simrun.results.parameters``: ``step_control.tolerance``, ``system.label``,
        ``integrator.order``, typed).

        From the file's /summary table; columns that an older table lacks (error_time and error, added
        in format 2) come from the runs."""
        import pandas

        table = self._summary_table
        if table is None:
            with self.opened() as file:
                rows = [summary_row(run_id, file["runs"][run_id]) for run_id in self.runs]
            table = np.array(rows, dtype=SUMMARY_DTYPE)
        stored = table.dtype.names
        frame = pandas.DataFrame({name: _decoded(table[name]) for name in SUMMARY_COLUMNS if name in stored})
        order = {run_id: number for number, run_id in enumerate(self.runs)}
        frame = frame.sort_values("run_id", key=lambda ids: ids.map(order)).reset_index(drop=True)
        for name in SUMMARY_COLUMNS:
            if name not in stored:
                frame.insert(SUMMARY_COLUMNS.index(name), name, [getattr(self.runs[run_id], name) for run_id in frame["run_id"]])
        columns = parameter_columns([self.runs[run_id].params for run_id in frame["run_id"]], self.config)
        for name, values in columns.items():
            frame[name] = typed_series(values)
        return frame

    @functools.cached_property
    def fits(self):
        """The calibration's fits (``simrun fit``), as ``simrun.results.fits.FitResults``; None when the file
        holds none."""
        with self.opened() as file:
            return read_fits(file)

    @contextlib.contextmanager
    def opened(self) -> Iterator[h5py.File]:
        """The file, open for reading; nested uses share one handle (reading many runs' datasets in a block)."""
        if self._file is not None:
            yield self._file
            return
        with h5py.File(self.path, "r") as file:
            self._file = file
            try:
                yield file
            finally:
                self._file = None


def unreadable_reason(path: Path, error: OSError) -> str:
    """Why HDF5 cannot open ``path``, in words: a truncated file (its size against the size HDF5 recorded), else
    HDF5's own reason (the part of h5py's message in parentheses)."""
    text = str(error)
    truncated = re.search(r"truncated file: eof = (\d+).*stored_eof = (\d+)", text)
    if truncated:
        size, expected = (int(value) for value in truncated.groups())
        return f"is truncated: {size:,} of its {expected:,} bytes (written by an interrupted process, or copied in part?)"
    reason = re.search(r"\((.*)\)", text)
    return f"cannot be opened: {reason.group(1) if reason else text or error.__class__.__name__}"


def load(path: str | Path) -> Results:
    """Open a results file: its root attributes and every run's attributes now, datasets on first use.

    Raises ResultsFileError (one line) for a file that is missing, not HDF5, not a simrun results
    file, or of a format version this simrun cannot read.
    """
    path = Path(path)
    if path.is_dir():
        hint = f"; did you mean {str(path / RESULTS_NAME)!r}?" if (path / RESULTS_NAME).is_file() else ""
        raise ResultsFileError(f"results: {str(path)!r} is a folder, not a results file{hint}")
    if not path.is_file():
        raise ResultsFileError(f"results: {str(path)!r} does not exist (expected e.g. results/quickstart/results.h5)")
    if not h5py.is_hdf5(path):
        raise ResultsFileError(f"results: {str(path)!r} is not an HDF5 file (expected e.g. results/quickstart/results.h5)")
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise ResultsFileError(f"results: {str(path)!r} {unreadable_reason(path, error)}") from None
    with file:
        if "runs" not in file:
            raise ResultsFileError(f"results: {str(path)!r} is an HDF5 file without /runs: not a simrun results file")
        attrs = {key: attribute_value(value) for key, value in file.attrs.items()}
        version = int(attrs.get("format_version", 0))
        if version not in READABLE_VERSIONS:
            raise ResultsFileError(f"results: {str(path)!r} has format version {version}; this simrun reads versions "
                                   + ", ".join(map(str, READABLE_VERSIONS)))
        results = Results(path, attrs, summary_table=file["summary"][()] if "summary" in file else None)
        stored = []
        for run_id, group in file["runs"].items():
            run_attrs = {key: attribute_value(value) for key, value in group.attrs.items()}
            stored.append(StoredRun(results, run_id, run_attrs, tuple(group.keys())))
        if LANES_GROUP in file:
            for name, chunk in file[LANES_GROUP].items():
                if chunk.attrs.get("complete", False):  # an incomplete chunk: a killed write, which a resume runs again
                    stored.extend(StoredRun(results, *run) for run in lane_runs(name, chunk))
    stored.sort(key=lambda run: run.index)
    results.runs = {run.run_id: run for run in stored}
    return results


def _decoded(column: np.ndarray):
    return [as_text(item) for item in column] if column.dtype.kind == "O" else column


def _compat():
    """simrun.results.compat, imported when an older file asks for it."""
    from simrun.results import compat

    return compat


# -- the deprecated table -----------------------------------------------------------------------------
def load_summary(path) -> np.ndarray:
    """Deprecated (use ``load(path).summary``): the summary table as a numpy structured array, strings decoded.

    Kept for one version after format 2 (``simrun.results`` offers it); it reads
    through ``load``."""
    import warnings

    warnings.warn("load_summary(path) is deprecated: use simrun.load(path).summary (a pandas DataFrame)",
                  DeprecationWarning, stacklevel=2)
    frame = load(path).summary
    table = np.empty(len(frame), dtype=[(name, object if SUMMARY_DTYPE[name].kind == "O" else SUMMARY_DTYPE[name])
                                        for name in SUMMARY_COLUMNS])
    for name in SUMMARY_COLUMNS:
        table[name] = frame[name].to_numpy()
    return table


__all__ = ["Results", "StoredRun", "load", "load_summary"]
