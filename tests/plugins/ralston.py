"""Ralston's third-order Runge-Kutta method as a simrun plug-in: an explicit method is its Butcher tableau.

Ralston (Math. Comp. 16 (1962) 431-437) chose the weights of the three-stage, third-order methods that bound the
truncation error best: c = (0, 1/2, 3/4), b = (2/9, 1/3, 4/9). simrun steps the tableau on u = (x, v).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from simrun.integrators import ButcherTableau, ExplicitRungeKutta


class Ralston3(ExplicitRungeKutta):
    name: ClassVar[str] = "ralston3"
    order: ClassVar[int] = 3
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "Ralston's three-stage third-order Runge-Kutta method"
    tableau: ClassVar[ButcherTableau] = ButcherTableau(
        A=((0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.75, 0.0)), b=(2.0 / 9.0, 1.0 / 3.0, 4.0 / 9.0),
        c=(0.0, 0.5, 0.75), order=3)

    def closed_form_spectral_radius(self, hw):
        """|R(i h w)|: three stages of order three make R(z) = 1 + z + z^2/2 + z^3/6."""
        z = 1j * np.asarray(hw, dtype=float)
        return np.abs(1.0 + z + z * z / 2.0 + z ** 3 / 6.0)
