"""How the tables, findings and report write a derived quantity: the number formats they share, units included."""

from __future__ import annotations

import numpy as np

from simrun.analysis.rows import ROUND_OFF_DAMPING


def real_time_text(value: float) -> str:
    """The real-time factor: "0.31x", "12x", "1234x"; "–" when unknown. Two digits: timing is noisier than that."""
    if value is None or not np.isfinite(value):
        return "–"
    return f"{value:.0f}x" if value >= 10 else f"{value:.2g}x"


def frame_time_text(value: float) -> str:
    """Wall time per 1/60 s frame (given in s) in ms: "16.7", "0.42"; "–" when unknown."""
    return "–" if value is None or not np.isfinite(value) else f"{1e3 * value:.3g}"


def distance_text(value: float) -> str:
    """A contact distance (given in m) in mm, "−0.19 mm" for a penetration; "none" when nothing came near (inf)."""
    if value is None or np.isnan(value):
        return "–"
    if not np.isfinite(value):
        return "none"
    return f"{1e3 * value:.3g} mm".replace("-", "−")


def damping_text(value: float) -> str:
    """d/w with round-off shown as 0 (rho = 1 to the last bits gives |d/w| ~ 1e-15)."""
    return "0" if np.isfinite(value) and abs(value) < ROUND_OFF_DAMPING else number_text(value)


def number_text(value: float) -> str:
    if value is None or not np.isfinite(value):
        return "–" if value is None or np.isnan(value) else ("inf" if value > 0 else "-inf")
    if value == 0:
        return "0"
    if 1e-3 <= abs(value) < 1e4:
        return f"{value:.4g}"
    return f"{value:.2e}"
