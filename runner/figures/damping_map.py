"""The damping map: the amplitude's decay per period over (h w, zeta) for each method, measured against predicted.

Runs of a linear oscillator (a system that declares one: the spring, damped or not, with ``natural_frequency`` w
and ``damping_ratio`` zeta) carry the decay per period they measured (``decay_per_period``: (V(t)/V(0))^(pi/(w t))
at their last usable sample, V the modal energy). One panel per method: the measured decay as colour (log10, one
scale for all panels; growth red, diverged cells hatched), its contours (white) over the predicted ones (black
dashed) from the method's amplification matrix at every point (probed with the points as lanes:
analysis.amplification_matrices), the predicted stability boundary rho = 1 (thick red), and the physical decay
e^(-2 pi zeta) of the exact motion (orange dots, zeta < 1) for reference.
Each run is a cell; the panel title counts the cells a run did not fill (missing, failed) and the diverged ones.
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import Normalize

from simrun.figures import _layout as layout
from simrun.figures._data import FigureData
from simrun.results import Status

# a map needs this many distinct h w and zeta values for one method (fewer: the damping curves say it better)
MIN_HW, MIN_ZETA = 3, 2
# the colour scale, log10 of the decay per period, from "annihilated" (clipped below) to 0 (kept); growth has a colour
# of its own
FLOOR_DECADES = -4.0
GROWTH_COLOUR = "#d62728"
# a "growth" below this many decades per period is round-off of a kept amplitude (the implicit midpoint rule's
# undamped runs measure 1 + 1e-14), drawn as 0
GROWTH_ROUNDOFF = 1e-6
CONTOUR_LEVELS = (-3.0, -2.0, -1.0, -0.3, -0.1, -0.03, -0.01)
DECIMALS = 9  # h w and zeta are told apart to this many significant digits (a grid of floats)


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
                       linewidths=0.8)
        if predicted is not None:
            predicted = predicted.reshape(grid_hw.shape)
            ax.contour(grid_hw, grid_zeta, np.clip(predicted, FLOOR_DECADES * 2, None), levels=CONTOUR_LEVELS,
                       colors="k", linewidths=1.0, linestyles="--")
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
    handles = [plt.Line2D([], [], color="0.55", lw=0.8, label="measured (white contours)"),
               plt.Line2D([], [], color="k", lw=1.0, ls="--", label="predicted, ρ(A)^(2π/hw)"),
               plt.Line2D([], [], color=GROWTH_COLOUR, lw=2.6, label="stability boundary ρ = 1"),
               plt.Line2D([], [], color="orange", lw=1.3, ls=":", label="exact motion, e^(−2πζ)")]
    layout.figure_legend(figure, handles, "contours at log₁₀ " + ", ".join(f"{level:g}" for level in CONTOUR_LEVELS))
    layout.add_notes(figure, notes)
    layout.suptitle(figure, data, "damping map, decay of the amplitude per period")
    return figure


def map_cells(data: FigureData) -> dict[str, list[tuple[float, float, float, Status]]]:
    """label -> [(h w, zeta, measured decay per period, status)], in label order, for the labels whose runs of a
    linear oscillator (``natural_frequency``, ``damping_ratio``) span a map: MIN_HW values of h w, MIN_ZETA of zeta."""
    points: dict[str, list] = {}
    for run in data.runs:
        attrs = run.stored.attrs
        frequency, ratio = attrs.get("natural_frequency", math.nan), attrs.get("damping_ratio", math.nan)
        if not (isinstance(frequency, float) and math.isfinite(frequency) and math.isfinite(ratio)):
            continue
        points.setdefault(run.label, []).append((_rounded(run.dt * frequency), _rounded(ratio),
                                                 float(attrs.get("decay_per_period", math.nan)), run.status))
    return {label: points[label] for label in data.labels if label in points
            and len({cell[0] for cell in points[label]}) >= MIN_HW and len({cell[1] for cell in points[label]}) >= MIN_ZETA}


def predicted_decades(data: FigureData, label: str, hw: np.ndarray, zeta: np.ndarray) -> np.ndarray | None:
    """log10 of the predicted amplitude factor per period, rho(A)^(2 pi / (h w)), of the method of ``label`` at each
    (h w, zeta), A probed with the points as lanes; None for a method without a lane form."""
    from simrun.analysis import amplification_matrices, integrator_from_params

    run = next(run for run in data.runs if run.label == label)
    matrices = amplification_matrices(integrator_from_params(run.integrator, run.integrator_params), hw, zeta)
    if matrices is None:
        return None
    rho = np.max(np.abs(np.linalg.eigvals(matrices)), axis=1)
    with np.errstate(divide="ignore"):
        return np.log10(rho) * (2.0 * math.pi / np.asarray(hw))


def exact_decades(zeta) -> np.ndarray:
    """log10 of the exact motion's amplitude factor per period 2 pi / w, for damping ratios zeta >= 0: e^(-2 pi zeta)
    below critical damping, its slow mode's e^(-2 pi (zeta - sqrt(zeta^2 - 1))) above."""
    zeta = np.asarray(zeta, dtype=float)
    slow = np.where(zeta < 1.0, zeta, zeta - np.sqrt(np.maximum(zeta * zeta - 1.0, 0.0)))
    return -2.0 * math.pi * slow / math.log(10.0)


def _axis_values(cells: list, axis: int) -> np.ndarray:
    return np.array(sorted({cell[axis] for cell in cells}))


def _rounded(value: float) -> float:
    return float(f"{value:.{DECIMALS}g}")


def _edges(centres: np.ndarray, log: bool) -> np.ndarray:
    """Cell edges around sorted centres: midpoints (geometric on a log axis), the ends mirrored."""
    values = np.log(centres) if log else centres
    if values.size == 1:
        edges = np.array([values[0] - 0.5, values[0] + 0.5])
    else:
        middle = 0.5 * (values[1:] + values[:-1])
        edges = np.concatenate([[2 * values[0] - middle[0]], middle, [2 * values[-1] - middle[-1]]])
    return np.exp(edges) if log else edges
