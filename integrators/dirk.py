"""Diagonally implicit Runge-Kutta methods, each stage an incremental potential.

On the first-order form u = (x, v), u' = F(u) = (v, M^-1 f(x, v)), stage i of a DIRK method with tableau (A, b, c),
A lower triangular with diagonal gamma_i = A_ii, is

    X_i = x_n + h sum_{j<i} A_ij V_j + h gamma_i V_i,    V_i = v_n + h sum_{j<i} A_ij a_j + h gamma_i a_i,

a_j = M^-1 f(X_j, V_j). With the origin o_i = x_n + h sum_{j<i} A_ij V_j and the divisor b_i = h gamma_i, V_i =
(X_i - o_i) / b_i, and the second equation times M is

    M (X_i - o_i - b_i v^_i) = b_i^2 f(X_i, V_i),    v^_i = v_n + h sum_{j<i} A_ij a_j:

the incremental potential of backward Euler with y = X_i, y~ = o_i + b_i v^_i, scale b_i^2 and the velocity map
(y - o_i)/b_i. So every solver, contact with IPC and its CCD-filtered line search, and friction work per stage as
they do for backward Euler. A stage's acceleration comes from its own equation, a_i = (V_i - v^_i) / b_i, so no
force is evaluated (nor M inverted) beyond the solves; an explicit first stage (A_11 = 0, ESDIRK) takes
a_1 = M^-1 f(x_n, v_n). A stiffly accurate method (b = the last row of A) ends at the last stage, u_{n+1} = U_s;
any other at u_n + h sum_i b_i F(U_i).

Tableaux (Hairer & Wanner, Solving ODEs II, sec. IV.6; Kennedy & Carpenter 2016, NASA/TM-2016-219173):
- ``sdirk2``: Alexander 1977, two stages, gamma = 1 - 1/sqrt(2); order 2, L-stable, stiffly accurate.
- ``sdirk3``: Alexander 1977, three stages, gamma the root near 0.4359 of gamma^3 - 3 gamma^2 + 3/2 gamma - 1/6;
  order 3, L-stable, stiffly accurate.
- ``trbdf2``: Bank et al. 1985 as an ESDIRK (Hosea & Shampine 1996): gamma = 2 - sqrt(2), the trapezoidal rule to
  t_n + gamma h and BDF2 to t_{n+1}; order 2, L-stable, stiffly accurate; with Hosea and Shampine's embedded
  third-order weights.
- ``esdirk``: a user's tableau (``tableau: {A, b, c, order}``), checked against its order conditions (rooted
  trees up to order 4) when the config is loaded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from simrun.solvers import SolveStats
from simrun.systems.forms import contact_needs_step_filter

from .base import Integrator, State, StepPlan, solve_step
from .explicit import weighted_error, weighted_step

# a tableau's sums match their order conditions to this (the published coefficients' digits)
ORDER_TOLERANCE = 1e-10


@dataclass(frozen=True)
class DirkTableau:
    """A (lower-triangular) DIRK tableau: A (s x s), b (s,), c (s,), its order, and optionally embedded weights
    b_hat of order ``embedded_order`` (for an error estimate h sum_i (b_i - b_hat_i) F(U_i))."""

    A: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    b_hat: tuple[float, ...] | None = None
    embedded_order: int | None = None

    @property
    def stage_count(self) -> int:
        return len(self.b)

    @property
    def stiffly_accurate(self) -> bool:
        return all(abs(self.b[j] - self.A[-1][j]) <= ORDER_TOLERANCE for j in range(self.stage_count))

    def stability_function(self, z: complex) -> complex:
        """R(z) = 1 + z b^T (I - z A)^-1 1: the factor of y' = lambda y per step, z = h lambda."""
        A, b = np.array(self.A, dtype=complex), np.array(self.b, dtype=complex)
        ones = np.ones(self.stage_count, dtype=complex)
        return complex(1.0 + z * b @ np.linalg.solve(np.eye(self.stage_count) - z * A, ones))


def order_condition_errors(A, b, c, order: int) -> list[tuple[str, float, float]]:
    """(condition, value, required) of every order condition up to ``order`` (at most 4) that the tableau misses by
    more than ORDER_TOLERANCE: the rooted trees' b^T Phi = 1 / gamma, with c = A 1 (Butcher 2008, sec. 3.1)."""
    A, b, c = np.asarray(A, dtype=float), np.asarray(b, dtype=float), np.asarray(c, dtype=float)
    conditions = [("sum b = 1", b.sum(), 1.0, 1)]
    conditions += [("b . c = 1/2", b @ c, 1 / 2, 2)]
    conditions += [("b . c^2 = 1/3", b @ c ** 2, 1 / 3, 3), ("b . A c = 1/6", b @ A @ c, 1 / 6, 3)]
    conditions += [("b . c^3 = 1/4", b @ c ** 3, 1 / 4, 4), ("b . (c A c) = 1/8", b @ (c * (A @ c)), 1 / 8, 4),
                   ("b . A c^2 = 1/12", b @ A @ c ** 2, 1 / 12, 4), ("b . A A c = 1/24", b @ A @ A @ c, 1 / 24, 4)]
    return [(name, float(value), required) for name, value, required, tree_order in conditions
            if tree_order <= order and abs(value - required) > ORDER_TOLERANCE]


def tableau_refusal(A, b, c, order: int) -> str | None:
    """Why (A, b, c) is not a DIRK method of ``order`` (one line), or None."""
    s = len(b)
    if not (1 <= order <= 4):
        return f"order {order}: the order conditions are checked up to 4"
    if len(A) != s or any(len(row) != s for row in A) or len(c) != s:
        return f"A must be {s} x {s} and c of length {s}, as b is"
    values = np.array(A, dtype=float)
    if not np.all(np.isfinite(values)) or not np.all(np.isfinite(b)) or not np.all(np.isfinite(c)):
        return "every coefficient must be finite"
    upper = np.argwhere(np.triu(values, 1) != 0.0)
    if upper.size:
        i, j = upper[0]
        return f"A[{i}][{j}] = {values[i, j]:g}: a diagonally implicit method has A_ij = 0 above the diagonal"
    diagonal = np.diag(values)
    if np.any(diagonal[1:] <= 0.0) or diagonal[0] < 0.0:
        return (f"the diagonal {diagonal.tolist()} must be positive (each stage an incremental potential), the first "
                "entry may be 0 (an explicit first stage)")
    sums = values.sum(axis=1)
    if np.any(np.abs(sums - np.asarray(c, dtype=float)) > ORDER_TOLERANCE):
        row = int(np.argmax(np.abs(sums - np.asarray(c, dtype=float)) > ORDER_TOLERANCE))
        return f"c[{row}] = {c[row]:g} is not the sum of A's row {row}, {sums[row]:.12g}"
    if diagonal[0] == 0.0 and any(values[0] != 0.0):
        return "an explicit first stage has a zero first row"
    missed = order_condition_errors(A, b, c, order)
    if missed:
        name, value, required = missed[0]
        return f"fails its order-{order} condition {name}: {value:.12g} (and {len(missed) - 1} more)" if len(missed) > 1 \
            else f"fails its order-{order} condition {name}: {value:.12g}"
    return None


def _alexander3() -> DirkTableau:
    """Alexander's three-stage L-stable SDIRK of order 3 (Hairer & Wanner II, table IV.6.5 with its gamma)."""
    gamma = 0.43586652150845899941601945  # the root of gamma^3 - 3 gamma^2 + 3/2 gamma - 1/6 in (1/3, 1/2)
    tau = (1.0 + gamma) / 2.0
    b1 = -(6.0 * gamma * gamma - 16.0 * gamma + 1.0) / 4.0
    b2 = (6.0 * gamma * gamma - 20.0 * gamma + 5.0) / 4.0
    return DirkTableau(A=((gamma, 0.0, 0.0), (tau - gamma, gamma, 0.0), (b1, b2, gamma)), b=(b1, b2, gamma),
                       c=(gamma, tau, 1.0), order=3)


def _trbdf2() -> DirkTableau:
    """TR-BDF2 (Bank et al. 1985) as an ESDIRK, with Hosea & Shampine's (1996) embedded third-order weights."""
    gamma = 2.0 - math.sqrt(2.0)
    d, w = gamma / 2.0, math.sqrt(2.0) / 4.0
    return DirkTableau(A=((0.0, 0.0, 0.0), (d, d, 0.0), (w, w, d)), b=(w, w, d), c=(0.0, gamma, 1.0), order=2,
                       b_hat=((1.0 - w) / 3.0, (3.0 * w + 1.0) / 3.0, d / 3.0), embedded_order=3)


_GAMMA2 = 1.0 - 1.0 / math.sqrt(2.0)
TABLEAUX = {
    "sdirk2": DirkTableau(A=((_GAMMA2, 0.0), (1.0 - _GAMMA2, _GAMMA2)), b=(1.0 - _GAMMA2, _GAMMA2), c=(_GAMMA2, 1.0),
                          order=2),
    "sdirk3": _alexander3(),
    "trbdf2": _trbdf2(),
}


def _add(total: SolveStats | None, stats: SolveStats) -> SolveStats:
    """The statistics of a step's solves summed (``SolveStats.followed_by``); None: none yet."""
    return stats if total is None else total.followed_by(stats)


class DiagonallyImplicitRungeKutta(Integrator):
    """A DIRK method on u = (x, v): see the module docstring. A subclass names its ``TABLEAUX`` entry."""

    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    family: ClassVar[str] = "dirk"
    tableau_name: ClassVar[str]

    @property
    def dirk_tableau(self) -> DirkTableau:
        return TABLEAUX[self.tableau_name]

    @property
    def order_of_accuracy(self) -> int:
        return self.dirk_tableau.order

    def refusal(self, system):
        """A stiffly accurate method's last stage is x_{n+1} itself, which IPC's CCD keeps out of the colliders as it
        does every stage; any other's x_{n+1} combines the stages, which no line search cuts."""
        if contact_needs_step_filter(system) and not self.dirk_tableau.stiffly_accurate:
            return ("ends the step at a combination of its stages, which CCD does not keep out of a collider: IPC "
                    "contact needs a stiffly accurate tableau (b = the last row of A)")
        return super().refusal(system)

    @property
    def error_estimate(self) -> str | None:
        tableau = self.dirk_tableau
        return None if tableau.b_hat is None else f"embedded order {tableau.embedded_order}"

    @property
    def estimate_order(self) -> int:
        tableau = self.dirk_tableau
        return min(tableau.order, tableau.embedded_order or tableau.order) + 1

    def step(self, system, state, dt, solver):
        new, stats, _, _ = self._stages(system, state, dt, solver)
        return new, stats

    def step_with_error(self, system, state, dt, solver, error_tolerance=None):
        """The step and h sum_i (b_i - b_hat_i) F(U_i), its difference from the embedded solution, as (x, v) rows."""
        new, stats, velocities, accelerations = self._stages(system, state, dt, solver)
        tableau = self.dirk_tableau
        weights = [dt * (b - b_hat) for b, b_hat in zip(tableau.b, tableau.b_hat)]
        return new, stats, weighted_error(weights, velocities, accelerations)

    def _stages(self, system, state, dt, solver):
        """(the new state, the solves' statistics summed, the stages' velocities V_i and accelerations a_i)."""
        tableau = self.dirk_tableau
        velocities, accelerations, stats, y = [], [], None, state.x
        for i, row in enumerate(tableau.A):
            gamma = row[i]
            if gamma == 0.0:  # an explicit first stage: U_1 = u_n
                velocities.append(state.v)
                accelerations.append(system.acceleration(state.x, state.v))
                continue
            origin, v_hat = state.x, state.v
            for j in range(i):
                if row[j]:
                    origin = origin + (dt * row[j]) * velocities[j]
                    v_hat = v_hat + (dt * row[j]) * accelerations[j]
            divisor = dt * gamma
            predictor = origin + divisor * v_hat
            plan = StepPlan(predictor, divisor * divisor, origin, divisor, predictor)
            # the prescribed vertices at the stage's time t_n + c_i h, on their paths
            problem = plan.problem(system, state, tableau.c[i] * dt)
            y, stage_stats = solve_step(solver, problem, problem.start_point(state.x))
            stats = _add(stats, stage_stats)
            velocity = (y - origin) / divisor
            velocities.append(velocity)
            accelerations.append((velocity - v_hat) / divisor)
        if tableau.stiffly_accurate:
            return State(state.t + dt, y, velocities[-1]), stats, velocities, accelerations
        return weighted_step(state, dt, tableau.b, velocities, accelerations), stats, velocities, accelerations


class SDIRK2(DiagonallyImplicitRungeKutta):
    """Alexander's two-stage SDIRK, gamma = 1 - 1/sqrt(2): order 2, L-stable, stiffly accurate; each stage a
    backward Euler-like incremental potential with scale (gamma h)^2. R(z) = (1 + (1 - 2 gamma) z) / (1 - gamma z)^2."""

    name: ClassVar[str] = "sdirk2"
    order: ClassVar[int] = 2
    tableau_name: ClassVar[str] = "sdirk2"
    summary: ClassVar[str] = "Alexander's 2-stage SDIRK; 2nd order, L-stable, two incremental potentials per step"


class SDIRK3(DiagonallyImplicitRungeKutta):
    """Alexander's three-stage SDIRK, gamma = 0.4358665: order 3, L-stable, stiffly accurate."""

    name: ClassVar[str] = "sdirk3"
    order: ClassVar[int] = 3
    tableau_name: ClassVar[str] = "sdirk3"
    summary: ClassVar[str] = "Alexander's 3-stage SDIRK; 3rd order, L-stable, three incremental potentials per step"


class TRBDF2(DiagonallyImplicitRungeKutta):
    """TR-BDF2 (Bank et al. 1985): the trapezoidal rule to t_n + gamma h, gamma = 2 - sqrt(2), then BDF2 to t_{n+1};
    an ESDIRK whose first stage is explicit (one force evaluation); order 2, L-stable, stiffly accurate."""

    name: ClassVar[str] = "trbdf2"
    order: ClassVar[int] = 2
    tableau_name: ClassVar[str] = "trbdf2"
    summary: ClassVar[str] = "TR-BDF2: trapezoidal rule then BDF2 in one step; 2nd order, L-stable"


class UserTableau(BaseModel):
    """A DIRK tableau written in a config: A (lower triangular, positive diagonal, the first entry may be 0), b, c
    and the order it claims, checked against the order conditions up to that order."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    A: tuple[tuple[float, ...], ...] = Field(description="s x s, lower triangular")
    b: tuple[float, ...] = Field(description="the weights (s,)")
    c: tuple[float, ...] = Field(description="the stage times (s,): the row sums of A")
    order: int = Field(description="the order it claims (1..4), checked")

    @model_validator(mode="after")
    def _meets_its_order_conditions(self) -> "UserTableau":
        reason = tableau_refusal(self.A, self.b, self.c, self.order)
        if reason is not None:
            raise ValueError(reason)
        return self


class ESDIRK(DiagonallyImplicitRungeKutta):
    """A user's DIRK or ESDIRK tableau (``tableau: {A, b, c, order}``), each implicit stage an incremental potential."""

    name: ClassVar[str] = "esdirk"
    order: ClassVar[int] = 2
    summary: ClassVar[str] = "a DIRK/ESDIRK of the config's own tableau, checked against its order conditions"
    tableau: UserTableau = Field(
        UserTableau(A=((0.0, 0.0), (0.5, 0.5)), b=(0.5, 0.5), c=(0.0, 1.0), order=2),
        description="{A, b, c, order}: the default is the trapezoidal rule (an ESDIRK of two stages)")

    @property
    def dirk_tableau(self) -> DirkTableau:
        spec = self.tableau
        return DirkTableau(A=spec.A, b=spec.b, c=spec.c, order=spec.order)
