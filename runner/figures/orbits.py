"""Orbits: the x-y trajectory of each planar run (one body in the x-y plane), against the circle through its start."""

from __future__ import annotations

import dataclasses

import numpy as np
from matplotlib.lines import Line2D

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData

# An orbit panel (in): square, since x and y share a scale.
ORBIT_PANEL_SIZE = (3.3, 3.0)
# A diverged orbit is clipped to this many radii around the centre.
ORBIT_BOX_RADII = 3.0


def orbits(data: FigureData):
    """x-y trajectories of the planar runs per dt (rows per group), with the circle through the start dashed:
    the exact orbit of circular motion, for both of its force laws."""
    planar = [run for run in data.runs if run.stored.planar]
    if not planar:
        return None
    groups = [(title, [run for run in runs if run.stored.planar]) for title, runs in data.groups]
    subset = dataclasses.replace(data, runs=planar, groups=[group for group in groups if group[1]])
    rows, note = layout.dt_panels(subset)
    figure, axes = layout.panel_grid(rows, panel_size=ORBIT_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH)
    circle = np.linspace(0.0, 2.0 * np.pi, 361)
    for (title, runs), ax in zip(layout.flatten(rows), axes):
        radius = _start_radius(runs)
        reach = radius
        for run in layout.in_label_order(runs, data):
            colour = data.colours[run.label]
            xy = run.xy if run.xy is not None else np.empty((0, 2))
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if xy.shape[0] == 0:
                ax.plot([], [], ls=":", color=colour, label=f"{run.label} (failed, no data)")
                continue
            stopped = run.status.stopped
            ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.0, alpha=0.9, label=layout.status_label(run),
                    marker="x" if stopped else None, markevery=[xy.shape[0] - 1], ms=7, mew=1.8)
            reach = max(reach, float(np.abs(xy).max()))
        ax.plot(radius * np.cos(circle), radius * np.sin(circle), "--", color="black", lw=1.0)
        ax.plot(radius, 0.0, "o", color="black", ms=4, zorder=5)
        limit = min(reach, ORBIT_BOX_RADII * radius) * 1.08
        ax.set_xlim(-limit, limit)
        ax.set_ylim(-limit, limit)
        ax.set_aspect("equal")
        clipped = reach > ORBIT_BOX_RADII * radius
        ax.set_title(title + (f"\n(clipped to ±{ORBIT_BOX_RADII:g} r)" if clipped else ""), fontsize=9)
        layout.status_legend(ax)
        ax.grid(True, alpha=0.3)
    handles = layout.label_handles(data, [label for label in data.labels if any(run.label == label for run in planar)])
    handles += [Line2D([], [], ls="--", color="black", label="exact orbit (the circle through the start)"),
                Line2D([], [], ls="none", marker="o", color="black", ms=4, label="start"),
                Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="run stopped (diverged/failed)")]
    layout.label_outer(axes, rows, "x (m)", "y (m)")
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{data.name}: orbits" + note, fontsize=11)
    return figure



def _start_radius(runs) -> float:
    """|x0| in the x-y plane (m): the radius of the circle through the start (1 when no run has a sample)."""
    for run in runs:
        if run.xy.shape[0]:
            return float(np.hypot(*run.xy[0]))
    return 1.0
