"""The findings of a damping map (runs of a linear oscillator over h w and the damping ratio zeta, the damping_map
figure): per method, from which h w it damps the motion noticeably more than the physics, and how closely the
measured decay per period follows the one its amplification matrix predicts.

The physics: the exact motion's amplitude falls by e^(-2 pi zeta) per period 2 pi / w below critical damping, and
by e^(-2 pi (zeta - sqrt(zeta^2 - 1))) (its slow mode) above it.
"""

from __future__ import annotations

import math

import numpy as np

from simrun.analysis.damping_map import FLOOR_DECADES, exact_decades, map_cells, predicted_decades
from simrun.findings.base import Finding
from simrun.format.summary import Status

# "noticeably more": the method keeps at most 90 % of the amplitude the exact motion keeps per period
NOTICEABLE = -math.log10(0.9)
# the findings read the cells below this damping ratio: towards critical damping the two roots meet, the motion's
# t e^(-w t) transient is not a decay per period, and the modal energy E + d q v / 2 degenerates (at zeta = 1)
UNDERDAMPED = 0.9


def map_findings(data) -> list[Finding]:
    points = map_cells(data)
    labels = list(points)
    if not labels:
        return []
    parts, evidence = [], {}
    for label in labels:
        cells = [cell for cell in points[label] if 0.0 <= cell[1] < UNDERDAMPED]
        if not cells:
            continue
        hw = np.array([cell[0] for cell in cells])
        zeta = np.array([cell[1] for cell in cells])
        with np.errstate(divide="ignore", invalid="ignore"):
            measured = np.log10(np.array([cell[2] for cell in cells]))
        kept = np.isfinite(measured) & np.array([cell[3] is Status.OK for cell in cells])
        excess = exact_decades(zeta) - measured  # decades per period the method takes beyond the physics
        noticeable = kept & (excess >= NOTICEABLE)
        item = {"cells": int(kept.sum())}
        if noticeable.any():
            first = int(np.argmin(np.where(noticeable, hw, np.inf)))
            item.update(from_hw=float(hw[first]), at_zeta=float(zeta[first]))
            text = f"{label} from h w = {hw[first]:.3g} (at ζ = {zeta[first]:.3g})"
        else:
            text = f"{label} nowhere in the map"
        predicted = predicted_decades(data, label, hw, zeta)
        if predicted is not None:
            # the cells whose decay is resolved (above the colour floor) and that stayed bounded
            compared = kept & np.isfinite(predicted) & (predicted > FLOOR_DECADES) & (measured > FLOOR_DECADES)
            if compared.any():
                gap = float(np.max(np.abs(measured[compared] - predicted[compared])))
                item["largest_gap_decades"] = gap
                text += f" (measured within {gap:.1g} decades of predicted per period)"
        evidence[label] = item
        parts.append(text)
    if not parts:
        return []
    hw_all = [cell[0] for label in labels for cell in points[label]]
    zeta_all = [cell[1] for label in labels for cell in points[label] if 0.0 <= cell[1] < UNDERDAMPED]
    sentence = (f"Damping map (h w {min(hw_all):.3g}–{max(hw_all):.3g}, ζ {min(zeta_all):.3g}–{max(zeta_all):.3g}, "
                f"below ζ = {UNDERDAMPED:g}): each method keeps at most 90 % of the amplitude that the exact motion keeps "
                "per period, measured: " + "; ".join(parts) + ".")
    return [Finding(sentence, "#figure-damping_map", {"noticeable_decades": NOTICEABLE, "methods": evidence}, "damping")]
