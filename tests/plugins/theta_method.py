"""The theta-method as a simrun plug-in: one incremental potential a step (a StepPlan).

    x_{n+1} = x_n + h [(1 - theta) v_n + theta v_{n+1}],   v_{n+1} = v_n + h [(1 - theta) a_n + theta a_{n+1}],

with M a = f(x, v) at each end of the step; theta = 1 is backward Euler, theta = 1/2 the trapezoidal rule (Hughes,
The Finite Element Method, sec. 8.2, on the first-order form). In y = x_{n+1}: M (y - y~) = (theta h)^2 f(y, v(y)),
y~ = x_n + h v_n + theta (1 - theta) h^2 a_n, v(y) = (y - x_n - (1 - theta) h v_n) / (theta h). The acceleration a_n
is carried from step to step (State.aux), so every array of the plan is linear in the step's start state.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from simrun.integrators import Integrator, State
from simrun.integrators.base import StepPlan


class ThetaMethod(Integrator):
    name: ClassVar[str] = "theta_method"
    order: ClassVar[int] = 1  # 2 at theta = 1/2: order_of_accuracy says which
    explicit: ClassVar[bool] = False
    summary: ClassVar[str] = "the theta-method on (x, v): backward Euler at 1, the trapezoidal rule at 1/2"
    problem_kind: ClassVar[str | None] = "incremental_potential"
    started_aux: ClassVar[tuple[str, ...]] = ("acceleration",)

    theta: float = Field(0.6, ge=0.5, le=1.0, description="the weight of the step's end (1/2 ... 1)")

    @property
    def order_of_accuracy(self) -> int:
        return 2 if self.theta == 0.5 else 1

    def start(self, system, state):
        return State(state.t, state.x, state.v, (system.acceleration(state.x, state.v),))

    def plan(self, state, dt):
        theta, (acceleration,) = self.theta, state.aux
        return StepPlan(y_tilde=state.x + dt * state.v + (theta * (1.0 - theta) * dt * dt) * acceleration,
                        scale=(theta * dt) ** 2, velocity_origin=state.x + ((1.0 - theta) * dt) * state.v,
                        velocity_divisor=theta * dt, damping_at=state.x)

    def finish(self, state, plan, y, dt):
        v = (y - plan.velocity_origin) / plan.velocity_divisor
        acceleration = (v - state.v - ((1.0 - self.theta) * dt) * state.aux[0]) / (self.theta * dt)
        return State(state.t + dt, y, v, (acceleration,))

    step = Integrator.potential_step

    def closed_form_spectral_radius(self, hw):
        """|R(i h w)|, R(z) = (1 + (1 - theta) z) / (1 - theta z), and the carried acceleration's own root
        -(1 - theta) / theta."""
        hw, theta = np.asarray(hw, dtype=float), self.theta
        principal = np.sqrt((1.0 + ((1.0 - theta) * hw) ** 2) / (1.0 + (theta * hw) ** 2))
        return np.maximum(principal, (1.0 - theta) / theta)
