"""The volume ratio of finite elements: J = det F, each element's volume over its rest volume, smallest and largest
over the elements at every sample.

What users of FEM watch: a neo-Hookean element cannot reach J = 0 (its energy is infinite there, and the line search
keeps every element above a tenth of its volume at the search's start); co-rotated, StVK and linear elements can
invert, and a method's damping or its large steps show as volume lost or gained. One panel per time step and setting
(the energy figures' grid), a band from the smallest to the largest J per run; below 0 shaded: inverted elements. A
shell's J is its triangles' area ratio sqrt(det F^T F), which cannot be negative (a triangle turned over is a rotation
of it); the figure says which it shows.
"""

from __future__ import annotations

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from simrun.analysis.runs import RunData
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData

INVERTED_COLOUR = "#f6d5d1"
BAND_ALPHA = 0.18
# the axis stops at this J where a run goes beyond it (a blow-up would flatten every other run to a line); the
# note names the runs cut and how far they went
AXIS_CAP = 3.0


def has_volume_ratios(run: RunData) -> bool:
    return "volume_ratio_min" in run.stored and run.t.size > 1


def is_shell(run: RunData) -> bool:
    """A finite-element shell: the only model with a thickness."""
    return (run.stored.system_params or {}).get("thickness") is not None


def volume_ratio(data: FigureData):
    """min and max J over the elements against t, a band per series, a panel per dt and setting; J < 0 shaded."""
    rows, notes = layout.dt_grid(data, keep=has_volume_ratios)
    if not rows:
        return None
    panels = layout.flatten(rows)
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, legend_width=layout.FIGURE_LEGEND_WIDTH,
                                     extra_height=0.25 * len([note for note in notes if note]))
    values, inverted, beyond = [], set(), {}
    for panel, ax in zip(panels, axes):
        for run in layout.in_label_order(panel.runs, data):
            t = run.t
            low = np.asarray(run.stored.series("volume_ratio_min"), dtype=float)[: t.size]
            high = np.asarray(run.stored.series("volume_ratio_max"), dtype=float)[: t.size]
            finite = np.isfinite(t[: low.size]) & np.isfinite(low) & np.isfinite(high)
            if not finite.any():
                continue
            t, low, high = t[: low.size][finite], low[finite], high[finite]
            series = data.series_of(run)
            ax.fill_between(t, low, high, color=series.colour, alpha=BAND_ALPHA, lw=0)
            ax.plot(t, low, color=series.colour, ls=series.linestyle, lw=1.1)
            ax.plot(t, high, color=series.colour, ls=series.linestyle, lw=1.1)
            values += [low, high]
            name = layout.join_titles(panel.row, panel.title, series.name)
            if low.min() <= 0.0:
                inverted.add(layout.join_titles(panel.row, series.name))
            if high.max() > AXIS_CAP:
                beyond[name] = float(high.max())
        ax.axhline(1.0, color="0.5", lw=0.7, ls=":", zorder=1)
        ax.axhline(0.0, color="0.3", lw=0.8, zorder=1)
        ax.set_title(panel.title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    every = np.concatenate(values) if values else np.ones(1)
    low, high = min(float(every.min()), 0.0), max(float(every.max()), 1.0)
    if beyond:
        high = max(float(every[every <= AXIS_CAP].max(initial=1.0)), 1.0)
        high = min(max(high, 1.5), AXIS_CAP)
        notes.append(f"the axis stops short of J = {AXIS_CAP:g}; beyond it: " + "; ".join(
            f"{name} (J up to {value:.3g})" for name, value in beyond.items()))
    margin = 0.06 * (high - low)
    for ax in axes:
        ax.set_ylim(low - margin, high + margin)
        ax.axhspan(low - margin, 0.0, color=INVERTED_COLOUR, zorder=0, lw=0)
    durations = [run.duration for panel in panels for run in panel.runs if np.isfinite(run.duration)]
    if durations:
        axes[0].set_xlim(0.0, max(durations))
    shells = {is_shell(run) for panel in panels for run in panel.runs}
    measure = {frozenset([False]): "volume ratio J = det F (1)",
               frozenset([True]): "area ratio J = sqrt(det F^T F) (1)"}.get(
        frozenset(shells), "J (1): volume ratio det F; shells: area ratio")
    layout.label_outer(axes, rows, "time t (s)", measure)
    layout.row_headers(axes, rows)
    shown = list(dict.fromkeys(data.series_of(run) for panel in panels for run in panel.runs))
    handles = layout.series_handles(data, shown, markers=False, lw=1.1)
    handles += [Patch(facecolor="0.6", alpha=BAND_ALPHA * 2, label="smallest to largest J over the elements"),
                Line2D([], [], color="0.5", lw=0.7, ls=":", label="J = 1: the rest volume"),
                Patch(facecolor=INVERTED_COLOUR, label="J <= 0: an inverted element")]
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "element volume ratio J over time (smallest and largest)")
    notes.append(f"inverted or collapsed (J <= 0 at some sample): {'; '.join(sorted(inverted))}" if inverted
                 else "no element inverts or collapses: the smallest J stays positive in every run")
    without = [run for run in data.runs if not has_volume_ratios(run)]
    if without:  # springs beside elements in one sweep: they have no J
        sections = [title for title, members in data.sections if title and not any(map(has_volume_ratios, members))]
        notes.append(f"{len(data.runs) - len(without)} of {len(data.runs)} runs shown: the others have no elements "
                     f"(no J){': ' + '; '.join(sections) if sections else ''}")
    layout.add_notes(figure, notes)
    return figure
