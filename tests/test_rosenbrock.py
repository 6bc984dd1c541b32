"""The Rosenbrock methods (integrators/rosenbrock.py) against theory: the step equals the scheme written on the
first-order system u' = F(u) with the 2n x 2n Jacobian (the reduction to one n x n solve per stage is exact),
observed orders on the spring and on Kepler's orbit, L-stability of ros2 and rodas3 and ros3p's |R(inf)| = sqrt(3) - 1,
and the refusal of IPC. Pins, sliding and prescribed vertices: tests/test_mass_spring.py's tests for every integrator."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse

from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.integrators.rosenbrock import SCHEMES
from simrun.systems import CircularMotionParams, SpringMassParams
from test_integrators import DampedChain


def first_order_step(system, scheme, x, v, h):
    """One step of the scheme on u = (x, v) with F(u) = (v, M^-1 f) and J = [[0, I], [-M^-1 K, -M^-1 D]] formed
    densely, the pinned dofs' rows of J and F zero: the textbook form, independent of the product's reduction."""
    n = system.dof_count
    inverse_mass = 1.0 / system.mass
    stiffness = system.hessian(x)
    stiffness = stiffness.toarray() if scipy.sparse.issparse(stiffness) else np.asarray(stiffness)
    damping = system.damping_matrix(x)
    damping = np.zeros((n, n)) if damping is None else (damping.toarray() if scipy.sparse.issparse(damping)
                                                         else np.asarray(damping))
    free = np.ones(n)
    free[system.fixed_dofs] = 0.0
    jacobian = np.block([[np.zeros((n, n)), np.diag(free)],
                         [-(free * inverse_mass)[:, None] * stiffness, -(free * inverse_mass)[:, None] * damping]])

    def rate(u):
        return np.concatenate([free * u[n:], system.force(u[:n], u[n:]) * inverse_mass])

    u = np.concatenate([x, v])
    stages = []
    matrix = np.eye(2 * n) / (h * scheme.gamma) - jacobian
    for i in range(len(scheme.m)):
        point = u + sum(scheme.a[i][j] * stages[j] for j in range(i))
        right = rate(point) + sum((scheme.c[i][j] / h) * stages[j] for j in range(i))
        stages.append(np.linalg.solve(matrix, right))
    new = u + sum(weight * stage for weight, stage in zip(scheme.m, stages))
    return new[:n], new[n:]


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_the_reduced_stage_solve_is_the_first_order_scheme(scheme):
    """On the damped nonlinear chain with a pinned dof, 5 steps: equal to 1e-10 relative."""
    system = DampedChain(sparse=True)
    method = INTEGRATORS["rosenbrock"](scheme=scheme)
    state = State(0.0, system.x0.copy(), system.v0.copy())
    x, v = system.x0.copy(), system.v0.copy()
    for _ in range(5):
        state, stats = method.step(system, state, 0.05, None)
        x, v = first_order_step(system, SCHEMES[scheme], x, v, 0.05)
        assert stats.linear_iterations == len(SCHEMES[scheme].m) and stats.iterations == 0
    np.testing.assert_allclose(state.x, x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(state.v, v, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("scheme, order", [("ros2", 2), ("ros3p", 3), ("rodas3", 3)])
def test_observed_order_on_the_spring_and_on_kepler(scheme, order):
    method = INTEGRATORS["rosenbrock"](scheme=scheme)
    spring = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.0).build()
    kepler = CircularMotionParams(force="gravity").build()
    for system, duration, exact in ((spring, 1.0, np.array([math.cos(10.0)])),
                                    (kepler, 2 * math.pi, kepler.exact_solution(2 * math.pi)[0][0])):
        errors = []
        for count in (400, 800, 1600):
            state = State(0.0, system.x0.copy(), system.v0.copy())
            for _ in range(count):
                state, _ = method.step(system, state, duration / count, None)
            errors.append(np.linalg.norm(state.x - exact))
        slopes = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
        assert np.all(np.abs(slopes - order) < 0.15), (scheme, slopes)


@pytest.mark.parametrize("scheme, at_infinity", [("ros2", 0.0), ("rodas3", 0.0), ("ros3p", math.sqrt(3) - 1)])
def test_stability(scheme, at_infinity):
    """|R(i y)| <= 1 on the imaginary axis; R(-inf) = 0 for the L-stable ros2 and rodas3, sqrt(3) - 1 for ros3p."""
    method = SCHEMES[scheme]
    for y in np.logspace(-3, 6, 200):
        assert abs(method.stability_function(1j * y)) <= 1.0 + 1e-12
    assert abs(method.stability_function(-1e9)) == pytest.approx(at_infinity, abs=1e-6)


@pytest.mark.parametrize("system, message", [
    ({"type": "fem", "model": {"box": {"size": [0.1, 0.1, 0.05], "cells": [1, 1, 1]}}, "initial": {"translate": [0, 0, 0.02]},
      "contact": {"method": "ipc", "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0, 0, 0]}]}},
     "IPC contact needs an incremental-potential method"),
])
def test_what_rosenbrock_cannot_step_is_refused_in_one_line(system, message):
    config = {"name": "bad", "system": system, "integrators": ["rosenbrock"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        expand_runs(load_experiment(config)[0])
    assert message in str(error.value) and "\n" not in str(error.value)
