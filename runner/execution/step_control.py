"""Adaptive steps: the step controller that ``simulate`` asks for each step of a step-controlled run.

A step from (t, u) of the proposed size h is taken with the method's own error estimate (``step_with_error``) or,
on request, Richardson's: one step of h against two of h/2, e = (u_{h/2,h/2} - u_h) / (2^p - 1), the two half steps
kept. The estimate's scaled norm err (runner/experiment/step_control.py: scipy's) accepts the step when err <= 1;
otherwise, or when the step's solve did not converge, or its numbers are not finite, the step is taken again from
the same state, smaller. The next size is h min(5, max(0.2, safety err^(-0.7/q) err_previous^(0.4/q))) for the PI
controller (h (safety / err)^(1/q) for I, and after a rejection), capped at 1 after a rejection and at dt_max. A
multistep method grows its step at most 2-fold, and keeps it while the proposal is in [h, 1.2 h); Radau IIA keeps
it below 1.2 h (``step_growth``, ``step_hold_below`` and ``step_hold``). Steps land exactly on the stops: the
duration, the error time and the releases of prescribed paths. Hairer, Norsett & Wanner, Solving ODEs I (1993), sec.
II.4; Hairer & Wanner II (1996), sec. IV.8.
"""

from __future__ import annotations

import math

import numpy as np

from simrun.experiment.step_control import PI_EXPONENTS, uses_richardson
from simrun.integrators import State

MIN_FACTOR, MAX_FACTOR = 0.2, 5.0
# a step that did not converge, or whose numbers are not finite, is taken again at this fraction
FAILED_FACTOR = 0.25
# the previous accepted error the PI controller divides by is at least this (Hairer's DOPRI5: 1e-4)
SMALLEST_PREVIOUS_ERROR = 1e-4
# a stop within this fraction of a step beyond the proposal is reached by this step (no sliver of a step after it)
LANDING_SLACK = 1e-2


class StepTooSmall(RuntimeError):
    """The controller would need a step below step_control.dt_min."""


class StepController:
    """The proposed step, the acceptance test and the counts of one step-controlled run; ``t`` is the time reached.

    stops: the times every step must land on (the duration last)."""

    def __init__(self, params, integrator, system, stops: list[float]):
        self.params = params
        self.richardson = uses_richardson(params, integrator)
        self.integrator = integrator
        self.order = integrator.order_of_accuracy  # Richardson's p
        self.exponent = 1.0 / (self.order + 1 if self.richardson else integrator.estimate_order)
        self.growth = min(MAX_FACTOR, integrator.step_growth)
        self.stops = sorted(stop for stop in set(stops) if stop > 0.0)
        self.t = 0.0
        self.proposed: float | None = None if params.dt_initial == "auto" else float(params.dt_initial)
        self.previous_error = 1.0
        self.rejected_last = False
        self.accepted_steps = self.rejected_steps = self.failed_solves = 0
        self.error_tolerance = (params.tolerance, params.atol)
        self.changed(system)

    def changed(self, system) -> None:
        """The free dofs, whose error the norm measures (pinned and prescribed dofs follow their constraints)."""
        held = np.asarray(system.fixed_dofs, dtype=np.intp)
        constraints = system.constraints
        if constraints is not None and constraints.moving_dofs.size:
            held = np.union1d(held, constraints.moving_dofs)
        free = np.ones(system.dof_count, dtype=bool)
        free[held] = False
        self.free = free

    @property
    def done(self) -> bool:
        return self.t >= self.stops[-1]

    def error_norm(self, error: np.ndarray, start: State, end: State) -> float:
        """err = |e / (atol + rtol max(|u_n|, |u_{n+1}|))| over the free dofs' positions and velocities."""
        params, free = self.params, self.free
        scale_x = params.atol + params.tolerance * np.maximum(np.abs(start.x[free]), np.abs(end.x[free]))
        scale_v = params.atol + params.tolerance * np.maximum(np.abs(start.v[free]), np.abs(end.v[free]))
        scaled = np.concatenate([error[0, free] / scale_x, error[1, free] / scale_v])
        if not scaled.size:
            return 0.0
        if params.norm == "max":
            return float(np.max(np.abs(scaled)))
        return float(np.sqrt(np.mean(scaled * scaled)))

    def initial_step(self, system, state: State) -> float:
        """Hairer's starting step (Solving ODEs I, sec. II.4; scipy's ``select_initial_step``) from F(u_0) and
        F(u_0 + h_0 F(u_0)), with the scales of the error norm at u_0."""
        params, free = self.params, self.free
        u = np.concatenate([state.x[free], state.v[free]])
        scale = params.atol + params.tolerance * np.abs(u)

        def rate(x, v):
            return np.concatenate([v[free], system.acceleration(x, v)[free]])

        def norm(vector):
            return float(np.sqrt(np.mean((vector / scale) ** 2))) if vector.size else 0.0

        acceleration = system.acceleration(state.x, state.v)
        f0 = np.concatenate([state.v[free], acceleration[free]])
        d0, d1 = norm(u), norm(f0)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        x1, v1 = state.x + h0 * state.v, state.v + h0 * acceleration
        d2 = norm(rate(x1, v1) - f0) / h0
        if not math.isfinite(d2):
            return h0
        largest = max(d1, d2)
        exponent = self.exponent if self.richardson else 1.0 / self.integrator.estimate_order_from(state)
        h1 = max(1e-6, 1e-3 * h0) if largest <= 1e-15 else (0.01 / largest) ** exponent
        return min(100.0 * h0, h1)

    def step_size(self, system, state: State) -> float:
        """The size of the next attempt: the proposal, at most dt_max, cut to land on the next stop."""
        if self.proposed is None:
            self.proposed = self._bounded(self.initial_step(system, state))
        stop = next(stop for stop in self.stops if stop > self.t)
        size = self.proposed
        if self.t + size * (1.0 + LANDING_SLACK) >= stop:
            size = stop - self.t
        return size

    def _bounded(self, size: float) -> float:
        params = self.params
        if params.dt_max is not None:
            size = min(size, params.dt_max)
        return max(size, params.dt_min)

    def attempt(self, system, state: State, size: float, solver, prepare) -> tuple[State, object, float]:
        """One try of a step of ``size`` from ``state``: (the new state, its statistics, err). ``prepare(t, dt, x)``
        moves the colliders before each (sub)step."""
        integrator = self.integrator
        if not self.richardson:
            self.exponent = 1.0 / integrator.estimate_order_from(state)  # a variable-order start raises it
            prepare(self.t, size, state.x)
            new, stats, error = integrator.step_with_error(system, state, size, solver, self.error_tolerance)
            return new, stats, self.error_norm(error, state, new)
        prepare(self.t, size, state.x)
        whole, stats = integrator.step(system, state, size, solver)
        half = 0.5 * size
        prepare(self.t, half, state.x)
        middle, first = integrator.step(system, state, half, solver)
        prepare(self.t + half, half, middle.x)
        new, second = integrator.step(system, middle, half, solver)
        stats = _combined(_combined(stats, first), second)
        divisor = 2.0 ** self.order - 1.0
        error = np.stack([(new.x - whole.x) / divisor, (new.v - whole.v) / divisor])
        return new, stats, self.error_norm(error, state, new)

    def judge(self, size: float, error: float, converged: bool) -> bool:
        """Accept (True: t advances by ``size``) or reject the attempt, and propose the next size."""
        params = self.params
        failed = not converged or not math.isfinite(error)
        if failed or error > 1.0:
            self.rejected_steps += 1
            self.failed_solves += not converged
            factor = FAILED_FACTOR if failed else max(MIN_FACTOR, params.safety * error ** -self.exponent)
            self.proposed = size * factor
            self.rejected_last = True
            if self.proposed < params.dt_min:
                why = "did not converge" if not converged else f"had error {error:.3g} (of the tolerance)"
                raise StepTooSmall(f"step_control: at t = {self.t:.6g} s a step of {size:.3g} s {why}; the next would "
                                   f"be {self.proposed:.3g} s, below dt_min {params.dt_min:g} s")
            return False
        if error == 0.0:
            factor = MAX_FACTOR
        elif params.controller == "pi" and not self.rejected_last:
            alpha, beta = PI_EXPONENTS
            factor = (params.safety * error ** (-alpha * self.exponent)
                      * max(self.previous_error, SMALLEST_PREVIOUS_ERROR) ** (beta * self.exponent))
        else:
            factor = params.safety * error ** -self.exponent
        factor = min(self.growth, max(MIN_FACTOR, factor))
        low, high = self.integrator.step_hold_below, self.integrator.step_hold  # an accepted step kept in [low, high)
        if self.rejected_last:
            factor = min(factor, 1.0)
        elif low <= factor < high:
            factor = 1.0
        proposal = size * factor
        if self.proposed is not None and size < self.proposed and factor >= 1.0:
            proposal = max(proposal, self.proposed)  # a step cut short to land on a stop: the proposal it was cut from
        self.proposed = self._bounded(proposal)
        self.previous_error = error
        self.rejected_last = False
        self.accepted_steps += 1
        stop = next(stop for stop in self.stops if stop > self.t)
        self.t = stop if self.t + size >= stop else self.t + size  # a landing step ends exactly on the stop
        return True


def _combined(first, later):
    return later if first is None else first.followed_by(later)
