"""What the solver did: Newton iterations per step, and wall time per step, against dt."""

from __future__ import annotations

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter

from simrun.analysis.runs import RunData, run_iteration_names
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.format.summary import Status

# Height (in) of the line of notes under the panels.
NOTE_LINE = 0.16
# Iterations spanning more than this factor (Newton's few, a first-order method's hundreds) get a log axis.
ITERATIONS_LOG_RANGE = 30.0
STOPPED_HANDLE = dict(ls="none", marker="o", mfc="white", mec="0.4", mew=1.6, ms=8, label="run stopped early (diverged/failed)")


def newton_iterations_vs_dt(data: FigureData):
    """Mean (and largest) solver iterations per step against dt, implicit integrators only; one panel per
    setting and family of lines. The axis names the iteration (Newton's, L-BFGS's, a local-global or VBD sweep),
    "solver iterations" with a note naming each where the solvers mix."""
    def counted(run: RunData) -> bool:
        return not run.explicit and run.newton_iterations.size > 0

    notes: list[str] = []
    panels = layout.summary_panels(data, counted, notes)
    if not panels:
        return None
    rows = layout.wrap(panels)
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH)
    curves = []  # per panel: (series, its runs sorted by dt, (dts, mean iterations))
    for panel in panels:
        lines = []
        for series in panel.series:
            mine = sorted((run for run in panel.runs if data.series_of(run) is series), key=lambda run: run.dt)
            lines.append((series, mine, (np.array([run.dt for run in mine]),
                                         np.array([run.newton_iterations.mean() for run in mine]))))
        curves.append(lines)
    # identical counts (a solver that ignores the swept linear solver): drawn once, both names in the legend
    merged, overlaid = layout.twins([[(series, curve) for series, _, curve in lines] for lines in curves],
                                    merge=data.colour_per_series)
    peak_curves = [[(series, (curve[0], np.array([run.newton_iterations.max() for run in mine], dtype=float)))
                    for series, mine, curve in lines if series not in merged] for lines in curves]
    _, peaks_overlaid = layout.twins(peak_curves, merge=False)
    peaks = np.concatenate([curve[1] for lines in peak_curves for _, curve in lines])
    means = np.concatenate([curve[1] for lines in curves for _, _, curve in lines])
    logarithmic = peaks.max() > ITERATIONS_LOG_RANGE * max(means.min(), 1.0)
    marked = set()
    for number, (panel, ax, lines) in enumerate(zip(panels, axes, curves)):
        for index, (series, mine, (dts, mean)) in enumerate(lines):
            if series in merged:
                continue
            style = layout.series_style(series, index)
            if (number, series) in overlaid:
                style["ls"] = layout.OVERLAY_DASHES
            peak = np.array([run.newton_iterations.max() for run in mine])
            ax.plot(dts, mean, lw=1.3, **style)
            # the largest: dotted (or, where line styles tell settings apart, the line's own style, faded); dashed
            # over an identical one
            ls = ":" if data.colour_per_series else series.linestyle
            ax.plot(dts, peak, ls=layout.OVERLAY_DASHES if (number, series) in peaks_overlaid else ls, lw=1.0,
                    color=series.colour, alpha=1.0 if data.colour_per_series else 0.45)
            stopped = np.array([run.status.stopped for run in mine])
            if stopped.any():  # the mean over the steps before the run stopped
                ax.plot(dts[stopped], mean[stopped], **{**style, "ls": "none", "mfc": "white", "mew": 1.6})
                marked |= {run.status for run in mine if run.status.stopped}
            marked |= layout.ring_not_converged(ax, dts, mean, mine)
        ax.set_xscale("log")
        ax.set_title(panel.title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    if logarithmic:  # one scale for the figure: Newton's few iterations and a first-order method's hundreds
        axes[0].set_yscale("log")
        axes[0].set_ylim(max(0.8 * min(means.min(), peaks.min()), 0.5), 1.5 * peaks.max())
        axes[0].yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    else:
        axes[0].set_ylim(0, max(peaks.max(), 1.0) * 1.12)
        axes[0].yaxis.get_major_locator().set_params(integer=True)
    for ax in axes:
        layout.tidy_log_axes(ax)
    handles = layout.series_handles(data, [series for panel in panels for series in panel.series], merged, lw=1.3)
    handles += [Line2D([], [], ls="-", color="0.4", label="mean per step"),
                Line2D([], [], ls=":" if data.colour_per_series else "-", alpha=1.0 if data.colour_per_series else 0.45,
                       color="0.4", label="largest in one step")]
    if marked & {Status.DIVERGED, Status.FAILED}:
        handles.append(Line2D([], [], **STOPPED_HANDLE))
    handles += layout.status_handles(marked & {Status.NOT_CONVERGED}, "")
    names = run_iteration_names([run for panel in panels for run in panel.runs])
    counted_as = set(names.values())
    what = counted_as.pop() if len(counted_as) == 1 else "solver"
    layout.label_outer(axes, rows, "time step dt (s)", f"{what} iterations per step")
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, f"{what[0].upper()}{what[1:]} iterations against time step")
    explicit = sorted({run.label for run in data.runs if run.explicit})
    each = ("an iteration is, for " + "; ".join(f"{kind}: {name}" for kind, name in names.items())
            if what == "solver" else "")
    layout.add_notes(figure, notes + [each, f"explicit methods (no solver): {', '.join(explicit)}" if explicit else "",
                                      layout.SAME_CURVE_NOTE if merged else ""])
    return figure


def wall_time_per_step_vs_dt(data: FigureData):
    """Wall time per step against dt, one line per series, one panel per setting and family of lines."""
    notes: list[str] = []
    panels = layout.summary_panels(data, lambda run: run.steps > 0 and run.wall_time > 0, notes)
    if not panels:
        return None
    rows = layout.wrap(panels)
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH)
    stopped_any = False
    costs = []
    for panel, ax in zip(panels, axes):
        for number, series in enumerate(panel.series):
            mine = sorted((run for run in panel.runs if data.series_of(run) is series), key=lambda run: run.dt)
            style = layout.series_style(series, number)
            dts = np.array([run.dt for run in mine])
            cost = np.array([run.wall_time / run.steps for run in mine]) * 1e3
            costs.append(cost)
            ax.plot(dts, cost, lw=1.2, **style)
            stopped = np.array([run.status.stopped for run in mine])
            if stopped.any():
                ax.plot(dts[stopped], cost[stopped], **{**style, "ls": "none", "mfc": "white", "mew": 1.6})
                stopped_any = True
        layout.log_log_panel(ax, panel.title)
    limits = layout.log_limits(np.concatenate(costs), pad=1.3)
    if limits:
        axes[0].set_ylim(*limits)
    for ax in axes:
        layout.tidy_log_axes(ax)
    layout.label_outer(axes, rows, "time step dt (s)", "wall time per step (ms)")
    handles = layout.series_handles(data, [series for panel in panels for series in panel.series], lw=1.2)
    if stopped_any:
        handles.append(Line2D([], [], **STOPPED_HANDLE))
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "cost per step against time step")
    untimed = [run for run in data.runs if not (run.steps > 0 and run.wall_time > 0)]
    layout.add_notes(figure, notes + [f"{len(untimed)} of {len(data.runs)} runs took no step: not drawn" if untimed else ""])
    return figure
