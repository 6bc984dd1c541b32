"""The ``step_control`` block of a config: adaptive steps chosen by a local error estimate.

The error of a step is measured as scipy's ``solve_ivp`` measures it, so that a sweep of tolerances means the same
for simrun's methods and for scipy's: on u = (x, v), the estimate e of the step's local error, scaled per component by
``absolute_tolerance + tolerance * max(|u_n|, |u_{n+1}|)``, in the rms (or max) norm over the free degrees of freedom;
a step is accepted when that norm is at most 1. The controller is the executor's (runner/execution/step_control.py).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

# the controllers' exponents, as multiples of 1/q (q the estimate's order): the I controller h (1/err)^(1/q), and the
# PI controller of Gustafsson (1991) in Hairer & Wanner's form (Solving ODEs II, sec. IV.8, eq. 8.21; DOPRI5's
# beta = 0.04 for q = 5): h (1/err)^(0.7/q) err_previous^(0.4/q)
PI_EXPONENTS = (0.7, 0.4)


class StepControlParams(BaseModel):
    """Adaptive steps: the tolerance, the norm, the controller and the bounds of the step."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    tolerance: float = Field(1e-6, gt=0, lt=1, allow_inf_nan=False,
                             description="the relative tolerance of each step's local error (scipy's rtol)")
    absolute_tolerance: float | None = Field(None, gt=0, allow_inf_nan=False,
                                             description="the absolute tolerance (m for positions, m/s for velocities; "
                                                         "scipy's atol); default: the same number as tolerance")
    norm: Literal["rms", "max"] = Field("rms", description="rms (scipy's, Hairer's) or max over the free dofs")
    controller: Literal["pi", "i"] = Field("pi", description="pi (Gustafsson's, which damps the step's oscillation) "
                                                            "or i (the elementary controller)")
    estimate: Literal["method", "richardson", "auto"] = Field(
        "method", description="method: the method's own estimate (embedded pair, TR-BDF2's, Radau's); richardson: "
                              "two half steps against one whole, for any one-step method; auto: the method's own "
                              "where it has one, else Richardson's")
    dt_initial: float | Literal["auto"] = Field(
        "auto", description="the first step (s); auto: Hairer's choice from the first derivatives (scipy's)")
    dt_min: float = Field(1e-12, gt=0, allow_inf_nan=False,
                          description="a step that must fall below this (s) ends the run, failed")
    dt_max: float | None = Field(None, gt=0, allow_inf_nan=False, description="the largest step (s); default: none")
    safety: float = Field(0.9, gt=0, lt=1, description="the controller's factor on its proposed step")

    @model_validator(mode="after")
    def _consistent(self) -> "StepControlParams":
        if self.dt_max is not None and self.dt_min > self.dt_max:
            raise ValueError(f"dt_min: {self.dt_min:g} s is more than dt_max {self.dt_max:g} s")
        if self.dt_initial != "auto":
            if not (math.isfinite(self.dt_initial) and self.dt_initial > 0):
                raise ValueError(f"dt_initial: expected 'auto' or a step > 0 (s), got {self.dt_initial!r}")
            if self.dt_initial < self.dt_min or (self.dt_max is not None and self.dt_initial > self.dt_max):
                raise ValueError(f"dt_initial: {self.dt_initial:g} s is outside [dt_min, dt_max]")
        return self

    @property
    def atol(self) -> float:
        return self.tolerance if self.absolute_tolerance is None else self.absolute_tolerance


def uses_richardson(step_control: StepControlParams, integrator) -> bool:
    """Whether ``integrator``'s steps are controlled by Richardson's estimate (asked for, or auto without its own)."""
    return step_control.estimate == "richardson" or (step_control.estimate == "auto" and integrator.error_estimate is None)


def estimate_refusal(step_control: StepControlParams, integrator) -> str | None:
    """Why ``integrator`` cannot take ``step_control``'s adaptive steps (one line), or None."""
    if integrator.whole_run:  # a peer: its own code controls its steps, at the block's tolerances
        return None
    if integrator.fixed_steps_only:
        return (f"{integrator.label} takes steps of one size (its engine's time step is a model option): sweep dt "
                "instead of step_control")
    if uses_richardson(step_control, integrator):
        if integrator.carries_history:
            return (f"{integrator.label} carries a history of states at its own past steps: a Richardson estimate "
                    "(two half steps from the same state) is not its step")
        return None
    if integrator.error_estimate is None:
        return (f"{integrator.label} has no error estimate of its own; methods that have one: dopri5, trbdf2, "
                "rosenbrock, radau_iia (3 stages), bdf; or set step_control.estimate: richardson (or auto)")
    return None
