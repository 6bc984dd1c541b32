"""Radau IIA, the coupled stage system solved by simplified Newton in the real and complex eigenblocks of A^-1
(Hairer & Wanner, Solving ODEs II, sec. IV.8: RADAU5), with the stage positions as the unknowns (issue 28).

On u = (x, v), u' = (v, M^-1 f(x, v)), the stages U_i = u_n + Z_i satisfy Z = h (A x I) F(u_n + Z). With W = A^-1
and Z_i = (X_i, V_i) (displacements from x_n and v_n), the position rows give V = (W X) / h - v_n 1, so the
velocity of stage i is (W X)_i / h, and the velocity rows times h M become, for the stage displacements X alone,

    G(X)_i = M (W^2 X)_i - h (W 1)_i M v_n - h^2 f(x_n + X_i, (W X)_i / h) = 0,   i = 1..s,

s n unknowns. Simplified Newton takes K and D at x_n for every stage: dG/dX ~ W^2 x M + h W x D + h^2 I x K. With
W = T diag(lambda) T^-1 (one real eigenvalue and a complex pair for s = 3, a complex pair for s = 2), the change of
variables X = (T x I) Y decouples the iteration into lambda^2 M + h lambda D + h^2 K per eigenvalue: one real and
one complex solve of the size of x per iteration for s = 3, one complex for s = 2 (the conjugate eigenvalue's
solution is the conjugate). Each matrix is factorised once per step. The method is stiffly accurate, u_{n+1} =
U_s. Orders 2s - 1 (3 and 5), L-stable.

Pinned dofs keep X = 0; the dofs of prescribed paths take X_i = p(t_n + c_i h) - x_n, their stage positions on the
path, and are held there by the iteration. Sliding vertices keep X in their filters' range S: the residual is
filtered and each block solve is (S B S + I - S) y = S r, the filtered dynamics' own Newton equation.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar, Literal

import numpy as np
import scipy.sparse
from pydantic import Field

from simrun.solvers import SolveStats
from simrun.solvers.base import max_norm

from .base import Integrator, State
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

    @property
    def order_of_accuracy(self) -> int:
        return 2 * self.stages - 1

    def refusal(self, system):
        if system.has_contact and system.contact_needs_step_filter:
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
        new, stats, _ = self._solve(system, state, dt)
        return new, stats

    def step_with_error(self, system, state, dt, solver):
        """The step and RADAU5's estimate (Hairer & Wanner II, sec. IV.8, eq. 8.20; scipy's Radau): with mu the real
        eigenvalue of A^-1, e = (mu/h - J)^-1 (F(u_n) + sum_i E_i Z_i / h), E = (-13 - 7 sqrt 6, -13 + 7 sqrt 6, -1)/3.
        With J = [[0, I], [-M^-1 K, -M^-1 D]] and r = (r_x, r_v) that is (mu^2 M + h mu D + h^2 K) e_v = h^2 (mu/h M r_v
        - K r_x), the real block of the iteration, and e_x = h (r_x + e_v) / mu."""
        if self.stages != 3:
            raise TypeError("radau_iia has an error estimate of its own with 3 stages only")
        new, stats, (X, velocities, real_block, real_value, free, stiffness) = self._solve(system, state, dt)
        h, r6 = dt, math.sqrt(6.0)
        weights = np.array([-13.0 - 7.0 * r6, -13.0 + 7.0 * r6, -1.0]) / 3.0
        displacement_v = velocities - state.v  # V_i: the stages' velocity displacements
        r_x = state.v + weights @ X / h
        mass_r_v = system.force(state.x, state.v) + system.mass_times(weights @ displacement_v / h)
        right = h * h * (real_value / h * mass_r_v - stiffness @ r_x)
        if system.sliding is not None:
            right = system.sliding.matrix @ right
        error = np.zeros((2, system.dof_count))
        error[1, free] = real_block(right[free])
        error[0, free] = h * (r_x[free] + error[1, free]) / real_value
        return new, stats, error

    def _solve(self, system, state, dt):
        """(the new state, its statistics, what the error estimate reuses: the stage displacements X, the stage
        velocities, the real eigenvalue's factorised block and the eigenvalue (None for 2 stages), the free dofs, K)."""
        s, h, n = self.stages, dt, system.dof_count
        c, W, WW, values, T, T_inverse, row_sums = _transformation(s)
        x, v = state.x, state.v
        stiffness = system.hessian(x)
        damping = system.damping_matrix(x) if system.is_damped else None
        # the held dofs: pinned (X = 0) and on prescribed paths (X_i on the path at t_n + c_i h)
        held = system.fixed_dofs
        X = np.zeros((s, n))
        constraints = system.constraints
        if constraints is not None and constraints.moving_dofs.size:
            moving = constraints.moving_dofs
            held = np.union1d(held, moving)
            for i in range(s):
                X[i, moving] = constraints.path(state.t + c[i] * h)[0] - x[moving]
        free = np.setdiff1d(np.arange(n), held)
        sliding = system.sliding.matrix if system.sliding is not None else None
        # one factorisation per distinct eigenvalue (a conjugate pair shares one)
        blocks = []
        for k, value in enumerate(values):
            if value.imag < -1e-12:
                blocks.append(None)  # the conjugate of a block already made
                continue
            complex_valued = abs(value.imag) > 1e-12
            value = value if complex_valued else value.real
            matrix = _mass_plus(system, value * value, stiffness * (h * h) + (0 if damping is None else damping * (h * value)))
            if sliding is not None:
                matrix = filtered(matrix, sliding)
            blocks.append(factorised(matrix, free, complex_valued))
        momentum = system.mass_times(v)
        iterations, converged, residual = 0, False, math.inf
        for iterations in range(1, self.max_iterations + 1):
            velocities = (W @ X) / h
            residual_rows = np.empty((s, n))
            for i in range(s):
                residual_rows[i] = (system.mass_times(WW[i] @ X) - h * row_sums[i] * momentum
                                    - h * h * system.force(x + X[i], velocities[i]))
            residual_rows[:, held] = 0.0
            if sliding is not None:
                residual_rows = (sliding @ residual_rows.T).T
            residual = max_norm(residual_rows)
            transformed = T_inverse @ residual_rows  # (s, n), complex
            update = np.zeros((s, n), dtype=complex)
            for k, value in enumerate(values):
                if blocks[k] is not None:
                    update[k, free] = blocks[k](-transformed[k, free])
            for k, value in enumerate(values):  # the conjugate eigenvalue's update is the conjugate of its pair's
                if blocks[k] is None:
                    partner = int(np.argmin(np.abs(values - np.conj(value))))
                    update[k] = np.conj(update[partner])
            change = np.real(T @ update)
            if sliding is not None:
                change = (sliding @ change.T).T
            X = X + change
            if max_norm(change) <= self.tolerance * max_norm(X) + 1e-14:
                converged = True
                break
        velocities = (W @ X) / h
        real = [k for k, value in enumerate(values) if abs(value.imag) <= 1e-12]
        reused = (X, velocities, blocks[real[0]] if real else None, values[real[0]].real if real else None, free, stiffness)
        return (State(state.t + h, x + X[-1], velocities[-1]),
                SolveStats(iterations=iterations, linear_iterations=iterations * len([b for b in blocks if b is not None]),
                           residual=residual, converged=converged), reused)


def _mass_plus(system, factor, matrix):
    """factor M + matrix (a real or complex factor; M with a consistent mass's correction where it has one)."""
    mass = scipy.sparse.diags_array(system.mass) if scipy.sparse.issparse(matrix) else np.diag(system.mass)
    if system.mass_correction is not None:
        mass = mass + (system.mass_correction if scipy.sparse.issparse(matrix) else system.mass_correction.toarray())
    return factor * mass + matrix
