"""Contact: the smallest signed distance to the colliders (and, with self-contact, between the model's own
triangles) at every step, the penetration a penalty leaves and the gap IPC keeps.

A run with contact records per step the smallest signed distance over its vertices (``contact_distance``, m;
negative: a vertex inside a collider). One panel per time step and setting (the energy figures' grid), a line per
run; distances below zero are shaded: what a penalty method lets through, and what IPC must never show. The y axis
is symmetric-log in millimetres where the distances span decades (IPC's gaps of micrometres next to a penalty's
millimetres), linear otherwise.
"""

from __future__ import annotations

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from simrun.analysis.runs import RunData
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData

PENETRATION_COLOUR = "#f6d5d1"
MILLIMETRE = 1e-3
# a symmetric-log axis where the largest |distance| is this many times the smallest nonzero one
DECADES_FOR_SYMLOG = 100.0


def has_contact(run: RunData) -> bool:
    return "contact_distance" in run.stored and run.steps > 0


def contact_distance(data: FigureData):
    """min signed distance (mm) against t, a panel per dt and setting, a line per series; penetration shaded."""
    rows, notes = layout.dt_grid(data, keep=has_contact)
    if not rows:
        return None
    panels = layout.flatten(rows)
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, legend_width=layout.FIGURE_LEGEND_WIDTH,
                                     extra_height=0.25 * len([note for note in notes if note]))
    values = []
    penetrating = set()
    for panel, ax in zip(panels, axes):
        for run in layout.in_label_order(panel.runs, data):
            distance = np.asarray(run.stored["contact_distance"], dtype=float)[: run.steps] / MILLIMETRE
            t = run.dt * np.arange(1, distance.size + 1)
            t, distance = layout.finite(t, distance)
            if not distance.size:
                continue
            series = data.series_of(run)
            ax.plot(t, distance, color=series.colour, ls=series.linestyle, lw=1.2)
            values.append(distance)
            if distance.min() < 0.0:
                penetrating.add(layout.join_titles(panel.row, series.name))
        ax.axhline(0.0, color="0.3", lw=0.8, zorder=1)
        ax.set_title(panel.title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    every = np.concatenate(values) if values else np.zeros(1)
    low, high = min(float(every.min()), 0.0), max(float(every.max()), 0.0)
    nonzero = np.abs(every[every != 0.0])
    span = (high - low) or 1.0
    if nonzero.size and nonzero.max() > DECADES_FOR_SYMLOG * nonzero.min():
        axes[0].set_yscale("symlog", linthresh=float(max(nonzero.min(), 1e-6 * nonzero.max())))
        margin = 1.5
        limits = (low * margin if low < 0 else -float(nonzero.min()), high * margin)
    else:
        limits = (low - 0.08 * span, high + 0.08 * span)
    for ax in axes:
        ax.set_ylim(*limits)
        ax.axhspan(min(limits[0], 0.0), 0.0, color=PENETRATION_COLOUR, zorder=0, lw=0)
    durations = [run.duration for panel in panels for run in panel.runs if np.isfinite(run.duration)]
    if durations:
        axes[0].set_xlim(0.0, max(durations))
    layout.label_outer(axes, rows, "time t (s)", "smallest signed distance (mm)")
    layout.row_headers(axes, rows)
    shown = list(dict.fromkeys(data.series_of(run) for panel in panels for run in panel.runs))
    handles = layout.series_handles(data, shown, markers=False, lw=1.2)
    handles += [Line2D([], [], color="0.3", lw=0.8, label="0: touching"),
                Patch(facecolor=PENETRATION_COLOUR, label="below 0: a vertex inside a collider")]
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "contact distance per step (negative: penetration)")
    notes.append(f"penetrating (a distance below 0 at some step): {'; '.join(sorted(penetrating))}" if penetrating
                 else "no run penetrates: every step's smallest distance is positive")
    layout.add_notes(figure, notes)
    return figure
