"""Radau IIA, the coupled stage system solved by simplified Newton in the real and complex eigenblocks of A^-1
(Hairer & Wanner, Solving ODEs II, sec. IV.8: RADAU5), with the stage positions as the unknowns.

On u = (x, v), u' = (v, M^-1 f(x, v)), the stages U_i = u_n + Z_i satisfy Z = h (A x I) F(u_n + Z). With W = A^-1
and Z_i = (X_i, V_i) (displacements from x_n and v_n), the position rows give V = (W X) / h - v_n 1, so the
velocity of stage i is (W X)_i / h, and the velocity rows times h M become, for the stage displacements X alone,

    G(X)_i = M (W^2 X)_i - h (W 1)_i M v_n - h^2 f(x_n + X_i, (W X)_i / h) = 0,   i = 1..s,

s n unknowns. Simplified Newton takes K and D at x_n for every stage: dG/dX ~ W^2 x M + h W x D + h^2 I x K. With
W = T diag(lambda) T^-1 (one real eigenvalue and a complex pair for s = 3, a complex pair for s = 2), the change of
variables X = (T x I) Y decouples the iteration into lambda^2 M + h lambda D + h^2 K per eigenvalue: one real and
one complex solve of the size of x per iteration for s = 3, one complex for s = 2 (the conjugate eigenvalue's
solution is the conjugate). The method is stiffly accurate, u_{n+1} = U_s. Orders 2s - 1 (3 and 5), L-stable.

A fixed step evaluates K and D at x_n and factorises its blocks. A step-controlled run saves as RADAU5 does (Hairer &
Wanner II, sec. IV.8): each step starts from the last step's collocation polynomial, extrapolated; K and D are kept
until an iteration contracts slowly (or fails, when they are evaluated at x_n and the step is solved again); the
blocks are kept while h is, and the step controller keeps h for any proposal below 1.2 h (scipy's Radau). On the
16 x 16 cloth at tolerance 1e-6 that took 887 steps with 7 Jacobians and 34 sets of blocks (``jacobian_refresh``
0.1; 878 steps, 112 Jacobians and 127 sets at RADAU5's default 1e-3), where a factorisation per step took 1,170
steps (docs/performance.md).

Pinned dofs keep X = 0; the dofs of prescribed paths take X_i = p(t_n + c_i h) - x_n, their stage positions on the
path, and are held there by the iteration. Sliding vertices keep X in their filters' range S: the residual is
filtered and each block solve is (S B S + I - S) y = S r, the filtered dynamics' own Newton equation.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
import scipy.sparse
from pydantic import Field

from simrun.solvers import SolveStats
from simrun.solvers.base import max_norm
from simrun.systems.forms import contact_needs_step_filter

from .base import Integrator, State
from .multistep import lagrange_weights
from .rosenbrock import factorised, filtered


def radau_tableau(stages: int) -> tuple[np.ndarray, np.ndarray]:
    """(A, c) of the s-stage Radau IIA method (s = 2: order 3; s = 3: order 5); b is A's last row."""
    if stages == 2:
        return np.array([[5.0 / 12.0, -1.0 / 12.0], [3.0 / 4.0, 1.0 / 4.0]]), np.array([1.0 / 3.0, 1.0])
    r = math.sqrt(6.0)
    A = np.array([[(88.0 - 7.0 * r) / 360.0, (296.0 - 169.0 * r) / 1800.0, (-2.0 + 3.0 * r) / 225.0],
                  [(296.0 + 169.0 * r) / 1800.0, (88.0 + 7.0 * r) / 360.0, (-2.0 - 3.0 * r) / 225.0],
                  [(16.0 - r) / 36.0, (16.0 + r) / 36.0, 1.0 / 9.0]])
    return A, np.array([(4.0 - r) / 10.0, (4.0 + r) / 10.0, 1.0])


@functools.cache
def _transformation(stages: int):
    """(c, W = A^-1, W^2, W's eigenvalues, T, T^-1, W 1) of the s-stage method: the same for every step."""
    A, c = radau_tableau(stages)
    W = np.linalg.inv(A)
    values, T = np.linalg.eig(W)
    return c, W, W @ W, values, T, np.linalg.inv(T), W.sum(axis=1)


def stability_function(stages: int, z: complex) -> complex:
    """R(z) = 1 + z b^T (I - z A)^-1 1, b = A's last row."""
    A, _ = radau_tableau(stages)
    ones = np.ones(stages)
    return complex(1.0 + z * A[-1] @ np.linalg.solve(np.eye(stages) - z * A, ones))


class RadauIIA(Integrator):
    """Radau IIA with ``stages`` 2 (order 3) or 3 (order 5): the coupled stage system in the stage positions, solved
    by simplified Newton in the eigenblocks of A^-1 (RADAU5's transformation), with K and D at the step's start;
    L-stable and stiffly accurate. The iteration stops when the largest update of a stage position falls below
    ``tolerance`` times the largest stage displacement (plus 1e-14 m), or after ``max_iterations`` (not converged)."""

    name: ClassVar[str] = "radau_iia"
    order: ClassVar[int] = 5
    family: ClassVar[str] = "radau"
    explicit: ClassVar[bool] = False
    summary: ClassVar[str] = "Radau IIA (stages 2: order 3, 3: order 5), simplified Newton in A's eigenblocks; L-stable"
    stages: Literal[2, 3] = Field(3, description="2 (order 3) | 3 (order 5)")
    tolerance: float = Field(1e-10, gt=0, lt=1, allow_inf_nan=False,
                             description="the simplified Newton's stop: the update relative to the stage displacements")
    max_iterations: int = Field(20, ge=1, le=1000, description="simplified Newton iterations per step")
    jacobian_refresh: float = Field(
        0.1, ge=0, lt=1, allow_inf_nan=False,
        description="step-controlled runs: K and D are evaluated anew at the next step after an iteration of more "
                    "than two updates contracting by more than this per update (RADAU5's THET)")
    # an accepted step's proposal below 1.2 h keeps the step, and with it the factorised blocks (scipy's Radau; RADAU5
    # keeps it in [h, 1.2 h]: QUOT1, QUOT2)
    step_hold: ClassVar[float] = 1.2
    step_hold_below: ClassVar[float] = 0.0

    @property
    def order_of_accuracy(self) -> int:
        return 2 * self.stages - 1

    def refusal(self, system):
        if contact_needs_step_filter(system):
            return ("solves its stages together by a Newton iteration without a line search, which CCD cannot cut: "
                    "IPC contact needs an incremental-potential method (backward_euler, sdirk2, bdf2)")
        return super().refusal(system)

    @property
    def error_estimate(self) -> str | None:
        return "RADAU5's embedded order 3" if self.stages == 3 else None

    @property
    def estimate_order(self) -> int:
        return 4 if self.stages == 3 else super().estimate_order

    def step(self, system, state, dt, solver):
        new, stats, _ = self._solve(system, state, dt, economy=False)
        return new, stats

    def step_with_error(self, system, state, dt, solver, error_tolerance=None):
        """The step and RADAU5's estimate (Hairer & Wanner II, sec. IV.8, eq. 8.20; scipy's Radau): with mu the real
        eigenvalue of A^-1, e = (mu/h - J)^-1 (F(u_n) + sum_i E_i Z_i / h), E = (-13 - 7 sqrt 6, -13 + 7 sqrt 6, -1)/3.
        With J = [[0, I], [-M^-1 K, -M^-1 D]] and r = (r_x, r_v) that is (mu^2 M + h mu D + h^2 K) e_v = h^2 (mu/h M r_v
        - K r_x), the real block of the iteration, and e_x = h (r_x + e_v) / mu. K is the iteration's: RADAU5 filters
        its estimate with the same (possibly older) Jacobian and factors.

        A step-controlled run reuses (RADAU5's economy): the new state's ``reusable`` holds K, D, the blocks and the
        step's collocation polynomial, and the next step starts from the polynomial's extrapolation, with the same K
        (and the same factors while h is unchanged) unless the last iteration contracted slowly. With
        ``error_tolerance`` (rtol, atol) the iteration stops in the error norm's own scale (``_Stop``)."""
        if self.stages != 3:
            raise TypeError("radau_iia has an error estimate of its own with 3 stages only")
        new, stats, kept = self._solve(system, state, dt, economy=True, error_tolerance=error_tolerance)
        h, r6 = dt, math.sqrt(6.0)
        weights = np.array([-13.0 - 7.0 * r6, -13.0 + 7.0 * r6, -1.0]) / 3.0
        displacement_v = kept.velocities - state.v  # V_i: the stages' velocity displacements
        r_x = state.v + weights @ kept.X / h
        mass_r_v = system.force(state.x, state.v) + system.mass_times(weights @ displacement_v / h)
        real_value = kept.real_value
        right = h * h * (real_value / h * mass_r_v - kept.stiffness @ r_x)
        if system.sliding is not None:
            right = system.sliding.matrix @ right
        free = kept.free
        error = np.zeros((2, system.dof_count))
        error[1, free] = kept.blocks[kept.real_index](right[free])
        error[0, free] = h * (r_x[free] + error[1, free]) / real_value
        return new, stats, error

    def _solve(self, system, state, dt, economy: bool, error_tolerance=None):
        """(the new state, its statistics, the step's ``_Reusable``: what the error estimate and, with ``economy``,
        the next step reuse). Without economy every step evaluates K and D at x_n, factorises its blocks and starts
        from X = 0 (the fixed-step form, whose amplification the analyses probe)."""
        s, h, n = self.stages, dt, system.dof_count
        c, W, WW, values, T, T_inverse, row_sums = _transformation(s)
        x, v = state.x, state.v
        # the held dofs: pinned (X = 0) and on prescribed paths (X_i on the path at t_n + c_i h)
        constraints = system.constraints
        moving = constraints.moving_dofs if constraints is not None else ()
        last = state.reusable if economy else None
        if not (isinstance(last, _Reusable) and last.system is system):
            last = None  # a first step, a released system (a system of its own): nothing to reuse
        if last is not None:  # a system's pinned and prescribed dofs are its own: the same as the last step's
            held, free = last.held, last.free
        else:
            held = np.union1d(system.fixed_dofs, moving) if len(moving) else system.fixed_dofs
            free = np.setdiff1d(np.arange(n), held)
        X = np.zeros((s, n)) if last is None else last.extrapolated(state.t, h, c)
        X[:, held] = 0.0
        for i in range(s if len(moving) else 0):
            X[i, moving] = constraints.path(state.t + c[i] * h)[0] - x[moving]
        start = X
        sliding = system.sliding.matrix if system.sliding is not None else None
        if last is None or last.refresh:
            stiffness, damping, current = _jacobian(system, x)
            blocks = None
        else:
            stiffness, damping, current = last.stiffness, last.damping, False
            blocks = last.blocks if last.h == h else None
        if blocks is None:
            blocks = _blocks(system, values, h, stiffness, damping, free, sliding)
        stop = _Stop.for_step(self, state, free, h, error_tolerance, last)
        momentum = system.mass_times(v)
        iterations = 0
        while True:
            X, taken, converged, residual = self._iterate(system, x, momentum, X, h, free, held, blocks, sliding, stop)
            iterations += taken
            if converged or current:
                break
            # a stale Jacobian that does not contract: K and D at x_n, the blocks again, the iteration from its start
            stiffness, damping, current = _jacobian(system, x)
            blocks = _blocks(system, values, h, stiffness, damping, free, sliding)
            X = start
            stop = _Stop.for_step(self, state, free, h, error_tolerance, None)
        velocities = (W @ X) / h
        real = [k for k, value in enumerate(values) if abs(value.imag) <= 1e-12]
        kept = _Reusable(system=system, held=held, free=free, stiffness=stiffness, damping=damping, h=h, blocks=blocks,
                         real_index=real[0] if real else None, real_value=values[real[0]].real if real else None,
                         t0=state.t, X=X, velocities=velocities, contraction=stop.contraction,
                         refresh=taken > 2 and stop.rate > self.jacobian_refresh)
        linear = iterations * len([block for block in blocks if block is not None])
        return (State(state.t + h, x + X[-1], velocities[-1], (), kept if economy else None),
                SolveStats(iterations=iterations, linear_iterations=linear, residual=residual, converged=converged),
                kept)

    def _iterate(self, system, x, momentum, X, h, free, held, blocks, sliding, stop: "_Stop"):
        """Simplified Newton from X, until ``stop`` says it has converged or cannot: (X, iterations, converged, the
        last residual). The stages' forces are evaluated together (``System.forces``); the transformations by T^-1
        and T are real products with their real and imaginary parts, on the free dofs alone."""
        c, W, WW, values, T, T_inverse, row_sums = _transformation(self.stages)
        inverse_real, inverse_imag = np.ascontiguousarray(T_inverse.real), np.ascontiguousarray(T_inverse.imag)
        # the eigenvalues whose blocks are solved, and each conjugate's partner (its update is the partner's conjugate)
        solved = [k for k, block in enumerate(blocks) if block is not None]
        conjugates = [(k, int(np.argmin(np.abs(values - np.conj(values[k]))))) for k, block in enumerate(blocks)
                      if block is None]
        drift = (h * row_sums)[:, None] * momentum
        update_real = np.zeros((self.stages, free.size))
        update_imag = np.zeros((self.stages, free.size))
        residual = math.inf
        for iteration in range(1, self.max_iterations + 1):
            velocities = (W @ X) / h
            rows = _mass_rows(system, WW @ X) - drift - (h * h) * system.forces(x + X, velocities)
            rows[:, held] = 0.0
            if sliding is not None:
                rows = (sliding @ rows.T).T
            residual = max_norm(rows)
            free_rows = rows[:, free]
            transformed_real, transformed_imag = inverse_real @ free_rows, inverse_imag @ free_rows
            for k in solved:
                if abs(values[k].imag) > 1e-12:
                    solution = blocks[k](-(transformed_real[k] + 1j * transformed_imag[k]))
                    update_real[k], update_imag[k] = solution.real, solution.imag
                else:
                    update_real[k] = blocks[k](-transformed_real[k])
            for k, partner in conjugates:
                update_real[k], update_imag[k] = update_real[partner], -update_imag[partner]
            change = np.zeros_like(X)
            change[:, free] = T.real @ update_real - T.imag @ update_imag  # Re(T U)
            if sliding is not None:
                change = (sliding @ change.T).T
            X = X + change
            verdict = stop.judge(change, X, iteration, self.max_iterations)
            if verdict is not None:
                return X, iteration, verdict, residual
        return X, self.max_iterations, False, residual


@dataclass
class _Stop:
    """When the simplified Newton iteration of a step stops (Hairer & Wanner II, sec. IV.8, p. 121; RADAU5).

    With theta the rate |dX_k| / |dX_{k-1}|, the error left after an update is about theta / (1 - theta) |dX_k|; the
    iteration has converged when ``contraction`` |dX_k| <= ``bound``, where ``contraction`` is theta / (1 - theta)
    once a rate is known and, before that, the last step's raised to the power 0.8 (1 at a first step): so that a
    step whose prediction needs one update takes one. In a step-controlled run (``error_tolerance`` (rtol, atol))
    |dX| is the rms over the free dofs of the stage positions' and velocities' updates, each divided by
    atol + rtol |u_n|, and the bound is max(10 eps / rtol, min(0.03, rtol^(1/2))) (RADAU5's FNEWT; scipy's Radau): the
    iteration's error is then a small fraction of what the error estimate accepts. A fixed step stops when the largest
    update of a stage position itself is below ``tolerance`` times the largest stage displacement plus 1e-14 m (the
    rate's bound, from two updates, stopped it early enough to cap the chain's observed order at 2.3). A
    step-controlled iteration gives up (not converged: the step is taken again, with a new Jacobian or smaller) when
    theta >= 0.99, or when the rate would not reach the bound within the iterations left; a fixed step iterates to
    the last."""

    # 1 / (atol + rtol |x_n|) per dof, 0 on the held ones (their updates are 0), or None: the fixed-step form's max norm
    inverse_x: np.ndarray | None
    inverse_v: np.ndarray | None  # 1 / (h (atol + rtol |v_n|)), 0 on the held dofs
    count: int  # the free dofs
    h: float
    tolerance: float  # the fixed-step form's relative bound; the step-controlled form's FNEWT
    contraction: float
    rate: float = 0.0
    previous: float | None = None

    @classmethod
    def for_step(cls, method: "RadauIIA", state: State, free: np.ndarray, h: float, error_tolerance, last) -> "_Stop":
        contraction = max(last.contraction if last is not None else 1.0, EPSILON) ** 0.8
        if error_tolerance is None:
            return cls(None, None, free.size, h, method.tolerance, contraction)
        rtol, atol = error_tolerance
        bound = max(10.0 * EPSILON / rtol, min(0.03, math.sqrt(rtol)))
        inverse_x, inverse_v = np.zeros_like(state.x), np.zeros_like(state.v)
        inverse_x[free] = 1.0 / (atol + rtol * np.abs(state.x[free]))
        inverse_v[free] = 1.0 / (h * (atol + rtol * np.abs(state.v[free])))
        return cls(inverse_x, inverse_v, free.size, h, bound, contraction)

    def judge(self, change: np.ndarray, X: np.ndarray, iteration: int, max_iterations: int) -> bool | None:
        """After an update: True (converged), False (gave up: no convergence) or None (iterate on)."""
        if self.inverse_x is None:
            size, bound, give_up = max_norm(change), self.tolerance * max_norm(X) + 1e-14, False
        else:
            W = _transformation(change.shape[0])[1]
            positions = change * self.inverse_x
            velocities = (W @ change) * self.inverse_v
            size = math.sqrt((np.vdot(positions, positions) + np.vdot(velocities, velocities))
                             / (2 * change.shape[0] * self.count)) if self.count else 0.0
            bound, give_up = self.tolerance, True
        if not math.isfinite(size):  # the step's numbers are gone: the run diverges, or the controller retries
            return False
        if self.previous is not None:
            self.rate = size / self.previous if self.previous > 0.0 else 0.0
            if self.rate < 0.99:
                self.contraction = self.rate / (1.0 - self.rate)
                left = max_iterations - iteration
                if give_up and left and self.contraction * size * self.rate ** left > bound:
                    return False
            elif give_up:
                return False
        if (self.contraction if give_up else 1.0) * size <= bound or size <= 1e-300:
            return True
        self.previous = max(size, 1e-300)
        return None


EPSILON = float(np.finfo(float).eps)


@dataclass
class _Reusable:
    """What a Radau IIA step leaves for the next (RADAU5's economy): K and D, the blocks factorised for step h, the
    held and free dofs they were reduced to, the system they belong to, and the step's collocation polynomial (from
    t0 over h: X(0) = 0, X(c_i) = X_i, the stage displacements, with their velocities); ``refresh``: evaluate K anew."""

    system: object
    held: np.ndarray
    free: np.ndarray
    stiffness: object
    damping: object
    h: float
    blocks: list
    real_index: int | None
    real_value: float | None
    t0: float
    X: np.ndarray
    velocities: np.ndarray
    contraction: float  # the iteration's last theta / (1 - theta) (``_Stop``)
    refresh: bool

    def extrapolated(self, t: float, h: float, c: np.ndarray) -> np.ndarray:
        """The stage displacements that the polynomial predicts for a step from t of size h: X(tau_i) - X(tau_t), with
        tau = (time - t0) / h_polynomial (Hairer & Wanner II, sec. IV.8: the starting values of RADAU5)."""
        nodes = np.concatenate([[0.0], c])
        values = np.vstack([np.zeros((1, self.X.shape[1])), self.X])
        taus = (t + np.concatenate([[0.0], c]) * h - self.t0) / self.h
        weights = lagrange_weights(nodes, taus)
        predicted = weights @ values
        return predicted[1:] - predicted[0]


def _jacobian(system, x):
    """(K, D, True): the Jacobian's parts at x, current there."""
    return system.hessian(x), (system.damping_matrix(x) if system.is_damped else None), True


def _blocks(system, values, h, stiffness, damping, free, sliding):
    """One factorised lambda^2 M + h lambda D + h^2 K per distinct eigenvalue lambda of A^-1 (a conjugate pair shares
    one: None for the second)."""
    blocks = []
    for value in values:
        if value.imag < -1e-12:
            blocks.append(None)  # the conjugate of a block already made
            continue
        complex_valued = abs(value.imag) > 1e-12
        value = value if complex_valued else value.real
        matrix = _mass_plus(system, value * value, stiffness * (h * h) + (0 if damping is None else damping * (h * value)))
        if sliding is not None:
            matrix = filtered(matrix, sliding)
        blocks.append(factorised(matrix, free, complex_valued))
    return blocks


def _mass_rows(system, rows: np.ndarray) -> np.ndarray:
    """M times every row of ``rows`` (M with a consistent mass's correction where it has one)."""
    product = system.mass * rows
    if system.mass_correction is not None:
        product += (system.mass_correction @ rows.T).T
    return product


def _mass_plus(system, factor, matrix):
    """factor M + matrix (a real or complex factor; M with a consistent mass's correction where it has one)."""
    mass = scipy.sparse.diags_array(system.mass) if scipy.sparse.issparse(matrix) else np.diag(system.mass)
    if system.mass_correction is not None:
        mass = mass + (system.mass_correction if scipy.sparse.issparse(matrix) else system.mass_correction.toarray())
    return factor * mass + matrix
