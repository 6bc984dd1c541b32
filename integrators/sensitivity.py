"""Exact forward sensitivities of an incremental-potential method: dx_n/dtheta along the run, for a calibration.

A step of such a method (``Integrator.plan``) minimises E(y) = 1/2 |y - y~|_M^2 + s P(y; theta) + s/(2b)
(y - a)^T D(x_d; theta) (y - a); its minimiser y* solves g(y*) = 0. Differentiating g(y*) = 0 along theta, with the
step's start state (x_n, v_n, aux) itself a function of theta, gives one linear solve with the Hessian at y*:

    H(y*) dy = M dy~ + s/b D da - s d(grad P)/dtheta - s/b [dD/dtheta + D'(x_d)[dx_d]] (y* - a),

where dy~, da, dx_d are the plan of the tangent state (the plan is linear in the state, ``StepPlan``) and the
parameter's derivatives come from the system (``System.parameter_derivative``). The next tangent state is the
method's ``finish`` applied to the tangent state and dy: the method's own update, so every incremental-potential
method (backward Euler, implicit midpoint, BDF2, Newmark, generalized-alpha) is covered without a formula of its
own. The Hessian at y* is factored once per step for all parameters. Pinned vertices never move (dy = 0 there)
and vertices on prescribed paths follow their paths whatever theta is.
"""

from __future__ import annotations

import copy

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from simrun.systems import System
from simrun.systems.base import ParameterDerivative

from .base import Integrator, State, solve_step


def exact_refusal(system: System, integrator: Integrator) -> str | None:
    """Why the forward sensitivities of ``integrator`` on ``system`` are not offered (one line), or None."""
    if type(integrator).plan is Integrator.plan:
        return f"{integrator.label} takes no incremental-potential steps"
    if system.contact_form():
        return "contact (barriers, CCD-cut steps and lagged friction) is not differentiated"
    if system.sliding is not None:
        return "sliding constraints are not differentiated"
    if system.mass_correction is not None:
        return "the tangent equations take a diagonal M, not a consistent mass matrix"
    if not system.damping_is_constant and type(system).damping_derivative is System.damping_derivative:
        return f"{type(system).__name__}'s damping matrix moves with x and the system gives no derivative of it"
    return None


class ForwardSensitivity:
    """Steps a run and its tangent states (x, v and the method's carried arrays, each of shape (dofs, parameters))."""

    def __init__(self, system: System, integrator: Integrator, derivatives: list[ParameterDerivative]):
        reason = exact_refusal(system, integrator)
        if reason is not None:
            raise ValueError(f"no exact sensitivities: {reason}")
        self.integrator, self.derivatives = integrator, list(derivatives)
        self.count = len(self.derivatives)
        self._constrain(system)

    def _constrain(self, system: System) -> None:
        self.system = system
        fixed = system.fixed_dofs
        self.free = np.setdiff1d(np.arange(system.dof_count), fixed)
        self.fixed = np.asarray(fixed, dtype=np.intp)
        constraints = system.constraints
        self.moving = constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp)

    def released(self, system: System) -> ForwardSensitivity:
        """These sensitivities on ``system.released(t)``: the same method and derivatives (the energy does not
        depend on the constraints), with its free, fixed and moving dofs; the tangents carry on (a released
        vertex's tangent is 0 there, as it was on its path)."""
        sensitivity = copy.copy(self)
        sensitivity._constrain(system)
        return sensitivity

    def start(self, state: State) -> State:
        """The tangent of ``integrator.start``: the initial state does not depend on theta; a carried acceleration
        M^-1 f(x0, v0) does, by M^-1 (-d(grad P)/dtheta - dD/dtheta v0), zero on fixed dofs as the force is."""
        zeros = np.zeros((self.system.dof_count, self.count))
        aux = []
        for name in self.integrator.started_aux:
            if name != "acceleration":
                raise ValueError(f"{self.integrator.label}: no tangent for its carried {name!r}")
            rate = np.zeros_like(zeros)
            for column, derivative in enumerate(self.derivatives):
                force = -derivative.gradient(state.x)
                if derivative.damping is not None:
                    force = force - derivative.damping(state.x) @ state.v
                rate[:, column] = force / self.system.mass
            rate[self.fixed] = 0.0
            aux.append(rate)
        return State(state.t, zeros, zeros.copy(), tuple(aux))

    def step(self, state: State, tangent: State, dt: float, solver):
        """One step of the method from ``state`` and of its tangent; returns (state, tangent, solver statistics)."""
        integrator, system = self.integrator, self.system
        plan = integrator.plan(state, dt)
        problem = plan.problem(system, state, dt)
        y, stats = solve_step(solver, problem, problem.start_point(state.x))
        new = integrator.finish(state, plan, y, dt)
        tangent_plan = integrator.plan(tangent, dt)
        dy = self._solve(problem, plan, tangent_plan, tangent, y)
        new_tangent = integrator.finish(tangent, tangent_plan, dy, dt)
        if self.moving.size:  # on their paths, whatever theta is
            new_tangent.x[self.moving] = 0.0
            new_tangent.v[self.moving] = 0.0
        return new, new_tangent, stats

    def _solve(self, problem, plan, tangent_plan, tangent: State, y: np.ndarray) -> np.ndarray:
        system = self.system
        scale, weight = problem.scale, problem.damping_weight
        rhs = system.mass[:, None] * tangent_plan.y_tilde
        rate = y - plan.velocity_origin
        if problem.damping is not None:
            rhs += weight * np.asarray(problem.damping @ tangent_plan.velocity_origin)
            moved = system.damping_derivative(plan.damping_at, tangent_plan.damping_at, rate)
            if moved is not None:
                rhs -= weight * moved
        for column, derivative in enumerate(self.derivatives):
            rhs[:, column] -= scale * derivative.gradient(y)
            if derivative.damping is not None:
                rhs[:, column] -= weight * np.asarray(derivative.damping(plan.damping_at) @ rate).ravel()
        # fixed dofs keep their start: pinned ones x_n (tangent x_n), prescribed ones y~ (IncrementalPotential.start_point)
        dy = np.array(tangent.x, dtype=float)
        if self.moving.size:
            dy[self.moving] = tangent_plan.y_tilde[self.moving]
        hessian = problem.hessian(y)
        free, fixed = self.free, self.fixed
        if scipy.sparse.issparse(hessian):
            hessian = hessian.tocsr()
            block = hessian[free][:, free].tocsc()
            known = hessian[free][:, fixed] @ dy[fixed] if fixed.size else 0.0
            dy[free] = scipy.sparse.linalg.splu(block).solve(np.ascontiguousarray(rhs[free] - known))
        elif not fixed.size:  # a small dense system (the spring): numpy's solve, without scipy's checks
            dy = np.linalg.solve(np.asarray(hessian, dtype=float), rhs)
        else:
            hessian = np.asarray(hessian, dtype=float)
            known = hessian[np.ix_(free, fixed)] @ dy[fixed]
            dy[free] = np.linalg.solve(hessian[np.ix_(free, free)], rhs[free] - known)
        return dy


__all__ = ["ForwardSensitivity", "exact_refusal"]
