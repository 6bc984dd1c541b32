"""Convergence and work-precision: each run's error at its error time against dt (with the observed order) and
against its wall time.

The error is ``RunData.error``: max |x − x_exact| (in phase space on the test equation) at the run's
error time, a fixed horizon shorter than the duration (or against a reference solution on request); the
axis says at which time. Files from before error times have the error at the end of the run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.lines import Line2D

from simrun.analysis.equal_error import left_out_reason
from simrun.analysis.runs import RunData
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData, Series

if TYPE_CHECKING:
    from simrun.analysis import oscillator as analysis

# An error of exactly zero cannot sit on a log axis: drawn at this floor (m).
ERROR_FLOOR = 1e-16
# Room (in) per entry of the legend of orders under each panel when there are several.
ORDER_LEGEND_LINE = 0.16
NOTE_LINE = 0.16


def _usable(run: RunData) -> bool:
    """A run that reached its error time with a known error (exact solution, or a reference on request)."""
    return not run.status.stopped and np.isfinite(run.error)


def _fixed_step(run: RunData) -> bool:
    """A usable run of fixed steps: the convergence figure and the observed orders draw those (a step-controlled run's
    error falls against its mean step at its estimate's order, not its method's: the work-precision figure draws it)."""
    return _usable(run) and not np.isfinite(run.tolerance)


def error_runs(data: FigureData) -> list[RunData]:
    return [run for run in data.runs if _usable(run)]


def order_fits(data: FigureData) -> dict[tuple[str, Series], tuple["analysis.OrderFit", list[RunData]]]:
    """(panel title, series) -> (observed order fit, runs sorted by dt) for every line with errors."""
    from simrun.analysis import oscillator as analysis  # on first use: importing the figures loads no integrator

    fits = {}
    for panel in layout.summary_panels(data, _fixed_step):
        for series in panel.series:
            mine = sorted((run for run in panel.runs if data.series_of(run) is series), key=lambda run: run.dt)
            fit = analysis.observed_order([run.dt for run in mine], [run.error for run in mine],
                                          scale=mine[0].length_scale)
            fits[(panel.title, series)] = (fit, mine)
    return fits


def order_text(fit: "analysis.OrderFit", footnotes: dict[str, int] | None = None) -> str:
    """"p = 1.98", "exact (round-off)", or "no slope (1)" with the reason as footnote 1 (``footnotes``: reason -> number)."""
    if np.isfinite(fit.order):
        return f"p = {fit.order:.2f}"
    if fit.exact:
        return "exact (round-off)"
    reason = fit.reason or "too few points in the asymptotic range"
    if footnotes is None:
        return f"no slope: {reason}"
    number = footnotes.setdefault(reason, len(footnotes) + 1)
    return f"no slope ({number})"


def error_axis_label(runs: list[RunData]) -> str:
    """'error at t = 2.1 s (m)': the time at which the runs' errors were measured (each at its nearest step)."""
    times = np.array([run.error_time for run in runs if np.isfinite(run.error_time)])
    reference = " vs reference" if any(run.error_from_reference for run in runs) else ""
    if times.size == 0:
        return f"error (m){reference}"
    spread = max(run.dt for run in runs)
    if times.max() - times.min() <= spread * (1.0 + 1e-9):
        return f"error at t = {float(np.median(times)):.3g} s (m){reference}"
    return f"error at the run's error time (m){reference}\n({times.min():.3g} to {times.max():.3g} s)"


def convergence(data: FigureData):
    """Error at the error time against dt (log-log); each line's fitted slope (observed order) in its legend."""
    from simrun.analysis import oscillator as analysis  # on first use: importing the figures loads no integrator

    fits = order_fits(data)
    if not fits:
        return None
    capped: list[str] = []
    panels = layout.summary_panels(data, _fixed_step, capped)
    curves = [[(series, _curve(fits[(panel.title, series)][1])) for series in panel.series] for panel in panels]
    merged, overlaid = layout.twins(curves, merge=data.colour_per_series)
    rows = layout.wrap(panels, columns=3)
    single = len(panels) == 1
    figure, axes = layout.panel_grid(rows, panel_size=layout.SUMMARY_PANEL_SIZE, sharey=True,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH + 0.6 if single else 0.0)
    if not single:  # each panel's legend of orders under it
        entries = [max(len(panel.series) for panel in row) for row in rows]
        figure.set_figheight(figure.get_figheight() + ORDER_LEGEND_LINE * sum(entries) + 0.3 * len(rows))
    footnotes: dict[str, int] = {}
    errors = []
    for number, (panel, ax) in enumerate(zip(panels, axes)):
        handles = []
        for index, series in enumerate(panel.series):
            if series in merged:
                continue
            fit, mine = fits[(panel.title, series)]
            style = layout.series_style(series, index)
            if (number, series) in overlaid:
                style["ls"] = layout.OVERLAY_DASHES
            dts, values = _curve(mine)
            values = np.maximum(values, ERROR_FLOOR)
            errors.append(values)
            names = " = ".join([series.name] + [other.name for other in panel.series if merged.get(other) is series])
            handles += ax.plot(dts, values, lw=1.2, label=f"{names}: {order_text(fit, footnotes)}", **style)
            if np.isfinite(fit.order):
                ends = dts[fit.used][[0, -1]]
                ax.plot(ends, np.exp(fit.intercept) * ends ** fit.order, "--", color="black", lw=0.9, zorder=5)
        layout.log_log_panel(ax, panel.title)
        if not single:
            ax.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False,
                      handlelength=2.2, borderaxespad=0.0)
    runs = _error_axes(data, axes, rows, errors, "time step dt (s)")
    fit_handle = Line2D([], [], ls="--", color="black", lw=0.9,
                        label=f"least-squares fit (≤ {analysis.ORDER_FIT_POINTS} smallest dt)")
    if single:
        layout.figure_legend(figure, axes[0].get_legend_handles_labels()[0] + [fit_handle], data.legend_title)
    else:
        layout.figure_legend(figure, [fit_handle], data.legend_title)
    layout.suptitle(figure, data, "convergence (observed order p)")
    notes = capped + [f"({number}) {reason}" for reason, number in footnotes.items()]
    notes.append(layout.SAME_CURVE_NOTE if merged else "")
    notes.append(_left_out_note(data, runs))
    layout.add_notes(figure, notes)
    figure.set_figheight(figure.get_figheight() + NOTE_LINE * len([note for note in notes if note]))
    return figure


def _curve(runs: list[RunData]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([run.dt for run in runs]), np.array([run.error for run in runs])


def _left_out_note(data: FigureData, runs: list[RunData]) -> str:
    """Which runs have no error to draw, and why."""
    stopped = sum(run.status.stopped for run in data.runs)
    unknown = len(data.runs) - len(runs) - stopped
    parts = ([f"{stopped} stopped before their error time"] if stopped else []) + \
            ([f"{unknown} without a known error"] if unknown else [])
    return f"{len(runs)} of {len(data.runs)} runs drawn ({'; '.join(parts)})" if parts else ""


# the work a run's error is set against: (axis label, the run's cost), each a column of the figure where any run has it
WORK_MEASURES = (("wall time of the run (s)", lambda run: run.wall_time),
                 ("nonlinear iterations of the run", lambda run: run.nonlinear_iterations),
                 ("force evaluations of the run", lambda run: run.function_evaluations))


def work_precision(data: FigureData):
    """Error at the error time against the work of the run (log-log): wall time, nonlinear iterations and force
    evaluations, a column each; one line per series, and the Pareto front of every panel (the runs no other run beats
    in both error and that work)."""
    notes: list[str] = []
    panels = _section_panels(data, lambda run: _usable(run) and run.wall_time > 0, notes)
    if not panels:
        return None
    measures = [(label, cost) for label, cost in WORK_MEASURES
                if any(_positive(cost(run)) for panel in panels for run in panel.runs)]
    rows = [[layout.Panel(panel.title if number == 0 else "", panel.runs, panel.series) for number in range(len(measures))]
            for panel in panels]
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH, extra_height=2 * NOTE_LINE)
    errors, unpriced = [], set()
    accuracies = [_reference_accuracy(data, panel.runs) for panel in panels]
    for row_number, (panel, row) in enumerate(zip(panels, rows)):
        for column, (label, cost) in enumerate(measures):
            ax = axes[row_number * len(measures) + column]
            front, drawn = [], []  # drawn: the panel's curves so far, so that a twin is drawn dashed over its pair
            for number, series in enumerate(panel.series):
                mine = sorted((run for run in panel.runs if data.series_of(run) is series and _positive(cost(run))),
                              key=lambda run: run.dt)
                unpriced.update((label, run.label) for run in panel.runs
                                if data.series_of(run) is series and not _positive(cost(run)))
                if not mine:
                    continue
                values = np.maximum([run.error for run in mine], ERROR_FLOOR)
                errors.append(values)
                costs = [cost(run) for run in mine]
                front += zip(costs, values)
                style = layout.series_style(series, number)
                if any(len(costs) == len(other[0]) and np.allclose(costs, other[0]) and np.allclose(values, other[1])
                       for other in drawn):
                    style["ls"] = "--"  # the same work and error as a method drawn already (backward Euler's twins)
                drawn.append((costs, values))
                ax.plot(costs, values, lw=1.2, **style)
            _draw_front(ax, front)
            layout.log_log_panel(ax, row[column].title, minor_grid=False)
    runs = _error_axes(data, axes, rows, errors, "")
    accuracy_drawn = False
    for row_number, accuracy in enumerate(accuracies):  # below it the errors are the reference's own
        if np.isfinite(accuracy) and accuracy >= axes[row_number * len(measures)].get_ylim()[0]:
            for column in range(len(measures)):
                axes[row_number * len(measures) + column].axhline(accuracy, color=ACCURACY_COLOUR, ls=":", lw=1.2, zorder=1)
            accuracy_drawn = True
    for row_number in range(len(rows)):  # each column its own work (label_outer gives every column one label)
        for column, (label, _) in enumerate(measures):
            axes[row_number * len(measures) + column].set_xlabel(label if row_number == len(rows) - 1 else "", fontsize=9)
    handles = layout.series_handles(data, [series for panel in panels for series in panel.series], lw=1.2)
    handles.append(Line2D([], [], color=FRONT_COLOUR, lw=4.0, alpha=0.5, label="Pareto front"))
    if accuracy_drawn:
        handles.append(Line2D([], [], color=ACCURACY_COLOUR, ls=":", lw=1.2, label="reference's own accuracy"))
    handles.append(Line2D([], [], ls="none", label="lower left is better"))
    layout.figure_legend(figure, handles, data.legend_title)
    points = "the tolerances" if any(np.isfinite(run.tolerance) for run in data.runs) else "the time steps"
    layout.suptitle(figure, data, f"work-precision (points: {points})")
    unpriced_labels = {}
    for label, method in sorted(unpriced):
        unpriced_labels.setdefault(label.split(" of the run")[0], []).append(method)
    notes += [f"not on the {what} axis (none counted): {', '.join(dict.fromkeys(methods))}"
              for what, methods in unpriced_labels.items()]
    notes += [_reference_note(data, [run for panel in panels for run in panel.runs]), _left_out_reasons(data, runs)]
    layout.add_notes(figure, notes)
    figure.set_figheight(figure.get_figheight() + NOTE_LINE * _wrapped_lines(figure, notes[-2]))
    return figure


# the line of a reference's estimated accuracy (the work-precision figure)
ACCURACY_COLOUR = "0.3"


def _reference_accuracy(data: FigureData, runs: list[RunData]) -> float:
    """m: the estimated accuracy of the reference these runs' errors are measured against (NaN: none of them is, or
    its accuracy was not estimated)."""
    if data.reference is None:
        return float("nan")
    return data.reference.accuracy_of(run.run_id for run in runs if run.error_from_reference)


def _reference_note(data: FigureData, runs: list[RunData]) -> str:
    """What the errors of the runs without an exact solution are measured against, how well that is known, and which
    drawn runs' errors are at or below it (there the figure shows the reference's error, not the run's)."""
    measured = [run for run in runs if run.error_from_reference]
    if data.reference is None or not measured:
        return ""
    note = f"errors vs reference: against {data.reference.statement()}"
    if not np.isfinite(data.reference.accuracy_of(run.run_id for run in measured)):
        return note
    below = set(data.reference.below_accuracy(run.run_id for run in measured))
    if not below:
        return note + "; every drawn run's error is above it"
    by_label: dict[str, list[RunData]] = {}
    for run in measured:
        if run.run_id in below:
            by_label.setdefault(run.label, []).append(run)
    listed = [f"{label} ({_settings_text(mine)})" for label, mine in by_label.items()]
    return note + f"; at or below it, so no measure of the method: {', '.join(listed)}"


def _wrapped_lines(figure, note: str) -> int:
    """How many lines ``layout.add_notes`` writes a note in (the figure grows by that many)."""
    return len(layout.note_lines(figure, note)) if note else 0


def _section_panels(data: FigureData, keep, notes: list[str]) -> list:
    """One panel per section with every series of it: the methods compared are the methods on one axes, whatever
    family of lines they belong to elsewhere (scipy's beside simrun's). At most MAX_SUMMARY_PANELS, with a note."""
    panels = []
    for section, runs in data.sections:
        mine = [run for run in runs if keep(run)]
        if mine:
            series = list(dict.fromkeys(data.series_of(run) for run in mine))
            order = [one for _, members in data.families for one in members]
            series.sort(key=order.index)
            panels.append(layout.Panel(section, mine, series))
    if len(panels) > layout.MAX_SUMMARY_PANELS:
        notes.append(f"{layout.MAX_SUMMARY_PANELS} of {len(panels)} settings shown: the first ones")
        panels = panels[:layout.MAX_SUMMARY_PANELS]
    return panels


def _settings_text(runs: list[RunData]) -> str:
    """The tolerances (or time steps) of one method's left-out runs: one value, or the count and the range."""
    controlled = np.isfinite(runs[0].tolerance)
    values = sorted({run.tolerance if controlled else run.dt for run in runs})
    what, unit = ("tol", "") if controlled else ("dt", " s")
    counted = f"{len(runs)} runs, " if len(runs) > 1 else ""
    if len(values) == 1:
        return f"{counted}{what} {values[0]:g}{unit}"
    return f"{counted}{what} {values[0]:g} to {values[-1]:g}{unit}"


def _left_out_reasons(data: FigureData, drawn: list[RunData]) -> str:
    """Which runs are not drawn and why, by method (``left_out_reason``): diverged, over the wall-time budget, not
    converged, failed, or without a known error."""
    shown = set(map(id, drawn))
    reasons: dict[str, list[str]] = {}
    for run in data.runs:
        if id(run) in shown:
            continue
        why = left_out_reason(run) or "no known error"
        reasons.setdefault(why, {}).setdefault(run.label, []).append(run)
    if not reasons:
        return ""
    parts = []
    for why, by_label in reasons.items():
        listed = [f"{label} ({_settings_text(runs)})" for label, runs in by_label.items()]
        more = f" and {len(listed) - 8} more methods" if len(listed) > 8 else ""
        parts.append(f"{why}: {', '.join(listed[:8])}{more}")
    return f"{len(drawn)} of {len(data.runs)} runs drawn; left out, " + "; ".join(parts)


# the Pareto front's colour: behind the lines, wide and light
FRONT_COLOUR = "0.55"


def _positive(value: float) -> bool:
    return bool(np.isfinite(value) and value > 0)


def _draw_front(ax, points: list[tuple[float, float]]) -> None:
    """The Pareto front of the panel's points (cost, error): the runs that no cheaper run beats in error, joined."""
    front, best = [], np.inf
    for cost, error in sorted(points):
        if error < best:
            front.append((cost, error))
            best = error
    if len(front) > 1:
        xs, ys = zip(*front)
        ax.plot(xs, ys, color=FRONT_COLOUR, lw=4.0, alpha=0.5, zorder=0, solid_capstyle="round")


def _error_axes(data: FigureData, axes, rows, errors: list[np.ndarray], xlabel: str) -> list[RunData]:
    """The shared error axis of the convergence and work-precision figures: limits from every error drawn,
    tidy log ticks, labels on the outer panels; returns the runs with errors (for the legend's notes)."""
    limits = layout.log_limits(np.concatenate(errors))
    if limits:
        axes[0].set_ylim(*limits)
    for ax in axes:
        layout.tidy_log_axes(ax)
    runs = error_runs(data)
    layout.label_outer(axes, rows, xlabel, error_axis_label(runs))
    return runs
