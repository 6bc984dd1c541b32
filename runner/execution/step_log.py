"""The per-step arrays of one run: the columns of simrun.format.record's STEP_COLUMNS, one row per step.

``simulate`` and the peers fill one; lanes keep the same columns with a lane axis (lane_recording.py). An explicit
step solves nothing: its solver columns stay at zero, what EXPLICIT_STEP reports.
"""

from __future__ import annotations

import operator

import numpy as np

from simrun.format.record import STEP_COLUMNS


class StepLog:
    """Zero-filled rows of the named STEP_COLUMNS; ``grow_to`` doubles them where the step count is not known ahead."""

    def __init__(self, names, rows: int):
        self.arrays = {name: np.zeros(rows, dtype=STEP_COLUMNS[name].dtype) for name in names}
        self.rows = rows
        self._bind()

    def _bind(self) -> None:
        solver = [name for name in self.arrays if STEP_COLUMNS[name].stats_field is not None]
        self._solver_arrays = [self.arrays[name] for name in solver]
        fields = [STEP_COLUMNS[name].stats_field for name in solver]
        # one C call for every field of a SolveStats: the loop's cost per step, not per field (attrgetter gives a
        # tuple for two fields or more)
        self._solver_fields = operator.attrgetter(*fields) if len(fields) > 1 else lambda stats: [
            getattr(stats, field) for field in fields]

    def grow_to(self, rows: int) -> None:
        """At least ``rows`` rows: twice as many as now when they are full."""
        if rows > self.rows:
            self.arrays = {key: np.concatenate([value, np.zeros_like(value)]) for key, value in self.arrays.items()}
            self.rows *= 2
            self._bind()

    def record(self, row: int, stats) -> None:
        """A solve's statistics (SolveStats) in the step's row of the solver columns."""
        for array, value in zip(self._solver_arrays, self._solver_fields(stats)):
            array[row] = value

    def put(self, row: int, **values) -> None:
        """The loop's own columns of a step (its size, contact, factorisation path)."""
        arrays = self.arrays
        for key, value in values.items():
            arrays[key][row] = value

    def column(self, name: str, steps: int) -> np.ndarray:
        return self.arrays[name][:steps]

    def result(self, steps: int) -> dict[str, np.ndarray]:
        """The first ``steps`` rows of every column, as the run stores them."""
        return {key: value[:steps] for key, value in self.arrays.items()}
