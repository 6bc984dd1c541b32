"""Bathe's composite scheme as a simrun plug-in integrator (docs/integrators.md, "Writing your own integrator").

    integrators: ["bathe:Bathe", {type: "bathe:Bathe", gamma: 0.586}]     # with this folder on PYTHONPATH

Each step of h is two implicit sub-steps (Bathe & Baig, Computers & Structures 83 (2005) 2513-2524; Bathe,
Computers & Structures 85 (2007) 437-445, with the sub-step fraction gamma of Bathe & Noh, Computers & Structures
98-99 (2012) 1-6):

1. the trapezoidal rule over gamma h:
       x_g = x_n + (gamma h / 2) (v_n + v_g),   v_g = v_n + (gamma h / 2) (a_n + a_g);
2. the three-point backward difference over t_n, t_n + gamma h, t_{n+1}:
       v_{n+1} = c1 x_n + c2 x_g + c3 x_{n+1},   a_{n+1} = c1 v_n + c2 v_g + c3 v_{n+1},
       c1 = (1 - gamma) / (gamma h),  c2 = -1 / ((1 - gamma) gamma h),  c3 = (2 - gamma) / ((1 - gamma) h),

with M a = f(x, v) at each sub-step's end. Second order; unconditionally stable; its spectral radius on the undamped
spring falls from 1 to 0 as h w grows (rho_inf = 0 for every gamma in (0, 1)): strong damping of the unresolved
frequencies, little of the resolved ones.

Each sub-step is an incremental potential (integrators/base.py, StepPlan), so the method runs with every solver that
minimises one, and with damping, pins and prescribed paths as the built-in implicit methods do:
- sub-step 1: y~ = x_n + k v_n + (k^2 / 4) a_n, scale k^2 / 4, velocity (y - x_n - (k/2) v_n) / (k/2), k = gamma h;
- sub-step 2: M c3^2 (x_{n+1} - y~) = f with y~ = a - (c1 v_n + c2 v_g) / c3^2, a = -(c1 x_n + c2 x_g) / c3, so the
  scale is 1 / c3^2 and the velocity (y - a) c3.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from simrun.integrators import Integrator, State
from simrun.integrators.base import StepPlan, solve_step


class Bathe(Integrator):
    """Bathe's composite scheme: a trapezoidal sub-step of gamma h, then a three-point backward difference."""

    name: ClassVar[str] = "bathe"
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    summary: ClassVar[str] = "Bathe's composite scheme: trapezoidal sub-step, then three-point backward difference"
    problem_kind: ClassVar[str | None] = "incremental_potential"

    gamma: float = Field(0.5, gt=0.0, lt=1.0, allow_inf_nan=False,
                         description="the trapezoidal sub-step's fraction of h (0.5: Bathe's method; 2 - sqrt(2): "
                                     "the two sub-steps' Newton matrices are the same)")

    @property
    def unknown_fraction(self) -> float:  # the first sub-step's unknown is x at t_n + gamma h
        return self.gamma

    def coefficients(self, dt: float) -> tuple[float, float, float]:
        """c1, c2, c3 (1/s) of the three-point backward difference."""
        gamma = self.gamma
        return ((1.0 - gamma) / (gamma * dt), -1.0 / ((1.0 - gamma) * gamma * dt), (2.0 - gamma) / ((1.0 - gamma) * dt))

    def step(self, system, state, dt, solver):
        k = self.gamma * dt
        x, v = state.x, state.v
        acceleration = system.acceleration(x, v)
        trapezoidal = StepPlan(y_tilde=x + k * v + (0.25 * k * k) * acceleration, scale=0.25 * k * k,
                               velocity_origin=x + (0.5 * k) * v, velocity_divisor=0.5 * k, damping_at=x,
                               fraction=self.gamma)
        problem = trapezoidal.problem(system, state, dt)
        x_g, first = solve_step(solver, problem, problem.start_point(x))
        v_g = (x_g - trapezoidal.velocity_origin) / trapezoidal.velocity_divisor
        if not first.converged:
            return State(state.t + dt, x_g, v_g), first
        c1, c2, c3 = self.coefficients(dt)
        origin = -(c1 * x + c2 * x_g) / c3
        middle = State(state.t + k, x_g, v_g)
        backward = StepPlan(y_tilde=origin - (c1 * v + c2 * v_g) / (c3 * c3), scale=1.0 / (c3 * c3),
                            velocity_origin=origin, velocity_divisor=1.0 / c3, damping_at=x_g)
        problem = backward.problem(system, middle, dt - k)
        y, second = solve_step(solver, problem, problem.start_point(x_g))
        return State(state.t + dt, y, (y - origin) * c3), first.followed_by(second)

    def closed_form_spectral_radius(self, hw: np.ndarray) -> np.ndarray:
        """rho(h w) on the undamped spring from the two sub-steps' matrices written out (not from ``step``)."""
        hw = np.atleast_1d(np.asarray(hw, dtype=float))
        radius = np.empty(hw.shape)
        for index, value in enumerate(hw.tolist()):
            k, w2 = self.gamma, value * value  # h = 1 s, w = h w
            trapezoidal = np.array([[1.0 - 0.25 * k * k * w2, k], [-k * w2, 1.0 - 0.25 * k * k * w2]]) / (1.0 + 0.25 * k * k * w2)
            c1, c2, c3 = self.coefficients(1.0)
            # x_{n+1} = -(c1 v_n + c2 v_g + c3 (c1 x_n + c2 x_g)) / (w^2 + c3^2), v_{n+1} = c1 x_n + c2 x_g + c3 x_{n+1}
            start = np.eye(2)
            middle = trapezoidal @ start
            x_end = -(c1 * start[1] + c2 * middle[1] + c3 * (c1 * start[0] + c2 * middle[0])) / (w2 + c3 * c3)
            v_end = c1 * start[0] + c2 * middle[0] + c3 * x_end
            radius[index] = np.max(np.abs(np.linalg.eigvals(np.vstack([x_end, v_end]))))
        return radius
