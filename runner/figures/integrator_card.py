"""The integrator card of ``simrun check-integrator``: a method on the test spring, at damping ratios 0 and 0.1,
against h w: spectral radius (with the method's closed form where it declares one), artificial damping d/w and the
relative period error, the stability limit marked; the observed orders beside."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np

from simrun.figures import _layout as layout

if TYPE_CHECKING:
    from simrun.contracts.integrator import IntegratorCard

RATIO_STYLES = {0.0: dict(color="C0", linestyle="-"), 0.1: dict(color="C1", linestyle="--")}
# d/w and period errors below this are drawn at it (a log axis; exact zeros are round-off)
LOG_FLOOR = 1e-16


def card_figure(card: "IntegratorCard"):
    """Three panels side by side, and the orders and the stability limit in the title."""
    figure, axes = plt.subplots(1, 3, figsize=(15.0, 4.6), layout="constrained")
    radius_axis, damping_axis, period_axis = axes
    measured = card.source == "measured runs"
    marker = dict(marker="o", markersize=4) if measured else {}
    for ratio, curves in card.curves.items():
        style = {**RATIO_STYLES.get(ratio, {}), **marker}
        name = f"zeta = {ratio:g}"
        radius_axis.plot(card.hw, curves["spectral_radius"], label=name, **style)
        damping_axis.plot(card.hw, np.clip(np.abs(curves["damping"]), LOG_FLOOR, None), label=name, **style)
        period_axis.plot(card.hw, np.clip(np.abs(curves["period_error"]), LOG_FLOOR, None), label=name, **style)
    if card.closed_form is not None:
        radius_axis.plot(card.hw, card.closed_form, color="black", linestyle=":", linewidth=2.0,
                         label="declared closed form (zeta = 0)")
    if math.isfinite(card.stability_limit) and card.stability_limit > 0:
        for axis in axes:
            axis.axvline(card.stability_limit, color="red", linewidth=1.0, alpha=0.6)
        what = "first diverged run" if card.source == "measured runs" else "stability limit"
        radius_axis.annotate(f"{what}\nh w = {card.stability_limit:.3g}", (card.stability_limit, 0.05),
                             xycoords=("data", "axes fraction"), color="red", fontsize=8, ha="right")
    radius_axis.set(xscale="log", ylabel="spectral radius rho (1)", title="spectral radius")
    largest = np.nanmax(np.concatenate([curves["spectral_radius"] for curves in card.curves.values()]), initial=1.0)
    radius_axis.set_ylim(0.0, max(1.05, min(2.0, float(largest) * 1.05)))
    damping_axis.set(xscale="log", ylabel="|artificial damping| d/w (1)",
                     title="artificial damping (beyond the physical 2 zeta w)")
    period_axis.set(xscale="log", ylabel="|relative period error| |T/T_exact - 1| (1)", title="period error")
    for axis, key in ((damping_axis, "damping"), (period_axis, "period_error")):
        values = np.concatenate([curves[key] for curves in card.curves.values()])
        if np.any(np.isfinite(values)):
            axis.set_yscale("log")
        else:  # nothing to draw: say so rather than leave an empty frame
            axis.text(0.5, 0.5, f"no {key.replace('_', ' ')} defined at any h w of the grid", transform=axis.transAxes,
                      ha="center", va="center", fontsize=9)
    for axis in axes:
        axis.set_xlabel("h w (time step x angular frequency, dimensionless)")
        axis.grid(True, which="both", alpha=0.3)
        if axis.get_legend_handles_labels()[0]:
            axis.legend(fontsize=8, loc="best")
    figure.suptitle(_title(card), fontsize=11)
    return figure


def _title(card: "IntegratorCard") -> str:
    orders = ", ".join(f"observed order {order.order:.2f} ({problem})" if math.isfinite(order.order)
                       else f"exact ({problem})" if order.exact else f"no order ({problem})"
                       for problem, order in card.orders.items())
    rho_inf = f", rho_inf = {card.rho_inf:.3g}" if math.isfinite(card.rho_inf) else ""
    source = "from the amplification matrix" if card.source == "amplification matrix" else \
        "measured from runs (the step is not linear)"
    return f"{card.label}: integrator card, {source}{rho_inf}" + (f"\n{orders}" if orders else "")


def save_card(card: "IntegratorCard", path, svg: bool = False) -> list:
    """The card as PNG (and SVG) at ``path`` without its suffix; the files written."""
    figure = card_figure(card)
    try:
        return layout.save_figure(figure, path, formats=layout.VECTOR_FORMATS if svg else layout.FORMATS)
    finally:
        plt.close(figure)
