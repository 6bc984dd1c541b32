"""The stability map: integrators x dt, coloured by the largest energy growth, with the predicted limits."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import TwoSlopeNorm

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData, RunData
from simrun.figures.theory import predictions_for, test_equation_runs
from simrun.results import Status

# Smallest half-range (decades) of the stability map's colour scale, so that round-off-sized
# changes stay pale instead of saturating the map.
MIN_GROWTH_DECADES = 1.0
# The stability map's key (two lines of 7.5-pt text) needs this width (in).
MAP_MIN_WIDTH = 6.0
# More stability-map columns than this get slanted dt labels.
MAP_COLUMNS_UPRIGHT = 8


def stability_map(data: FigureData):
    """Integrators (rows) x dt (columns), coloured by log10 of the largest energy growth."""
    panels = [(title, runs) for title, runs in data.groups[:layout.MAX_GROUPS]]
    signed = not all(run.energy.size and run.energy[0] > 0 and np.nanmin(run.energy) >= 0
                     for run in data.runs if run.has_series)
    tables = [_growth_table(runs, data.labels, signed) for _, runs in panels]
    values = np.concatenate([table[2].ravel() for table in tables])
    values = values[np.isfinite(values)]
    low = min(float(values.min()) if values.size else 0.0, -MIN_GROWTH_DECADES)
    high = max(float(values.max()) if values.size else 0.0, MIN_GROWTH_DECADES)
    norm = TwoSlopeNorm(vcenter=0.0, vmin=low, vmax=high)
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.93")
    widest = max(len(table[1]) for table in tables)
    size = (max(MAP_MIN_WIDTH, 1.0 + 0.75 * widest + 0.11 * max(map(len, data.labels))),
            0.9 + sum(0.45 * len(table[0]) + 0.7 for table in tables))
    figure, axes = plt.subplots(len(panels), 1, figsize=size, layout="constrained", squeeze=False)
    axes = axes.ravel()
    image, names = None, data.dt_names
    predictions = predictions_for(data) if test_equation_runs(data) else {}
    limits_drawn = False
    for (title, runs), (labels, dts, growth, statuses), ax in zip(panels, tables, axes):
        image = ax.imshow(np.ma.masked_invalid(growth), cmap=cmap, norm=norm, aspect="auto", interpolation="nearest")
        for row, column in np.ndindex(growth.shape):
            _annotate_cell(ax, row, column, growth[row, column], statuses[row][column], norm)
        limits_drawn |= _draw_predicted_limits(ax, labels, dts, runs, predictions)
        ax.set_xticks(range(len(dts)), [names[dt] for dt in dts], fontsize=8,
                      rotation=45 if len(dts) > MAP_COLUMNS_UPRIGHT else 0, ha="right" if len(dts) > MAP_COLUMNS_UPRIGHT else "center",
                      rotation_mode="anchor")
        ax.set_yticks(range(len(labels)), labels, fontsize=8)
        ax.set_xticks(np.arange(len(dts) + 1) - 0.5, minor=True)
        ax.set_yticks(np.arange(len(labels) + 1) - 0.5, minor=True)
        ax.grid(which="minor", color="white", lw=1.5)
        ax.tick_params(which="minor", length=0)
        ax.set_xlabel("time step dt (s)", fontsize=9)
        if title:
            ax.set_title(title, fontsize=9)
    what = "sign(ΔE)·log$_{10}$(1 + |ΔE| / |E$_0$|)" if signed else "log$_{10}$ (E / E$_0$)"
    colourbar = figure.colorbar(image, ax=list(axes), shrink=0.9, pad=0.02)
    colourbar.set_label(f"largest energy growth\n{what}", fontsize=8)
    colourbar.ax.tick_params(labelsize=7)
    present = {run.status for run in data.runs}
    marks = [note for status, note in ((Status.DIVERGED, "X diverged (value at divergence)"), (Status.FAILED, "! failed"),
                                       (Status.NOT_CONVERGED, "* solver did not converge in some steps")) if status in present]
    if limits_drawn:
        marks.append("┃ predicted stability limit (ρ > 1 to its right)")
    key = "blue: energy lost, red: gained" + ("\n" + ",   ".join(marks) if marks else "")
    more = f"  (first {layout.MAX_GROUPS} of {len(data.groups)} groups)" if len(data.groups) > layout.MAX_GROUPS else ""
    figure.suptitle(f"{data.name}: stability map" + more, fontsize=11)
    figure.supxlabel(key, fontsize=7.5, color="0.25")
    return figure


def _draw_predicted_limits(ax, labels: list[str], dts: list[float], runs: list[RunData], predictions: dict) -> bool:
    """A thick bar in each row at the predicted stability limit dt = (h w)* / w, between the columns it falls between.

    A limit below the smallest dt (forward Euler: unstable at every h) sits on the left edge; no
    bar when the limit lies beyond the largest dt. Only for runs on the undamped test equation.
    """
    frequency = next((run.frequency for run in runs if run.frequency is not None), None)
    if frequency is None:
        return False
    drawn = False
    log_dts = np.log(dts)
    for row, label in enumerate(labels):
        prediction = predictions.get(label)
        if prediction is None or not np.isfinite(prediction.stability_limit):
            continue
        limit_dt = prediction.stability_limit / frequency
        if limit_dt > dts[-1]:
            continue
        if limit_dt <= dts[0]:
            position = -0.5
        else:
            position = float(np.interp(math.log(limit_dt), log_dts, np.arange(len(dts))))
        ax.plot([position, position], [row - 0.5, row + 0.5], color="black", lw=3.0, solid_capstyle="butt", zorder=6)
        drawn = True
    return drawn


def _growth_table(runs: list[RunData], labels: list[str], signed: bool):
    """(row labels, sorted dts, growth (rows x dts; NaN where no value), statuses)."""
    rows = [label for label in labels if any(run.label == label for run in runs)]
    dts = sorted({run.dt for run in runs})
    growth = np.full((len(rows), len(dts)), np.nan)
    statuses = [[""] * len(dts) for _ in rows]
    for run in runs:
        row, column = rows.index(run.label), dts.index(run.dt)
        statuses[row][column] = run.status
        if run.has_change:
            growth[row, column] = _growth(run, signed)
    return rows, dts, growth, statuses


def _growth(run: RunData, signed: bool) -> float:
    """The largest excursion of the energy from E0 over the run, in decades (see the colour bar)."""
    energy = run.energy[np.isfinite(run.energy)]
    if signed:
        change = (energy - energy[0]) / run.energy_ref
        values = np.sign(change) * np.log10(1.0 + np.abs(change))
    else:
        values = np.log10(np.maximum(energy / energy[0], np.finfo(float).tiny))
    return float(values[np.argmax(np.abs(values))])


def _annotate_cell(ax, row: int, column: int, value: float, status: str, norm) -> None:
    """The value in the cell, an X over diverged runs, '!' for failed ones, '*' where the solver gave up."""
    if status == "":
        return
    if status == Status.FAILED and not np.isfinite(value):
        ax.text(column, row, "!", ha="center", va="center", fontsize=13, fontweight="bold", color="firebrick")
        return
    dark = np.isfinite(value) and abs(norm(value) - 0.5) > 0.3
    ink = "white" if dark else "black"
    if status == Status.DIVERGED:
        ax.plot(column, row, marker="x", ms=26, mew=2.0, color=ink, alpha=0.45)
    if abs(value) < 0.005:
        text = "0.00"  # no sign on a change that rounds to nothing
    else:
        text = f"{value:+.2f}" if abs(value) < 10 else f"{value:+.0f}"
    text += {Status.FAILED: " !", Status.NOT_CONVERGED: "*"}.get(status, "")
    ax.text(column, row, text, ha="center", va="center", fontsize=8, color=ink,
            fontweight="bold" if status == Status.DIVERGED else "normal")

