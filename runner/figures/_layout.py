"""Layout shared by the figures: sizes, colours and markers, panel grids, legends and notes, axis scales, saving.

Private to simrun.figures; a figure module imports it as ``from simrun.figures import _layout as layout``.

The rules every figure follows: every run of the file is drawn, or a note in the figure (the line under
the panels) says what is left out and why; at most ``_data.MAX_LINES`` lines share a panel; legends sit
outside the data (a figure legend at the right); one y scale per figure, decided from all its panels;
lines that coincide to round-off are drawn once with both names in the legend, or the later one dashed
over the earlier, so that neither hides the other.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")  # files only: no display, and safe in worker processes

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from simrun.format.summary import Status  # noqa: E402

if TYPE_CHECKING:
    from simrun.analysis.runs import RunData
    from simrun.figures._data import FigureData, Series

# PNG always (the report shows them); SVG on request (`--svg`): a vector copy for papers, which costs a third more
# drawing time again (its writer lays out every glyph as a path)
FORMATS = ("png",)
VECTOR_FORMATS = ("png", "svg")
PNG_DPI = 150
# One panel of the small multiples (in); large enough for 8-pt tick labels to stay readable.
PANEL_SIZE = (3.6, 2.7)
# More dt panels than this become unreadable; show this many, spread over the range.
MAX_DT_PANELS = 12
# With several rows of panels (settings, families), fewer dt columns: a row wider than this no longer fits a page.
MAX_DT_PANELS_PER_ROW = 6
# ... and with three rows or more, this many (the figure stays about as wide as it is tall).
MAX_DT_PANELS_MANY_ROWS = 4
# Rows of small multiples beyond this make a figure taller than a page: the rest are left out, with a note.
MAX_PANEL_ROWS = 12
PANEL_COLUMNS = 4
# Panels of a figure against dt beyond this make it taller than a page: the rest are left out, with a note.
MAX_SUMMARY_PANELS = 24
# One panel of the figures against dt (in): one line per integrator needs more room than a small multiple.
SUMMARY_PANEL_SIZE = (5.0, 3.6)
# Diverged runs off a log scale: drawn at this fraction of the axes height, above
# the data, which a y range padded by this factor leaves room for.
TOP_EDGE, TOP_PADDING = 0.95, 30.0
# Room for a legend beside the panels (in): the longest entry is about 30 characters at 8 pt.
FIGURE_LEGEND_WIDTH = 2.2
# A note under the panels (what a figure leaves out, footnotes), in points.
NOTE_SIZE = 7.5

# Each later line's marker is drawn this much smaller (pt), so coinciding points show as rings.
MARKER_SHRINK = 0.5
LEGEND_MARKER_SIZE = 6.0
# Two curves are the same when they differ by less than this, relative to the larger of them (round-off
# of a few hundred steps is ~1e-13; a real difference between methods is many orders larger).
SAME_CURVE = 1e-9
SAME_CURVE_NOTE = f"A = B in the legend: the curves agree to {SAME_CURVE:g} of their size everywhere, drawn once"
# The dash pattern of a line drawn over an identical one: gaps of this many points show the line beneath.
OVERLAY_DASHES = (0, (3.0, 3.0))
# Linear y axes for values within this magnitude; beyond, symlog.
LINEAR_RANGE = 10.0
# A log axis covers at most this many decades below the largest value (a decay to underflow is not data).
MAX_LOG_DECADES = 20.0


def save_figure(figure, stem: Path, dpi: int = PNG_DPI, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Write stem.png (and stem.svg, with ``formats`` VECTOR_FORMATS). The layout is computed once and then dropped: matplotlib draws a figure twice per
    file while it has a layout engine (a draw that renders nothing lays it out first), so each file costs one draw
    instead of two. The engine is run by itself, which is what that first draw does before it draws the artists for
    nothing (the same pixels, a sixth less time)."""
    engine = figure.get_layout_engine()
    if engine is not None:
        # laid out at the dpi it is drawn at: text measured at the default 100 dpi and drawn at 150 grew past the
        # left edge (a stability map's longest row label lost its first letter)
        figure.set_dpi(dpi)
        engine.execute(figure)
        try:
            figure.set_layout_engine(None)  # the axes keep the positions the layout gave them
        except RuntimeError:  # a layout whose colourbars no other engine may take over: keep a placeholder
            figure.set_layout_engine("none")
    written = []
    for extension in formats:
        target = stem.with_name(f"{stem.name}.{extension}")  # not with_suffix: names may contain dots
        # no creation date in the metadata, so redrawing the same file gives the same SVG
        metadata = {"Date": None} if extension == "svg" else None
        figure.savefig(target, dpi=dpi, metadata=metadata)
        written.append(target)
    return written


# -- panels ---------------------------------------------------------------------------------------
@dataclass
class Panel:
    """One axes of a figure: its title, the runs it draws and the lines (series) they belong to."""

    title: str
    runs: list
    series: list
    row: str = ""  # the row's header (section and family) in grids whose columns are the time steps


def summary_panels(data: FigureData, keep=None, notes: list[str] | None = None) -> list[Panel]:
    """One panel per section (setting of the panel keys) and family of lines, with the runs `keep` accepts.

    With ``notes`` (a figure's), at most MAX_SUMMARY_PANELS: the first ones, and a note that says so."""
    panels = []
    for section, runs in data.sections:
        for family, members in data.families:
            wanted = set(map(id, members))
            mine = [run for run in runs if id(data.series_of(run)) in wanted and (keep is None or keep(run))]
            if mine:
                lines = [one for one in members if any(data.series_of(run) is one for run in mine)]
                panels.append(Panel(join_titles(section, family), mine, lines))
    if notes is not None and len(panels) > MAX_SUMMARY_PANELS:
        notes.append(f"{MAX_SUMMARY_PANELS} of {len(panels)} panels (settings × families) shown: the first ones "
                     "(every run: the stability map)")
        panels = panels[:MAX_SUMMARY_PANELS]
    return panels


def step_setting(run) -> tuple[str, float]:
    """What sets a run's steps: ("tol", its step_control.tolerance) for a step-controlled run, else ("dt", its dt)."""
    return ("tol", run.tolerance) if np.isfinite(run.tolerance) else ("dt", run.dt)


def step_setting_title(data: FigureData, setting: tuple[str, float]) -> str:
    kind, value = setting
    return f"tol = {value:g}" if kind == "tol" else f"dt = {data.dt_names[value]} s"


def dt_grid(data: FigureData, keep=None) -> tuple[list[list[Panel]], list[str]]:
    """Small multiples: a row per section and family of lines, a column per time step, or per tolerance for
    step-controlled runs (whose dt is only their mean step); (rows, notes).

    With one row the columns wrap onto rows of PANEL_COLUMNS, and so do the settings where each row would hold
    one panel. At most MAX_DT_PANELS time steps or tolerances (fewer with several rows), spread over the range: the
    notes say how many of how many are shown."""
    blocks = summary_panels(data, keep)
    notes = []
    if len(blocks) > MAX_PANEL_ROWS:
        notes.append(f"{MAX_PANEL_ROWS} of {len(blocks)} rows (settings × families) shown: the first ones")
        blocks = blocks[:MAX_PANEL_ROWS]
    settings = sorted({step_setting(run) for block in blocks for run in block.runs})
    cap = MAX_DT_PANELS if len(blocks) == 1 else MAX_DT_PANELS_PER_ROW if len(blocks) == 2 else MAX_DT_PANELS_MANY_ROWS
    shown = spread(settings, cap)
    if len(shown) < len(settings):
        tolerances = all(kind == "tol" for kind, _ in settings)
        what = "tolerances" if tolerances else "time steps"
        every = "the error and cost table" if tolerances else "the energy drift figure and the stability map"
        notes.append(f"{len(shown)} of {len(settings)} {what} shown, spread over the range (every one: {every})")
    rows = []
    for block in blocks:
        row = [Panel(step_setting_title(data, setting), [run for run in block.runs if step_setting(run) == setting],
                     block.series, block.title)
               for setting in shown]
        row = [panel for panel in row if panel.runs]
        if len(blocks) == 1:
            rows += [row[start:start + PANEL_COLUMNS] for start in range(0, len(row), PANEL_COLUMNS)]
        elif row:
            rows.append(row)
    if len(rows) > 2 and all(len(row) == 1 for row in rows):
        # one time step and many settings: a column of rows one panel wide would be a strip 5,000 px tall; the panels
        # wrap into rows instead, each titled with its setting and its time step
        rows = wrap([Panel(f"{row[0].row}\n{row[0].title}" if row[0].row else row[0].title, row[0].runs, row[0].series)
                     for row in rows])
    return rows, notes


def join_titles(*parts: str) -> str:
    return " · ".join(part for part in parts if part)


def wrap(panels: list, columns: int = PANEL_COLUMNS) -> list[list]:
    """Panels in rows of at most `columns`, balanced (5 panels: 3 + 2, not 4 + 1)."""
    if not panels:
        return []
    count = math.ceil(len(panels) / columns)
    width = math.ceil(len(panels) / count)
    return [panels[start:start + width] for start in range(0, len(panels), width)]


def spread(values: list[float], count: int) -> list[float]:
    """At most `count` of the sorted values, evenly spread and always including both ends."""
    if len(values) <= count:
        return list(values)
    picks = np.unique(np.round(np.linspace(0, len(values) - 1, count)).astype(int))
    return [values[pick] for pick in picks]


def panel_grid(rows, sharex=False, sharey=False, panel_size=PANEL_SIZE, legend_width=0.0, extra_height=0.0):
    """A figure with one axes per panel (rows of varying length); returns (figure, axes in panel order).

    legend_width (in) is added for a figure legend on the right, so that it does not squeeze the panels;
    extra_height (in) for notes under the panels."""
    columns = max(len(row) for row in rows)
    size = (panel_size[0] * columns + legend_width, panel_size[1] * len(rows) + 0.6 + extra_height)
    figure, grid = plt.subplots(len(rows), columns, figsize=size,
                                layout="constrained", squeeze=False, sharex=sharex, sharey=sharey)
    axes = []
    for number, row in enumerate(rows):
        axes += list(grid[number, :len(row)])
        for ax in grid[number, len(row):]:
            ax.set_visible(False)
    return figure, axes


def label_outer(axes, rows, xlabel: str, ylabel: str) -> None:
    """Axis labels on the left column and on the lowest panel of each column only."""
    columns = max(len(row) for row in rows)
    positions = [(number, column) for number, row in enumerate(rows) for column in range(len(row))]
    lowest = {column: max(number for number, c in positions if c == column) for column in range(columns)}
    for ax, (number, column) in zip(axes, positions):
        if lowest[column] == number:
            ax.set_xlabel(xlabel, fontsize=9)
            ax.xaxis.set_tick_params(labelbottom=True)  # shared x hides them above an empty slot
        if column == 0 and ylabel:
            ax.set_ylabel(ylabel, fontsize=9)
        ax.tick_params(labelsize=8)


def row_headers(axes, rows) -> None:
    """The header of each row of a dt grid (its section and family), as the y label of its first panel."""
    start = 0
    for row in rows:
        if row and row[0].row:
            below = axes[start].get_ylabel()
            axes[start].set_ylabel(row[0].row + (f"\n{below}" if below else ""), fontsize=9, fontweight="bold")
        start += len(row)


def flatten(rows):
    return [panel for row in rows for panel in row]


# -- styles and legends ----------------------------------------------------------------------------
def series_style(series: Series, number: int = 0, markers: bool = True) -> dict:
    """Colour, line style and marker of a line; later lines get smaller markers, so coinciding points show as rings."""
    style = {"color": series.colour, "ls": series.linestyle}
    if markers:
        style.update(marker=series.marker, ms=max(4.0, 8.0 - MARKER_SHRINK * number), fillstyle=series.fillstyle)
    return style


def series_handles(data: FigureData, shown: list[Series], merged: dict | None = None, markers: bool = True,
                   lw: float = 1.5) -> list[Line2D]:
    """Legend entries for the lines of a figure.

    With a colour per line: one entry per line, named "A = B" where B is drawn under A (identical curves,
    ``merged``: B -> A). With colours per integrator and line styles per setting: one entry per
    integrator (colour) and one per setting (line style, grey)."""
    merged = merged or {}
    shown = [one for one in data.series if one in shown]
    if data.colour_per_series:
        handles = []
        for one in shown:
            if one in merged:
                continue
            twins = [other.name for other in shown if merged.get(other) is one]
            name = " = ".join([one.name, *twins])
            handles.append(Line2D([], [], lw=lw, label=name, **{**series_style(one, markers=markers),
                                                                "ms": LEGEND_MARKER_SIZE}))
        return handles
    labels = list(dict.fromkeys(one.label for one in shown))
    settings = list(dict.fromkeys(one for one in shown if one.setting))
    handles = [Line2D([], [], color=data.colours[label], lw=lw, marker=data.markers[label] if markers else None,
                      ms=LEGEND_MARKER_SIZE, label=label) for label in labels]
    seen = set()
    for one in settings:
        if one.setting not in seen:
            seen.add(one.setting)
            handles.append(Line2D([], [], color="0.35", lw=lw, ls=one.linestyle,
                                  **({"marker": "o", "fillstyle": one.fillstyle, "ms": LEGEND_MARKER_SIZE} if markers else {}),
                                  label=f"{' × '.join(data.line_keys)} = {one.setting}"))
    return handles


def figure_legend(figure, handles: list, title: str = "") -> None:
    """The figure's legend, at the right of the panels (never over the data)."""
    legend = figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False,
                           title=title or None, title_fontsize=8)
    if title:
        legend.get_title().set_ha("left")


def add_notes(figure, notes: list[str]) -> None:
    """A line under the panels for each note: what the figure leaves out and why, footnotes."""
    notes = list(dict.fromkeys(note for note in notes if note))
    if notes:
        lines = [line for note in notes for line in note_lines(figure, note)]
        figure.supxlabel("\n".join(lines), fontsize=NOTE_SIZE, color="0.25", ha="center")


def note_lines(figure, note: str) -> list[str]:
    """A note's lines as ``add_notes`` writes them: wrapped where wider than the figure (a character of the note's font,
    DejaVu Sans, is on average 0.6 of its size wide: at half its size a work-precision note of 300 characters ran
    past both edges)."""
    width = max(40, int(figure.get_figwidth() * 72.0 / (0.6 * NOTE_SIZE)) - 4)
    return textwrap.wrap(note, width, break_on_hyphens=False) or [""]


def suptitle(figure, data: FigureData, what: str) -> None:
    figure.suptitle(f"{data.name}: {what}", fontsize=11)


def status_handles(marked: set[str], where: str) -> list[Line2D]:
    """Legend entries for the ways runs ended that the figure shows."""
    entries = {
        Status.DIVERGED: dict(marker="o", mfc="none", mec="0.3", mew=1.6, ms=8, label=f"diverged, hollow {where}".strip()),
        Status.FAILED: dict(marker="X", color="0.3", ms=8, label=f"failed {where}".strip()),
        Status.NOT_CONVERGED: dict(marker="o", mfc="none", mec="black", ms=12, label="solver not converged in some steps"),
    }
    return [Line2D([], [], ls="none", **entries[status]) for status in entries if status in marked]


def ring_not_converged(ax, dts: np.ndarray, values: np.ndarray, runs: list[RunData]) -> set[str]:
    """A black ring around the points of runs whose solver gave up in some steps."""
    late = np.array([run.status == Status.NOT_CONVERGED for run in runs])
    if not late.any():
        return set()
    ax.plot(dts[late], values[late], "o", ms=12, mfc="none", mec="black", mew=1.0, zorder=5)
    return {Status.NOT_CONVERGED}


def no_data_note(runs: list[RunData], data: FigureData) -> str:
    """Names the runs that have nothing to draw (failed before their first sample)."""
    empty = [run for run in runs if not run.has_series]
    if not empty:
        return ""
    names = ", ".join(f"{data.series_of(run).name} at dt = {data.dt_names[run.dt]} s" for run in empty[:6])
    more = f" and {len(empty) - 6} more" if len(empty) > 6 else ""
    return f"no data (failed before the first sample): {names}{more}"


# -- identical lines -----------------------------------------------------------------------------
def same_curve(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], unit: float = 0.0) -> bool:
    """Two (x, y) curves equal over their whole length: each y within SAME_CURVE of the larger of the two, or
    of `unit` (what the axis measures in: 1 for an energy change in E_ref; 0 on a log axis, where every
    decade shows)."""
    (xa, ya), (xb, yb) = a, b
    if xa.shape != xb.shape or ya.shape != yb.shape or ya.size == 0:
        return False
    finite = np.isfinite(ya)
    if not np.array_equal(finite, np.isfinite(yb)) or not np.allclose(xa, xb, rtol=SAME_CURVE, atol=0.0):
        return False
    size = np.maximum(np.maximum(np.abs(ya[finite]), np.abs(yb[finite])), unit)
    return bool(np.all(np.abs(ya[finite] - yb[finite]) <= SAME_CURVE * size))


def twins(panels: list[list[tuple[object, tuple[np.ndarray, np.ndarray]]]], merge: bool = True,
          unit: float = 0.0) -> tuple[dict, set]:
    """Which lines coincide with an earlier line of the same panel.

    ``panels``: for each panel, (key, (x, y)) of its lines in drawing order. Returns (merged, overlaid):
    merged maps B -> A when B equals A in every panel where B is drawn (draw B not at all, name both in
    the legend; only with ``merge``); overlaid holds (panel number, B) where B equals an earlier line in
    that panel and is not merged (draw B dashed over it)."""
    first: dict = {}  # key -> the earlier line it equals in every panel so far (None: not in one)
    overlaid = set()
    for number, lines in enumerate(panels):
        for index, (key, curve) in enumerate(lines):
            match = next((other for other, earlier in lines[:index] if same_curve(earlier, curve, unit)), None)
            if match is not None:
                overlaid.add((number, key))
            if key not in first:
                first[key] = match
            elif first[key] is not None and first[key] != match:
                first[key] = None
    merged = {key: match for key, match in first.items() if match is not None} if merge else {}
    # a line merged into another that is itself merged: draw only the first of the chain
    for key in list(merged):
        while merged[key] in merged:
            merged[key] = merged[merged[key]]
    overlaid = {(number, key) for number, key in overlaid if key not in merged}
    return merged, overlaid


# -- axis scales ------------------------------------------------------------------------------------
def symlog_threshold(peaks: list[float]) -> float:
    """linthresh for a symlog axis from each curve's largest |value|: the smallest non-negligible peak, rounded
    down to a power of ten, between 1e-6 of the largest peak and 1."""
    peaks = np.array([peak for peak in peaks if np.isfinite(peak) and peak > 0])
    if peaks.size == 0:
        return 1.0
    low = max(float(peaks.min()), 1e-6 * float(peaks.max()), 1e-12)
    return float(min(1.0, 10.0 ** math.floor(math.log10(low))))


def apply_signed_scale(axes, curves: list[np.ndarray]) -> str:
    """One y scale for every panel of a figure, from all its curves: linear when every |value| < LINEAR_RANGE,
    else symlog with the linear part chosen from the data (symlog_threshold). Returns the scale's name."""
    values = np.concatenate([curve[np.isfinite(curve)] for curve in curves] or [np.empty(0)])
    if values.size == 0 or np.max(np.abs(values)) < LINEAR_RANGE:
        for ax in axes:
            ax.ticklabel_format(axis="y", useOffset=False)
        return "linear"
    threshold = symlog_threshold([float(np.max(np.abs(curve[np.isfinite(curve)]))) for curve in curves
                                  if np.isfinite(curve).any()])
    for ax in axes:
        ax.set_yscale("symlog", linthresh=threshold, linscale=0.5)
    # the data's range (and 0) padded in the axis' own coordinates: autoscaling a shared symlog axis
    # mirrors the range about 0, decades of empty axis below a curve that only lost energy
    transform = axes[0].yaxis.get_transform()
    low, high = transform.transform(np.array([[min(values.min(), 0.0)], [max(values.max(), 0.0)]]))[:, 0]
    margin = 0.04 * (high - low)
    axes[0].set_ylim(*transform.inverted().transform(np.array([[low - margin], [high + margin]]))[:, 0])
    return "symlog"


def log_limits(values, pad: float = 2.0) -> tuple[float, float] | None:
    """(low, high) of a log axis for the positive finite values, at most MAX_LOG_DECADES apart; None without any."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values) & (values > 0)]
    if values.size == 0:
        return None
    high = float(values.max())
    low = max(float(values.min()), high * 10.0 ** -MAX_LOG_DECADES)
    return low / pad, high * pad


def pad_top(ax) -> None:
    """Room above the data for the markers of diverged runs, drawn at the top edge."""
    low, high = ax.get_ylim()
    ax.set_ylim(low, high * TOP_PADDING)


# A log axis spanning fewer decades than this gets ticks at 1, 2 and 5 times the powers of ten, in
# plain numbers (matplotlib would otherwise label the minor ticks in crowded scientific notation).
SHORT_LOG_DECADES = 2.0


def tidy_log_axes(ax) -> None:
    for axis, limits in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        low, high = sorted(limits)
        if axis.get_scale() == "log" and low > 0 and high / low < 10.0 ** SHORT_LOG_DECADES:
            axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
            axis.set_minor_formatter(NullFormatter())


def log_log_panel(ax, title: str, minor_grid: bool = True) -> None:
    """A panel of a figure against dt or time: both axes logarithmic, its title, a light grid."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="major", alpha=0.3)
    if minor_grid:
        ax.grid(True, which="minor", alpha=0.08)


def energy_label(runs: list[RunData], what: str = "(E − E$_0$) / E$_{ref}$") -> str:
    """An energy axis label that says what E_ref is: the runs' one reference, or a pointer to the report."""
    names = sorted({run.energy_reference_name for run in runs})
    if len(names) == 1:
        return f"{what}\nE$_{{ref}}$ = {_plain(names[0])}"
    return f"{what}\nE$_{{ref}}$: the system's energy scale (see the report)"


def _plain(text: str) -> str:
    """Text that matplotlib must not read as mathtext (a $ in a stored name)."""
    return text.replace("$", r"\$")


def in_label_order(runs: list[RunData], data: FigureData) -> list[RunData]:
    order = {id(one): number for number, one in enumerate(data.series)}
    return sorted(runs, key=lambda run: order[id(data.series_of(run))])


def finite(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    count = min(t.size, values.size)
    t, values = t[:count], values[:count]
    keep = np.isfinite(t) & np.isfinite(values)
    return t[keep], values[keep]
