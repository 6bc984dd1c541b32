"""What older results files did not store, restated for ``simrun.results`` (docs/results-format.md, "Versions").

- Format 1 did not store what a system declares about itself (format 2 does, as run attributes). Its three
  systems are a closed set, so what each declares is restated here once, from its stored parameters, keyed by
  its name in format 1 (tests/test_results.py checks it against the systems); its drifts were relative to
  ``drift_scale``.
- Files written before ``model_edges`` (format 1, and format 2 before ``mass_spring``) hold cloth frames on a
  ``frame_shape`` grid: the springs drawn are the grid's row and column neighbours, the surface two triangles
  per grid cell.
- ``load_summary``, the summary as a numpy structured array, is deprecated (kept one version after format 2).

``simrun.results`` imports this module on first use (a current file never needs it) and offers ``drift_scale``
and ``load_summary`` under its own name. Like the reader, it imports numpy and simrun.errors only (and the
reader, when ``load_summary`` is called).
"""

from __future__ import annotations

import math

import numpy as np

from simrun.errors import ResultsFileError


# -- format 1: the drift reference and the capabilities ---------------------------------------------
def drift_scale(energy: np.ndarray, kinetic: np.ndarray, potential: np.ndarray) -> float:
    """Format 1's drift reference (J): |E0|, else |KE0| + |PE0| (E0 = 0), else 1 J."""
    if energy.size and np.isfinite(energy[0]) and energy[0] != 0:
        return abs(float(energy[0]))
    if kinetic.size and potential.size:
        scale = abs(float(kinetic[0])) + abs(float(potential[0]))
        if np.isfinite(scale) and scale > 0:
            return scale
    return 1.0


def _spring_mass_format1(params: dict) -> dict:
    undamped = float(params.get("damping", 0.0)) == 0.0
    frequency = math.sqrt(float(params.get("stiffness", 100.0)) / float(params.get("mass", 1.0))) if undamped else math.nan
    return {"test_frequency": frequency, "planar": False, "frame_shape": np.zeros(0, dtype=np.int64)}


def _circular_motion_format1(params: dict) -> dict:
    frequency = float(params.get("angular_velocity", 1.0)) if params.get("force", "linear") == "linear" else math.nan
    return {"test_frequency": frequency, "planar": True, "frame_shape": np.zeros(0, dtype=np.int64)}


def _cloth_format1(params: dict) -> dict:
    rows_and_columns = np.array(params["resolution"][::-1], dtype=np.int64)  # resolution is [nx, ny]
    return {"test_frequency": math.nan, "planar": False, "frame_shape": rows_and_columns}


# system name in format 1 -> its capabilities (test_frequency, planar, frame_shape) from its system_params
FORMAT1_CAPABILITIES = {"spring_mass": _spring_mass_format1, "circular_motion": _circular_motion_format1,
                        "cloth": _cloth_format1}


def format1_capability(run, key: str):
    """The capability ``key`` that a format-1 run (a ``StoredRun``) did not store, restated from its parameters."""
    if run.system not in FORMAT1_CAPABILITIES:
        raise ResultsFileError(f"results: run {run.run_id!r} stores no {key!r} and its system {run.system!r} "
                               "is not one of format 1; the file is damaged")
    return FORMAT1_CAPABILITIES[run.system](run.system_params)[key]


# -- files without model_edges: the cloth's grid --------------------------------------------------------
def grid_model(run) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(edges, triangles) drawn for a run written before ``model_edges``: those of its frame_shape grid when it
    has frames on a grid of (rows, columns), else (None, None)."""
    shape = run.frame_shape if "frames" in run else None
    if shape is None or len(shape) != 2:
        return None, None
    return grid_edges(shape), grid_triangles(shape)


def grid_edges(shape: tuple[int, int]) -> np.ndarray:
    """(m, 2) int32: the row and column neighbours of a (rows, columns) vertex grid, vertex = row * columns + column."""
    index = np.arange(shape[0] * shape[1], dtype=np.int32).reshape(shape)
    pairs = [(index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])]
    return np.concatenate([np.stack([first.ravel(), second.ravel()], axis=1) for first, second in pairs])


def grid_triangles(shape: tuple[int, int]) -> np.ndarray:
    """(t, 3) int32: each cell of a (rows, columns) vertex grid split along its diagonal into two triangles."""
    index = np.arange(shape[0] * shape[1], dtype=np.int32).reshape(shape)
    corner, right, below, across = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    return np.concatenate([np.stack([corner.ravel(), right.ravel(), across.ravel()], axis=1),
                           np.stack([corner.ravel(), across.ravel(), below.ravel()], axis=1)])


# -- the deprecated table -----------------------------------------------------------------------------
def load_summary(path) -> np.ndarray:
    """Deprecated (use ``load(path).summary``): the summary table as a numpy structured array, strings decoded.

    Kept for one version after format 2 (``simrun.results`` and ``simrun.store`` re-export it); it reads
    through ``load``."""
    import warnings

    from simrun.results import SUMMARY_COLUMNS, SUMMARY_DTYPE, load  # the reader, which imports this module

    warnings.warn("load_summary(path) is deprecated: use simrun.load(path).summary (a pandas DataFrame)",
                  DeprecationWarning, stacklevel=2)
    frame = load(path).summary
    table = np.empty(len(frame), dtype=[(name, object if SUMMARY_DTYPE[name].kind == "O" else SUMMARY_DTYPE[name])
                                        for name in SUMMARY_COLUMNS])
    for name in SUMMARY_COLUMNS:
        table[name] = frame[name].to_numpy()
    return table
