"""Explicit methods beyond Euler: leapfrog (velocity Verlet) and the Runge-Kutta methods, given as Butcher tableaux."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from simrun.solvers import EXPLICIT_STEP

from .base import Integrator, State


class Leapfrog(Integrator):
    """Velocity Verlet (kick-drift-kick):
        v_{n+1/2} = v_n + h/2 M^-1 f(x_n, v_n),  x_{n+1} = x_n + h v_{n+1/2},
        v_{n+1} = v_{n+1/2} + h/2 M^-1 f(x_{n+1}, v*),   v* = 2 v_{n+1/2} - v_n = v_n + h M^-1 f(x_n, v_n).

    Second order, symplectic and time-reversible without damping. Stable on the spring for h w < 2,
    where it adds no artificial damping (the energy oscillates, bounded); beyond, the amplification
    is (x^2 - 2 + x sqrt(x^2 - 4)) / 2 with x = h w. Damping: the last half kick takes the damping
    force at the extrapolated velocity v* (an O(h^2) estimate of v_{n+1}), which keeps the method
    explicit and second order; without damping v* is not used and this is exactly velocity Verlet.
    Source: Hairer, Lubich & Wanner, Geometric Numerical Integration (2006), ch. I (Stoermer-Verlet).
    """

    name: ClassVar[str] = "leapfrog"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "velocity Verlet / kick-drift-kick; symplectic, 2nd order, stable for h w < 2"

    def step(self, system, state, dt, solver):
        acceleration = system.acceleration(state.x, state.v)
        v_half = state.v + 0.5 * dt * acceleration
        x = state.x + dt * v_half
        v = v_half + 0.5 * dt * system.acceleration(x, state.v + dt * acceleration)
        return State(state.t + dt, x, v), EXPLICIT_STEP


@dataclass(frozen=True)
class ButcherTableau:
    """An explicit Runge-Kutta method as data: stages k_i = F(u_n + h sum_{j<i} A_ij k_j), u_{n+1} = u_n + h sum_i b_i k_i.

    ``c`` (the stage times, c_i = sum_j A_ij) is kept for completeness: the systems are autonomous.
    """

    A: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    b_hat: tuple[float, ...] | None = None  # embedded weights, for the error estimate of adaptive steps
    embedded_order: int | None = None

    @property
    def stage_count(self) -> int:
        return len(self.b)

    @property
    def first_same_as_last(self) -> bool:
        """Whether the last stage is the new point (A's last row is b): its slope is the next step's first."""
        return tuple(self.A[-1]) == tuple(self.b) and self.c[-1] == 1.0


class ExplicitRungeKutta(Integrator):
    """Explicit Runge-Kutta on the first-order system u = (x, v), u' = (v, M^-1 f(x, v)).

    A subclass supplies only its ``tableau``; stability on the spring is |R(i h w)| with R the
    method's stability polynomial (sum_k z^k / k! up to the order, for s = p <= 4 stages).
    """

    family: ClassVar[str] = "explicit"
    tableau: ClassVar[ButcherTableau]

    @property
    def error_estimate(self) -> str | None:
        tableau = self.tableau
        return None if tableau.b_hat is None else f"embedded order {tableau.embedded_order}"

    @property
    def estimate_order(self) -> int:
        tableau = self.tableau
        return min(tableau.order, tableau.embedded_order or tableau.order) + 1

    def step(self, system, state, dt, solver):
        new, _, _ = self._stages(system, state, dt)
        return new, EXPLICIT_STEP

    def step_with_error(self, system, state, dt, solver, error_tolerance=None):
        """The step and h sum_i (b_i - b_hat_i) F(U_i), its difference from the embedded solution, as (x, v) rows.

        A first-same-as-last pair (dopri5) leaves its last stage's acceleration, F at the new state, in the new
        state's ``reusable``: the next step (or a retry of it from the same state) takes it as its first stage, six
        force evaluations a try instead of seven, while the state is the one it was computed at (a vertex put on its
        prescribed path, or a released system, makes a state or system of its own)."""
        last = state.reusable
        first = (last.acceleration if isinstance(last, LastSlope) and last.system is system and last.x is state.x
                 and last.v is state.v else None)
        new, slopes_x, slopes_v = self._stages(system, state, dt, first)
        weights = [dt * (b - b_hat) for b, b_hat in zip(self.tableau.b, self.tableau.b_hat)]
        if self.tableau.first_same_as_last:
            new.reusable = LastSlope(system, new.x, new.v, slopes_v[-1])
        return new, EXPLICIT_STEP, weighted_error(weights, slopes_x, slopes_v)

    def _stages(self, system, state, dt, first: np.ndarray | None = None):
        """(the new state, the stages' slopes dx/dt and dv/dt); ``first``: the first stage's acceleration, if known."""
        tableau = self.tableau
        slopes_x: list[np.ndarray] = []  # dx/dt at each stage (a velocity)
        slopes_v: list[np.ndarray] = []  # dv/dt at each stage (an acceleration)
        for row in tableau.A:
            x, v = state.x, state.v
            for weight, slope_x, slope_v in zip(row, slopes_x, slopes_v):
                if weight:
                    x = x + (dt * weight) * slope_x
                    v = v + (dt * weight) * slope_v
            slopes_x.append(v)
            slopes_v.append(first if first is not None and not slopes_v else system.acceleration(x, v))
        if tableau.first_same_as_last:  # the last stage is the new point itself
            return State(state.t + dt, x, v), slopes_x, slopes_v
        return weighted_step(state, dt, tableau.b, slopes_x, slopes_v), slopes_x, slopes_v


@dataclass(frozen=True)
class LastSlope:
    """A first-same-as-last step's acceleration at its new state (x, v) of ``system``: the next step's first stage."""

    system: object
    x: np.ndarray
    v: np.ndarray
    acceleration: np.ndarray


def weighted_step(state: State, dt: float, weights, slopes_x, slopes_v) -> State:
    """u_n + h sum_i b_i F(U_i): a Runge-Kutta method's new state from its stages' slopes (velocities, accelerations)."""
    x, v = state.x, state.v
    for weight, slope_x, slope_v in zip(weights, slopes_x, slopes_v):
        if weight:
            x = x + (dt * weight) * slope_x
            v = v + (dt * weight) * slope_v
    return State(state.t + dt, x, v)


def weighted_error(weights, slopes_x, slopes_v) -> np.ndarray:
    """(2, n): sum_i w_i (slope_x_i, slope_v_i), a step's error estimate in its position and velocity rows."""
    error = np.zeros((2, slopes_x[0].size))
    for weight, slope_x, slope_v in zip(weights, slopes_x, slopes_v):
        if weight:
            error[0] += weight * slope_x
            error[1] += weight * slope_v
    return error


EXPLICIT_MIDPOINT_TABLEAU = ButcherTableau(
    A=((0.0, 0.0), (0.5, 0.0)),
    b=(0.0, 1.0),
    c=(0.0, 0.5),
    order=2,
)

RK4_TABLEAU = ButcherTableau(
    A=((0.0, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0, 0.0), (0.0, 0.5, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0)),
    b=(1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0),
    c=(0.0, 0.5, 0.5, 1.0),
    order=4,
)


class ExplicitMidpoint(ExplicitRungeKutta):
    """RK2, explicit midpoint: k1 = F(u_n), k2 = F(u_n + h/2 k1), u_{n+1} = u_n + h k2.

    Second order. On the spring R(z) = 1 + z + z^2/2, so |R(i x)| = sqrt(1 + x^4/4) > 1: unstable
    for every h without damping (energy grows, slowly: by about x^4/4 per step). With damping it is
    stable for small enough h. Source: Hairer, Norsett & Wanner, Solving ODEs I (1993), ch. II.
    """

    name: ClassVar[str] = "explicit_midpoint"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = EXPLICIT_MIDPOINT_TABLEAU.order
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "RK2 (explicit midpoint); energy grows by ~ (h w)^4/4 per step on the spring"
    tableau: ClassVar[ButcherTableau] = EXPLICIT_MIDPOINT_TABLEAU


class RK4(ExplicitRungeKutta):
    """Classical Runge-Kutta: u_{n+1} = u_n + h (k1 + 2 k2 + 2 k3 + k4) / 6.

    Fourth order. On the spring |R(i x)|^2 = 1 - x^6/72 + x^8/576: slightly dissipative for
    x < 2 sqrt(2), unstable beyond. Source: Hairer, Norsett & Wanner, Solving ODEs I (1993), ch. II.
    """

    name: ClassVar[str] = "rk4"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = RK4_TABLEAU.order
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "classical Runge-Kutta; 4th order, slightly dissipative, stable for h w < 2.83"
    tableau: ClassVar[ButcherTableau] = RK4_TABLEAU


# Dormand & Prince (1980), "A family of embedded Runge-Kutta formulae", J. Comput. Appl. Math. 6: RK5(4)7M, the
# fifth-order weights (its last stage, at the new point, is the next step's first: first same as last)
DOPRI5_TABLEAU = ButcherTableau(
    A=((0.0,) * 7,
       (1.0 / 5.0,) + (0.0,) * 6,
       (3.0 / 40.0, 9.0 / 40.0) + (0.0,) * 5,
       (44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0) + (0.0,) * 4,
       (19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0) + (0.0,) * 3,
       (9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0, 0.0, 0.0),
       (35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0, 0.0)),
    b=(35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0, 0.0),
    c=(0.0, 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0, 1.0, 1.0),
    order=5,
    # the embedded fourth-order weights, for the error estimate of adaptive steps
    b_hat=(5179.0 / 57600.0, 0.0, 7571.0 / 16695.0, 393.0 / 640.0, -92097.0 / 339200.0, 187.0 / 2100.0, 1.0 / 40.0),
    embedded_order=4,
)
class Dopri5(ExplicitRungeKutta):
    """Dormand-Prince 5(4) (1980), the explicit baseline of error-controlled integration (scipy's RK45, MATLAB's
    ode45): seven stages, fifth order. On the spring R(z) = sum_{k<=5} z^k/k! + z^6/600 (its seventh stage, at the
    new point, adds the z^6 term): on the undamped spring slightly dissipative for h w < 0.997 and growing beyond
    (3 % a step at h w = 2; its region reaches -3.3 along the real axis). Source: Dormand & Prince,
    J. Comput. Appl. Math. 6 (1980); Hairer, Norsett & Wanner, Solving ODEs I (1993), sec. II.5."""

    name: ClassVar[str] = "dopri5"
    order: ClassVar[int] = DOPRI5_TABLEAU.order
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "Dormand-Prince 5(4), the fifth-order explicit baseline (scipy's RK45)"
    tableau: ClassVar[ButcherTableau] = DOPRI5_TABLEAU
