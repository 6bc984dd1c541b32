"""Radau IIA (integrators/radau.py) against theory: each step solves the collocation equations Z = h (A x I) F(u_n + Z)
(checked independently on a nonlinear damped chain), orders 3 and 5 on the spring and on Kepler's orbit, L-stability,
one iteration (and the confirming one) on a linear problem, the coefficients' simplifying conditions, and the
vertices of prescribed paths on their paths at the stage times."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.integrators.radau import radau_tableau, stability_function
from simrun.systems import CircularMotionParams, SpringMassParams
from test_integrators import DampedChain


@pytest.mark.parametrize("stages", [2, 3])
def test_the_tableau_meets_the_simplifying_conditions_of_its_order(stages):
    """B(2s - 1) and C(s) (Hairer & Wanner II, sec. IV.5): sum_i b_i c_i^(k-1) = 1/k for k <= 2s - 1 and
    sum_j a_ij c_j^(k-1) = c_i^k / k for k <= s, with b = A's last row and c_s = 1."""
    A, c = radau_tableau(stages)
    b = A[-1]
    for k in range(1, 2 * stages):
        assert b @ c ** (k - 1) == pytest.approx(1.0 / k, abs=1e-14)
    assert b @ c ** (2 * stages - 1) != pytest.approx(1.0 / (2 * stages), abs=1e-6)  # and no more
    for k in range(1, stages + 1):
        np.testing.assert_allclose(A @ c ** (k - 1), c ** k / k, atol=1e-14)


@pytest.mark.parametrize("stages", [2, 3])
def test_a_step_solves_the_collocation_equations(stages):
    """On the damped nonlinear chain (a pinned dof), from a state off the start: Z = h (A x I) F(u_n + Z) solved here
    on the first-order system by a dense Newton of our own (finite-difference Jacobian); the method's u_{n+1}, from
    its iteration on the stage positions alone, equals u_n + Z_s."""
    system = DampedChain(sparse=False)
    method = INTEGRATORS["radau_iia"](stages=stages, tolerance=1e-14, max_iterations=100)
    A, _ = radau_tableau(stages)
    state = State(0.0, system.x0.copy(), system.v0.copy())
    state, _ = method.step(system, state, 0.05, None)  # somewhere off the start
    h, n = 0.08, system.dof_count
    free = np.ones(n)
    free[system.fixed_dofs] = 0.0

    def rate(u):
        return np.concatenate([free * u[n:], system.force(u[:n], u[n:]) / system.mass])

    u0 = np.concatenate([state.x, state.v])
    Z = np.zeros((stages, 2 * n))
    for _ in range(50):
        def defect(flat):
            stages_z = flat.reshape(stages, 2 * n)
            slopes = np.array([rate(u0 + z) for z in stages_z])
            return (stages_z - h * A @ slopes).ravel()
        value = defect(Z.ravel())
        if np.abs(value).max() < 1e-13:
            break
        jacobian = np.empty((value.size, value.size))
        for column in range(value.size):
            step = np.zeros(value.size)
            step[column] = 1e-7
            jacobian[:, column] = (defect(Z.ravel() + step) - defect(Z.ravel() - step)) / 2e-7
        Z = (Z.ravel() - np.linalg.solve(jacobian, value)).reshape(stages, 2 * n)
    new, stats = method.step(system, state, h, None)
    assert stats.converged
    np.testing.assert_allclose(new.x, state.x + Z[-1, :n], atol=1e-10)
    np.testing.assert_allclose(new.v, state.v + Z[-1, n:], atol=1e-9)


@pytest.mark.parametrize("stages, order", [(2, 3), (3, 5)])
def test_observed_order_on_the_spring_and_on_kepler(stages, order):
    method = INTEGRATORS["radau_iia"](stages=stages, tolerance=1e-13)
    spring = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.0).build()
    kepler = CircularMotionParams(force="gravity").build()
    for system, duration, exact in ((spring, 1.0, np.array([math.cos(10.0)])),
                                    (kepler, 2 * math.pi, kepler.exact_solution(2 * math.pi)[0][0])):
        errors = []
        for count in (50, 100, 200):
            state = State(0.0, system.x0.copy(), system.v0.copy())
            for _ in range(count):
                state, stats = method.step(system, state, duration / count, None)
                assert stats.converged
            errors.append(np.linalg.norm(state.x - exact))
        slopes = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
        assert np.all(np.abs(slopes - order) < 0.15), (stages, slopes)


@pytest.mark.parametrize("stages", [2, 3])
def test_l_stable_and_exact_in_one_iteration_on_a_linear_problem(stages):
    """|R(i y)| <= 1, R(-inf) = 0; on the linear spring the simplified Newton matrix is the exact Jacobian, so the
    first iteration solves the stages and the second confirms it."""
    for y in np.logspace(-3, 6, 200):
        assert abs(stability_function(stages, 1j * y)) <= 1.0 + 1e-14
    assert abs(stability_function(stages, -1e9)) < 1e-6
    spring = SpringMassParams(stiffness=100.0, damping=2.0, x0=1.0, v0=0.3).build()
    _, stats = INTEGRATORS["radau_iia"](stages=stages).step(spring, State(0.0, spring.x0, spring.v0), 0.1, None)
    assert stats.converged and stats.iterations == 2


def test_prescribed_vertices_are_on_their_paths_at_the_stage_times(tmp_path):
    """A rope whose first vertex moves at a constant velocity: after each step it is exactly on its path."""
    config = {"name": "path", "system": {
        "type": "mass_spring", "model": {"rope": {"count": 4, "length": 0.3}}, "stiffness": 50.0, "gravity": [0, 0, -9.81],
        "prescribed": [{"vertices": [0], "velocity": [0.1, 0.0, 0.0]}]},
        "integrators": ["radau_iia"], "duration": 0.05, "sweep": {"dt": [0.01]}}
    run = expand_runs(load_experiment(config)[0])[0]
    system = run.system.build()
    state = State(0.0, system.x0.copy(), system.v0.copy())
    moving = system.constraints.moving_dofs
    for _ in range(5):
        state, stats = run.integrator.step(system, state, 0.01, None)
        assert stats.converged
        np.testing.assert_allclose(state.x[moving], system.constraints.path(state.t)[0], atol=1e-14)


def test_ipc_is_refused_in_one_line():
    config = {"name": "bad", "system": {
        "type": "fem", "model": {"box": {"size": [0.1, 0.1, 0.05], "cells": [1, 1, 1]}}, "initial": {"translate": [0, 0, 0.02]},
        "contact": {"method": "ipc", "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0, 0, 0]}]}},
        "integrators": ["radau_iia"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match="radau_iia: solves its stages together"):
        expand_runs(load_experiment(config)[0])


def test_the_collocation_polynomial_extrapolates_a_cubic_exactly():
    """The next step's starting stages come from the last step's collocation polynomial (degree s = 3 through X(0) =
    0 and the stages): for stage displacements on a cubic p(tau) it predicts p(1 + c_i h'/h) - p(1) exactly, and for
    a retry from the same start p(c_i h'/h)."""
    from simrun.integrators.radau import _Reusable, _transformation

    c = _transformation(3)[0]
    coefficients = np.array([[0.3, -1.2], [0.7, 0.4], [-0.5, 2.0]])  # tau, tau^2, tau^3 of two dofs

    def p(tau):
        return np.stack([tau ** (k + 1) for k in range(3)], axis=-1) @ coefficients

    h, t0 = 0.02, 1.5
    kept = _Reusable(system=None, held=np.zeros(0, dtype=int), free=np.arange(2), stiffness=None, damping=None, h=h,
                     blocks=[], real_index=None, real_value=None, t0=t0, X=p(c), velocities=np.zeros((3, 2)),
                     contraction=1.0, refresh=False)
    for start, fraction in ((t0 + h, 1.0), (t0, 0.0)):
        for h_new in (0.5 * h, h, 1.7 * h):
            expected = p(fraction + c * h_new / h) - p(np.array([fraction]))
            np.testing.assert_allclose(kept.extrapolated(start, h_new, c), expected, atol=1e-14)


def test_a_step_controlled_step_reuses_the_last_ones_jacobian_and_factors():
    """RADAU5's economy: a step from a state that carries the last step's K and blocks (same h) evaluates no Hessian
    and factorises nothing, and lands where a step from scratch (K at x_n, fresh blocks, X = 0) lands, within the
    iteration's bound (a small fraction of the tolerance's scale)."""
    from simrun.solvers.linear import RUN_FACTORISATIONS, FactorisationLog

    system = DampedChain(sparse=True)
    method = INTEGRATORS["radau_iia"]()
    tolerance = (1e-6, 1e-6)
    state = State(0.0, system.x0.copy(), system.v0.copy())
    first, _, _ = method.step_with_error(system, state, 0.05, None, tolerance)
    assert first.reusable is not None
    hessians = []
    original = system.hessian
    system.hessian = lambda x, project_spd=False: hessians.append(1) or original(x, project_spd)
    log = FactorisationLog()
    token = RUN_FACTORISATIONS.set(log)
    try:
        reused, stats, _ = method.step_with_error(system, first, 0.05, None, tolerance)
        assert stats.converged and not hessians and log.total == 0
        again, _, _ = method.step_with_error(system, State(first.t, first.x, first.v), 0.05, None, tolerance)
        assert len(hessians) == 1 and log.total == 2  # K at x_n; the real and the complex block
    finally:
        RUN_FACTORISATIONS.reset(token)
    scale = 1e-6 + 1e-6 * np.abs(again.x)
    assert np.max(np.abs(reused.x - again.x) / scale) < 0.05


def test_a_step_controlled_run_counts_its_factorisations():
    """The run's ``factorisations``: two per set of blocks (the real and the complex), sets made only where K was
    evaluated anew or h changed, so fewer than twice the tries; and no more Jacobians than factorisations."""
    config = {"name": "count", "system": {"type": "spring_mass", "stiffness": 100.0, "mass": 1.0, "x0": 1.0},
              "integrators": ["radau_iia"], "duration": 2.0, "step_control": {"tolerance": 1e-8}}
    from simrun.execution.simulate import simulate

    result = simulate(expand_runs(load_experiment(config)[0])[0])
    attrs = result.attrs
    tries = attrs["accepted_steps"] + attrs["rejected_steps"]
    assert attrs["factorisations"] % 2 == 0 and 2 <= attrs["factorisations"] < 2 * tries
    assert attrs["jacobian_evaluations"] <= attrs["factorisations"] // 2


FORCE_SYSTEMS = {
    # the compiled spring pass (MassSpring.gradients), with spring damping, a pin, sliding in a plane and along a line,
    # and each spring law
    "cloth_hookean": {"type": "mass_spring", "model": {"grid": {"resolution": [4, 4], "size": [0.3, 0.3]}},
                      "stiffness": {"stretch": 60.0, "shear": 10.0, "bend": 1.0}, "mass": {"total": 0.2},
                      "damping": [{"model": "spring", "coefficient": 0.02}], "pinned": [0],
                      "constraints": [{"vertices": [5], "normal": [0.3, -0.2, 1.0]},
                                      {"vertices": [10], "direction": [0.0, 1.0, 0.0]}]},
    "rope_squared_length": {"type": "mass_spring", "model": {"rope": {"count": 5, "length": 0.4}},
                            "spring_law": "squared_length", "stiffness": 50.0, "gravity": [0.0, 0.0, -9.81]},
    # penalty contact, per state
    "cloth_on_a_sphere": {"type": "cloth", "resolution": [5, 5], "stretch_stiffness": 1e3, "shear_stiffness": 1e2,
                          "bend_stiffness": 1.0, "damping": 0.5, "pinned": [],
                          "contact": {"sphere": {"center": [0.5, 0.5, -0.3], "radius": 0.35, "stiffness": 1e4}}},
    # the default: one gradient per state
    "fem_bar": {"type": "fem", "model": {"box": {"size": [0.2, 0.05, 0.05], "cells": [4, 1, 1]}}, "pinned": [0]},
}


@pytest.mark.parametrize("name", sorted(FORCE_SYSTEMS))
def test_the_stages_forces_together_are_each_stages_force(name):
    """``System.forces`` at three states (the stages' positions and velocities) is ``force`` at each, to round-off:
    the compiled spring pass against the numpy gradient, the damping, fixed dofs, filters and contact per state."""
    system = load_experiment({"name": "forces", "system": FORCE_SYSTEMS[name], "integrators": ["radau_iia"],
                              "sweep": {"dt": [0.01]}})[0].system.build()
    rng = np.random.default_rng(7)
    X = system.x0 + 0.02 * rng.standard_normal((3, system.dof_count))
    V = rng.standard_normal((3, system.dof_count))
    together = system.forces(X, V)
    each = np.stack([system.force(x, v) for x, v in zip(X, V)])
    assert together.shape == (3, system.dof_count)
    np.testing.assert_allclose(together, each, rtol=0.0, atol=1e-13 * np.max(np.abs(each)))
    assert np.max(np.abs(each)) > 0.0


def test_the_run_counts_each_stage_of_a_joint_force_evaluation():
    """function_evaluations: three per simplified Newton iteration (the stages' forces, evaluated together), one per
    try for the error estimate's F(u_n), and two before the first step (the controller's first step size)."""
    config = {"name": "count", "system": {"type": "spring_mass", "stiffness": 100.0, "mass": 1.0, "x0": 1.0},
              "integrators": ["radau_iia"], "duration": 2.0, "step_control": {"tolerance": 1e-8}}
    from simrun.execution.simulate import simulate

    result = simulate(expand_runs(load_experiment(config)[0])[0])
    tries = result.attrs["accepted_steps"] + result.attrs["rejected_steps"]
    iterations = int(np.sum(result.per_step["newton_iterations"]))
    assert result.attrs["function_evaluations"] == 3 * iterations + tries + 2


def test_a_lower_jacobian_refresh_evaluates_more_jacobians():
    """``jacobian_refresh`` (RADAU5's THET): K is evaluated anew after an iteration slower than it, so 0 evaluates it
    after every iteration of more than two updates and 0.9 hardly ever; both runs end ok."""
    from simrun.execution.simulate import simulate

    counts = {}
    for refresh in (0.0, 0.9):
        config = {"name": "refresh", "system": {"type": "cloth", "resolution": [4, 4], "stretch_stiffness": 1e3,
                                                "shear_stiffness": 1e2, "bend_stiffness": 1.0, "damping": 0.0},
                  "integrators": [{"type": "radau_iia", "jacobian_refresh": refresh}], "duration": 0.3,
                  "step_control": {"tolerance": 1e-6}}
        result = simulate(expand_runs(load_experiment(config)[0])[0])
        assert result.status == "ok"
        counts[refresh] = result.attrs["jacobian_evaluations"]
    assert counts[0.0] > 2 * counts[0.9] >= 2
