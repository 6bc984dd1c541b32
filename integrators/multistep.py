"""Multistep methods: BDF2, Ascher's theta-mix of BDF2 and the implicit midpoint rule, and the k-step BDF (k <= 5).

BDF2 and the mix carry the previous state (x_{n-1}, v_{n-1}) in ``State.aux``; it is empty at the start, and the
first step is then taken with backward Euler (BDF1). The k-step BDF carries k - 1 previous states and starts with a
one-step method of order k - 1 or more; under step control it takes variable steps in its fixed-leading-coefficient
form (``BDF.step_with_error``). BDF2 and the mix keep dt fixed, as their formulas assume.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydantic import Field

from simrun.systems.forms import contact_needs_step_filter

from .base import Integrator, State, StepPlan, on_paths, solve_step
from .segment import SegmentPotential
from .euler import BackwardEuler

# BDF2 increment: u_{n+1} - u_n = HISTORY (u_n - u_{n-1}) + IMPLICIT_WEIGHT h F(u_{n+1})
BDF2_HISTORY, BDF2_IMPLICIT_WEIGHT = 1.0 / 3.0, 2.0 / 3.0


class BDF2(Integrator):
    """x_{n+1} = 4/3 x_n - 1/3 x_{n-1} + 2/3 h v_{n+1},  M v_{n+1} = M (4/3 v_n - 1/3 v_{n-1}) + 2/3 h f(x_{n+1}, v_{n+1}).

    Incremental potential in y = x_{n+1}: with x^ = (4 x_n - x_{n-1})/3 and v^ = (4 v_n - v_{n-1})/3,
    y~ = x^ + 2/3 h v^, c = 4/9, v_{n+1} = (y - x^)/(2h/3). The first step is backward Euler.
    Second order, A-stable and L-stable: the spectral radius on the spring is the largest root of
    (1 - 2z/3) r^2 - 4/3 r + 1/3 = 0, z = +-i h w; it falls from 1 (artificial damping of order
    (h w)^4 per step at small h w) to 0 as h w -> infinity (like 1/sqrt(2 h w)). Source: Hairer &
    Wanner, Solving ODEs II (1996), ch. V; Ascher, Numerical Methods for Evolutionary
    Differential Equations (SIAM 2008), ch. 5.
    """

    name: ClassVar[str] = "bdf2"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    summary: ClassVar[str] = "two-step BDF, started with one backward Euler step; 2nd order, L-stable (damps)"
    carries_history: ClassVar[bool] = True

    def plan(self, state, dt):
        if not state.aux:  # the first step: backward Euler
            return BackwardEuler().plan(state, dt)
        x_prev, v_prev = state.aux
        x_hat = state.x + BDF2_HISTORY * (state.x - x_prev)
        v_hat = state.v + BDF2_HISTORY * (state.v - v_prev)
        divisor = BDF2_IMPLICIT_WEIGHT * dt
        predictor = x_hat + divisor * v_hat  # x_{n+1} to O(h^2): D(x) there keeps the method second order
        return StepPlan(predictor, divisor * divisor, x_hat, divisor, predictor)

    def finish(self, state, plan, y, dt):
        # (y - a)/b: backward Euler's (x - x_n)/h on the first step, BDF2's (x - x^)/(2h/3) after it
        return State(state.t + dt, y, (y - plan.velocity_origin) / plan.velocity_divisor, (state.x, state.v))

    step = Integrator.potential_step


class BDF2MidpointMix(Integrator):
    """Ascher's theta method: increment = theta * (BDF2 increment) + (1 - theta) * (implicit midpoint increment),
    u_{n+1} - u_n = theta [1/3 (u_n - u_{n-1}) + 2/3 h F(u_{n+1})] + (1 - theta) h F((u_n + u_{n+1})/2),  u = (x, v).

    Eliminating v_{n+1} = (x_{n+1} - a)/(kappa h), kappa = 1/2 + theta/6,
    a = x_n + theta/3 (x_n - x_{n-1}) + (1 - theta) h/2 v_n, the step is the segment potential in
    y = x_{n+1} with y~ = a + kappa h (v_n + theta/3 (v_n - v_{n-1})) and the force sampled at
    y (weight 2 theta kappa/3) and at the midpoint (x_n + y)/2 (weight (1 - theta) kappa): a residual
    whose Jacobian is symmetric, so it also has a value. The first step replaces BDF2 by its
    one-step member, backward Euler (history weight 0, implicit weight 1). Second order for every
    theta; theta = 0 is the implicit midpoint rule (no artificial damping), theta = 1 is BDF2;
    more theta, more damping: the spectral radius at h w -> infinity is 3 (1 - theta)/(3 + theta),
    and at every h w it does not grow with theta. A-stable for theta in [0, 1]. Source: the
    course's "Ascher theta method" as the project's specification defines it (no published reference was found to
    cite); the two members: Ascher, Numerical Methods for Evolutionary Differential Equations
    (SIAM 2008), ch. 5 and 6.
    """

    name: ClassVar[str] = "bdf2_midpoint_mix"
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "segment_potential"
    summary: ClassVar[str] = "Ascher's theta * BDF2 + (1 - theta) * implicit midpoint; 2nd order, more theta = more damping"
    carries_history: ClassVar[bool] = True

    theta: float = Field(0.5, ge=0.0, le=1.0, allow_inf_nan=False,
                         description="share of BDF2 in the increment: 0 = implicit midpoint (no damping), 1 = BDF2")

    def step(self, system, state, dt, solver):
        if state.aux:
            x_prev, v_prev = state.aux
            history, implicit_weight = BDF2_HISTORY, BDF2_IMPLICIT_WEIGHT
        else:  # first step: backward Euler in place of BDF2
            x_prev, v_prev = state.x, state.v
            history, implicit_weight = 0.0, 1.0
        theta = self.theta
        kappa = theta * implicit_weight + 0.5 * (1.0 - theta)  # weight of v_{n+1} in the position increment / h
        divisor = kappa * dt
        origin = state.x + (theta * history) * (state.x - x_prev) + (0.5 * (1.0 - theta) * dt) * state.v
        y_tilde = origin + divisor * (state.v + (theta * history) * (state.v - v_prev))
        # D(x) at each node's point x_n + s h v_n, right to O(h^2), keeps the method second order
        problem = SegmentPotential(system, y_tilde, state.x, state.v, nodes=(1.0, 0.5),
                                   weights=(theta * implicit_weight * kappa, (1.0 - theta) * kappa), dt=dt,
                                   velocity_origin=origin, velocity_divisor=divisor,
                                   damping_at=[state.x + dt * state.v, state.x + (0.5 * dt) * state.v])
        problem.prescribed = on_paths(system, state, dt)
        x, stats = solve_step(solver, problem, problem.start_point(state.x))
        return State(state.t + dt, x, (x - origin) / divisor, (state.x, state.v)), stats


def bdf_coefficients(k: int) -> tuple[np.ndarray, float]:
    """(alpha, beta) of the k-step BDF, u_{n+1} + sum_{j=1..k} alpha_j u_{n+1-j} = h beta F(u_{n+1}) (alpha_0 = 1):
    sum_{j=1..k} (1/j) nabla^j u_{n+1} = h F(u_{n+1}) (Hairer, Norsett & Wanner I, sec. III.1), normalised."""
    from math import comb

    alpha = np.zeros(k + 1)
    for j in range(1, k + 1):  # nabla^j u_{n+1} = sum_i (-1)^i C(j, i) u_{n+1-i}
        for i in range(j + 1):
            alpha[i] += (-1) ** i * comb(j, i) / j
    beta = 1.0 / alpha[0]
    return alpha / alpha[0], beta


class BDF(Integrator):
    """The k-step backward differentiation formula, k = ``order`` (1..5), on u = (x, v):

        x_{n+1} + sum_j alpha_j x_{n+1-j} = h beta v_{n+1},   M (v_{n+1} + sum_j alpha_j v_{n+1-j}) = h beta f(x_{n+1}, v_{n+1}),

    the incremental potential of BDF2's form with x^ = -sum_j alpha_j x_{n+1-j}, v^ likewise, divisor b = h beta,
    y~ = x^ + b v^ and scale b^2 (BDF2 is k = 2). The history (x, v)_{n-1..n-k+1} rides in ``State.aux``. Order k;
    A-stable for k <= 2 only: BDF3-5 are A(alpha)-stable and grow on the undamped spring at small h w, where the
    root locus of rho(r) - z sigma(r) crosses the imaginary axis.

    Started so that the observed order stays k: the first k - 1 steps by a one-step method of order >= k - 1
    (whose local error O(h^k) leaves the global error O(h^k)): sdirk3 for k <= 4; for k = 5 sdirk3 with Richardson
    extrapolation, (8 u_{two half steps} - u_{one step}) / 7, of order 4. Until the history is full its missing
    entries are NaN, so that the state's layout is the same from the first step on (what the amplification probe
    reads). Source: Hairer & Wanner, Solving ODEs II (1996), sec. V.1; Hairer, Norsett & Wanner I, sec. III.1.
    """

    name: ClassVar[str] = "bdf"
    explicit: ClassVar[bool] = False
    family: ClassVar[str] = "bdf"
    problem_kind: ClassVar[str | None] = "incremental_potential"
    summary: ClassVar[str] = "k-step BDF (order: 1..5), started by sdirk3; A-stable to k = 2, BDF3-5 grow at small h w"
    carries_history: ClassVar[bool] = True
    order: int = Field(2, ge=1, le=5, description="k, the number of steps and the order (1..5)")

    @property
    def order_of_accuracy(self) -> int:
        return self.order

    def refusal(self, system):
        if self.order == 5 and contact_needs_step_filter(system):
            return ("starts with Richardson-extrapolated steps, combinations of states that CCD does not keep out of a "
                    "collider: IPC contact takes bdf up to order 4")
        return super().refusal(system)

    def step(self, system, state, dt, solver):
        k = self.order
        history = state.aux
        if k == 1 or (history and not np.isnan(history[-1][0])):
            return self._bdf_step(system, state, dt, solver)
        # the start: a one-step method of order >= k - 1, the history filled in as it goes
        start, stats = self._start_step(system, state, dt, solver)
        known = [(state.x, state.v)] + [(history[2 * j], history[2 * j + 1]) for j in range(len(history) // 2)
                                        if not np.isnan(history[2 * j][0])]
        missing = np.full_like(state.x, np.nan)
        pairs = known[:k - 1] + [(missing, missing)] * (k - 1 - len(known[:k - 1]))
        return State(start.t, start.x, start.v, tuple(part for pair in pairs for part in pair)), stats

    @property
    def error_estimate(self) -> str | None:
        return "the corrector's difference from the predictor"

    step_hold: ClassVar[float] = 1.2
    step_growth: ClassVar[float] = 2.0

    def estimate_order_from(self, state):
        if len(_timed_history(state, self.order)[0]) < self.order:  # the start: TR-BDF2's estimate
            return 3
        return self.order + 1

    def step_with_error(self, system, state, dt, solver, error_tolerance=None):
        """A step of the variable-step BDF in its fixed-leading-coefficient form, and its local error estimate.

        The history is the states at their own past times: ``State.aux`` holds (times, x_{n-1}, v_{n-1}, ...,
        x_{n-k}, v_{n-k}), NaN times where the run is younger. The first k steps are TR-BDF2's, with its own
        estimate (order 2, an error O(h^3): steps of tol^(1/3), where backward Euler's start would need steps of
        tol^(1/2), whose velocities (x - x^)/(beta h) lose the digits a tight tolerance asks for to round-off).
        After them the predictor phi is the polynomial through the k + 1 newest states, and the step is the
        constant-step BDF_k with phi's values at t_{n+1} - j h, j = 1..k, as its history (Jackson & Sacks-Davis
        1980; DASSL's form): at constant steps it is the fixed-step BDF_k. The estimate is the difference u_{n+1} -
        phi(t_{n+1}) times the ratio of the local error to it, both to leading order (``_estimate_factor``)."""
        k = self.order
        times, past = _timed_history(state, k)
        if len(past) < k:  # the start
            from .dirk import TRBDF2

            new, stats, error = TRBDF2().step_with_error(system, state, dt, solver)
        else:
            nodes = np.array([state.t] + times)
            points = [(state.x, state.v)] + past
            targets = np.concatenate([state.t + dt - dt * np.arange(1, k + 1), [state.t + dt]])
            weights = lagrange_weights(nodes, targets)
            values = [(sum(w * x for w, (x, _) in zip(row, points)), sum(w * v for w, (_, v) in zip(row, points)))
                      for row in weights]
            grid, predicted = values[:k], values[k]
            grid[0] = points[0]  # t_{n+1} - h = t_n: the state itself, not its round-off
            y, v, stats = _bdf_solve(system, state, dt, solver, grid)
            new = State(state.t + dt, y, v)
            error = _estimate_factor(k, nodes, targets, dt) * np.stack([new.x - predicted[0], new.v - predicted[1]])
        kept = ([(state.x, state.v)] + past)[:k]
        missing = np.full_like(state.x, np.nan)
        kept += [(missing, missing)] * (k - len(kept))
        new_times = np.full(k, np.nan)
        new_times[:min(k, len(times) + 1)] = ([state.t] + times)[:k]
        return State(new.t, new.x, new.v, (new_times, *(part for pair in kept for part in pair))), stats, error

    def _start_step(self, system, state, dt, solver):
        from .dirk import SDIRK3, _add

        method = SDIRK3()
        if self.order < 5:
            return method.step(system, state, dt, solver)
        whole, stats = method.step(system, state, dt, solver)
        half, first = method.step(system, state, 0.5 * dt, solver)
        half, second = method.step(system, half, 0.5 * dt, solver)
        x = (8.0 * half.x - whole.x) / 7.0
        v = (8.0 * half.v - whole.v) / 7.0
        return State(state.t + dt, x, v), _add(_add(stats, first), second)

    def _bdf_step(self, system, state, dt, solver):
        k = self.order
        past = [(state.x, state.v)] + [(state.aux[2 * j], state.aux[2 * j + 1]) for j in range(k - 1)]
        y, v, stats = _bdf_solve(system, state, dt, solver, past)
        history = tuple(part for pair in past[:k - 1] for part in pair)
        return State(state.t + dt, y, v, history), stats


def _bdf_solve(system, state: State, dt: float, solver, history: list[tuple[np.ndarray, np.ndarray]]):
    """(x_{n+1}, v_{n+1}, the solve's statistics) of the constant-step BDF of order len(history) from ``history``,
    (x, v) at t_n, t_n - h, ..., newest first: the incremental potential with x^ = -sum_j alpha_j x_{n+1-j}, v^
    likewise, divisor beta h."""
    alpha, beta = bdf_coefficients(len(history))
    x_hat = -sum(alpha[j + 1] * x for j, (x, _) in enumerate(history))
    v_hat = -sum(alpha[j + 1] * v for j, (_, v) in enumerate(history))
    divisor = beta * dt
    predictor = x_hat + divisor * v_hat
    plan = StepPlan(predictor, divisor * divisor, x_hat, divisor, predictor)
    problem = plan.problem(system, state, dt)
    y, stats = solve_step(solver, problem, problem.start_point(state.x))
    return y, (y - x_hat) / divisor, stats


def _estimate_factor(p: int, nodes: np.ndarray, targets: np.ndarray, dt: float) -> float:
    """The ratio of the step's local error to u_{n+1} - phi(t_{n+1}), both to leading order in u^{(p+1)}.

    With e(t) = prod_i (t - t_{n-i}) / (p + 1)! (phi's interpolation error over u^{(p+1)}), the local error is
    beta/(p + 1) h^{p+1} (the constant-step BDF_p's) + sum_j alpha_j e(t_{n+1} - j h) (what the interpolated history
    adds; 0 at constant steps, where those times are the nodes), and u_{n+1} - phi(t_{n+1}) is that + e(t_{n+1})."""
    alpha, beta = bdf_coefficients(p)

    def spread(t):
        return float(np.prod(t - nodes)) / math.factorial(p + 1)

    local = beta / (p + 1) * dt ** (p + 1) + sum(alpha[j + 1] * spread(t) for j, t in enumerate(targets[:p]))
    return local / (local + spread(targets[p]))


def _timed_history(state: State, k: int) -> tuple[list[float], list[tuple[np.ndarray, np.ndarray]]]:
    """The past times and states a variable-step BDF step carries (``BDF.step_with_error``), newest first."""
    if not state.aux:
        return [], []
    times = state.aux[0]
    known = int(np.count_nonzero(np.isfinite(times)))
    return ([float(t) for t in times[:known]],
            [(state.aux[1 + 2 * j], state.aux[2 + 2 * j]) for j in range(known)])


def lagrange_weights(nodes: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(targets, nodes) weights of the interpolating polynomial through ``nodes``: row i gives its value at
    targets[i] as a combination of the nodes' values."""
    weights = np.ones((targets.size, nodes.size))
    for j, node in enumerate(nodes):
        for m, other in enumerate(nodes):
            if m != j:
                weights[:, j] *= (targets - other) / (node - other)
    return weights


BDF.order = 2  # the class's order at the default k (the field shadows the ClassVar of Integrator)
