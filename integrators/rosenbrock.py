"""Rosenbrock (linearly implicit) methods: one linear solve per stage with the step's Jacobian, no Newton.

On u = (x, v), u' = F(u) = (v, M^-1 f(x, v)), with J = dF/du at u_n, a Rosenbrock method in the form of Hairer &
Wanner (Solving ODEs II, sec. IV.7, eq. 7.4') is

    (I / (h gamma) - J) U_i = F(u_n + sum_{j<i} a_ij U_j) + sum_{j<i} (c_ij / h) U_j,    u_{n+1} = u_n + sum_i m_i U_i.

With J = [[0, I], [-M^-1 K, -M^-1 D]] (K the Hessian of P at x_n, D the damping matrix there) and U_i = (p_i, q_i),
r_i = (r_x, r_v) the right-hand side, the stage is p/(h gamma) - q = r_x and M q/(h gamma) + K p + D q = M r_v, so

    (M / (h gamma)^2 + D / (h gamma) + K) p = M r_v + (M / (h gamma) + D) r_x,    q = p / (h gamma) - r_x,

one solve of the size of x with the same matrix for every stage (factorised once per step), where M r_v =
f(X_i, V_i) + M sum_j (c_ij / h) q_j: no M^-1 is formed. Pinned dofs keep p = q = 0. Sliding vertices keep U in
their filters' range S: the solve is (S A S + I - S) p = S b, the filtered dynamics' own stage equation (S commutes
with a vertex's lumped mass). The dofs of prescribed paths have the rates J gives them as the exponential
Rosenbrock-Euler method does, dx/dt = v and dv/dt = the path's acceleration, held constant: q = h gamma r_v and
p = h gamma (r_x + q) there, explicitly, and their coupling to the free dofs moves to the right-hand side.

Schemes (coefficients as their authors give them in this form):
- ``ros2``: Verwer, Spee, Blom & Hundsdorfer 1999, gamma = 1 + 1/sqrt(2), a_21 = 1/gamma, c_21 = -2/gamma,
  m = (3/(2 gamma), 1/(2 gamma)); order 2, L-stable.
- ``ros3p``: Lang & Verwer 2001 (BIT 41), gamma = 1/2 + sqrt(3)/6; order 3, A-stable (|R(inf)| = 0.73), designed
  to keep its order on parabolic problems.
- ``rodas3``: Sandu et al. 1997 (Atmos. Environ. 31), gamma = 1/2, four stages; order 3, stiffly accurate,
  L-stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg
from pydantic import Field

from simrun.solvers import SolveStats
from simrun.solvers.linear import record_dense_factorisation, sparse_lu

from .base import Integrator, State, add_mass


@dataclass(frozen=True)
class RosenbrockScheme:
    """gamma; a and c strictly lower triangular (s x s); m (s,); the order."""

    gamma: float
    a: tuple[tuple[float, ...], ...]
    c: tuple[tuple[float, ...], ...]
    m: tuple[float, ...]
    order: int
    m_hat: tuple[float, ...]  # the embedded solution's weights, of order ``order - 1``: the adaptive steps' estimate

    def stability_function(self, z: complex) -> complex:
        """R(z) on y' = lambda y (z = h lambda, J = lambda exact): (1/gamma - z) U_i = z (1 + sum a_ij U_j) +
        sum c_ij U_j with y_n = 1, R = 1 + sum m_i U_i."""
        stages = []
        for i in range(len(self.m)):
            right = z * (1.0 + sum(self.a[i][j] * stages[j] for j in range(i))) + sum(self.c[i][j] * stages[j]
                                                                                 for j in range(i))
            stages.append(right / (1.0 / self.gamma - z))
        return complex(1.0 + sum(weight * stage for weight, stage in zip(self.m, stages)))


def _ros2() -> RosenbrockScheme:
    gamma = 1.0 + 1.0 / math.sqrt(2.0)
    return RosenbrockScheme(gamma, ((0.0, 0.0), (1.0 / gamma, 0.0)), ((0.0, 0.0), (-2.0 / gamma, 0.0)),
                            (1.5 / gamma, 0.5 / gamma), 2,
                            # the embedded first-order solution u_n + U_1 / gamma (Verwer et al. 1999, sec. 2)
                            (1.0 / gamma, 0.0))


def _ros3p() -> RosenbrockScheme:
    gamma = 0.5 + math.sqrt(3.0) / 6.0
    # Lang & Verwer's a_21 = a_31 = 1.267949192431123 = 1/gamma, c_21 = -1.607695154586736 = -1/gamma^2,
    # c_31 = -3.464101615137755 = -2 sqrt(3), c_32 = -1.732050807568877 = -sqrt(3), m = (2, 0.5773502691896258,
    # 0.4226497308103742) = (2, 1/sqrt(3), 1 - 1/sqrt(3)), written in closed form
    root3 = math.sqrt(3.0)
    return RosenbrockScheme(gamma, ((0.0, 0.0, 0.0), (1.0 / gamma, 0.0, 0.0), (1.0 / gamma, 0.0, 0.0)),
                            ((0.0, 0.0, 0.0), (-1.0 / gamma ** 2, 0.0, 0.0), (-2.0 * root3, -root3, 0.0)),
                            (2.0, 1.0 / root3, 1.0 - 1.0 / root3), 3,
                            # the embedded second-order weights as Lang & Verwer give them
                            (2.113248654051871, 1.0, 0.4226497308103742))


def _rodas3() -> RosenbrockScheme:
    return RosenbrockScheme(0.5, ((0.0,) * 4, (0.0, 0.0, 0.0, 0.0), (2.0, 0.0, 0.0, 0.0), (2.0, 0.0, 1.0, 0.0)),
                            ((0.0,) * 4, (4.0, 0.0, 0.0, 0.0), (1.0, -1.0, 0.0, 0.0), (1.0, -1.0, -8.0 / 3.0, 0.0)),
                            (2.0, 0.0, 1.0, 1.0), 3,
                            # the embedded solution is the third stage's (Sandu et al.): the error is U_4
                            (2.0, 0.0, 1.0, 0.0))


SCHEMES = {"ros2": _ros2(), "ros3p": _ros3p(), "rodas3": _rodas3()}


class Rosenbrock(Integrator):
    """Rosenbrock (linearly implicit) methods on u = (x, v): ``scheme`` ros2 (order 2, L-stable), ros3p (order 3,
    A-stable) or rodas3 (order 3, L-stable, stiffly accurate). Per step one Jacobian (K and D at x_n), one
    factorisation of M/(h gamma)^2 + D/(h gamma) + K and one solve and force evaluation per stage; no Newton
    iteration, so nothing converges or fails to: the step is exact for linear problems' own order of accuracy only
    as far as J is exact (it is, at u_n). The module docstring has the stage equations and the sources."""

    name: ClassVar[str] = "rosenbrock"
    order: ClassVar[int] = 3
    family: ClassVar[str] = "rosenbrock"
    # no nonlinear solve, as the exponential Rosenbrock-Euler method: the solver is never called (and IPC, whose
    # steps a line search must cut, is refused)
    explicit: ClassVar[bool] = True
    summary: ClassVar[str] = "linearly implicit Rosenbrock: ros2, ros3p, rodas3; one solve per stage, no Newton"
    scheme: Literal[tuple(SCHEMES)] = Field("ros3p", description="ros2 | ros3p | rodas3")  # type: ignore[valid-type]

    @property
    def order_of_accuracy(self) -> int:
        return SCHEMES[self.scheme].order

    @property
    def error_estimate(self) -> str | None:
        return f"embedded order {SCHEMES[self.scheme].order - 1}"

    @property
    def estimate_order(self) -> int:
        return SCHEMES[self.scheme].order

    def step(self, system, state, dt, solver):
        new, stats, _, _ = self._stages(system, state, dt)
        return new, stats

    def step_with_error(self, system, state, dt, solver, error_tolerance=None):
        """The step and sum_i (m_i - m_hat_i) U_i, its difference from the embedded solution, as (x, v) rows."""
        new, stats, positions, velocities = self._stages(system, state, dt)
        scheme = SCHEMES[self.scheme]
        error = np.zeros((2, system.dof_count))
        for weight, weight_hat, p, q in zip(scheme.m, scheme.m_hat, positions, velocities):
            if weight != weight_hat:
                error[0] += (weight - weight_hat) * p
                error[1] += (weight - weight_hat) * q
        return new, stats, error

    def _stages(self, system, state, dt):
        """(the new state, its statistics, the stages' U_i = (p_i, q_i))."""
        scheme = SCHEMES[self.scheme]
        x, v = state.x, state.v
        scale = dt * scheme.gamma  # h gamma
        stiffness = system.hessian(x)
        damping = system.damping_matrix(x) if system.is_damped else None
        constraints = system.constraints
        moving = constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp)
        free = np.setdiff1d(np.arange(system.dof_count), np.union1d(system.fixed_dofs, moving))
        # A = M/(h gamma)^2 + D/(h gamma) + K; with sliding vertices S A S + I - S
        matrix = add_mass(stiffness * (scale * scale), system) / (scale * scale)
        if damping is not None:
            matrix = matrix + damping / scale
        coupled = matrix  # the free rows' coupling to the prescribed dofs
        sliding = system.sliding.matrix if system.sliding is not None else None
        if sliding is not None:
            matrix = filtered(matrix, sliding)
        solve = factorised(matrix, free)
        positions, velocities = [], []
        for i in range(len(scheme.m)):
            stage_x, stage_v = x, v
            for j in range(i):
                if scheme.a[i][j]:
                    stage_x = stage_x + scheme.a[i][j] * positions[j]
                    stage_v = stage_v + scheme.a[i][j] * velocities[j]
            extra_x, extra_v = np.zeros_like(x), np.zeros_like(v)
            for j in range(i):
                if scheme.c[i][j]:
                    extra_x += (scheme.c[i][j] / dt) * positions[j]
                    extra_v += (scheme.c[i][j] / dt) * velocities[j]
            r_x = stage_v + extra_x
            force = system.force(stage_x, stage_v) + system.mass_times(extra_v)  # M r_v
            right = force + system.mass_times(r_x) / scale
            if damping is not None:
                right = right + damping @ r_x
            p, q = np.zeros_like(x), np.zeros_like(v)
            if moving.size:  # the path's rates, explicitly, and their pull on the free dofs
                q[moving] = scale * (constraints.accelerations_along(stage_v) + extra_v[moving])
                p[moving] = scale * (r_x[moving] + q[moving])
                held = np.zeros_like(x)
                held[moving] = p[moving]
                right = right - coupled @ held
                if damping is not None:  # D q_m with q_m = p_m / (h gamma) - r_x on those dofs
                    correction = np.zeros_like(v)
                    correction[moving] = q[moving] - p[moving] / scale + r_x[moving]
                    right = right - damping @ correction
            if sliding is not None:
                right = sliding @ right
            p[free] = solve(right[free])
            q[free] = p[free] / scale - r_x[free]
            if sliding is not None:
                q = sliding @ q
            positions.append(p)
            velocities.append(q)
        for weight, p, q in zip(scheme.m, positions, velocities):
            x = x + weight * p
            v = v + weight * q
        stages = len(scheme.m)
        return State(state.t + dt, x, v), SolveStats(iterations=0, linear_iterations=stages), positions, velocities


def filtered(matrix, sliding):
    """S A S + I - S: the filtered vertices' directions out of their filters' range get the identity."""
    if scipy.sparse.issparse(matrix):
        return (sliding @ matrix @ sliding + scipy.sparse.identity(sliding.shape[0]) - sliding).tocsr()
    dense = sliding.toarray()
    return dense @ np.asarray(matrix) @ dense + np.eye(dense.shape[0]) - dense


def factorised(matrix, free: np.ndarray, complex_valued: bool = False):
    """The solve of matrix[free, free] y = b, factorised once: SuperLU for a sparse matrix, LU for a dense one;
    complex where the matrix is (Radau IIA's complex eigenblocks), else real (of b's real part).

    Every matrix here (M/(h gamma)^2 + D/(h gamma) + K, lambda^2 M + h lambda D + h^2 K, filtered or not) is symmetric,
    complex symmetric for a complex lambda: SuperLU takes the symmetric paths of the Newton solves (diagonal pivots
    in the MMD ordering of A^T + A, solvers/linear.py ``sparse_lu``), faster than the default COLAMD with partial
    pivoting (docs/performance.md, "Step control and work-precision"); pivoting stays the fallback where a pivot is too
    small."""
    dtype = complex if complex_valued else float

    def cast(right):
        return np.asarray(right, dtype=dtype) if complex_valued else np.real(right)  # SuperLU solves a copy

    if scipy.sparse.issparse(matrix):
        reduced = scipy.sparse.csc_matrix(scipy.sparse.csc_matrix(matrix, dtype=dtype)[free][:, free])
        # A^T in CSC is A in CSC for a symmetric A; its solves are then A^T y = A y = b
        factor, _ = sparse_lu(reduced, spd=False)
        return lambda right: factor.solve(cast(right), trans="T")
    dense = np.asarray(matrix, dtype=dtype)[np.ix_(free, free)]
    record_dense_factorisation()
    factor = scipy.linalg.lu_factor(dense)
    return lambda right: scipy.linalg.lu_solve(factor, cast(right))
