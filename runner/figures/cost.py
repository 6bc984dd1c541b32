"""What a method costs and what it buys: wall time per frame against the distance from a converged solve.

The numbers are the cost findings' (``simrun.findings.cost``: the same baseline, the same runs standing for each
method, the same distances), so that the figure and the report's sentences cannot disagree.
"""

from __future__ import annotations

import math
import re

import numpy as np
from matplotlib.lines import Line2D

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.figures._style import label_colours
from simrun.format.summary import FRAME_TIME

# Panels (comparisons: a dt, per setting of the other swept keys) drawn; the rest are named in a note.
MAX_COST_PANELS = 4
EXPLICIT_MARKER = "^"
IMPLICIT_MARKER = "o"
DRIFT_LABEL = "max |E − E$_0$| / E$_{ref}$"


def cost_vs_accuracy(data: FigureData):
    """Per comparison of the cost findings, two panels: the distance max |x - x_ref| from the baseline's positions
    (or, without a baseline, the error or the energy drift the findings use) and the largest energy change, each
    against the wall time per 1/60 s frame, one marker per method; the real-time line at 16.7 ms."""
    from simrun.analysis.rows import summary_rows
    from simrun.findings.cost import solver_cost  # the findings import the figures' data layer: on use, not at import

    rows = summary_rows(data)
    drift = {row.run_id: row.max_rel_energy_drift for row in rows}
    comparisons = [finding.evidence for finding in solver_cost(data, rows) if "methods" in finding.evidence]
    if not comparisons:
        return None
    shown = comparisons[:MAX_COST_PANELS]
    notes = []
    if len(comparisons) > len(shown):
        notes.append(f"{len(comparisons) - len(shown)} more comparisons (other dts or settings) are in the report's "
                     "cost findings")
    # a solver's variants together, numbers in numeric order (substeps=5 before substeps=10)
    names = sorted(dict.fromkeys(name for evidence in shown for name in evidence["methods"]), key=_natural)
    colours = label_colours(names)
    figure, axes = layout.panel_grid([[None, None] for _ in shown], panel_size=layout.SUMMARY_PANEL_SIZE,
                                     legend_width=3.4, extra_height=0.3)
    for number, evidence in enumerate(shown):
        distance_ax, drift_ax = axes[2 * number], axes[2 * number + 1]
        where = f"dt = {evidence['dt']:g} s" + "".join(f", {key} = {value}" for key, value in evidence["setting"].items())
        baseline = evidence["baseline"]
        by_distance = baseline is not None
        left_label = (f"max |x − x$_{{ref}}$| from {baseline} (m)" if by_distance
                      else "error (m)" if evidence["measure"] == "error" else DRIFT_LABEL)
        for ax, title in ((distance_ax, "distance from the converged solve" if by_distance else "accuracy"),
                          (drift_ax, "energy change (artificial damping)")):
            layout.log_log_panel(ax, f"{where}:\n{title}")  # two lines: a swept setting makes the first one long
            ax.axvline(1e3 * FRAME_TIME, color="0.35", ls=":", lw=1.0)
        left, right, floor_marker = [], [], None
        for name, method in evidence["methods"].items():
            x = 1e3 * method["wall_time_per_frame"]
            style = dict(color=colours[name], marker=EXPLICIT_MARKER if method["explicit"] else IMPLICIT_MARKER,
                         ls="none", ms=7, mec="black", mew=0.6)
            if by_distance and name == baseline:
                style.update(marker="*", ms=13)
            y = method["deviation"] if by_distance else method["measure"]
            if name != baseline and np.isfinite(y) and y > 0:
                distance_ax.plot([x], [y], **style)
                left.append(y)
            elif name == baseline:  # at distance 0: on the axis's floor, after the limits are known
                floor_marker = (x, style)
            change = drift.get(method["run_id"], math.nan)
            if np.isfinite(change) and change > 0:
                drift_ax.plot([x], [change], **style)
                right.append(change)
        for ax, values in ((distance_ax, left), (drift_ax, right)):
            limits = layout.log_limits(values)
            if limits is not None:
                ax.set_ylim(*limits)
        if floor_marker is not None:
            x, style = floor_marker
            distance_ax.plot([x], [distance_ax.get_ylim()[0]], clip_on=False, zorder=5, **style)
        distance_ax.set_ylabel(left_label)
        drift_ax.set_ylabel(DRIFT_LABEL)
        for ax in (distance_ax, drift_ax):
            ax.set_xlabel("wall time per 1/60 s frame (ms)")
            layout.tidy_log_axes(ax)
    baselines = {evidence["baseline"] for evidence in shown}
    explicit = {name for evidence in shown for name, method in evidence["methods"].items() if method["explicit"]}
    handles = [Line2D([], [], color=colours[name], ls="none", mec="black", mew=0.6, ms=7, label=name,
                      marker="*" if name in baselines else EXPLICIT_MARKER if name in explicit else IMPLICIT_MARKER)
               for name in names]
    handles.append(Line2D([], [], color="0.35", ls=":", lw=1.0, label="real time (16.7 ms per frame)"))
    layout.figure_legend(figure, handles)
    drawn = {method["run_id"] for evidence in shown for method in evidence["methods"].values()}
    implicit = sorted({run.label for run in data.runs if not run.explicit and run.run_id in drawn})
    solved = f" ({', '.join(implicit)})" if implicit else ""
    notes.append("★ the baseline (the fastest Newton run whose every step converged), drawn on the floor of its panel "
                 f"(distance 0); ▲ explicit methods; ○ implicit ones{solved}, named by their solver")
    if len(drawn) < len(data.runs):
        notes.append(f"{len(drawn)} of {len(data.runs)} runs: each method's fastest run (of its linear solvers) at the "
                     "largest and the smallest dt the methods share")
    layout.add_notes(figure, notes)
    layout.suptitle(figure, data, "cost against accuracy")
    return figure


def _natural(name: str) -> list:
    """A sort key that orders the numbers within names by value."""
    return [(0, float(part), "") if part[:1].isdigit() else (1, 0.0, part) for part in re.findall(r"\d+(?:\.\d+)?|\D+", name)]


__all__ = ["cost_vs_accuracy"]
