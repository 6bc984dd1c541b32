"""Convergence and work-precision: the error at the end time against dt (with the observed order) and against wall time."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.lines import Line2D

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData, RunData

if TYPE_CHECKING:
    from simrun import analysis

# An error of exactly zero cannot sit on a log axis: drawn at this floor (m).
ERROR_FLOOR = 1e-16


def _error_runs(data: FigureData) -> list[RunData]:
    """Runs that reached the end time with a known error (exact solution, or a reference on request)."""
    return [run for run in data.runs if not run.status.stopped and np.isfinite(run.final_error)]


def order_fits(data: FigureData) -> dict[tuple[str, str], tuple["analysis.OrderFit", list[RunData]]]:
    """(group title, label) -> (observed order fit, runs sorted by dt) for every label with errors."""
    from simrun import analysis  # on first use: importing the figures loads no integrator

    fits = {}
    usable = set(map(id, _error_runs(data)))
    for title, runs in data.groups:
        for label in data.labels:
            mine = sorted((run for run in runs if run.label == label and id(run) in usable), key=lambda run: run.dt)
            if mine:
                fit = analysis.observed_order([run.dt for run in mine], [run.final_error for run in mine],
                                              scale=mine[0].length_scale)
                fits[(title, label)] = (fit, mine)
    return fits


def order_text(fit: "analysis.OrderFit") -> str:
    if np.isfinite(fit.order):
        return f"p = {fit.order:.2f}"
    return "exact (round-off)" if fit.exact else "p: too few points"


def convergence(data: FigureData):
    """Error at the end time against dt (log-log); the fitted slope (observed order) of each label in the legend."""
    from simrun import analysis  # on first use: importing the figures loads no integrator

    fits = order_fits(data)
    if not fits:
        return None
    panels = [(title, runs) for title, runs in data.groups[:layout.MAX_GROUPS] if any((title, label) in fits for label in data.labels)]
    rows = [panels[start:start + layout.PANEL_COLUMNS] for start in range(0, len(panels), layout.PANEL_COLUMNS)]
    single = len(panels) == 1
    figure, axes = layout.panel_grid(rows, panel_size=layout.SUMMARY_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH + 0.4 if single else 0.0)
    handles = []
    for (title, _), ax in zip(layout.flatten(rows), axes):
        for number, label in enumerate(data.labels):
            if (title, label) not in fits:
                continue
            fit, mine = fits[(title, label)]
            style = layout.label_style(data, label, number)
            dts = np.array([run.dt for run in mine])
            errors = np.maximum([run.final_error for run in mine], ERROR_FLOOR)
            ax.plot(dts, errors, "-", lw=1.2, **{**style, "label": f"{label}: {order_text(fit)}"})
            if np.isfinite(fit.order):
                ends = dts[fit.used][[0, -1]]
                ax.plot(ends, np.exp(fit.intercept) * ends ** fit.order, "--", color="black", lw=0.9, zorder=5)
        layout.log_log_panel(ax, title)
        if single:
            handles = ax.get_legend_handles_labels()[0]
        else:
            ax.legend(fontsize=6.5, loc="lower right", framealpha=0.85, handlelength=1.5)
    reference = any(run.error_from_reference for run in _error_runs(data))
    layout.label_outer(axes, rows, "time step dt (s)", "error at the end time (m)" + (" vs reference" if reference else ""))
    fit_handle = Line2D([], [], ls="--", color="black", lw=0.9, label=f"least-squares fit (≤ {analysis.ORDER_FIT_POINTS} smallest dt)")
    if single:
        figure.legend(handles=handles + [fit_handle], loc="outside right center", fontsize=8, frameon=False)
    else:
        axes[0].add_artist(axes[0].legend(handles=[fit_handle], fontsize=6.5, loc="upper left", framealpha=0.85))
    figure.suptitle(f"{data.name}: convergence (observed order p)", fontsize=11)
    return figure


def work_precision(data: FigureData):
    """Error at the end time against the wall time of the run (log-log), one line per label."""
    fits = order_fits(data)
    timed = {key: (fit, [run for run in runs if run.wall_time > 0]) for key, (fit, runs) in fits.items()}
    timed = {key: value for key, value in timed.items() if value[1]}
    if not timed:
        return None
    panels = [(title, runs) for title, runs in data.groups[:layout.MAX_GROUPS] if any((title, label) in timed for label in data.labels)]
    rows = [panels[start:start + layout.PANEL_COLUMNS] for start in range(0, len(panels), layout.PANEL_COLUMNS)]
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH)
    labels = []
    for (title, _), ax in zip(layout.flatten(rows), axes):
        for number, label in enumerate(data.labels):
            if (title, label) not in timed:
                continue
            _, mine = timed[(title, label)]
            labels.append(label)
            ax.plot([run.wall_time for run in mine], np.maximum([run.final_error for run in mine], ERROR_FLOOR),
                    "-", lw=1.2, **layout.label_style(data, label, number))
        layout.log_log_panel(ax, title, minor_grid=False)
    layout.label_outer(axes, rows, "wall time of the run (s)", "error at the end time (m)")
    handles = [Line2D([], [], ls="-", **{**layout.label_style(data, label, number), "ms": layout.LEGEND_MARKER_SIZE})
               for number, label in enumerate(data.labels) if label in labels]
    handles.append(Line2D([], [], ls="none", label="lower left is better"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{data.name}: work-precision (points: the time steps)", fontsize=11)
    return figure

