"""Energy figures: E/E0 over time, the relative drift against dt, and where the energy goes (the budget)."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.transforms import blended_transform_factory

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData, RunData
from simrun.results import Status

# Signed energies (bound orbits, E0 < 0) reaching this many times |E0| get a symlog axis.
SYMLOG_RANGE = 10.0
# A y range wider than this factor is drawn on a log axis (forward Euler grows by decades).
LOG_AXIS_RANGE = 100.0
# Exact conservation (zero drift) cannot sit on a log axis: drawn at double-precision round-off.
DRIFT_FLOOR = 1e-16


# -- energy over time ----------------------------------------------------------------------------
def energy_over_time(data: FigureData):
    """E/E0 against t: small multiples per dt (rows per group), one line per integrator label."""
    rows, note = layout.dt_panels(data)
    figure, axes = layout.panel_grid(rows, sharex=True, legend_width=layout.FIGURE_LEGEND_WIDTH)
    for (title, runs), ax in zip(layout.flatten(rows), axes):
        drawn = [run for run in runs if run.has_series]
        for run in layout.in_label_order(drawn, data):
            t, ratio = layout.finite(run.t, run.energy_ratio)
            if ratio.size == 0:
                continue
            stopped = run.status.stopped
            ax.plot(t, ratio, color=data.colours[run.label], lw=1.1, label=layout.status_label(run),
                    marker="x" if stopped else None, markevery=[ratio.size - 1], ms=7, mew=1.8)
        layout.no_data_entries(ax, runs, data)
        values = np.concatenate([layout.finite(run.t, run.energy_ratio)[1] for run in drawn] or [np.empty(0)])
        _energy_axis(ax, values)
        if values.size:  # the exact energy: E / E_ref stays at its start, +1 (or -1 for a bound orbit)
            ax.axhline(np.sign(values[0]), color="0.6", lw=0.8, ls="--", zorder=0)
        ax.set_title(title, fontsize=9)
        layout.status_legend(ax)
        ax.grid(True, which="major", alpha=0.3)
    layout.label_outer(axes, rows, "time t (s)", _energy_label(data.runs))
    handles = layout.label_handles(data, data.labels)
    handles += [Line2D([], [], ls="--", color="0.6", lw=0.8, label="exact (E conserved)"),
                Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="run stopped (diverged/failed)")]
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{data.name}: energy over time" + note, fontsize=11)
    return figure


def _energy_label(runs: list[RunData]) -> str:
    if all(run.energy.size and run.energy[0] > 0 for run in runs if run.has_series):
        return "energy E / E$_0$"
    if any(run.energy.size and run.energy[0] == 0 for run in runs):
        return "energy E / E$_{ref}$  (|E$_0$|, or |KE$_0$|+|PE$_0$| if E$_0$=0)"
    return "energy E / |E$_0$|"


def _energy_axis(ax, values: np.ndarray) -> None:
    """Log axis when positive values span decades, symlog when signed values do, else linear."""
    if values.size == 0:
        return
    if np.all(values > 0) and values.max() / values.min() > LOG_AXIS_RANGE:
        ax.set_yscale("log")
    elif np.any(values <= 0) and np.abs(values).max() > SYMLOG_RANGE:
        ax.set_yscale("symlog", linthresh=1.0)  # linear within the initial energy scale
    else:
        ax.ticklabel_format(axis="y", useOffset=False)


# -- energy drift against dt ---------------------------------------------------------------------
def energy_drift_vs_dt(data: FigureData):
    """max |E - E0| / |E0| against dt, log-log; one panel per group, one line per integrator label."""
    panels = layout.group_panels(data)
    figure, axes = layout.panel_grid(panels, sharey=True, panel_size=layout.SUMMARY_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH)
    floored, marked = False, set()
    for (title, runs), ax in zip(layout.flatten(panels), axes):
        top = blended_transform_factory(ax.transData, ax.transAxes)  # x in data, y in axes fraction
        for number, label in enumerate(data.labels):
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            style = layout.label_style(data, label, number)
            shown = [run for run in mine if not run.status.stopped and run.has_change]
            if shown:
                dts = np.array([run.dt for run in shown])
                drifts = np.array([_max_drift(run) for run in shown])
                floored |= bool(np.any(drifts < DRIFT_FLOOR))
                drifts = np.maximum(drifts, DRIFT_FLOOR)
                ax.plot(dts, drifts, "-", lw=1.3, **style)
                marked |= layout.ring_not_converged(ax, dts, drifts, shown)
            for run in mine:
                if run.status == Status.DIVERGED:  # off the scale: hollow, at the top edge
                    ax.plot(run.dt, layout.TOP_EDGE, transform=top, clip_on=False, **{**style, "mfc": "none", "mew": 1.6})
                elif run.status == Status.FAILED:
                    ax.plot(run.dt, layout.TOP_EDGE, "X", color=style["color"], ms=8, transform=top, clip_on=False)
                marked.add(run.status)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.1)
        if any(run.status.stopped for run in runs):
            layout.pad_top(ax)
    handles = [Line2D([], [], ls="-", **{**layout.label_style(data, label, number), "ms": layout.LEGEND_MARKER_SIZE})
               for number, label in enumerate(data.labels)]
    handles += layout.status_handles(marked, "(at top edge)")
    if floored:
        handles.append(Line2D([], [], ls="none", label=f"zero drift drawn at {DRIFT_FLOOR:g}"))
    layout.label_outer(axes, panels, "time step dt (s)", "max |E − E$_0$| / |E$_0$| over the run")
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{data.name}: relative energy drift against time step", fontsize=11)
    return figure


def _max_drift(run: RunData) -> float:
    energy = run.energy[np.isfinite(run.energy)]
    return float(np.max(np.abs(energy - energy[0])) / run.energy_ref)



# -- where the energy goes -----------------------------------------------------------------------
BUDGET_PANELS = 16
BUDGET_PANEL_SIZE = (3.6, 2.5)
# The stack is cut at this multiple of the budget: a method that gains energy leaves the panel.
BUDGET_AXIS_TOP = 1.6
BUDGET_TERMS = (  # dataset, legend text, colour
    ("kinetic_energy", "kinetic", "#4c72b0"),
    ("potential_energy", "potential", "#55a868"),
    ("spring_energy", "potential: springs", "#55a868"),
    ("gravity_energy", "potential: gravity", "#ccb974"),
    ("contact_energy", "potential: contact", "#8172b2"),
    ("dissipated_energy", "dissipated by physical damping", "#c44e52"),
)
NUMERICAL_LOSS_COLOUR, NUMERICAL_GAIN_COLOUR = "0.82", "#dd8452"
# A term (or a gain) smaller than this fraction of the budget throughout is left out of the legend.
BUDGET_VISIBLE = 1e-3


def energy_budget(data: FigureData):
    """Where the energy goes, for each label at one dt: kinetic + potential terms + physical damping work,
    stacked over time; the gap to the initial energy is the integrator's numerical loss (or gain)."""
    if not data.groups:
        return None
    title, runs = data.groups[0]
    dt = _budget_dt(runs)
    chosen = [run for run in layout.in_label_order([run for run in runs if run.dt == dt], data) if run.t.size >= 2][:BUDGET_PANELS]
    if not chosen:
        return None
    budgets = {run.run_id: _budget(run) for run in chosen}
    panels = [(run.label + run.status_note(), run) for run in chosen]
    rows = [panels[start:start + layout.PANEL_COLUMNS] for start in range(0, len(panels), layout.PANEL_COLUMNS)]
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, panel_size=BUDGET_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH + 0.3)
    shown: dict[str, str] = {}
    gained = False
    for (panel_title, run), ax in zip(layout.flatten(rows), axes):
        t, terms, budget = budgets[run.run_id]
        bottom = np.zeros_like(t)
        for key, text, colour in BUDGET_TERMS:
            if key in terms:
                ax.fill_between(t, bottom / budget, (bottom + terms[key]) / budget, color=colour, lw=0)
                bottom = bottom + terms[key]
                if np.nanmax(terms[key]) > BUDGET_VISIBLE * budget:
                    shown[text] = colour
        # what is left of the budget: the integrator's own loss (below the line) or gain (above)
        ax.fill_between(t, bottom / budget, 1.0, where=bottom <= budget, interpolate=True,
                        facecolor=NUMERICAL_LOSS_COLOUR, lw=0)
        if np.any(bottom > budget * (1.0 + BUDGET_VISIBLE)):
            # hatched over the stack: the terms above the line are there, but only through the method's gain
            ax.fill_between(t, 1.0, np.minimum(bottom / budget, BUDGET_AXIS_TOP), where=bottom > budget, interpolate=True,
                            facecolor="none", edgecolor=NUMERICAL_GAIN_COLOUR, hatch="xx", lw=0)
            gained = True
        ax.axhline(1.0, color="black", lw=0.9, ls="--")
        if t.size > 1:
            ax.set_xlim(t[0], t[-1])
        ax.set_title(panel_title, fontsize=8.5)
        ax.grid(True, alpha=0.25)
    axes[0].set_ylim(0.0, BUDGET_AXIS_TOP if gained else 1.05)
    layout.label_outer(axes, rows, "time t (s)", "energy / initial budget")
    handles = [Patch(facecolor=colour, label=text) for text, colour in shown.items()]
    handles.append(Patch(facecolor=NUMERICAL_LOSS_COLOUR, label="numerical loss (the integrator)"))
    if gained:
        handles.append(Patch(facecolor="none", edgecolor=NUMERICAL_GAIN_COLOUR, hatch="xx", label="numerical gain (the integrator)"))
    handles.append(Line2D([], [], ls="--", color="black", lw=0.9, label="initial energy (the budget)"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    where = f", {title}" if title else ""
    figure.suptitle(f"{data.name}: where the energy goes (dt = {data.dt_names[dt]} s{where})", fontsize=11)
    return figure


def _budget_dt(runs: list[RunData]) -> float:
    """The dt shown: nearest the geometric middle of the swept dts among those where every run reached the end."""
    dts = sorted({run.dt for run in runs})
    complete = [dt for dt in dts if all(not run.status.stopped for run in runs if run.dt == dt)] or dts
    middle = math.sqrt(dts[0] * dts[-1])
    return min(complete, key=lambda dt: abs(math.log(dt / middle)))


def _budget(run: RunData) -> tuple[np.ndarray, dict[str, np.ndarray], float]:
    """(t, energy terms (each >= 0), budget): potential terms that can be negative (gravity) are counted
    from their lowest value in the run, and the budget is E0 minus those offsets."""
    stored = run.stored
    t = run.t
    parts = ("spring_energy", "gravity_energy", "contact_energy") if "spring_energy" in stored else ("potential_energy",)
    terms = {key: stored.series(key)[: t.size] for key in ("kinetic_energy", *parts, "dissipated_energy") if key in stored}
    count = min([t.size] + [values.size for values in terms.values()])
    finite = np.all([np.isfinite(values[:count]) for values in terms.values()], axis=0) & np.isfinite(t[:count])
    stop = int(np.argmin(finite)) if not finite.all() else count
    t = t[:stop]
    terms = {key: values[:stop] for key, values in terms.items()}
    for key in parts:
        if key in terms and terms[key].size and terms[key].min() < 0:
            terms[key] = terms[key] - float(terms[key].min())
    start = sum(float(values[0]) for key, values in terms.items() if key != "dissipated_energy") if t.size else 0.0
    return t, terms, start if start > 0 else 1.0
