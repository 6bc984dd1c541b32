"""The exponential Rosenbrock-Euler method of Chen, Ascher & Pai."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from simrun.solvers import EXPLICIT_STEP

from .base import Integrator, State, mass_refusal


class ExponentialRosenbrockEuler(Integrator):
    """u_{n+1} = u_n + h phi_1(h J_n) F(u_n),  u = (x, v),  F(u) = (v, M^-1 f(x, v)),  phi_1(z) = (e^z - 1)/z,
    J_n = [[0, I], [-M^-1 K(x_n), -M^-1 D(x_n)]] (K the Hessian of P; D held constant over the step).

    h phi_1(h J) F is the last column of exp([[h J, h F], [0, 0]]), applied to e_last with
    scipy.sparse.linalg.expm_multiply, so no matrix exponential is formed and J is sparse whenever
    the system's Hessian is (cloth); a dense Hessian (a small system) gives a dense J. Fixed degrees of freedom have zero rows in J and zero rates, so they stay fixed.
    Exact for linear problems (constant K and D): no artificial damping and no stability limit
    there, at any h. Second order when J_n is the exact Jacobian of F (constant D); with a
    position-dependent D the neglected dD/dx v term makes it first order. No nonlinear solve (the
    step reports no solver iterations); the cost is that of expm_multiply, which grows with
    ||h J||. Source: Chen, Ascher & Pai, "Exponential Rosenbrock-Euler integrators for elastodynamic
    simulation", IEEE TVCG 24 (2018); Hochbruck, Ostermann & Schweitzer, SIAM J. Numer. Anal. 47 (2009).
    """

    name: ClassVar[str] = "exponential_rosenbrock_euler"
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "Chen-Ascher-Pai exponential Rosenbrock-Euler; exact on linear problems, 2nd order"

    def refusal(self, system):
        return mass_refusal(self.name, system) or super().refusal(system)

    def step(self, system, state, dt, solver):
        n = system.dof_count
        free = np.ones(n)
        free[system.fixed_dofs] = 0.0
        stiffness = system.hessian(state.x)
        damping = system.damping_matrix(state.x)
        if system.sliding is not None:  # S K and S D: the accelerations of sliding vertices stay in their filters
            stiffness = system.sliding.matrix @ stiffness
            damping = None if damping is None else system.sliding.matrix @ damping
        if system.constraints is not None and system.constraints.moving_dofs.size:
            moving = system.constraints.moving_dofs
            position_rate = free.copy()
            position_rate[moving] = 1.0  # a vertex on a prescribed path moves with its velocity, unforced
        else:
            position_rate = free
        acceleration = system.acceleration(state.x, state.v)
        scaled_inverse_mass = dt * free / system.mass  # zero rows of J for fixed dofs
        # h [[J, F], [0, 0]]: rows for x, rows for v, and the zero row that makes phi_1 appear;
        # sparse when the system's Hessian is (large systems), dense otherwise (cheaper to assemble)
        if scipy.sparse.issparse(stiffness):
            inverse_mass = scipy.sparse.diags_array(scaled_inverse_mass)
            augmented = scipy.sparse.block_array([
                [None, scipy.sparse.diags_array(dt * position_rate), (dt * position_rate * state.v)[:, None]],
                [-(inverse_mass @ stiffness),
                 None if damping is None else -(inverse_mass @ scipy.sparse.csr_array(damping)),
                 (dt * acceleration)[:, None]],
                [None, None, scipy.sparse.csr_array((1, 1))],
            ], format="csr")
        else:
            augmented = np.zeros((2 * n + 1, 2 * n + 1))
            augmented[np.arange(n), n + np.arange(n)] = dt * position_rate
            augmented[n:2 * n, :n] = -scaled_inverse_mass[:, None] * np.asarray(stiffness)
            if damping is not None:
                dense_damping = damping.toarray() if scipy.sparse.issparse(damping) else np.asarray(damping)
                augmented[n:2 * n, n:2 * n] = -scaled_inverse_mass[:, None] * dense_damping
            augmented[:n, -1] = dt * position_rate * state.v
            augmented[n:2 * n, -1] = dt * acceleration
        last = np.zeros(2 * n + 1)
        last[-1] = 1.0
        increment = scipy.sparse.linalg.expm_multiply(augmented, last)
        return State(state.t + dt, state.x + increment[:n], state.v + increment[n:2 * n]), EXPLICIT_STEP
