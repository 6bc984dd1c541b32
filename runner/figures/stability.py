"""The stability map: integrators x dt, coloured by the largest energy growth, with the predicted limits."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import Normalize
from matplotlib.ticker import MaxNLocator

from simrun.analysis.runs import RunData, explicit_prediction, predictions_for, test_equation_runs
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.format.summary import Status

# Smallest half-range (decades) of the stability map's colour scale, so that round-off-sized
# changes stay pale instead of saturating the map.
MIN_GROWTH_DECADES = 1.0
# The stability map's key (two lines of 7.5-pt text) needs this width (in).
MAP_MIN_WIDTH = 6.0
# Tables of several sections sit side by side up to this width (in), one above the other beyond.
MAP_MAX_WIDTH = 16.0
# More stability-map columns than this get slanted dt labels.
MAP_COLUMNS_UPRIGHT = 8


def stability_map(data: FigureData):
    """Lines (integrators, at a setting of the keys drawn as lines; rows) x dt (columns), one table per section,
    coloured by the largest energy change in decades: every run of the file, a number in each cell.

    The colour scale is symmetric about 0 (as much blue for a loss as red for a gain of as many decades), so
    that its ticks read on both sides of 0."""
    if not data.runs:
        return None
    panels = [(title, runs) for title, runs in data.sections]
    signed = not all(run.energy.size and run.energy[0] > 0 and np.nanmin(run.energy) >= 0
                     and math.isclose(run.energy_ref, run.energy[0], rel_tol=1e-9)
                     for run in data.runs if run.has_series)
    tables = [_growth_table(runs, data, signed) for _, runs in panels]
    values = np.concatenate([table[2].ravel() for table in tables])
    values = values[np.isfinite(values)]
    half = max(float(np.max(np.abs(values))) if values.size else 0.0, MIN_GROWTH_DECADES)
    norm = Normalize(vmin=-half, vmax=half)
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.93")
    widest = max(len(table[1]) for table in tables)
    longest = max(len(series.name) for table in tables for series in table[0])
    # tables side by side while they fit the width of a page, else one above the other
    table_width = 0.75 * widest + 0.075 * longest + 0.6
    columns = max(1, min(len(tables), int(MAP_MAX_WIDTH // table_width)))
    grid: list[list[int]] = []  # consecutive tables with as many rows share a row of the grid (and its height)
    for number, table in enumerate(tables):
        if grid and len(grid[-1]) < columns and len(tables[grid[-1][0]][0]) == len(table[0]):
            grid[-1].append(number)
        else:
            grid.append([number])
    heights = [max(len(tables[number][0]) for number in row) for row in grid]
    size = (max(MAP_MIN_WIDTH, 1.4 + table_width * max(len(row) for row in grid)),
            1.3 + sum(0.42 * height + 0.8 for height in heights))
    figure, cells = plt.subplots(len(grid), max(len(row) for row in grid), figsize=size, layout="constrained",
                                 squeeze=False, height_ratios=[height + 1.5 for height in heights])
    axes = [cells[number, column] for number, row in enumerate(grid) for column in range(len(row))]
    for number, row in enumerate(grid):
        for ax in cells[number, len(row):]:
            ax.set_visible(False)
    first_column = {id(cells[number, 0]) for number in range(len(grid))}
    image, names = None, data.dt_names
    predictions = predictions_for(data) if test_equation_runs(data) else {}  # off it: each method's explicit form
    limits_drawn = False
    for (title, runs), (rows, dts, growth, statuses), ax in zip(panels, tables, axes):
        image = ax.imshow(np.ma.masked_invalid(growth), cmap=cmap, norm=norm, aspect="auto", interpolation="nearest")
        for row, column in np.ndindex(growth.shape):
            _annotate_cell(ax, row, column, growth[row, column], statuses[row][column], norm)
        limits_drawn |= _draw_predicted_limits(ax, [series.label for series in rows], dts, runs, predictions)
        slanted = len(dts) > MAP_COLUMNS_UPRIGHT
        ax.set_xticks(range(len(dts)), [names[dt] for dt in dts], fontsize=8, rotation=45 if slanted else 0,
                      ha="right" if slanted else "center", rotation_mode="anchor")
        ax.set_yticks(range(len(rows)), [series.name for series in rows], fontsize=8)
        ax.set_xticks(np.arange(len(dts) + 1) - 0.5, minor=True)
        ax.set_yticks(np.arange(len(rows) + 1) - 0.5, minor=True)
        ax.grid(which="minor", color="white", lw=1.5)
        ax.tick_params(which="minor", length=0)
        ax.set_xlabel("time step dt (s)", fontsize=8)
        if data.legend_title and id(ax) in first_column:
            ax.set_ylabel(data.legend_title.rstrip(":"), fontsize=8)
        if title:
            ax.set_title(title, fontsize=9)
    if signed:
        what = "sign(ΔE)·log$_{10}$(1 + |E − E$_0$| / E$_{ref}$)"
    else:
        what = "log$_{10}$(E / E$_{ref}$)"
    colourbar = figure.colorbar(image, ax=list(axes), shrink=min(0.9, 4.0 / size[1] + 0.3), pad=0.02, aspect=30)
    colourbar.locator = MaxNLocator(nbins=8, symmetric=True)
    colourbar.update_ticks()
    reference = layout.energy_label(data.runs, "").strip()
    colourbar.set_label(f"largest energy change (decades)\n{what}\n{reference}", fontsize=8)
    colourbar.ax.tick_params(labelsize=7)
    present = {run.status for run in data.runs}
    marks = [note for status, note in ((Status.DIVERGED, "X diverged (value at divergence)"), (Status.FAILED, "! failed"),
                                       (Status.NOT_CONVERGED, "* solver did not converge in some steps")) if status in present]
    if limits_drawn:
        marks.append("┃ predicted stability limit (ρ > 1 to its right)")
    layout.suptitle(figure, data, "stability map (every run)")
    layout.add_notes(figure, ["blue: energy lost, red: gained", ",   ".join(marks)])
    return figure


def _draw_predicted_limits(ax, labels: list[str], dts: list[float], runs: list[RunData], predictions: dict) -> bool:
    """A thick bar in each row at the predicted stability limit dt = (h w)* / w, between the columns it falls between.

    On the undamped test equation w is its frequency and (h w)* the method's limit. Elsewhere w is the frequency
    that bounds the method's step at the start shape (an explicit method's stiffest; IMEX Euler's of K_E - K_I:
    integrators/imex.py), and (h w)* the limit of the method's explicit form. A limit below the smallest
    dt (forward Euler: unstable at every h) sits on the left edge; no bar when the limit lies beyond the largest dt.
    """
    drawn = False
    log_dts = np.log(dts)
    for row, label in enumerate(labels):
        limit_dt = _limit_dt(label, runs, predictions)
        if limit_dt is None or limit_dt > dts[-1]:
            continue
        if limit_dt <= dts[0]:
            position = -0.5
        else:
            position = float(np.interp(math.log(limit_dt), log_dts, np.arange(len(dts))))
        ax.plot([position, position], [row - 0.5, row + 0.5], color="black", lw=3.0, solid_capstyle="butt", zorder=6)
        drawn = True
    return drawn


def _limit_dt(label: str, runs: list[RunData], predictions: dict) -> float | None:
    """s: the predicted stability limit of the runs of ``label`` (see _draw_predicted_limits), or None."""
    members = [run for run in runs if run.label == label]
    test_run = next((run for run in members if run.frequency is not None), None)
    if test_run is not None:
        prediction = predictions.get(label)
        frequency = test_run.frequency
    else:
        explicit_run = next((run for run in members if run.explicit_frequency and run.method is not None), None)
        if explicit_run is None:
            return None
        prediction, frequency = explicit_prediction(explicit_run.method), explicit_run.explicit_frequency
    if prediction is None or not np.isfinite(prediction.stability_limit):
        return None
    return prediction.stability_limit / frequency


def _growth_table(runs: list[RunData], data: FigureData, signed: bool):
    """(row series, sorted dts, growth (rows x dts; NaN where no value), statuses)."""
    rows = list(dict.fromkeys(data.series_of(run) for run in layout.in_label_order(runs, data)))
    dts = sorted({run.dt for run in runs})
    growth = np.full((len(rows), len(dts)), np.nan)
    statuses = [[""] * len(dts) for _ in rows]
    for run in runs:
        row, column = rows.index(data.series_of(run)), dts.index(run.dt)
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
    else:  # E_ref = E0 > 0 and E >= 0: decades of growth or loss
        values = np.log10(np.maximum(energy / run.energy_ref, np.finfo(float).tiny))
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

