"""What the figures draw from: the runs of a results file (read through ``simrun.results``), grouped by
their swept parameters, with a colour and a marker per integrator label, and the numbers measured
from their series (damping, period) computed once per run.

The measured and predicted numbers come from ``simrun.analysis``, imported on first use: importing
the figures loads no integrator, system or solver; drawing a theory figure does (it probes the
integrators named in the file, never the runs).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from pathlib import Path

import numpy as np

from simrun.figures import _layout as layout
from simrun.results import Results, Status, StoredRun, drift_scale


@dataclasses.dataclass(eq=False)
class RunData:
    """One run as the figures need it: the stored run, and what follows from its series."""

    stored: StoredRun
    group: str  # JSON of the swept parameters other than dt and integrator.*
    final_error: float  # m, against the exact solution, or a reference (see with_reference_errors)
    error_from_reference: bool = False

    # -- the stored description -----------------------------------------------------------------
    @property
    def run_id(self) -> str:
        return self.stored.run_id

    @property
    def index(self) -> int:
        return self.stored.index

    @property
    def label(self) -> str:
        return self.stored.label

    @property
    def integrator(self) -> str:
        return self.stored.integrator

    @property
    def integrator_params(self) -> dict:
        return self.stored.integrator_params

    @property
    def dt(self) -> float:
        return self.stored.dt

    @property
    def status(self) -> Status:
        return self.stored.status

    @property
    def explicit(self) -> bool:
        return self.stored.explicit

    @property
    def order(self) -> int:
        return self.stored.order

    @property
    def steps(self) -> int:
        return self.stored.steps

    @property
    def wall_time(self) -> float:
        return self.stored.wall_time

    @property
    def frequency(self) -> float | None:
        """w (rad/s) when the run is the undamped test equation, else None (the system's declaration)."""
        return self.stored.test_frequency

    @functools.cached_property
    def length_scale(self) -> float:
        return self.stored.length_scale

    # -- series, read on first use ------------------------------------------------------------
    @functools.cached_property
    def t(self) -> np.ndarray:
        return self.stored.series("t")

    @functools.cached_property
    def energy(self) -> np.ndarray:
        return self.stored.series("energy")

    @functools.cached_property
    def energy_ref(self) -> float:
        """J: |E0|, or |KE0| + |PE0| when E0 = 0 (1 when both vanish): the scale of the drift."""
        return drift_scale(self.energy, self.stored.series("kinetic_energy"), self.stored.series("potential_energy"))

    @functools.cached_property
    def newton_iterations(self) -> np.ndarray:
        return self.stored.series("newton_iterations")

    @functools.cached_property
    def positions(self) -> np.ndarray:
        """(samples, dof) m, or (0, 0) when the run keeps frames instead."""
        positions = self.stored.series("positions")
        return positions if positions.ndim == 2 else np.empty((0, 0))

    @property
    def xy(self) -> np.ndarray:
        """(samples, 2) m: the trajectory in the x-y plane of a planar run's body."""
        positions = self.positions
        return positions[:, :2] if positions.shape[1] >= 2 else np.empty((0, 2))

    @property
    def coordinate(self) -> np.ndarray | None:
        """(samples,) m, the first coordinate of a test-equation run (for its zero crossings)."""
        if self.frequency is None or self.positions.shape[0] == 0:
            return None
        return self.positions[:, 0]

    # -- what follows from them -------------------------------------------------------------------
    @property
    def hw(self) -> float:
        """h w of the run (NaN when it is not the test equation)."""
        return self.dt * self.frequency if self.frequency else math.nan

    @functools.cached_property
    def method(self):
        """The integrator object (from its name and parameters), or None if this simrun does not know it."""
        from simrun import analysis

        try:
            return analysis.integrator_from_params(self.integrator, self.integrator_params)
        except Exception:  # a file written by another version: no prediction, the rest still draws
            return None

    @functools.cached_property
    def damping_fit(self):
        """The measured artificial damping (``analysis.DampingFit``, energy decay) of an undamped linear run
        that did not stop early; None otherwise."""
        if self.frequency is None or self.status.stopped or not self.has_change:
            return None
        from simrun import analysis

        return analysis.measure_damping(self.t, self.energy, self.coordinate, self.frequency)

    @functools.cached_property
    def period_error(self) -> float:
        """T / T_exact - 1 measured from the zero crossings of the first coordinate (NaN where not measurable)."""
        if self.frequency is None or self.coordinate is None or self.status.stopped:
            return math.nan
        from simrun import analysis

        return analysis.measure_period_error(self.t, self.coordinate, self.frequency)

    @property
    def has_series(self) -> bool:
        """At least one finite energy sample: something to draw."""
        return int(np.count_nonzero(np.isfinite(self.energy))) >= 1

    @property
    def has_change(self) -> bool:
        """At least two finite energy samples: a drift or growth can be measured."""
        return int(np.count_nonzero(np.isfinite(self.energy))) >= 2

    @property
    def energy_ratio(self) -> np.ndarray:
        """E / E_ref: E/E0 where E0 > 0; starts at -1 where E0 < 0 (a bound orbit)."""
        return self.energy / self.energy_ref

    def status_note(self) -> str:
        return {Status.DIVERGED: " (diverged)", Status.FAILED: " (failed)",
                Status.NOT_CONVERGED: " (solver not converged)"}.get(self.status, "")


@dataclasses.dataclass
class FigureData:
    """Every run of a results file as the figures lay them out."""

    name: str
    runs: list[RunData]
    groups: list[tuple[str, list[RunData]]]  # (title, runs) in config order
    labels: list[str]  # integrator labels in config order
    colours: dict[str, tuple]
    markers: dict[str, str]
    dt_names: dict[float, str]  # dt (s) -> the shortest text that tells it from the other dts
    results: Results  # the file, for series that only one figure needs

    @property
    def path(self) -> Path:
        return self.results.path


def figure_data(results: Results, reference_errors: dict[str, float] | None = None) -> FigureData:
    """The runs of ``results`` for the figures; ``reference_errors`` (run id -> m) stand in for a NaN final error."""
    runs = []
    for stored in results.runs.values():
        error, from_reference = stored.final_error, False
        if reference_errors and stored.run_id in reference_errors and not np.isfinite(error):
            error, from_reference = reference_errors[stored.run_id], True
        runs.append(RunData(stored, json.dumps(stored.swept, sort_keys=True), error, from_reference))
    grouped: dict[str, list[RunData]] = {}
    for run in runs:
        grouped.setdefault(run.group, []).append(run)
    groups = [(_group_title(key), members) for key, members in grouped.items()]
    labels = list(dict.fromkeys(run.label for run in runs))
    markers = {label: layout.LABEL_MARKERS[number % len(layout.LABEL_MARKERS)] for number, label in enumerate(labels)}
    return FigureData(results.name, runs, groups, labels, layout.label_colours(labels), markers,
                      _dt_names(sorted({run.dt for run in runs})), results)


def _group_title(key: str) -> str:
    swept = json.loads(key)
    return ", ".join(f"{name} = {_format_value(value)}" for name, value in swept.items())


def _format_value(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _dt_names(dts: list[float]) -> dict[float, str]:
    """Three significant digits (logspace sweeps), more only where two time steps would read alike."""
    for digits in range(3, 18):
        names = [f"{dt:.{digits}g}" for dt in dts]
        if len(set(names)) == len(names):
            break
    return dict(zip(dts, names))
