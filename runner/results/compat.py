"""What older results files did not store, restated for the reader (docs/results-format.md, "Versions").

- Format 1 did not store what a system declares about itself (format 2 does, as run attributes). Its three
  systems are a closed set, so what each declares is restated here once, from its stored parameters, keyed by
  its name in format 1 (tests/test_results.py checks it against the systems); its drifts were relative to
  ``simrun.format.summary.drift_scale``.
- Files written before ``model_edges`` (format 1, and format 2 before ``mass_spring``) hold cloth frames on a
  ``frame_shape`` grid: the springs drawn are the grid's row and column neighbours, the surface two triangles
  per grid cell.

The reader imports this module on first use (a current file never needs it). Like the reader, it imports numpy
and simrun.errors only.
"""

from __future__ import annotations

import math

import numpy as np

from simrun.errors import ResultsFileError


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


