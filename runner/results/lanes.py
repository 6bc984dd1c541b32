"""Reading the lane chunks of a results file (/lanes/<chunk>, format 3; docs/results-format.md, "Lane chunks") into the
same ``StoredRun`` as the runs of /runs (the reader builds them): each run's attributes as its own group would hold
them, its series read on first use from its row of the chunk's datasets. Imports h5py and numpy only, as the reader does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import h5py
import numpy as np

from simrun.format.layout import LANES_GROUP, LANE_TABLE
from simrun.format.summary import as_text, attribute_value

WITH_ERROR_TIME = ("error",)


@dataclass(frozen=True)
class LaneLocation:
    """A lane run's row in its chunk (/lanes/<chunk>/series/<key>[row]), and the lengths that cut its padding off."""

    chunk: str
    row: int
    samples: int  # recorded samples: the series of samples are NaN after them
    steps: int  # steps taken: the per-step series are 0 after them
    per_step: frozenset  # the chunk's per-step series

    def read(self, file: h5py.File, key: str) -> np.ndarray:
        values = file[LANES_GROUP][self.chunk]["series"][key][self.row]
        if key == "error_positions":
            return values
        return values[: self.steps] if key in self.per_step else values[: self.samples]


# attributes of a lane chunk that are about the chunk, not its runs
CHUNK_ATTRS = ("complete", "optional_columns", "per_step_keys")


class _LaneAttrs(Mapping):
    """The attributes of one run of a lane chunk, as its own group would hold them: the chunk's shared ones and its row
    of the chunk's table (an optional field's NaN: the run has no such attribute), read on access (a map's chunk holds
    thousands of runs, whose attributes are rarely all read)."""

    __slots__ = ("_shared", "_columns", "_optional", "_row")

    def __init__(self, shared: dict, columns: dict[str, list], optional: frozenset, row: int):
        self._shared, self._columns, self._optional, self._row = shared, columns, optional, row

    def _absent(self, key) -> bool:
        if key in WITH_ERROR_TIME:
            key = "error_time"
        if key not in self._optional:
            return False
        value = self._columns[key][self._row] if key in self._columns else math.nan
        return value != value

    def __getitem__(self, key):
        if key in self._columns:
            if self._absent(key):
                raise KeyError(key)
            return self._columns[key][self._row]
        return self._shared[key]

    def __iter__(self):
        yield from self._shared
        for key in self._columns:
            if not self._absent(key):
                yield key

    def __len__(self) -> int:
        return sum(1 for _ in self)


def lane_runs(name: str, chunk: h5py.Group) -> list[tuple]:
    """The runs of one lane chunk as the reader's ``StoredRun`` takes them: (run id, the attributes a run's group would
    hold (``_LaneAttrs``), its datasets, its ``LaneLocation`` or None)."""
    shared = {key: attribute_value(value) for key, value in chunk.attrs.items() if key not in CHUNK_ATTRS}
    shared["complete"] = True
    optional = frozenset(as_text(key) for key in chunk.attrs.get("optional_columns", ()))
    table = chunk[LANE_TABLE][()]
    columns = {key: ([as_text(value) for value in table[key].tolist()] if table.dtype[key].kind == "O" else table[key].tolist())
               for key in table.dtype.names}
    series = chunk.get("series")
    series_keys = tuple(series.keys()) if series is not None else ()
    without_error = tuple(key for key in series_keys if key != "error_positions")
    per_step = frozenset(as_text(key) for key in chunk.attrs.get("per_step_keys", ()))
    counts = chunk["sample_count"][()].tolist() if "sample_count" in chunk else None
    error_times, steps = columns.get("error_time"), columns["steps"]
    runs = []
    for row, run_id in enumerate(columns.pop("run_id")):
        attrs = _LaneAttrs(shared, columns, optional, row)
        lane = None
        datasets = ()
        if series_keys:
            reached = error_times is not None and error_times[row] == error_times[row]
            datasets = series_keys if reached else without_error
            lane = LaneLocation(name, row, counts[row] if counts is not None else 0, int(steps[row]), per_step)
        runs.append((run_id, attrs, datasets, lane))
    return runs
