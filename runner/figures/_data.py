"""What the figures draw from: the runs of a results file (``simrun.analysis.runs.RunSet``: each run with what
follows from its series), laid out by their swept parameters (``FigureData``: sections drawn as panels, series
drawn as lines, each with its colour, marker and line style).
"""

from __future__ import annotations

import dataclasses
import json

from simrun.analysis.runs import RunData, RunSet, format_value, run_set, settings_title
from simrun.figures._style import LABEL_MARKERS, label_colours, label_markers
from simrun.results import Results


# At most this many lines share a panel; more are split into small multiples (by integrator family, then in
# chunks), since beyond about eight colours the legend no longer tells lines apart.
MAX_LINES = 8
# Line styles that tell the values of a swept key apart when colour already tells the integrators apart.
SETTING_LINESTYLES = ("-", "--", "-.", ":")
# with them, the markers' fills: a sweep at one dt draws points, which a line style cannot tell apart
SETTING_FILLS = ("full", "none", "left", "bottom")


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
    fillstyle: str = "full"  # the marker's fill, per setting where line styles tell settings apart (a single dt: no line)


@dataclasses.dataclass
class FigureData(RunSet):
    """Every run of a results file as the figures lay them out.

    The swept keys other than dt split the runs in two ways. ``groups`` has one entry per setting of
    all of them (the tables' view). The figures draw ``sections`` (one panel, or row of panels, per
    setting of the *panel keys*) and in each of them one line per ``Series`` (an integrator label at
    a setting of the *line keys*). A swept key is drawn as lines when it is the last one swept, its
    lines (values x labels) fit in one panel (MAX_LINES), and either the file has one integrator or
    the key is a solver option (lines compare what solves the same problem; panels separate
    problems). ``families`` splits the series into chunks of at most MAX_LINES for the small multiples.
    """

    colours: dict[str, tuple] = dataclasses.field(default_factory=dict)  # per integrator label
    markers: dict[str, str] = dataclasses.field(default_factory=dict)
    sections: list[tuple[str, list[RunData]]] = dataclasses.field(default_factory=list)  # (title, runs) per panel setting
    series: list[Series] = dataclasses.field(default_factory=list)
    line_keys: list[str] = dataclasses.field(default_factory=list)
    families: list[tuple[str, list[Series]]] = dataclasses.field(default_factory=list)  # (title, series) chunks
    _series_of: dict[int, Series] = dataclasses.field(default_factory=dict, repr=False)

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
    runs = run_set(results, reference_errors)
    data = FigureData(**{field.name: getattr(runs, field.name) for field in dataclasses.fields(RunSet)},
                      colours=label_colours(runs.labels), markers=label_markers(runs.labels))
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
    data.sections = [(settings_title({key: value for key, value in members[0].stored.swept.items() if key not in line_keys},
                                      width=PANEL_TITLE_WIDTH), members) for members in sections.values()]
    pairs = list(dict.fromkeys((run.label, settings[id(run)]) for run in data.runs))
    pairs.sort(key=lambda pair: data.labels.index(pair[0]))  # label-major, settings in config order
    names = [setting for _, setting in pairs]
    by_setting = len(data.labels) == 1 and bool(line_keys)
    setting_colours = label_colours(list(dict.fromkeys(names))) if by_setting else {}
    setting_order = list(dict.fromkeys(names))
    families = {}
    for run in data.runs:
        families.setdefault(run.label, run.integrator or run.label)
    series = {}
    for label, setting in pairs:
        number = setting_order.index(setting)
        if by_setting:  # runs that have no value for the line keys (a solver that takes no linear solver)
            style = dict(name=setting or f"(no {' × '.join(line_keys)})", colour=setting_colours[setting],
                         marker=LABEL_MARKERS[number % len(LABEL_MARKERS)], linestyle="-")
        else:
            style = dict(name=f"{label}, {setting}" if setting else label, colour=data.colours[label],
                         marker=data.markers[label], linestyle=SETTING_LINESTYLES[number % len(SETTING_LINESTYLES)],
                         fillstyle=SETTING_FILLS[number % len(SETTING_FILLS)])
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


