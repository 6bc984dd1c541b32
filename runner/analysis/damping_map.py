"""The damping map's numbers, which its figure and its findings share: the cells of a method's runs of a linear
oscillator over (h w, zeta) with the decay per period each measured, the decay its amplification matrix predicts
there, and the exact motion's."""

from __future__ import annotations

import math

import numpy as np

from simrun.format.record import run_attribute
from simrun.analysis.runs import RunSet
from simrun.format.summary import Status

# a map needs this many distinct h w and zeta values for one method (fewer: the damping curves say it better)
MIN_HW, MIN_ZETA = 3, 2
# the colour scale, log10 of the decay per period, from "annihilated" (clipped below) to 0 (kept); growth has a colour
# of its own
FLOOR_DECADES = -4.0
DECIMALS = 9  # h w and zeta are told apart to this many significant digits (a grid of floats)


def map_cells(data: RunSet) -> dict[str, list[tuple[float, float, float, Status]]]:
    """label -> [(h w, zeta, measured decay per period, status)], in label order, for the labels whose runs of a
    linear oscillator (``natural_frequency``, ``damping_ratio``) span a map: MIN_HW values of h w, MIN_ZETA of zeta."""
    points: dict[str, list] = {}
    for run in data.runs:
        attrs = run.stored.attrs
        frequency, ratio = run_attribute(attrs, "natural_frequency"), run_attribute(attrs, "damping_ratio")
        if not (isinstance(frequency, float) and math.isfinite(frequency) and math.isfinite(ratio)):
            continue
        points.setdefault(run.label, []).append((_rounded(run.dt * frequency), _rounded(ratio),
                                                 float(run_attribute(attrs, "decay_per_period")), run.status))
    return {label: points[label] for label in data.labels if label in points
            and len({cell[0] for cell in points[label]}) >= MIN_HW and len({cell[1] for cell in points[label]}) >= MIN_ZETA}


def predicted_decades(data: RunSet, label: str, hw: np.ndarray, zeta: np.ndarray) -> np.ndarray | None:
    """log10 of the predicted amplitude factor per period, rho(A)^(2 pi / (h w)), of the method of ``label`` at each
    (h w, zeta), A probed with the points as lanes (or as a bank of springs); None where the method cannot be probed
    (its plug-in does not import here, it carries more than a number per spring, or its step is not linear: then it
    has no amplification matrix, and its runs are measured only)."""
    from simrun.analysis.oscillator import amplification_matrices, integrator_from_params  # on first use, as runs.py

    run = next(run for run in data.runs if run.label == label)
    try:
        method = integrator_from_params(run.integrator, run.integrator_params, run.stored.integrator_class)
    except ValueError:  # a plug-in that does not import where the file is read, or a method without the matrix
        return None
    matrices = amplification_matrices(method, hw, zeta)
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


def _rounded(value: float) -> float:
    return float(f"{value:.{DECIMALS}g}")
