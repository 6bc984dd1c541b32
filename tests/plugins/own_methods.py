"""Small plug-in methods for the tests of plug-in integrators and of `simrun check-integrator`: three planted defects,
each caught by its own check, a built-in declared steppable as lanes, and declarations the resolver refuses."""

from __future__ import annotations

from typing import ClassVar

from simrun.integrators import Integrator, State
from simrun.integrators.euler import BackwardEuler, SymplecticEuler
from simrun.solvers import EXPLICIT_STEP


class ClaimsOrderTwo(SymplecticEuler):
    """Symplectic Euler, which is first order, declared second order: the order checks fail."""

    name: ClassVar[str] = "claims_order_two"
    order: ClassVar[int] = 2


class NonlinearKick(Integrator):
    """Symplectic Euler with the force taken at x + h^2 x^3 (componentwise): consistent, first order, and on a free
    system still momentum-conserving (springs' forces sum to zero wherever they are taken), but not linear."""

    name: ClassVar[str] = "nonlinear_kick"
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "symplectic Euler with its force taken off the state by h^2 x^3: not linear"

    def step(self, system, state, dt, solver):
        v = system.kick(state.x + dt * dt * state.x ** 3, state.v, dt)
        return State(state.t + dt, state.x + dt * v, v), EXPLICIT_STEP


class DeclaredNonlinear(NonlinearKick):
    """The same step, declared for what it is: no amplification matrix, its runs measured only."""

    name: ClassVar[str] = "declared_nonlinear"
    linear: ClassVar[bool] = False


class LeakyMomentum(Integrator):
    """Symplectic Euler that takes h^3 v off the velocity each step: linear, first order (the leak is O(h^3) a step),
    and it loses momentum."""

    name: ClassVar[str] = "leaky_momentum"
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "symplectic Euler with a leak of h^3 v a step: loses momentum"

    def step(self, system, state, dt, solver):
        v = system.kick(state.x, state.v, dt) - dt ** 3 * state.v
        return State(state.t + dt, state.x + dt * v, v), EXPLICIT_STEP


class LaneBackwardEuler(BackwardEuler):
    """Backward Euler under a name of its own, declared steppable as lanes (its step is the built-in's)."""

    name: ClassVar[str] = "lane_backward_euler"
    lanes: ClassVar[bool] = True


class Unnamed(Integrator):
    """Symplectic Euler again, declaring no name: its label is its path, own_methods:Unnamed."""

    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "symplectic Euler without a name of its own"

    def step(self, system, state, dt, solver):
        v = system.kick(state.x, state.v, dt)
        return State(state.t + dt, state.x + dt * v, v), EXPLICIT_STEP


# -- declarations the resolver refuses --------------------------------------------------------------------------
class NoOrder(Integrator):
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "declares no order"

    def step(self, system, state, dt, solver):
        return state, EXPLICIT_STEP


class OrderAsText(NoOrder):
    order: ClassVar[str] = "two"  # type: ignore[assignment]


class NoStep(Integrator):
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "declares everything but its step"


class TakesABuiltInName(LeakyMomentum):
    name: ClassVar[str] = "backward_euler"


class NotAMethod:
    """A class, but not an Integrator."""
