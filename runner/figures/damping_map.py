"""The damping map: the amplitude's decay per period over (h w, zeta) for each method, measured against predicted.

Runs of a linear oscillator (a system that declares one: the spring, damped or not, with ``natural_frequency`` w
and ``damping_ratio`` zeta) carry the decay per period they measured (``decay_per_period``: (V(t)/V(0))^(pi/(w t))
at their last usable sample, V the modal energy). One panel per method: the measured decay as colour (log10, one
scale for all panels; growth red, diverged cells hatched), its contours as white bands under the predicted ones
(black dashed, narrower: where they agree the dashes lie on the band, and both show) from the method's amplification matrix at every point (probed with the points as lanes:
analysis.amplification_matrices), the predicted stability boundary rho = 1 (thick red), and the physical decay
e^(-2 pi zeta) of the exact motion (orange dots, zeta < 1) for reference.
Each run is a cell; the panel title counts the cells a run did not fill (missing, failed) and the diverged ones.
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from matplotlib import patheffects
from matplotlib.colors import Normalize

from simrun.analysis.damping_map import FLOOR_DECADES, exact_decades, map_cells, predicted_decades
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.format.summary import Status

# growth (decay per period above 1) has a colour of its own, beyond the scale that ends at FLOOR_DECADES
GROWTH_COLOUR = "#d62728"
# a "growth" below this many decades per period is round-off of a kept amplitude (the implicit midpoint rule's
# undamped runs measure 1 + 1e-14), drawn as 0
GROWTH_ROUNDOFF = 1e-6
CONTOUR_LEVELS = (-3.0, -2.0, -1.0, -0.3, -0.1, -0.03, -0.01)
# The measured contours are wider than the predicted dashes drawn over them: where a method does what its
# amplification matrix predicts, the black dashes lie on a white band and both stay visible
MEASURED_WIDTH, PREDICTED_WIDTH = 2.2, 0.9


def damping_map(data: FigureData):
    points = map_cells(data)
    labels = list(points)
    if not labels:
        return None

    rows = layout.wrap(labels, columns=3)
    figure, axes = layout.panel_grid(rows, sharex=True, sharey=True, panel_size=(4.6, 3.6), legend_width=1.2)
    norm = Normalize(vmin=FLOOR_DECADES, vmax=0.0)
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.85", over=GROWTH_COLOUR)
    image = None
    notes = []
    for ax, label in zip(axes, labels):
        cells = points[label]
        hw, zeta = _axis_values(cells, 0), _axis_values(cells, 1)
        measured = np.full((zeta.size, hw.size), np.nan)
        diverged = np.zeros(measured.shape, dtype=bool)
        unfilled, duplicates = 0, 0
        for h, z, decay, status in cells:
            row, column = np.searchsorted(zeta, z), np.searchsorted(hw, h)
            if not math.isnan(measured[row, column]) or diverged[row, column]:
                duplicates += 1
                continue
            if status is Status.FAILED or not math.isfinite(decay) or decay <= 0.0:
                unfilled += 1
                continue
            measured[row, column] = math.log10(decay)
            diverged[row, column] = status is Status.DIVERGED
        grid_hw, grid_zeta = np.meshgrid(hw, zeta)
        predicted = predicted_decades(data, label, grid_hw.ravel(), grid_zeta.ravel())
        shown = np.where((measured > 0.0) & (measured <= GROWTH_ROUNDOFF), 0.0, np.maximum(measured, FLOOR_DECADES))
        image = ax.pcolormesh(_edges(hw, log=True), _edges(zeta, log=False), shown,
                              norm=norm, cmap=cmap, shading="flat", rasterized=True)
        finite = np.isfinite(measured)
        if finite.sum() >= 4 and np.ptp(measured[finite]) > 0:
            ax.contour(grid_hw, grid_zeta, np.where(finite, measured, np.nan), levels=CONTOUR_LEVELS, colors="w",
                       linewidths=MEASURED_WIDTH, zorder=2)
        if predicted is not None:
            predicted = predicted.reshape(grid_hw.shape)
            ax.contour(grid_hw, grid_zeta, np.clip(predicted, FLOOR_DECADES * 2, None), levels=CONTOUR_LEVELS,
                       colors="k", linewidths=PREDICTED_WIDTH, linestyles="--", zorder=3)
            if np.any(predicted > 1e-9) and np.any(predicted < 0.0):  # rho = 1 between: the boundary
                ax.contour(grid_hw, grid_zeta, predicted, levels=[1e-9], colors=GROWTH_COLOUR, linewidths=2.6)
        else:
            notes.append(f"{label}: no lane form to probe its amplification matrix; predicted contours not drawn")
        exact = np.where(grid_zeta < 1.0, exact_decades(grid_zeta), np.nan)
        if np.isfinite(exact).sum() >= 4 and np.ptp(exact[np.isfinite(exact)]) > 0:
            ax.contour(grid_hw, grid_zeta, exact, levels=CONTOUR_LEVELS, colors="orange", linewidths=1.3, linestyles=":")
        if diverged.any():
            ax.contourf(grid_hw, grid_zeta, diverged.astype(float), levels=[0.5, 1.5], colors="none", hatches=["xx"])
        counted = [f"{int(finite.sum())} cells"]
        if diverged.any():
            counted.append(f"{int(diverged.sum())} diverged (hatched)")
        if unfilled:
            counted.append(f"{unfilled} without a decay (grey)")
        if duplicates:
            counted.append(f"{duplicates} runs on a filled cell not shown")
        ax.set_title(f"{label}\n" + ", ".join(counted), fontsize=9)
        ax.set_xscale("log")
    layout.label_outer(axes, rows, "h w (time step × natural frequency)", "damping ratio ζ = d / (2 m w)")
    colourbar = figure.colorbar(image, ax=axes, shrink=0.6, pad=0.02, extend="both")
    colourbar.set_label("log₁₀ amplitude factor per period 2π/w, measured\n(red: growth; ≤ −4 shown as −4)", fontsize=9)
    handles = [plt.Line2D([], [], color="w", lw=MEASURED_WIDTH, label="measured (white band)",
                          path_effects=[patheffects.withStroke(linewidth=MEASURED_WIDTH + 1.2, foreground="0.45")]),
               plt.Line2D([], [], color="k", lw=PREDICTED_WIDTH, ls="--",
                          label="predicted, ρ(A)^(2π/hw), dashed\n(on the white band where they agree)"),
               plt.Line2D([], [], color=GROWTH_COLOUR, lw=2.6, label="stability boundary ρ = 1"),
               plt.Line2D([], [], color="orange", lw=1.3, ls=":", label="exact motion, e^(−2πζ)")]
    layout.figure_legend(figure, handles, "contours at log₁₀ " + ", ".join(f"{level:g}" for level in CONTOUR_LEVELS))
    layout.add_notes(figure, notes)
    layout.suptitle(figure, data, "damping map, decay of the amplitude per period")
    return figure


def _axis_values(cells: list, axis: int) -> np.ndarray:
    return np.array(sorted({cell[axis] for cell in cells}))


def _edges(centres: np.ndarray, log: bool) -> np.ndarray:
    """Cell edges around sorted centres: midpoints (geometric on a log axis), the ends mirrored."""
    values = np.log(centres) if log else centres
    if values.size == 1:
        edges = np.array([values[0] - 0.5, values[0] + 0.5])
    else:
        middle = 0.5 * (values[1:] + values[:-1])
        edges = np.concatenate([[2 * values[0] - middle[0]], middle, [2 * values[-1] - middle[-1]]])
    return np.exp(edges) if log else edges
