"""One-step implicit methods as incremental potentials: implicit midpoint, Newmark, generalized-alpha,
the semi-implicit (one Newton iteration) backward Euler of Baraff & Witkin, and the average vector field.

Each builds its problem from a predictor y~, a scale c h^2 and the velocity map v(y) = (y - a)/b of its
unknown y, hands it to the solver, and reconstructs (x_{n+1}, v_{n+1}) from the minimiser.
"""

from __future__ import annotations

import functools
from typing import ClassVar

import numpy as np
from pydantic import Field

from .base import Integrator, State, StepPlan, on_paths, solve_step
from .euler import BackwardEuler
from .segment import SegmentPotential


class ImplicitMidpoint(Integrator):
    """x_{n+1} = x_n + h v_{n+1/2},  M (v_{n+1} - v_n) = h f(x_{n+1/2}, v_{n+1/2}),  (.)_{n+1/2} = mean of n and n+1.

    Incremental potential in y = x_{n+1/2}: y~ = x_n + h/2 v_n, c = 1/4, v_{n+1/2} = (y - x_n)/(h/2);
    then x_{n+1} = 2 y - x_n, v_{n+1} = 2 v_{n+1/2} - v_n. Second order, symplectic, A-stable with
    |R(i x)| = 1: no artificial damping at any h (the spring's energy is conserved exactly, only
    the phase lags); conserves angular momentum under central forces. Physical damping is applied
    at the midpoint velocity. Source: Hairer, Lubich & Wanner, Geometric Numerical Integration
    (2006), ch. I, IV and VI; lecture notes (implicit midpoint as an incremental potential).
    """

    name: ClassVar[str] = "implicit_midpoint"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    summary: ClassVar[str] = "symplectic, 2nd order, A-stable with no artificial damping"

    @property
    def unknown_fraction(self) -> float:
        return 0.5

    def plan(self, state, dt):
        half = 0.5 * dt
        predictor = state.x + half * state.v  # x_{n+1/2} to O(h^2): D(x) there keeps the method second order
        return StepPlan(predictor, 0.25 * dt * dt, state.x, half, predictor, fraction=0.5)

    def finish(self, state, plan, y, dt):
        v_half = (y - state.x) / plan.velocity_divisor
        return State(state.t + dt, 2.0 * y - state.x, 2.0 * v_half - state.v)

    step = Integrator.potential_step


def _newmark_like_plan(state, dt, beta, gamma, alpha_m=0.0, alpha_f=0.0) -> StepPlan:
    """The step of the generalized-alpha family (Newmark: alpha_m = alpha_f = 0), carried acceleration in aux[0]:

        x_{n+1} = x_n + h v_n + h^2 [(1/2 - beta) a_n + beta a_{n+1}],  v_{n+1} = v_n + h [(1 - gamma) a_n + gamma a_{n+1}],
        M [(1 - alpha_m) a_{n+1} + alpha_m a_n] = f(x_{n+1-alpha_f}, v_{n+1-alpha_f}),  (.)_{n+1-alpha_f} = (1 - alpha_f) (.)_{n+1} + alpha_f (.)_n.

    As an incremental potential in y = x_{n+1-alpha_f}, with the Newmark predictor x^ = x_n + h v_n + h^2 (1/2 - beta) a_n:
    y~ = x_n + (1 - alpha_f) (x^ - x_n) - c h^2 alpha_m a_n,  c = beta (1 - alpha_f) / (1 - alpha_m),
    v_{n+1-alpha_f} = (y - a) / b with b = beta h / gamma, a = y0 - b (v_n + (1 - alpha_f) h (1 - gamma) a_n),
    y0 = x_n + (1 - alpha_f) (x^ - x_n). D(x) is taken at y0, the evaluation point to O(h^2), so that damping keeps
    the method's order.
    """
    (acceleration,) = state.aux
    x_hat = state.x + dt * state.v + (dt * dt * (0.5 - beta)) * acceleration
    y_start = state.x + (1.0 - alpha_f) * (x_hat - state.x)
    scale = beta * (1.0 - alpha_f) / (1.0 - alpha_m)
    divisor = beta * dt / gamma
    origin = y_start - divisor * (state.v + ((1.0 - alpha_f) * dt * (1.0 - gamma)) * acceleration)
    y_tilde = y_start - (scale * dt * dt * alpha_m) * acceleration
    return StepPlan(y_tilde, scale * dt * dt, origin, divisor, y_start, fraction=1.0 - alpha_f, carried=(x_hat,))


def _newmark_like_finish(state, plan, y, dt, beta, gamma, alpha_f=0.0) -> State:
    (acceleration,) = state.aux
    (x_hat,) = plan.carried
    x = state.x + (y - state.x) / (1.0 - alpha_f)
    new_acceleration = (x - x_hat) / (beta * dt * dt)
    v = state.v + dt * ((1.0 - gamma) * acceleration + gamma * new_acceleration)
    return State(state.t + dt, x, v, (new_acceleration,))


class Newmark(Integrator):
    """x_{n+1} = x_n + h v_n + h^2 [(1/2 - beta) a_n + beta a_{n+1}],  v_{n+1} = v_n + h [(1 - gamma) a_n + gamma a_{n+1}],
    M a_{n+1} = f(x_{n+1}, v_{n+1}); the acceleration a_n is carried in aux.

    Incremental potential in y = x_{n+1}: y~ = x_n + h v_n + h^2 (1/2 - beta) a_n, c = beta. This
    implicit form needs beta > 0 (beta = 0 is the explicit central-difference member, not offered here).
    Second order iff gamma = 1/2, else first. Unconditionally stable for 2 beta >= gamma >= 1/2;
    gamma > 1/2 adds first-order artificial damping, gamma < 1/2 negative damping (growth). The
    defaults beta = 1/4, gamma = 1/2 are the trapezoidal rule (average acceleration): spectral radius 1
    at every h, no artificial damping. Source: Newmark, J. Eng. Mech. Div. ASCE 85 (1959) 67-94;
    Hughes, The Finite Element Method (Dover 2000), sec. 9.1.
    """

    name: ClassVar[str] = "newmark"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    summary: ClassVar[str] = "Newmark family (beta > 0); defaults = trapezoidal rule: 2nd order, no damping"

    beta: float = Field(0.25, gt=0.0, le=1.0, allow_inf_nan=False,
                        description="beta in x_{n+1} (> 0 for this implicit form; 1/4 = trapezoidal)")
    gamma: float = Field(0.5, gt=0.0, le=1.0, allow_inf_nan=False,
                         description="gamma in v_{n+1} (1/2: 2nd order, no artificial damping; > 1/2 damps)")

    @property
    def order_of_accuracy(self) -> int:
        return 2 if self.gamma == 0.5 else 1

    started_aux: ClassVar[tuple[str, ...]] = ("acceleration",)

    def start(self, system, state):
        return State(state.t, state.x, state.v, (system.acceleration(state.x, state.v),))

    def plan(self, state, dt):
        return _newmark_like_plan(state, dt, self.beta, self.gamma)

    def finish(self, state, plan, y, dt):
        return _newmark_like_finish(state, plan, y, dt, self.beta, self.gamma)

    step = Integrator.potential_step


class GeneralizedAlpha(Integrator):
    """Chung & Hulbert's generalized-alpha: Newmark's updates with the equation of motion at intermediate points,
    M [(1 - alpha_m) a_{n+1} + alpha_m a_n] = f(x_{n+1-alpha_f}, v_{n+1-alpha_f}),
    alpha_m = (2 rho_inf - 1)/(rho_inf + 1), alpha_f = rho_inf/(rho_inf + 1),
    gamma = 1/2 - alpha_m + alpha_f, beta = (1 - alpha_m + alpha_f)^2 / 4.

    Incremental potential in y = x_{n+1-alpha_f} with c = beta (1 - alpha_f)/(1 - alpha_m). Second
    order for every rho_inf, unconditionally stable; the spectral radius falls from 1 at h w -> 0 to
    rho_inf at h w -> infinity (all three roots meet at -rho_inf), with minimal damping of the low
    frequencies. rho_inf = 1: no artificial damping (the trapezoidal rule on linear problems);
    rho_inf = 0: the highest frequencies are annihilated in one step. The acceleration a_n is
    carried in aux (started with M a_0 = f(x_0, v_0)); for rho_inf < 1 it approximates q'' at
    t_n + (alpha_m - alpha_f) h, not at t_n. Source: Chung & Hulbert, "A time integration algorithm
    for structural dynamics with improved numerical dissipation: the generalized-alpha method",
    J. Appl. Mech. 60 (1993) 371-375.
    """

    name: ClassVar[str] = "generalized_alpha"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    summary: ClassVar[str] = "Chung-Hulbert generalized-alpha; 2nd order, high-frequency damping set by rho_inf"

    rho_inf: float = Field(0.5, ge=0.0, le=1.0, allow_inf_nan=False,
                           description="spectral radius as h w -> infinity: 1 = no damping, 0 = annihilate the highest frequencies")

    @property
    def coefficients(self) -> tuple[float, float, float, float]:
        """(alpha_m, alpha_f, beta, gamma) of Chung & Hulbert (1993) for the given rho_inf."""
        rho = self.rho_inf
        alpha_m = (2.0 * rho - 1.0) / (rho + 1.0)
        alpha_f = rho / (rho + 1.0)
        gamma = 0.5 - alpha_m + alpha_f
        beta = 0.25 * (1.0 - alpha_m + alpha_f) ** 2
        return alpha_m, alpha_f, beta, gamma

    @property
    def unknown_fraction(self) -> float:
        return 1.0 - self.coefficients[1]

    started_aux: ClassVar[tuple[str, ...]] = ("acceleration",)

    def start(self, system, state):
        return State(state.t, state.x, state.v, (system.acceleration(state.x, state.v),))

    def plan(self, state, dt):
        alpha_m, alpha_f, beta, gamma = self.coefficients
        return _newmark_like_plan(state, dt, beta, gamma, alpha_m, alpha_f)

    def finish(self, state, plan, y, dt):
        _, alpha_f, beta, gamma = self.coefficients
        return _newmark_like_finish(state, plan, y, dt, beta, gamma, alpha_f)

    step = Integrator.potential_step


class SemiImplicitBackwardEuler(Integrator):
    """Backward Euler with exactly one Newton iteration started at x_n (Baraff & Witkin 1998):
    (M + h D + h^2 K(x_n)) v_{n+1} = M v_n - h dP/dx(x_n),  x_{n+1} = x_n + h v_{n+1},
    i.e. one Newton step on backward Euler's incremental potential (y~ = x_n + h v_n, c = 1) from y = x_n.
    The solver's ``initial_guess`` moves where that one step starts (``inertial``: linearised at x_n + h v_n,
    ``predictor``: at y~, the same point here); ``start``, the default, is Baraff & Witkin's x_n.

    First order. Identical to backward Euler on linear problems (artificial damping 1/(1 + (h w)^2)
    per step in energy, unconditionally stable there); on nonlinear ones it is a linearly implicit
    method with no stability guarantee and no convergence test: the solve always counts one
    iteration. Not the "semi-implicit Euler" that some lectures use for symplectic Euler (that is
    `symplectic_euler`). Source: Baraff & Witkin, "Large steps in cloth simulation", SIGGRAPH 1998,
    sec. 3; the course's "SI" method (Ascher).
    """

    name: ClassVar[str] = "semi_implicit_backward_euler"
    lanes: ClassVar[bool] = True
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "newton_step"  # one Newton step on the incremental potential, no iteration
    summary: ClassVar[str] = ("Baraff-Witkin: backward Euler with one Newton iteration from x_n "
                              "(not symplectic Euler, also called semi-implicit)")

    def step(self, system, state, dt, solver):
        problem = BackwardEuler().plan(state, dt).problem(system, state, dt)  # y~ = x_n + h v_n, c = 1, D at x_n
        x, stats = solver.newton_step(problem, problem.start_point(state.x))
        return State(state.t + dt, x, (x - state.x) / dt), stats


# More Gauss points than this integrate polynomial forces of degree 39 exactly and only cost.
MAX_QUADRATURE_POINTS = 20


@functools.cache
def gauss_legendre_on_unit_interval(points: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes in (0, 1) and weights summing to 1 of the Gauss-Legendre rule with ``points`` nodes."""
    nodes, weights = np.polynomial.legendre.leggauss(points)
    return 0.5 * (nodes + 1.0), 0.5 * weights


class AverageVectorField(Integrator):
    """x_{n+1} = x_n + h (v_n + v_{n+1})/2,
    M (v_{n+1} - v_n) = -h int_0^1 dP/dx(x_n + s (x_{n+1} - x_n)) ds - h D (v_n + v_{n+1})/2,
    the integral by Gauss-Legendre quadrature with ``quadrature_points`` nodes.

    Solved as a segment potential in y = x_{n+1}: y~ = x_n + h v_n, weights w_j/2 at the Gauss
    nodes s_j (the sampled gradient is that of [P(x_n + s_j (y - x_n)) - P(x_n)]/s_j). Second order,
    symmetric; conserves the energy exactly when the quadrature is exact (polynomial P of degree
    <= 2 q), otherwise to the quadrature's accuracy; no artificial damping; on linear problems it
    is the implicit midpoint/trapezoidal rule (spectral radius 1). With damping the energy decreases
    by exactly h v_mid^T D v_mid per step. Source: Quispel & McLaren, J. Phys. A 41 (2008) 045206;
    Celledoni et al., J. Comput. Phys. 231 (2012) 6770 (quadrature of the AVF integral).
    """

    name: ClassVar[str] = "average_vector_field"
    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "segment_potential"
    summary: ClassVar[str] = "energy-conserving AVF: force averaged along the step by Gauss-Legendre quadrature"

    quadrature_points: int = Field(3, ge=1, le=MAX_QUADRATURE_POINTS,
                                   description="Gauss-Legendre nodes for the average of the force along the step")

    def step(self, system, state, dt, solver):
        nodes, weights = gauss_legendre_on_unit_interval(self.quadrature_points)
        half = 0.5 * dt
        problem = SegmentPotential(system, state.x + dt * state.v, state.x, state.v,
                                   nodes=nodes, weights=0.5 * weights, dt=dt,
                                   velocity_origin=state.x + half * state.v, velocity_divisor=half,
                                   damping_at=[state.x + (s * dt) * state.v for s in nodes])  # each node's point to O(h^2)
        problem.prescribed = on_paths(system, state, dt)
        x, stats = solve_step(solver, problem, problem.start_point(state.x))
        return State(state.t + dt, x, 2.0 * (x - state.x) / dt - state.v), stats
