"""The three Euler methods of the lectures."""

from __future__ import annotations

from typing import ClassVar

from simrun.solvers import EXPLICIT_STEP

from .base import Integrator, State, StepPlan


class ForwardEuler(Integrator):
    """x_{n+1} = x_n + h v_n,  v_{n+1} = v_n + h M^-1 f(x_n, v_n).

    First order; unstable for every h on the undamped spring: the energy grows by exactly
    (1 + (h w)^2) per step.
    """

    name: ClassVar[str] = "forward_euler"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "explicit Euler; energy grows by (1 + (h w)^2) per step on the spring"

    def step(self, system, state, dt, solver):
        return State(state.t + dt, state.x + dt * state.v, system.kick(state.x, state.v, dt)), EXPLICIT_STEP


class SymplecticEuler(Integrator):
    """v_{n+1} = v_n + h M^-1 f(x_n, v_n),  x_{n+1} = x_n + h v_{n+1}  (velocity first).

    First order, symplectic: a modified energy is conserved, so the energy stays bounded for
    h w < 2 on the spring; conserves angular momentum under central forces exactly.
    """

    name: ClassVar[str] = "symplectic_euler"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "semi-implicit/symplectic Euler (velocity first); bounded energy for h w < 2"

    def step(self, system, state, dt, solver):
        v = system.kick(state.x, state.v, dt)  # v_n + h M^-1 f(x_n, v_n)
        return State(state.t + dt, state.x + dt * v, v), EXPLICIT_STEP


class BackwardEuler(Integrator):
    """M (x_{n+1} - x_n - h v_n) = h^2 f(x_{n+1}, v_{n+1}),  v_{n+1} = (x_{n+1} - x_n) / h.

    Solved as the minimisation of the incremental potential with y = x_{n+1}, y~ = x_n + h v_n,
    c = 1. First order, unconditionally stable; the energy of the spring shrinks by exactly
    1 / (1 + (h w)^2) per step (artificial damping).
    """

    name: ClassVar[str] = "backward_euler"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    summary: ClassVar[str] = "implicit Euler; energy shrinks by 1/(1 + (h w)^2) per step on the spring"

    def plan(self, state, dt):
        return StepPlan(state.x + dt * state.v, dt * dt, state.x, dt, state.x)

    def finish(self, state, plan, y, dt):
        return State(state.t + dt, y, (y - state.x) / dt)

    step = Integrator.potential_step
