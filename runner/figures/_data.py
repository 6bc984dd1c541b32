"""What the figures draw from: the runs of a results file (read through ``simrun.results``), laid out by
their swept parameters (``FigureData``: sections drawn as panels, series drawn as lines, each with its
colour, marker and line style), and the numbers measured from their series (damping, period) computed
once per run.

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
from simrun.results import Results, Status, StoredRun


@dataclasses.dataclass(eq=False)
class RunData:
    """One run as the figures need it: the stored run, and what follows from its series."""

    stored: StoredRun
    group: str  # JSON of the swept parameters other than dt and integrator.*
    reference_error: float = math.nan  # m, at the error time against a reference (figure_data), for runs without an exact solution
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
        """E_ref (J): the run's energy reference as its system declared it (``StoredRun.energy_reference``;
        format 1: |E0|, or |KE0| + |PE0| when E0 = 0). Every energy figure divides by it, never by E0 alone:
        a cloth at rest has E0 = 0 (or round-off)."""
        return float(self.stored.energy_reference)

    @property
    def energy_reference_name(self) -> str:
        """What E_ref is, e.g. "E0 (initial energy)" or "max(M |g| L, |KE0| + |PE0|)"."""
        return str(self.stored.energy_reference_name)

    @property
    def duration(self) -> float:
        """s: the run's planned duration (format 1, which did not store it: its last sample's time)."""
        if "duration" in self.stored.attrs:
            return float(self.stored.attrs["duration"])
        t = self.t[np.isfinite(self.t)]
        return float(t[-1]) if t.size else math.nan

    @property
    def error(self) -> float:
        """m: the run's error at its error time (``StoredRun.error``), or, for a run without an exact solution,
        its error against the reference that figure_data was given."""
        return self.reference_error if self.error_from_reference else self.stored.error

    @property
    def error_time(self) -> float:
        """s: when ``error`` was measured (``StoredRun.error_time``)."""
        return self.stored.error_time

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
    def energy_change(self) -> np.ndarray:
        """(E - E0) / E_ref over the run: 0 where the energy is conserved (every system, whatever the sign of E0)."""
        energy = self.energy
        if energy.size == 0 or not np.isfinite(energy[0]):
            return np.full(energy.shape, np.nan)
        return (energy - energy[0]) / self.energy_ref

    def status_note(self) -> str:
        return {Status.DIVERGED: " (diverged)", Status.FAILED: " (failed)",
                Status.NOT_CONVERGED: " (solver not converged)"}.get(self.status, "")


# At most this many lines share a panel; more are split into small multiples (by integrator family, then in
# chunks), since beyond about eight colours the legend no longer tells lines apart.
MAX_LINES = 8
# Line styles that tell the values of a swept key apart when colour already tells the integrators apart.
SETTING_LINESTYLES = ("-", "--", "-.", ":")


@dataclasses.dataclass(frozen=True)
class Series:
    """One line of the figures: the runs of one integrator label at one setting of the keys drawn as lines."""

    label: str  # the integrator label
    setting: str  # the values of the line keys, e.g. "cg" ("" when no swept key is drawn as lines)
    name: str  # the legend text: the label, the setting, or both
    colour: tuple
    marker: str
    linestyle: str
    family: str  # the integrator's name: labels of one family share small multiples


@dataclasses.dataclass
class FigureData:
    """Every run of a results file as the figures lay them out.

    The swept keys other than dt split the runs in two ways. ``groups`` has one entry per setting of
    all of them (the tables' view). The figures draw ``sections`` (one panel, or row of panels, per
    setting of the *panel keys*) and in each of them one line per ``Series`` (an integrator label at
    a setting of the *line keys*). A swept key is drawn as lines when it is the last one swept, its
    lines (values x labels) fit in one panel (MAX_LINES), and either the file has one integrator or
    the key is a solver option (lines compare what solves the same problem; panels separate
    problems). ``families`` splits the series into chunks of at most MAX_LINES for the small multiples.
    """

    name: str
    runs: list[RunData]
    groups: list[tuple[str, list[RunData]]]  # (title, runs) per setting of every swept key, in config order
    labels: list[str]  # integrator labels in config order
    colours: dict[str, tuple]
    markers: dict[str, str]
    dt_names: dict[float, str]  # dt (s) -> the shortest text that tells it from the other dts
    results: Results  # the file, for series that only one figure needs
    sections: list[tuple[str, list[RunData]]] = dataclasses.field(default_factory=list)  # (title, runs) per panel setting
    series: list[Series] = dataclasses.field(default_factory=list)
    line_keys: list[str] = dataclasses.field(default_factory=list)
    families: list[tuple[str, list[Series]]] = dataclasses.field(default_factory=list)  # (title, series) chunks
    _series_of: dict[int, Series] = dataclasses.field(default_factory=dict, repr=False)

    @property
    def path(self) -> Path:
        return self.results.path

    def series_of(self, run: RunData) -> Series:
        return self._series_of[id(run)]

    @property
    def colour_per_series(self) -> bool:
        """Each line has a colour and a legend entry of its own; else (several integrators and a key drawn as
        lines) colour tells the integrators apart and line style the settings."""
        return not (self.line_keys and len(self.labels) > 1)

    @property
    def legend_title(self) -> str:
        """What the lines' names are: with one integrator and lines per setting, its label and the line keys."""
        if self.line_keys and len(self.labels) == 1:
            return f"{self.labels[0]}, {' × '.join(self.line_keys)}:"
        return ""


def figure_data(results: Results, reference_errors: dict[str, float] | None = None) -> FigureData:
    """The runs of ``results`` for the figures; ``reference_errors`` (run id -> m) stand in for a NaN error."""
    runs = []
    for stored in results.runs.values():
        group = json.dumps(stored.swept, sort_keys=True)
        if reference_errors and stored.run_id in reference_errors and not np.isfinite(stored.error):
            runs.append(RunData(stored, group, reference_errors[stored.run_id], error_from_reference=True))
        else:
            runs.append(RunData(stored, group))
    grouped: dict[str, list[RunData]] = {}
    for run in runs:
        grouped.setdefault(run.group, []).append(run)
    groups = [(_settings_title(members[0].stored.swept), members) for members in grouped.values()]
    labels = list(dict.fromkeys(run.label for run in runs))
    markers = {label: layout.LABEL_MARKERS[number % len(layout.LABEL_MARKERS)] for number, label in enumerate(labels)}
    data = FigureData(results.name, runs, groups, labels, layout.label_colours(labels), markers,
                      _dt_names(sorted({run.dt for run in runs})), results)
    _lay_out(data)
    return data


def _lay_out(data: FigureData) -> None:
    """Sections, series and families of ``data`` (see FigureData)."""
    values: dict[str, list] = {}  # swept key -> its values, both in config order
    seen: dict[str, set] = {}
    for run in data.runs:
        for key, value in run.stored.swept.items():
            known = seen.setdefault(key, set())
            marker = json.dumps(value, sort_keys=True) if isinstance(value, (list, dict)) else value  # (lists: unhashable)
            if marker not in known:
                known.add(marker)
                values.setdefault(key, []).append(value)
    keys = list(values)
    line_keys = []
    if keys:
        last = keys[-1]
        if len(values[last]) * len(data.labels) <= MAX_LINES and (len(data.labels) == 1 or last.startswith("solver.")):
            line_keys = [last]
    data.line_keys = line_keys
    sections: dict[str, list[RunData]] = {}
    settings: dict[int, str] = {}
    for run in data.runs:
        swept = run.stored.swept
        panel = {key: value for key, value in swept.items() if key not in line_keys}
        sections.setdefault(json.dumps(panel, sort_keys=True), []).append(run)
        settings[id(run)] = ", ".join(format_value(swept[key]) for key in line_keys if key in swept)
    data.sections = [(_settings_title({key: value for key, value in members[0].stored.swept.items() if key not in line_keys},
                                      width=PANEL_TITLE_WIDTH), members) for members in sections.values()]
    pairs = list(dict.fromkeys((run.label, settings[id(run)]) for run in data.runs))
    pairs.sort(key=lambda pair: data.labels.index(pair[0]))  # label-major, settings in config order
    names = [setting for _, setting in pairs]
    by_setting = len(data.labels) == 1 and bool(line_keys)
    setting_colours = layout.label_colours(list(dict.fromkeys(names))) if by_setting else {}
    setting_order = list(dict.fromkeys(names))
    families = {}
    for run in data.runs:
        families.setdefault(run.label, run.integrator or run.label)
    series = {}
    for label, setting in pairs:
        number = setting_order.index(setting)
        if by_setting:  # runs that have no value for the line keys (a solver that takes no linear solver)
            style = dict(name=setting or f"(no {' × '.join(line_keys)})", colour=setting_colours[setting],
                         marker=layout.LABEL_MARKERS[number % len(layout.LABEL_MARKERS)], linestyle="-")
        else:
            style = dict(name=f"{label}, {setting}" if setting else label, colour=data.colours[label],
                         marker=data.markers[label], linestyle=SETTING_LINESTYLES[number % len(SETTING_LINESTYLES)])
        series[(label, setting)] = Series(label, setting, family=families[label], **style)
    data.series = list(series.values())
    data._series_of = {id(run): series[(run.label, settings[id(run)])] for run in data.runs}
    data.families = _families(data.series)


def _families(series: list[Series]) -> list[tuple[str, list[Series]]]:
    """(title, series) chunks of at most MAX_LINES: all in one, else one per integrator with several labels
    (its name) and the other methods together, each cut into chunks where still too many."""
    if len(series) <= MAX_LINES:
        return [("", list(series))]
    by_family: dict[str, list[Series]] = {}
    for one in series:
        by_family.setdefault(one.family, []).append(one)
    labels_of = {family: {one.label for one in members} for family, members in by_family.items()}
    chunks: list[tuple[str, list[Series]]] = []
    singles = [one for one in series if len(labels_of[one.family]) == 1]
    if singles:
        chunks.append(("other methods" if len(singles) < len(series) else "", singles))
    chunks += [(family, members) for family, members in by_family.items() if len(labels_of[family]) > 1]
    cut = []
    for title, members in chunks:
        parts = [members[start:start + MAX_LINES] for start in range(0, len(members), MAX_LINES)]
        cut += [(title + (f" ({number + 1}/{len(parts)})" if len(parts) > 1 else ""), part) for number, part in enumerate(parts)]
    return cut


# Characters per line of a panel's title of swept settings: what the narrowest panels (the stability map's) hold at 9 pt.
PANEL_TITLE_WIDTH = 36


def _settings_title(swept: dict, width: int | None = None) -> str:
    """"key = value, ..."; with ``width``, broken into lines of at most that many characters between settings
    (a panel's title: three swept solver keys side by side run into the neighbouring panels' titles)."""
    parts = [f"{name} = {format_value(value)}" for name, value in swept.items()]
    if width is None:
        return ", ".join(parts)
    lines = [""]
    for part in parts:
        if lines[-1] and len(lines[-1]) + 2 + len(part) > width:
            lines[-1] += ","
            lines.append(part)
        else:
            lines[-1] += (", " if lines[-1] else "") + part
    return "\n".join(lines)


def format_value(value) -> str:
    """A swept value as the figures write it: floats in %g, anything else as str."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def _dt_names(dts: list[float]) -> dict[float, str]:
    """Three significant digits (logspace sweeps), more only where two time steps would read alike."""
    for digits in range(3, 18):
        names = [f"{dt:.{digits}g}" for dt in dts]
        if len(set(names)) == len(names):
            break
    return dict(zip(dts, names))
