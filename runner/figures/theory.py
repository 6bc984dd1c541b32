"""Theory curves: the predicted artificial damping, spectral radius and period error of the integrators named in
the file (probed by ``simrun.analysis.oscillator``), with what the runs on the test equation measured as markers."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.transforms import blended_transform_factory

from simrun.analysis.runs import RunData, predictions_for, test_equation_runs
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.format.summary import Status

if TYPE_CHECKING:
    from simrun.analysis import oscillator as analysis

# Up to this many labels share one panel; more are split into families (one panel per integrator
# with several parameter values, one for the rest), so that the curves stay apart.
SHARED_PANEL_LABELS = 6
FAMILY_COLUMNS = 3
CURVE_PANEL_SIZE = (4.4, 3.3)
# Below zero the damping axis shows growth (rho > 1, dashed) down to this fraction of its top.
GROWTH_AXIS_FRACTION = 0.3
# A predicted damping below this (|d| / w) over the whole stable range is "no artificial damping".
NO_DAMPING = 1e-9
# The relative period error axis is cut here: beyond, the curves only say "far too slow".
PERIOD_ERROR_RANGE = (-0.5, 1.5)
RHO_AXIS_TOP = 1.3


def family_panels(predictions: dict[str, "analysis.Prediction"]) -> list[tuple[str, list[str]]]:
    """(title, labels) panels: all in one, or one per integrator with several parameter values plus one for the rest."""
    labels = list(predictions)
    by_name: dict[str, list[str]] = {}
    for label in labels:
        by_name.setdefault(predictions[label].integrator.name, []).append(label)
    families = {name: members for name, members in by_name.items() if len(members) > 1}
    if len(labels) <= SHARED_PANEL_LABELS or not families:
        return [("", labels)]
    singles = [label for label in labels if predictions[label].integrator.name not in families]
    panels = [("methods", singles)] if singles else []
    for name, members in families.items():
        dumps = [predictions[label].integrator.model_dump() for label in members]
        varied = [key for key in dumps[0] if len({json.dumps(dump[key]) for dump in dumps}) > 1]
        panels.append((f"{name}: {', '.join(varied)} varied" if varied else name, members))
    return panels


def _grid_rows(panels: list, columns: int = FAMILY_COLUMNS) -> list[list]:
    return [panels[start:start + columns] for start in range(0, len(panels), columns)]


def artificial_damping(data: FigureData):
    """d_method / w against h w: predicted lines (all labels), measured markers (undamped linear runs)."""
    return _predicted_and_measured(data, damping_figure, "artificial damping, predicted and measured")


def _predicted_and_measured(data: FigureData, draw, title: str):
    """A theory figure of the labels in the file, with the runs on the test equation as markers; None without such runs."""
    runs = test_equation_runs(data)
    predictions = predictions_for(data, runs) if runs else {}
    # the curves are of the fixed-step form; a step-controlled run has no one h w to mark
    fixed = [run for run in runs if not np.isfinite(run.tolerance)]
    if not predictions and not fixed:
        return None
    figure = draw(predictions, data.colours, data.markers, f"{data.name}: {title}", fixed)
    notes = []
    measured_only = _measured_only(fixed, predictions)
    if measured_only:
        notes.append("measured only, no curve (another code's run, or not simrun's fixed-step form: no amplification "
                     "matrix to probe): " + ", ".join(measured_only))
    unpredicted = [label for label in data.labels if label not in predictions and label not in measured_only]
    if unpredicted:
        notes.append("no curve (not simrun's fixed-step form: no amplification matrix to probe): " + ", ".join(unpredicted))
    if len(fixed) < len(runs):
        notes.append(f"{len(fixed)} of {len(runs)} runs on the test equation marked: under step control a run's h "
                     "changes from step to step, so it has no one h w")
    layout.add_notes(figure, notes)
    return figure


def _measured_only(runs: list[RunData], predictions: dict) -> list[str]:
    """The labels of ``runs`` without a prediction (a recorded trajectory, a peer), in the runs' order."""
    return [label for label in dict.fromkeys(run.label for run in runs) if label not in predictions]


def _damping_marker(ax, run: RunData, colour, marker: str, size: float, marked: set, diverged_marks: list) -> float:
    """The measured damping d/w of ``run`` as a marker on ``ax`` (hollow where the run does not resolve it; a stopped
    run queued for an x on the axis), noted in ``marked``; returns the value drawn (NaN: none)."""
    if run.status.stopped:
        diverged_marks.append((ax, run.hw, colour))
        marked.add(Status.DIVERGED)
        return math.nan
    fit = run.damping_fit
    if fit is None or not np.isfinite(fit.rate):
        return math.nan
    value = fit.rate / run.frequency
    style = dict(color=colour, marker=marker, ms=size, ls="none", zorder=4, mec="white", mew=0.6)
    if not fit.resolved:
        style.update(mfc="white", mec=colour, mew=1.2)
        marked.add("unresolved")
    else:
        marked.add("measured")
    ax.plot(run.hw, value, **style)
    return value


def damping_figure(predictions: dict[str, "analysis.Prediction"], colours: dict, markers: dict, title: str,
                   runs: list[RunData] = ()):
    """The damping curves (one panel per family), with the measured damping of `runs` as markers."""
    from simrun.analysis import oscillator as analysis  # on first use: importing the figures loads no integrator

    rows = _grid_rows(family_panels(predictions))
    figure, axes = layout.panel_grid(rows, sharey=True, panel_size=CURVE_PANEL_SIZE, legend_width=layout.FIGURE_LEGEND_WIDTH + 0.6)
    top, bottom, growth, marked = 0.0, 0.0, False, set()
    diverged_marks = []
    measured_only = _measured_only(runs, predictions)
    for (panel_title, labels), ax in zip(layout.flatten(rows), axes):
        drawn = []  # this panel's curves so far: a later identical one is dashed over them
        for number, label in enumerate(labels):
            prediction, colour = predictions[label], colours[label]
            stable = prediction.rho <= 1.0 + prediction.growth_tolerance
            damping = prediction.damping + 0.0  # no "-0" for rho = 1
            # later labels thinner, so that coinciding curves (backward Euler and its one-Newton-step twin) both show
            width = max(1.0, 2.0 - 0.3 * number)
            curve = (prediction.hw, np.where(stable, damping, np.nan))
            hidden = any(layout.same_curve(earlier, curve, unit=1.0) for earlier in drawn)
            drawn.append(curve)
            ax.plot(*curve, color=colour, lw=width, ls=layout.OVERLAY_DASHES if hidden else "-", zorder=3)
            if not stable.all():
                # dashed where rho > 1, joined to the solid part at the crossing
                unstable = ~stable | np.r_[~stable[1:], False]
                ax.plot(prediction.hw, np.where(unstable, damping, np.nan), "--", color=colour, lw=1.1, zorder=3)
                growth = True
            if stable.any():
                top = max(top, float(np.nanmax(damping[stable])))
            for run in (run for run in runs if run.label == label):
                value = _damping_marker(ax, run, colour, markers[label], max(4.0, 6.5 - 0.4 * number), marked,
                                        diverged_marks)
                top = max(top, value) if np.isfinite(value) else top
                bottom = min(bottom, value) if np.isfinite(value) else bottom
        if ax is axes[0]:  # the runs of codes simrun cannot probe (recorded trajectories, peers): measured only
            for label in measured_only:
                for run in (run for run in runs if run.label == label):
                    value = _damping_marker(ax, run, colours[label], markers[label], 6.5, marked, diverged_marks)
                    top = max(top, value) if np.isfinite(value) else top
                    bottom = min(bottom, value) if np.isfinite(value) else bottom
        ax.axhline(0.0, color="0.55", lw=0.8, zorder=1)
        ax.set_xscale("log")
        ax.set_title(panel_title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.08)
    top = max(top, 1e-3) * 1.08
    # measured values a hair below zero (round-off of energy-conserving methods) need no room for growth
    low = -GROWTH_AXIS_FRACTION * top if growth or bottom < -0.02 * top else -0.04 * top
    axes[0].set_ylim(low, top)
    for ax, x, colour in diverged_marks:
        edge = blended_transform_factory(ax.transData, ax.transAxes)
        ax.plot(x, 0.04, "x", color=colour, ms=7, mew=1.8, transform=edge, clip_on=False, zorder=5)
    layout.label_outer(axes, rows, "h w  (time step × natural frequency)", "d$_{method}$ / w  = −2 ln ρ / (h w)")
    handles = []
    seen: list[str] = []
    for label, prediction in predictions.items():
        stable = prediction.rho <= 1.0 + prediction.growth_tolerance
        # rho to the round-off of the coarser of the two probes (a float32 engine's is about 6e-5)
        resolution = [max(1e-10, analysis.ROUNDOFF_MARGIN * max(item.integrator.unit_roundoff
                                                                  for item in (predictions[other], prediction)))
                      for other in seen]
        twin = next((other for other, atol in zip(seen, resolution) if predictions[other].hw.shape == prediction.hw.shape
                     and np.allclose(predictions[other].rho, prediction.rho, rtol=0, atol=atol)), None)
        seen.append(label)
        notes = []
        rounding = analysis.ROUNDOFF_MARGIN * prediction.integrator.unit_roundoff
        if stable.any() and (np.nanmax(np.abs(prediction.damping[stable])) < NO_DAMPING
                             or np.nanmax(np.abs(prediction.rho[stable] - 1.0)) <= rounding):
            notes.append("no damping: on the axis")
        elif twin is not None:
            notes.append(f"= {twin} here")
        phrase = analysis.growth_phrase(prediction)
        if phrase is not None:
            notes.append(phrase)
        note = f"  ({'; '.join(notes)})" if notes else ""
        handles.append(Line2D([], [], color=colours[label], marker=markers[label] if runs else None, ms=layout.LEGEND_MARKER_SIZE,
                              lw=1.6, label=label + note))
    handles += [Line2D([], [], ls="none", color=colours[label], marker=markers[label], ms=layout.LEGEND_MARKER_SIZE,
                       label=f"{label}  (measured only)") for label in measured_only]
    if predictions:
        handles.append(Line2D([], [], ls="-", color="0.3", lw=1.6, label="predicted (amplification matrix)"))
    if growth:
        handles.append(Line2D([], [], ls="--", color="0.3", lw=1.1, label="predicted, ρ > 1: energy grows"))
    if "measured" in marked:
        handles.append(Line2D([], [], ls="none", marker="o", color="0.3", ms=6, label="measured: decay of ln E(t)"))
    if "unresolved" in marked:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.3", ms=6,
                              label="measured, not resolved by the run"))
    if Status.DIVERGED in marked:
        handles.append(Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="diverged: not fitted"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(title, fontsize=11)
    return figure


def spectral_radius_and_period(data: FigureData):
    """rho(h w) (top) and the relative period error (bottom), predicted; measured periods as markers."""
    return _predicted_and_measured(data, spectral_figure, "spectral radius and period error")


def spectral_figure(predictions: dict[str, "analysis.Prediction"], colours: dict, markers: dict, title: str,
                    runs: list[RunData] = ()):
    from simrun.analysis import oscillator as analysis  # on first use: importing the figures loads no integrator

    panels = family_panels(predictions)
    columns = len(panels)
    if columns == 1:  # one family: the two quantities side by side
        size = (2 * CURVE_PANEL_SIZE[0] + layout.FIGURE_LEGEND_WIDTH + 0.6, CURVE_PANEL_SIZE[1] + 0.6)
        figure, pair = plt.subplots(1, 2, figsize=size, layout="constrained", squeeze=False)
        grid = pair.reshape(2, 1)
    else:
        size = (CURVE_PANEL_SIZE[0] * columns + layout.FIGURE_LEGEND_WIDTH + 0.6, 2 * CURVE_PANEL_SIZE[1] + 0.6)
        figure, grid = plt.subplots(2, columns, figsize=size, layout="constrained", squeeze=False, sharex="row", sharey="row")
    measured = limits = False
    measured_only = _measured_only(runs, predictions)
    for column, (panel_title, labels) in enumerate(panels):
        radius_ax, period_ax = grid[0, column], grid[1, column]
        drawn = {"rho": [], "period": []}  # the curves of this column so far: a later identical one is dashed over them
        for number, label in enumerate(labels):
            prediction, colour = predictions[label], colours[label]
            for ax, key, values in ((radius_ax, "rho", prediction.rho), (period_ax, "period", prediction.period_error)):
                curve = (prediction.hw, np.asarray(values, dtype=float))
                hidden = any(layout.same_curve(earlier, curve, unit=1.0) for earlier in drawn[key])
                ax.plot(*curve, color=colour, lw=1.5, ls=layout.OVERLAY_DASHES if hidden else "-", zorder=3 if hidden else 2)
                drawn[key].append(curve)
            limit = prediction.stability_limit
            if 0.0 < limit < prediction.hw[-1]:
                radius_ax.plot(limit, 1.0, "o", color=colour, mfc="white", mew=1.4, ms=6, zorder=5)
                limits = True
            for run in (run for run in runs if run.label == label):
                if np.isfinite(run.period_error):
                    period_ax.plot(run.hw, run.period_error, ls="none", marker=markers[label], color=colour,
                                   ms=max(4.0, 6.5 - 0.25 * number), zorder=4)
                    measured = True
        if column == 0:  # the runs of codes simrun cannot probe (recorded trajectories, peers): measured only
            for label in measured_only:
                for run in (run for run in runs if run.label == label and np.isfinite(run.period_error)):
                    period_ax.plot(run.hw, run.period_error, ls="none", marker=markers[label], color=colours[label],
                                   ms=6.5, zorder=4)
                    measured = True
        radius_ax.axhline(1.0, color="0.55", lw=0.8, ls=":")
        period_ax.axhline(0.0, color="0.55", lw=0.8)
        period_ax.axvline(math.pi, color="0.55", lw=0.8, ls=":")
        for ax in (radius_ax, period_ax):
            ax.set_xscale("log")
            ax.grid(True, which="major", alpha=0.3)
            ax.tick_params(labelsize=8)
        radius_ax.set_title(panel_title, fontsize=9)
        radius_ax.set_xlabel("h w", fontsize=9)
        period_ax.set_xlabel("h w  (up to π: beyond, a step spans over half a period)", fontsize=8.5)
    growth = any(np.nanmax(prediction.rho) > 1.0 + prediction.growth_tolerance for prediction in predictions.values())
    grid[0, 0].set_ylim(0.0, RHO_AXIS_TOP if growth else 1.08)
    grid[0, 0].set_ylabel("spectral radius ρ(h w)", fontsize=9)
    # the period is defined up to h w = pi only: its row zooms onto that range
    low = min([prediction.hw[0] for prediction in predictions.values()] + [0.5 * min(run.hw for run in runs)] if runs
              else [prediction.hw[0] for prediction in predictions.values()])
    grid[1, 0].set_xlim(low, 1.3 * math.pi)
    if not predictions:  # only runs that no amplification matrix predicts: the radius is not measured by a run
        grid[0, 0].set_xlim(low, 1.3 * math.pi)
        grid[0, 0].text(0.5, 0.5, "no predicted ρ: every run here is measured only", transform=grid[0, 0].transAxes,
                        ha="center", va="center", fontsize=9, color="0.4")
    grid[1, 0].set_ylim(*PERIOD_ERROR_RANGE)
    grid[1, 0].set_ylabel("relative period error T$_h$/T − 1", fontsize=9)
    grid[1, 0].text(math.pi, 0.97 * PERIOD_ERROR_RANGE[1], "h w = π ", fontsize=7, color="0.4", va="top", ha="right")
    handles = [Line2D([], [], color=colours[label], lw=1.5, marker=markers[label] if measured else None,
                      ms=layout.LEGEND_MARKER_SIZE, label=label + _twin_note(label, predictions) + _limit_note(prediction))
               for label, prediction in predictions.items()]
    handles += [Line2D([], [], ls="none", color=colours[label], marker=markers[label], ms=layout.LEGEND_MARKER_SIZE,
                       label=f"{label}  (measured only)") for label in measured_only]
    if limits:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.3", mew=1.4, ms=6,
                              label="stability limit: ρ > 1 beyond"))
    if measured:
        handles.append(Line2D([], [], ls="none", marker="o", color="0.3", ms=6, label="measured period (zero crossings)"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(title, fontsize=11)
    return figure


def _twin_note(label: str, predictions: dict[str, "analysis.Prediction"]) -> str:
    """'  (= backward_euler here)' when an earlier label has the same ρ and period error curves (drawn dashed over it)."""
    mine = predictions[label]
    for other, prediction in predictions.items():
        if other == label:
            return ""
        if all(layout.same_curve((prediction.hw, np.asarray(a, dtype=float)), (mine.hw, np.asarray(b, dtype=float)), unit=1.0)
               for a, b in ((prediction.rho, mine.rho), (prediction.period_error, mine.period_error))):
            return f"  (= {other} here)"
    return ""


def _limit_note(prediction: "analysis.Prediction") -> str:
    from simrun.analysis import oscillator

    phrase = oscillator.growth_phrase(prediction)
    return "" if phrase is None else f"  ({phrase})"

