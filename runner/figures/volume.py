"""The volume ratio of finite elements: J = det F, each element's volume over its rest volume, smallest and largest
over the elements at every sample.

What users of FEM watch: a neo-Hookean element cannot reach J = 0 (its energy is infinite there, and the line search
keeps every element above a tenth of its volume at the search's start); co-rotated, StVK and linear elements can
invert, and a method's damping or its large steps show as volume lost or gained. One panel per time step and setting
(the energy figures' grid), a band from the smallest to the largest J per run; below 0 shaded: inverted elements.
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


def has_volume_ratios(run: RunData) -> bool:
    return "volume_ratio_min" in run.stored and run.t.size > 1


def volume_ratio(data: FigureData):
    """min and max J over the elements against t, a band per series, a panel per dt and setting; J < 0 shaded."""
    rows, notes = layout.dt_grid(data, keep=has_volume_ratios)
    if not rows:
        return None
    panels = layout.flatten(rows)
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, legend_width=layout.FIGURE_LEGEND_WIDTH,
                                     extra_height=0.25 * len([note for note in notes if note]))
    values, inverted = [], set()
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
            if low.min() <= 0.0:
                inverted.add(layout.join_titles(panel.row, series.name))
        ax.axhline(1.0, color="0.5", lw=0.7, ls=":", zorder=1)
        ax.axhline(0.0, color="0.3", lw=0.8, zorder=1)
        ax.set_title(panel.title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    every = np.concatenate(values) if values else np.ones(1)
    low, high = min(float(every.min()), 0.0), max(float(every.max()), 1.0)
    margin = 0.06 * (high - low)
    for ax in axes:
        ax.set_ylim(low - margin, high + margin)
        ax.axhspan(low - margin, 0.0, color=INVERTED_COLOUR, zorder=0, lw=0)
    durations = [run.duration for panel in panels for run in panel.runs if np.isfinite(run.duration)]
    if durations:
        axes[0].set_xlim(0.0, max(durations))
    layout.label_outer(axes, rows, "time t (s)", "volume ratio J = det F (1)")
    layout.row_headers(axes, rows)
    shown = list(dict.fromkeys(data.series_of(run) for panel in panels for run in panel.runs))
    handles = layout.series_handles(data, shown, markers=False, lw=1.1)
    handles += [Patch(facecolor="0.6", alpha=BAND_ALPHA * 2, label="smallest to largest J over the elements"),
                Line2D([], [], color="0.5", lw=0.7, ls=":", label="J = 1: the rest volume"),
                Patch(facecolor=INVERTED_COLOUR, label="J <= 0: an inverted element")]
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "element volume ratio J over time (smallest and largest)")
    notes.append(f"inverted (J <= 0 at some sample): {'; '.join(sorted(inverted))}" if inverted
                 else "no element inverts: the smallest J stays positive in every run")
    layout.add_notes(figure, notes)
    return figure
