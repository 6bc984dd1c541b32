"""The diagonally implicit Runge-Kutta methods (integrators/dirk.py) against theory: their tableaux' order conditions
(and the next order's, which they miss), observed orders on the spring and on Kepler's orbit, L-stability of R(z),
a user's tableau checked when the config is loaded, each stage an incremental potential that IPC's CCD keeps out of
a collider, and prescribed paths at the stages' own times."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import run_config_file

from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.integrators.dirk import TABLEAUX, order_condition_errors, tableau_refusal
from simrun.solvers import solver_params
from simrun.systems import CircularMotionParams, SpringMassParams

SOLVER = solver_params(tolerance=1e-13, max_iterations=50).build()
ORDERS = {"sdirk2": 2, "sdirk3": 3, "trbdf2": 2}


@pytest.mark.parametrize("name", sorted(TABLEAUX))
def test_each_tableau_meets_its_order_conditions_and_misses_the_next(name):
    """sum b = 1, c = A 1 and every rooted tree's condition up to the order; at order + 1 at least one fails, so the
    order is the tableau's exactly. TR-BDF2's embedded weights are of order 3."""
    tableau = TABLEAUX[name]
    assert tableau.order == ORDERS[name]
    assert order_condition_errors(tableau.A, tableau.b, tableau.c, tableau.order) == []
    assert order_condition_errors(tableau.A, tableau.b, tableau.c, tableau.order + 1)
    np.testing.assert_allclose(np.sum(tableau.A, axis=1), tableau.c, atol=1e-15)
    assert tableau.stiffly_accurate
    if tableau.b_hat is not None:
        assert order_condition_errors(tableau.A, tableau.b_hat, tableau.c, tableau.embedded_order) == []
        assert order_condition_errors(tableau.A, tableau.b_hat, tableau.c, tableau.embedded_order + 1)


@pytest.mark.parametrize("name", sorted(TABLEAUX))
def test_r_is_l_stable(name):
    """|R(i y)| <= 1 on the imaginary axis (A-stable there; the left half-plane by the maximum principle, R having
    its poles at 1/gamma > 0), R(z) -> 0 as z -> -inf and along the imaginary axis (L-stable), and R = e^z + O(z^(p+1))."""
    tableau = TABLEAUX[name]
    for y in np.logspace(-3, 6, 200):
        assert abs(tableau.stability_function(1j * y)) <= 1.0 + 1e-14
    assert abs(tableau.stability_function(-1e9)) < 1e-6
    assert abs(tableau.stability_function(1e9j)) < 1e-6
    poles = [1.0 / row[i] for i, row in enumerate(tableau.A) if row[i] > 0]
    assert all(pole > 0 for pole in poles)
    for z in (1e-2, 1e-2j, -1e-2):
        error = abs(tableau.stability_function(z) - np.exp(z))
        assert error < 10 * abs(z) ** (tableau.order + 1)


def observed_orders(name, system, exact, duration, counts):
    method = INTEGRATORS[name]()
    errors = []
    for count in counts:
        dt = duration / count
        state = method.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
        for _ in range(count):
            state, stats = method.step(system, state, dt, SOLVER)
            assert stats.converged
        errors.append(np.linalg.norm(state.x - exact))
    return np.log2(np.array(errors[:-1]) / np.array(errors[1:]))


@pytest.mark.parametrize("name", sorted(ORDERS))
def test_observed_order_on_the_spring_and_on_keplers_orbit(name):
    """Halving dt divides the final error by 2^p, p within 0.15, on the undamped spring (w = 10 rad/s, 1 s) and on
    a circular Kepler orbit (f = -GMm x/|x|^3, one revolution)."""
    spring = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.0).build()
    orders = observed_orders(name, spring, np.array([math.cos(10.0)]), 1.0, [100, 200, 400])
    assert np.all(np.abs(orders - ORDERS[name]) < 0.15), orders
    kepler = CircularMotionParams(force="gravity").build()
    period = 2 * math.pi
    orders = observed_orders(name, kepler, kepler.exact_solution(period)[0][0], period, [200, 400, 800])
    assert np.all(np.abs(orders - ORDERS[name]) < 0.15), orders


def test_a_users_tableau_is_the_built_in_method_bit_for_bit():
    """esdirk with sdirk3's tableau written out steps exactly as sdirk3."""
    tableau = TABLEAUX["sdirk3"]
    user = INTEGRATORS["esdirk"](tableau={"A": tableau.A, "b": tableau.b, "c": tableau.c, "order": 3})
    system = SpringMassParams(stiffness=100.0, damping=0.3, x0=1.0, v0=0.5).build()
    states = []
    for method in (INTEGRATORS["sdirk3"](), user):
        state = State(0.0, system.x0.copy(), system.v0.copy())
        for _ in range(20):
            state, _ = method.step(system, state, 0.05, SOLVER)
        states.append(state)
    assert np.array_equal(states[0].x, states[1].x) and np.array_equal(states[0].v, states[1].v)


@pytest.mark.parametrize("tableau, message", [
    ({"A": [[0.5, 0.0], [0.5, 0.5]], "b": [0.5, 0.5], "c": [0.5, 1.0], "order": 2}, "fails its order-2 condition b . c = 1/2"),
    ({"A": [[0.5, 0.1], [0.5, 0.5]], "b": [0.5, 0.5], "c": [0.6, 1.0], "order": 1}, "above the diagonal"),
    ({"A": [[0.5, 0.0], [0.5, 0.4]], "b": [0.5, 0.5], "c": [0.5, 0.8], "order": 1}, "c[1] = 0.8 is not the sum"),
    ({"A": [[0.0, 0.0], [0.5, 0.0]], "b": [0.5, 0.5], "c": [0.0, 0.5], "order": 1}, "must be positive"),
    ({"A": [[1.0]], "b": [1.0], "c": [1.0], "order": 5}, "checked up to 4"),
])
def test_a_tableau_that_is_not_what_it_claims_is_refused_in_one_line(tableau, message):
    config = {"name": "bad", "system": {"type": "spring_mass"}, "integrators": [{"type": "esdirk", "tableau": tableau}],
              "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        load_experiment(config)
    text = str(error.value)
    assert message in text and "integrators" in text and "\n" not in text
    assert tableau_refusal(tableau["A"], tableau["b"], tableau["c"], tableau["order"]) is not None


@pytest.mark.parametrize("name", ["sdirk2", "trbdf2"])
def test_ipc_keeps_every_stage_out_of_the_ground(tmp_path, name):
    """A soft box dropped on the ground with IPC: each stage is a CCD-filtered incremental potential, so no vertex
    reaches the ground at any sample, and the box comes to rest on it."""
    config = {"name": "drop", "system": {
        "type": "fem", "model": {"box": {"size": [0.1, 0.1, 0.05], "cells": [2, 2, 1]}},
        "material": {"model": "stable_neo_hookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3, "density": 500.0},
        "initial": {"translate": [0.0, 0.0, 0.02], "velocity": [0.0, 0.0, -1.0]},
        "contact": {"method": "ipc", "dhat": 1e-3,
                    "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.0]}]}},
        "integrators": [name], "solver": {"type": "newton", "tolerance": 1e-8, "max_iterations": 50},
        "duration": 0.1, "sweep": {"dt": [0.005]}}
    stored = run_config_file(config, tmp_path)
    assert stored.status.name.lower() == "ok"
    assert stored.series("contact_distance").min() > 0.0
    assert stored.series("active_contacts").max() > 0


def test_a_tableau_that_is_not_stiffly_accurate_is_refused_with_ipc():
    """x_{n+1} = x_n + h sum b_i V_i is no stage's position, and no CCD keeps it out of a collider."""
    gamma = 0.5 + math.sqrt(3) / 6  # the two-stage SDIRK of order 3 (Norsett), not stiffly accurate
    tableau = {"A": [[gamma, 0.0], [1 - 2 * gamma, gamma]], "b": [0.5, 0.5], "c": [gamma, 1 - gamma], "order": 3}
    config = {"name": "bad", "system": {
        "type": "fem", "model": {"box": {"size": [0.1, 0.1, 0.05], "cells": [1, 1, 1]}},
        "initial": {"translate": [0.0, 0.0, 0.02]},
        "contact": {"method": "ipc", "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0, 0, 0]}]}},
        "integrators": [{"type": "esdirk", "tableau": tableau}], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match="stiffly accurate"):
        expand_runs(load_experiment(config)[0])
