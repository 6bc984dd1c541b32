"""Orbits: the x-y trajectory of each planar run (one body in the x-y plane), against the circle through its start."""

from __future__ import annotations

import numpy as np
from matplotlib.lines import Line2D

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData

# An orbit panel (in): square, since x and y share a scale.
ORBIT_PANEL_SIZE = (3.3, 3.0)
# A diverged orbit is clipped to this many radii around the centre.
ORBIT_BOX_RADII = 3.0


def orbits(data: FigureData):
    """x-y trajectories of the planar runs: a row of panels (one per dt) per setting and family of lines, with the
    circle through the start dashed: the exact orbit of circular motion, for both of its force laws."""
    planar = [run for run in data.runs if run.stored.planar]
    if not planar:
        return None
    rows, notes = layout.dt_grid(data, lambda run: run.stored.planar)
    notes.append(layout.no_data_note(planar, data))
    figure, axes = layout.panel_grid(rows, panel_size=ORBIT_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH,
                                     extra_height=0.16 * len([note for note in notes if note]))
    circle = np.linspace(0.0, 2.0 * np.pi, 361)
    clipped_any, stopped_any = False, False
    for panel, ax in zip(layout.flatten(rows), axes):
        radius = _start_radius(panel.runs)
        reach = radius
        for run in layout.in_label_order(panel.runs, data):
            series = data.series_of(run)
            xy = run.xy[np.all(np.isfinite(run.xy), axis=1)]
            if xy.shape[0] == 0:
                continue
            stopped = run.status.stopped
            stopped_any |= stopped
            ax.plot(xy[:, 0], xy[:, 1], color=series.colour, ls=series.linestyle, lw=1.0, alpha=0.9,
                    marker="x" if stopped else None, markevery=[xy.shape[0] - 1], ms=7, mew=1.8)
            reach = max(reach, float(np.abs(xy).max()))
        ax.plot(radius * np.cos(circle), radius * np.sin(circle), "--", color="black", lw=1.0)
        ax.plot(radius, 0.0, "o", color="black", ms=4, zorder=5)
        limit = min(reach, ORBIT_BOX_RADII * radius) * 1.08
        ax.set_xlim(-limit, limit)
        ax.set_ylim(-limit, limit)
        ax.set_aspect("equal")
        clipped = reach > ORBIT_BOX_RADII * radius
        clipped_any |= clipped
        ax.set_title(panel.title + (" (clipped)" if clipped else ""), fontsize=9)
        ax.grid(True, alpha=0.3)
    handles = layout.series_handles(data, list(dict.fromkeys(data.series_of(run) for run in planar)), markers=False, lw=1.0)
    handles += [Line2D([], [], ls="--", color="black", label="exact orbit (the circle through the start)"),
                Line2D([], [], ls="none", marker="o", color="black", ms=4, label="start")]
    if stopped_any:
        handles.append(Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="run stopped (diverged/failed)"))
    layout.label_outer(axes, rows, "x (m)", "y (m)")
    layout.row_headers(axes, rows)
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "orbits")
    if clipped_any:
        notes.append(f"(clipped): the view is cut at {ORBIT_BOX_RADII:g} times the start radius")
    layout.add_notes(figure, notes)
    return figure


def _start_radius(runs) -> float:
    """|x0| in the x-y plane (m): the radius of the circle through the start (1 when no run has a sample)."""
    for run in runs:
        if run.xy.shape[0]:
            return float(np.hypot(*run.xy[0]))
    return 1.0
