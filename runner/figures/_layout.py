"""Layout shared by the figures: sizes, colours and markers per integrator label, panel grids, legends, saving.

Private to simrun.figures; a figure module imports it as ``from simrun.figures import _layout as layout``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")  # files only: no display, and safe in worker processes

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from simrun.results import Status  # noqa: E402

if TYPE_CHECKING:
    from simrun.figures._data import FigureData, RunData

FORMATS = ("png", "svg")
PNG_DPI = 150
# One panel of the small multiples (in); large enough for 8-pt tick labels to stay readable.
PANEL_SIZE = (3.6, 2.7)
# More dt panels than this become unreadable; show this many, spread over the range.
MAX_DT_PANELS = 12
# With several groups each group is a row; a row wider than this no longer fits a page.
MAX_DT_PANELS_PER_GROUP = 6
# Likewise at most this many groups (rows / panels) per figure.
MAX_GROUPS = 8
PANEL_COLUMNS = 4
# One panel of the figures against dt (in): one line per integrator needs more room than a small multiple.
SUMMARY_PANEL_SIZE = (5.0, 3.6)
# Diverged runs off a log scale: drawn at this fraction of the axes height, above
# the data, which a y range padded by this factor leaves room for.
TOP_EDGE, TOP_PADDING = 0.95, 30.0
# Room for a legend beside the panels (in): the longest entry is about 30 characters at 8 pt.
FIGURE_LEGEND_WIDTH = 2.2

# A marker per integrator label in the figures against dt, so that coinciding lines stay apart
# (and colour is not the only cue); "X" is kept for failed runs.
LABEL_MARKERS = "osD^vP<>hpd*"
# Each later label's marker is drawn this much smaller (pt), so coinciding points show as rings.
MARKER_SHRINK = 0.5
LEGEND_MARKER_SIZE = 6.0


# -- colours, markers, saving ----------------------------------------------------------------------
def label_colours(labels: list[str]) -> dict[str, tuple]:
    """A stable colour per integrator label: sorted labels -> tab10 (or tab20 beyond ten labels)."""
    ordered = sorted(labels)
    palette = plt.get_cmap("tab10" if len(ordered) <= 10 else "tab20")
    return {label: palette(number % palette.N) for number, label in enumerate(ordered)}


def save_figure(figure, stem: Path, dpi: int = PNG_DPI) -> list[Path]:
    """Write stem.png and stem.svg; the layout is computed once, for the first format (it is the costly part)."""
    written = []
    for extension in FORMATS:
        target = stem.with_name(f"{stem.name}.{extension}")  # not with_suffix: names may contain dots
        # no creation date in the metadata, so redrawing the same file gives the same SVG
        metadata = {"Date": None} if extension == "svg" else None
        figure.savefig(target, dpi=dpi, metadata=metadata)
        written.append(target)
        if figure.get_layout_engine() is not None:
            figure.set_layout_engine("none")  # the axes keep the positions the layout gave them
    return written


# -- marks of how runs ended -----------------------------------------------------------------------
def pad_top(ax) -> None:
    """Room above the data for the markers of diverged runs, drawn at the top edge."""
    low, high = ax.get_ylim()
    ax.set_ylim(low, high * TOP_PADDING)


def label_style(data: FigureData, label: str, number: int) -> dict:
    """Colour and marker of a label; later labels get smaller markers, so coinciding points stay visible."""
    size = max(4.0, 8.0 - MARKER_SHRINK * number)
    return {"color": data.colours[label], "marker": data.markers[label], "ms": size, "label": label}


def ring_not_converged(ax, dts: np.ndarray, values: np.ndarray, runs: list[RunData]) -> set[str]:
    """A black ring around the points of runs whose solver gave up in some steps."""
    late = np.array([run.status == Status.NOT_CONVERGED for run in runs])
    if not late.any():
        return set()
    ax.plot(dts[late], values[late], "o", ms=12, mfc="none", mec="black", mew=1.0, zorder=5)
    return {Status.NOT_CONVERGED}


def status_handles(marked: set[str], where: str) -> list[Line2D]:
    """Legend entries for the ways runs ended that the figure shows."""
    entries = {
        Status.DIVERGED: dict(marker="o", mfc="none", mec="0.3", mew=1.6, ms=8, label=f"diverged, hollow {where}".strip()),
        Status.FAILED: dict(marker="X", color="0.3", ms=8, label=f"failed {where}".strip()),
        Status.NOT_CONVERGED: dict(marker="o", mfc="none", mec="black", ms=12, label="solver not converged in some steps"),
    }
    return [Line2D([], [], ls="none", **entries[status]) for status in entries if status in marked]


# -- panels and legends ---------------------------------------------------------------------------
def dt_panels(data: FigureData) -> tuple[list[list[tuple[str, list[RunData]]]], str]:
    """Rows of (title, runs) panels, one per dt; wrapped rows for one group, a row per group otherwise."""
    groups = data.groups[:MAX_GROUPS]
    several = len(data.groups) > 1
    cap = MAX_DT_PANELS_PER_GROUP if several else MAX_DT_PANELS
    rows, notes = [], []
    for title, runs in groups:
        dts = sorted({run.dt for run in runs})
        shown = spread(dts, cap)
        if len(shown) < len(dts):
            notes.append(f"{len(shown)} of {len(dts)} time steps shown")
        panels = [(f"dt = {data.dt_names[dt]} s" + (f"\n{title}" if several else ""), [run for run in runs if run.dt == dt])
                  for dt in shown]
        if several:
            rows.append(panels)
        else:
            rows += [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    if len(data.groups) > MAX_GROUPS:
        notes.append(f"first {MAX_GROUPS} of {len(data.groups)} groups")
    note = f"  ({'; '.join(dict.fromkeys(notes))})" if notes else ""
    return rows, note


def group_panels(data: FigureData) -> list[list[tuple[str, list[RunData]]]]:
    panels = data.groups[:MAX_GROUPS]
    return [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]


def spread(values: list[float], count: int) -> list[float]:
    """At most `count` of the sorted values, evenly spread and always including both ends."""
    if len(values) <= count:
        return list(values)
    picks = np.unique(np.round(np.linspace(0, len(values) - 1, count)).astype(int))
    return [values[pick] for pick in picks]


def panel_grid(rows, sharex=False, sharey=False, panel_size=PANEL_SIZE, legend_width=0.0):
    """A figure with one axes per panel (rows of varying length); returns (figure, axes in panel order).

    legend_width (in) is added for a figure legend on the right, so that it does not squeeze the panels.
    """
    columns = max(len(row) for row in rows)
    size = (panel_size[0] * columns + legend_width, panel_size[1] * len(rows) + 0.6)
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
        if column == 0:
            ax.set_ylabel(ylabel, fontsize=9)
        ax.tick_params(labelsize=8)


def status_label(run: RunData) -> str:
    """A legend label for runs that did not end ok; ok runs stay out of the panel legends."""
    return run.label + run.status_note() if run.status is not Status.OK else "_nolegend_"


def no_data_entries(ax, runs: list[RunData], data: FigureData) -> None:
    for run in in_label_order([run for run in runs if not run.has_series], data):
        ax.plot([], [], ls=":", color=data.colours[run.label], label=f"{run.label} (failed, no data)")


def status_legend(ax) -> None:
    """A small legend in the panel naming its runs that diverged, failed or did not converge (if any)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(fontsize=7, loc="best", framealpha=0.85, handlelength=1.5)


def label_handles(data: FigureData, labels: list[str]) -> list[Line2D]:
    return [Line2D([], [], color=data.colours[label], lw=1.5, label=label) for label in labels]


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
    """A panel of a figure against dt or time: both axes logarithmic, tidy ticks, its title, a light grid."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    tidy_log_axes(ax)
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="major", alpha=0.3)
    if minor_grid:
        ax.grid(True, which="minor", alpha=0.08)


def flatten(rows):
    return [panel for row in rows for panel in row]


def in_label_order(runs: list[RunData], data: FigureData) -> list[RunData]:
    return sorted(runs, key=lambda run: data.labels.index(run.label))


def finite(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    count = min(t.size, values.size)
    t, values = t[:count], values[:count]
    keep = np.isfinite(t) & np.isfinite(values)
    return t[keep], values[keep]
