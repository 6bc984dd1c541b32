"""Energy figures: the energy change over time, the largest change against dt, and where the energy goes (the budget).

Every energy is divided by its run's one energy reference E_ref, which the run's system declared
(``RunData.energy_ref``: E0 for the spring, |E0| for an orbit, max(M |g| L, |KE0| + |PE0|) for the
cloth), never by E0 alone: a cloth that starts at rest has E0 = 0, and a nudge of 1e-8 m/s would
make E/E0 a number of 1e16. The axis labels say what E_ref is.
"""

from __future__ import annotations

import math
import textwrap

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.transforms import blended_transform_factory

from simrun.analysis.runs import RunData
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.format.summary import Status

# Exact conservation (zero drift) cannot sit on a log axis: drawn at double-precision round-off.
DRIFT_FLOOR = 1e-16
# Height (in) of one line of notes under the panels.
NOTE_LINE = 0.16


# -- energy over time ----------------------------------------------------------------------------
def energy_over_time(data: FigureData):
    """(E − E0) / E_ref against t: a row of small multiples (one per dt) per setting and family of lines.

    Why (E − E0) / E_ref rather than E / E_ref: 0 means "conserved" for every system, whatever the sign
    of E0: the spring (E0 > 0, where E / E_ref starts at 1), a bound orbit (E0 < 0: at −1) and a cloth
    at rest (E0 = 0: at 0); so panels of different systems and figures read alike, and it is the
    quantity whose largest value the drift figure and the stability map show. A decay reads as a fall
    towards −E0 / E_ref (−1 on the spring); its rate, over decades, is the artificial damping figure's.
    One y scale for the whole figure: linear while every |value| < 10, else symlog with its linear part
    taken from the curves (layout.apply_signed_scale). The x axes end at the runs' duration.
    """
    rows, notes = layout.dt_grid(data)
    if not rows:
        return None
    panels = layout.flatten(rows)
    curves = []  # per panel: (series, (t, change), run) in drawing order
    for panel in panels:
        lines = []
        for run in layout.in_label_order(panel.runs, data):
            t, change = layout.finite(run.t, run.energy_change)
            if change.size:
                lines.append((data.series_of(run), (t, change), run))
        curves.append(lines)
    merged, overlaid = layout.twins([[(series, curve) for series, curve, _ in lines] for lines in curves],
                                    merge=data.colour_per_series, unit=1.0)
    if merged:
        notes.append(layout.SAME_CURVE_NOTE)
    notes.append(layout.no_data_note([run for panel in panels for run in panel.runs], data))
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, legend_width=layout.FIGURE_LEGEND_WIDTH,
                                     extra_height=NOTE_LINE * len([note for note in notes if note]))
    marks = set()
    for number, (panel, ax, lines) in enumerate(zip(panels, axes, curves)):
        for series, (t, change), run in lines:
            if series in merged:
                continue
            dashed = (number, series) in overlaid
            ax.plot(t, change, color=series.colour, ls=layout.OVERLAY_DASHES if dashed else series.linestyle, lw=1.2,
                    zorder=3 if dashed else 2)
            if run.status.stopped:
                ax.plot(t[-1], change[-1], "x", color=series.colour, ms=7, mew=1.8, zorder=4)
                marks.add("stopped")
            elif run.status == Status.NOT_CONVERGED:
                ax.plot(t[-1], change[-1], "o", mfc="none", mec=series.colour, ms=7, mew=1.4, zorder=4)
                marks.add(Status.NOT_CONVERGED)
        ax.axhline(0.0, color="0.6", lw=0.8, ls="--", zorder=0)
        ax.set_title(panel.title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    scale = layout.apply_signed_scale(axes, [curve[1] for lines in curves for _, curve, _ in lines])
    durations = [run.duration for panel in panels for run in panel.runs if np.isfinite(run.duration)]
    if durations:
        axes[0].set_xlim(0.0, max(durations))
    layout.label_outer(axes, rows, "time t (s)", "")
    layout.row_headers(axes, rows)
    figure.supylabel(layout.energy_label(data.runs) + ("  (symlog)" if scale == "symlog" else ""), fontsize=9)
    shown = list(dict.fromkeys(series for lines in curves for series, _, _ in lines))
    handles = layout.series_handles(data, shown, merged, markers=False, lw=1.2)
    handles.append(Line2D([], [], ls="--", color="0.6", lw=0.8, label="0: energy conserved"))
    if "stopped" in marks:
        handles.append(Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="run stopped (diverged/failed)"))
    if Status.NOT_CONVERGED in marks:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="none", mec="0.3", ms=7, mew=1.4,
                              label="solver not converged in some steps"))
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "energy change over time")
    layout.add_notes(figure, notes)
    return figure


# -- energy drift against dt ---------------------------------------------------------------------
def energy_drift_vs_dt(data: FigureData):
    """max |E − E0| / E_ref against dt, log-log; one panel per setting and family of lines, a line per series."""
    notes: list[str] = []
    panels = layout.summary_panels(data, notes=notes)
    if not panels:
        return None
    curves = []  # per panel: (series, (dts, drifts), shown runs, all its runs)
    for panel in panels:
        lines = []
        for series in panel.series:
            mine = sorted((run for run in panel.runs if data.series_of(run) is series), key=lambda run: run.dt)
            shown = [run for run in mine if not run.status.stopped and run.has_change]
            curve = (np.array([run.dt for run in shown]), np.array([_max_drift(run) for run in shown]))
            lines.append((series, curve, shown, mine))
        curves.append(lines)
    merged, overlaid = layout.twins([[(series, curve) for series, curve, shown, _ in lines if shown] for lines in curves],
                                    merge=data.colour_per_series)
    rows = layout.wrap(panels)
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH, extra_height=NOTE_LINE)
    floored, marked = False, set()
    drawn_values, stopped_values = [], []
    for number, (panel, ax, lines) in enumerate(zip(panels, axes, curves)):
        top = blended_transform_factory(ax.transData, ax.transAxes)  # x in data, y in axes fraction
        for index, (series, (dts, drifts), shown, mine) in enumerate(lines):
            style = layout.series_style(series, index)
            if shown and series not in merged:
                floored |= bool(np.any(drifts < DRIFT_FLOOR))
                drifts = np.maximum(drifts, DRIFT_FLOOR)
                drawn_values.append(drifts)
                if (number, series) in overlaid:
                    style["ls"] = layout.OVERLAY_DASHES
                ax.plot(dts, drifts, lw=1.3, **style)
                marked |= layout.ring_not_converged(ax, dts, drifts, shown)
            for run in mine:
                if run.status == Status.DIVERGED:  # off the scale: hollow, at the top edge
                    ax.plot(run.dt, layout.TOP_EDGE, transform=top, clip_on=False,
                            **{**style, "ls": "none", "mfc": "none", "mew": 1.6})
                    if run.has_change:
                        stopped_values.append(_max_drift(run))
                elif run.status == Status.FAILED:
                    ax.plot(run.dt, layout.TOP_EDGE, "X", color=series.colour, ms=8, transform=top, clip_on=False)
                marked.add(run.status)
        layout.log_log_panel(ax, panel.title)
    # one y range for the figure: the drifts drawn; when every run stopped, the drifts they reached
    limits = layout.log_limits(np.concatenate(drawn_values) if drawn_values else np.array(stopped_values))
    axes[0].set_ylim(*(limits or (1e-3, 1e3)))
    if marked & {Status.DIVERGED, Status.FAILED}:
        layout.pad_top(axes[0])
    for ax in axes:
        layout.tidy_log_axes(ax)
    shown_series = [series for lines in curves for series, _, _, mine in lines if mine]
    handles = layout.series_handles(data, list(dict.fromkeys(shown_series)), merged, lw=1.3)
    handles += layout.status_handles(marked, "(at top edge)")
    layout.label_outer(axes, rows, "time step dt (s)", "")
    figure.supylabel(layout.energy_label(data.runs, "max |E − E$_0$| / E$_{ref}$ over the run"), fontsize=9)
    layout.figure_legend(figure, handles, data.legend_title)
    layout.suptitle(figure, data, "largest energy change against time step")
    notes += [f"zero drift (exact conservation) drawn at {DRIFT_FLOOR:g}" if floored else "",
             "every run stopped before its end: the axis spans the change they reached first"
             if not drawn_values and stopped_values else "",
             layout.SAME_CURVE_NOTE if merged else ""]
    layout.add_notes(figure, notes)
    return figure


def _max_drift(run: RunData) -> float:
    change = run.energy_change
    change = change[np.isfinite(change)]
    return float(np.max(np.abs(change))) if change.size else math.nan


# -- where the energy goes -----------------------------------------------------------------------
# More panels than this (runs at the chosen dt) are left out, with a note: the figure would outgrow a page.
BUDGET_PANELS = 24
BUDGET_PANEL_SIZE = (3.6, 2.5)
# A panel title longer than this (characters at 8.5 pt) is wrapped onto more lines: it would run into its neighbours.
BUDGET_TITLE_CHARACTERS = 52
# The stack is cut at this multiple of the budget: a method that gains energy leaves the panel.
BUDGET_AXIS_TOP = 1.6
BUDGET_TERMS = (  # dataset, legend text, colour
    ("kinetic_energy", "kinetic", "#4c72b0"),
    ("potential_energy", "potential", "#55a868"),
    ("spring_energy", "potential: springs", "#55a868"),
    ("elastic_energy", "potential: elastic", "#55a868"),
    ("membrane_energy", "potential: membrane", "#55a868"),
    ("bending_energy", "potential: bending", "#64b5cd"),
    ("gravity_energy", "potential: gravity", "#ccb974"),
    ("contact_energy", "potential: contact", "#8172b2"),
    ("dissipated_energy", "dissipated by physical damping", "#c44e52"),
    ("friction_dissipated", "dissipated by friction", "#937860"),
)
DISSIPATED = ("dissipated_energy", "friction_dissipated")  # losses that accumulate: not part of E0
NUMERICAL_LOSS_COLOUR, NUMERICAL_GAIN_COLOUR = "0.82", "#dd8452"
# A term (or a gain) smaller than this fraction of the budget throughout is left out of the legend.
BUDGET_VISIBLE = 1e-3


def energy_budget(data: FigureData):
    """Where the energy goes, for each line (an integrator at a setting) of each section at one dt: kinetic +
    potential terms + physical damping work, stacked over time, divided by E_ref; the gap up to the initial
    budget is the integrator's numerical loss (or gain)."""
    if not data.runs:
        return None
    setting = _budget_setting(data.runs)
    candidates = [(title, run) for title, runs in data.sections
                  for run in layout.in_label_order([run for run in runs if _step_setting(run) == setting], data)]
    chosen = [(title, run) for title, run in candidates if run.t.size >= 2]
    if not chosen:
        return None
    notes = []
    controlled = np.isfinite(data.runs[0].tolerance)
    setting_text = f"tol = {setting:g}" if controlled else f"dt = {data.dt_names[setting]} s"
    if len({_step_setting(run) for run in data.runs}) > 1:
        swept = "tolerances" if controlled else "time steps"
        notes.append(f"at one {'tolerance' if controlled else 'time step'}, {setting_text}: the one nearest the geometric "
                     f"middle of the swept {swept} where every run reached its end (every {swept[:-1]}: energy over time)")
    short = [run for _, run in candidates if run.t.size < 2]
    if short:
        notes.append("no budget (fewer than two samples): " + ", ".join(data.series_of(run).name for run in short))
    raw = {run.run_id: _budget_terms(run) for _, run in chosen}
    # potential terms that can be negative (gravity) are counted from one zero for every run: the lowest value any
    # run reached, so that runs from one start state have one budget, whatever distance each then slid or fell
    offsets = {key: min(float(terms[key].min()) for _, terms in raw.values() if key in terms and terms[key].size)
               for key in SHIFTED_TERMS if any(key in terms and terms[key].size for _, terms in raw.values())}
    offsets = {key: value for key, value in offsets.items() if value < 0}
    budgets = {run.run_id: _budget(run, *raw[run.run_id], offsets) for _, run in chosen}
    # runs of one section with the same budget to round-off (e.g. linear solvers that all converge): one panel
    panels: list[tuple[str, RunData, list[RunData]]] = []
    for title, run in chosen:
        twin = next((panel for panel in panels if panel[0] == title and _same_budget(budgets[panel[1].run_id],
                                                                                     budgets[run.run_id])), None)
        if twin is not None:
            twin[2].append(run)
        else:
            panels.append((title, run, [run]))
    if len(panels) < len(chosen):
        notes.append("A = B in a title: their budgets agree to round-off, drawn once")
    if len(panels) > BUDGET_PANELS:
        notes.append(f"{BUDGET_PANELS} of {len(panels)} panels shown (runs at this time step): the first ones")
        panels = panels[:BUDGET_PANELS]
    panels = [(_panel_title(title, members, data), run) for title, run, members in panels]
    rows = layout.wrap(panels)
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, panel_size=BUDGET_PANEL_SIZE,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH + 0.3, extra_height=NOTE_LINE * len(notes))
    shown: dict[str, str] = {}
    gained = False
    driven = False  # a run whose prescribed vertices did work: its budget moves with time
    tops = []
    for (panel_title, run), ax in zip(layout.flatten(rows), axes):
        t, terms, budget = budgets[run.run_id]
        reference = run.energy_ref
        bottom = np.zeros_like(t)
        for key, text, colour in BUDGET_TERMS:
            if key in terms:
                ax.fill_between(t, bottom / reference, (bottom + terms[key]) / reference, color=colour, lw=0)
                bottom = bottom + terms[key]
                if np.nanmax(terms[key]) > BUDGET_VISIBLE * float(np.max(budget)):
                    shown[text] = colour
        # what is left of the budget: the integrator's own loss (below the line) or gain (above)
        level = budget / reference
        ax.fill_between(t, bottom / reference, level, where=bottom <= budget, interpolate=True,
                        facecolor=NUMERICAL_LOSS_COLOUR, lw=0)
        if np.any(bottom > budget * (1.0 + BUDGET_VISIBLE)):
            # hatched over the stack: the terms above the line are there, but only through the method's gain
            ax.fill_between(t, level, np.minimum(bottom / reference, BUDGET_AXIS_TOP * level), where=bottom > budget,
                            interpolate=True, facecolor="none", edgecolor=NUMERICAL_GAIN_COLOUR, hatch="xx", lw=0)
            gained = True
        tops.append(float(np.max(level)))
        driven = driven or bool(np.ptp(level) > BUDGET_VISIBLE * float(np.max(np.abs(level))))
        ax.plot(t, level, color="black", lw=0.9, ls="--")
        ax.set_title(panel_title, fontsize=8.5)
        ax.grid(True, alpha=0.25)
    axes[0].set_ylim(0.0, max(tops) * (BUDGET_AXIS_TOP if gained else 1.05))
    durations = [run.duration for _, run in panels if np.isfinite(run.duration)]
    if durations:
        axes[0].set_xlim(0.0, max(durations))
    layout.label_outer(axes, rows, "time t (s)", "")
    figure.supylabel(layout.energy_label([run for _, run in panels], "energy / E$_{ref}$"), fontsize=9)
    handles = [Patch(facecolor=colour, label=text) for text, colour in shown.items()]
    handles.append(Patch(facecolor=NUMERICAL_LOSS_COLOUR, label="numerical loss (the integrator)"))
    if gained:
        handles.append(Patch(facecolor="none", edgecolor=NUMERICAL_GAIN_COLOUR, hatch="xx", label="numerical gain (the integrator)"))
    handles.append(Line2D([], [], ls="--", color="black", lw=0.9, label="initial energy + work of the prescribed\nvertices (the budget)"
                          if driven else "initial energy (the budget)"))
    layout.figure_legend(figure, handles)
    who = f"{data.labels[0]}, " if len(data.labels) == 1 else ""
    layout.suptitle(figure, data, f"where the energy goes ({who}{setting_text})")
    layout.add_notes(figure, notes)
    return figure


def _panel_title(section: str, runs: list[RunData], data: FigureData) -> str:
    """The section and the runs' lines ("A = B" for runs drawn once), wrapped to the panel's width."""
    names = " = ".join(data.series_of(run).name + run.status_note() for run in runs)
    return textwrap.fill(layout.join_titles(section, names), BUDGET_TITLE_CHARACTERS)


def _same_budget(a, b) -> bool:
    (ta, terms_a, budget_a), (tb, terms_b, budget_b) = a, b
    if ta.shape != tb.shape or set(terms_a) != set(terms_b):
        return False
    unit = float(np.max(budget_a)) if budget_a.size else 1.0
    if not layout.same_curve((ta, budget_a), (tb, budget_b), unit=unit):
        return False
    return all(layout.same_curve((ta, terms_a[key]), (tb, terms_b[key]), unit=unit) for key in terms_a)


def _step_setting(run: RunData) -> float:
    """What sets a run's steps: its tolerance under step control, else its dt (``layout.step_setting``'s value)."""
    return layout.step_setting(run)[1]


def _budget_setting(runs: list[RunData]) -> float:
    """The dt (or tolerance) shown: nearest the geometric middle of the swept ones among those where every run
    reached the end."""
    settings = sorted({_step_setting(run) for run in runs})
    complete = [value for value in settings
                if all(not run.status.stopped for run in runs if _step_setting(run) == value)] or settings
    middle = math.sqrt(settings[0] * settings[-1])
    return min(complete, key=lambda value: abs(math.log(value / middle)))


# the potential terms that can be negative (gravity: relative to where z = 0 happens to be)
SHIFTED_TERMS = ("spring_energy", "elastic_energy", "gravity_energy", "contact_energy", "potential_energy")
# the parts the potential is stored in: a shell's membrane and hinges, a mass-spring model's springs, a finite-element
# solid's elements
POTENTIAL_PARTS = (("membrane_energy", "bending_energy", "gravity_energy", "contact_energy"),
                   ("spring_energy", "gravity_energy", "contact_energy"), ("elastic_energy", "gravity_energy", "contact_energy"))


def _budget_terms(run: RunData) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(t, energy terms) of a run, cut where any stops being finite: kinetic, potential (springs or elements, gravity,
    contact, or the potential as one), the dissipated work."""
    stored = run.stored
    t = run.t
    parts = next((parts for parts in POTENTIAL_PARTS if parts[0] in stored), ("potential_energy",))
    terms = {key: stored.series(key)[: t.size] for key in ("kinetic_energy", *parts, *DISSIPATED) if key in stored}
    count = min([t.size] + [values.size for values in terms.values()])
    finite = np.all([np.isfinite(values[:count]) for values in terms.values()], axis=0) & np.isfinite(t[:count])
    stop = int(np.argmin(finite)) if not finite.all() else count
    return t[:stop], {key: values[:stop] for key, values in terms.items()}


def _budget(run: RunData, t: np.ndarray, terms: dict[str, np.ndarray], offsets: dict[str, float]
            ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """(t, energy terms (each >= 0), budget over t): potential terms that can be negative are counted from
    ``offsets`` (the figure's lowest value of each, over every run: one zero for all), and the budget is E0 minus
    those offsets, plus the work that vertices on prescribed paths have done on the system by t (a moving pin puts
    energy in)."""
    terms = {key: values - offsets[key] if key in offsets else values for key, values in terms.items()}
    start = sum(float(values[0]) for key, values in terms.items() if key not in DISSIPATED) if t.size else 0.0
    budget = np.full(t.size, start if start > 0 else 1.0)
    if "prescribed_work" in run.stored:
        budget = budget + run.stored.series("prescribed_work")[: t.size]
    return t, terms, budget
