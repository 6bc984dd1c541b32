"""What the solver did: Newton iterations per step, and wall time per step, against dt."""

from __future__ import annotations

import numpy as np
from matplotlib.lines import Line2D

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData, RunData
from simrun.results import Status

def newton_iterations_vs_dt(data: FigureData):
    """Mean (and largest) Newton iterations per step against dt, implicit integrators only."""
    def counted(run: RunData) -> bool:
        return not run.explicit and run.newton_iterations.size > 0

    implicit = [run for run in data.runs if counted(run)]
    if not implicit:
        return None
    panels = [(title, [run for run in runs if counted(run)]) for title, runs in data.groups[:layout.MAX_GROUPS]]
    panels = [panel for panel in panels if panel[1]]
    rows = [panels[start:start + layout.PANEL_COLUMNS] for start in range(0, len(panels), layout.PANEL_COLUMNS)]
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH)
    marked = set()
    labels = [label for label in data.labels if any(run.label == label for run in implicit)]
    for (title, runs), ax in zip(layout.flatten(rows), axes):
        for number, label in enumerate(labels):
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            if not mine:
                continue
            style = layout.label_style(data, label, number)
            dts = np.array([run.dt for run in mine])
            mean = np.array([run.newton_iterations.mean() for run in mine])
            peak = np.array([run.newton_iterations.max() for run in mine])
            ax.plot(dts, mean, "-", lw=1.3, **style)
            ax.plot(dts, peak, ":", lw=1.0, color=style["color"])
            stopped = np.array([run.status.stopped for run in mine])
            if stopped.any():  # the mean over the steps before the run stopped
                ax.plot(dts[stopped], mean[stopped], ls="none", **{**style, "mfc": "white", "mew": 1.6, "label": None})
                marked |= {run.status for run in mine if run.status.stopped}
            marked |= layout.ring_not_converged(ax, dts, mean, mine)
        ax.set_xscale("log")
        ax.set_ylim(0, max(ax.get_ylim()[1], 1.0) * 1.12)
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    handles = [Line2D([], [], ls="-", **{**layout.label_style(data, label, number), "ms": layout.LEGEND_MARKER_SIZE})
               for number, label in enumerate(labels)]
    handles += [Line2D([], [], ls="-", color="0.4", label="mean per step"),
                Line2D([], [], ls=":", color="0.4", label="largest in one step")]
    if marked & {Status.DIVERGED, Status.FAILED}:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.4", mew=1.6, ms=8,
                              label="run stopped early (diverged/failed)"))
    handles += layout.status_handles(marked & {Status.NOT_CONVERGED}, "")
    layout.label_outer(axes, rows, "time step dt (s)", "Newton iterations per step")
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{data.name}: Newton iterations against time step", fontsize=11)
    return figure



def wall_time_per_step_vs_dt(data: FigureData):
    """Wall time per step against dt, one line per label, one panel per group (e.g. per solver)."""
    timed = [run for run in data.runs if run.steps > 0 and run.wall_time > 0]
    if not timed:
        return None
    chosen = set(map(id, timed))
    panels = [(title, [run for run in runs if id(run) in chosen]) for title, runs in data.groups[:layout.MAX_GROUPS]]
    panels = [panel for panel in panels if panel[1]]
    rows = [panels[start:start + layout.PANEL_COLUMNS] for start in range(0, len(panels), layout.PANEL_COLUMNS)]
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH)
    stopped_any = False
    for (title, runs), ax in zip(layout.flatten(rows), axes):
        for number, label in enumerate(data.labels):
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            if not mine:
                continue
            style = layout.label_style(data, label, number)
            dts = np.array([run.dt for run in mine])
            cost = np.array([run.wall_time / run.steps for run in mine]) * 1e3
            ax.plot(dts, cost, "-", lw=1.2, **style)
            stopped = np.array([run.status.stopped for run in mine])
            if stopped.any():
                ax.plot(dts[stopped], cost[stopped], ls="none", **{**style, "mfc": "white", "mew": 1.6, "label": None})
                stopped_any = True
        layout.log_log_panel(ax, title)
    layout.label_outer(axes, rows, "time step dt (s)", "wall time per step (ms)")
    handles = [Line2D([], [], ls="-", **{**layout.label_style(data, label, number), "ms": layout.LEGEND_MARKER_SIZE})
               for number, label in enumerate(data.labels)]
    if stopped_any:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.4", mew=1.6, ms=8,
                              label="run stopped early (diverged/failed)"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{data.name}: cost per step against time step", fontsize=11)
    return figure

