"""scipy's solvers as peers (integrators/peers.py, runner/execution/peers.py): simrun's Radau IIA equals
scipy's Radau on the spring to the tolerance, the first-order Jacobian handed to scipy is the derivative of its
right-hand side, the peers' runs land on the duration and count scipy's own evaluations, and what a peer cannot run
is refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from simrun.errors import ConfigError
from simrun.execution.peers import first_order_form
from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs

SPRING = {"type": "spring_mass", "mass": 1.0, "stiffness": 100.0, "damping": 0.1, "x0": 1.0, "v0": 0.0}
CLOTH = {"type": "cloth", "resolution": [4, 4], "size": [0.3, 0.3], "mass": 0.2, "stretch_stiffness": 500.0,
         "shear_stiffness": 50.0, "bend_stiffness": 1.0, "damping": 0.05, "gravity": [0.0, 0.0, -9.81]}


def runs_of(system: dict, integrators: list, tolerances: list[float], duration: float, **extra):
    raw = {"name": "peers", "system": system, "integrators": integrators, "duration": duration,
           "solver": {"type": "newton", "tolerance": 1e-12}, "step_control": {"tolerance": tolerances[0]},
           "sweep": {"step_control.tolerance": tolerances}, **extra}
    return expand_runs(validate_experiment(raw))


@pytest.mark.parametrize("tolerance", [1e-6, 1e-9])
def test_radau_iia_equals_scipys_radau_on_the_spring(tolerance):
    """At the same tolerance and error norm, the two Radau IIA codes' states at the error time differ by less than
    10 tolerances (m), and each is within 10 tolerances of the exact motion."""
    ours, theirs = (simulate(run) for run in runs_of(SPRING, ["radau_iia", {"type": "solve_ivp", "method": "Radau"}],
                                                     [tolerance], 2.0))
    assert ours.status == theirs.status == "ok"
    assert ours.attrs["error_time"] == theirs.attrs["error_time"]
    difference = np.max(np.abs(ours.samples["error_positions"] - theirs.samples["error_positions"]))
    assert difference < 10.0 * tolerance
    assert ours.attrs["error"] < 10.0 * tolerance and theirs.attrs["error"] < 10.0 * tolerance


def test_the_jacobian_given_to_scipy_is_the_derivative_of_its_rate():
    """On an undamped 4 x 4 cloth with two pinned corners, J u equals the central difference of F along u to 1e-6
    relative, and the pinned dofs' rows are zero (their rate is zero whatever u is). (With damping J takes D at x and
    leaves out dD/dx v, as simrun's own Newton matrices do.)"""
    system = validate_experiment({"name": "j", "system": {**CLOTH, "damping": 0.0, "pinned": [0, 3]},
                                  "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}).system.build()
    rate, jacobian = first_order_form(system)
    rng = np.random.default_rng(3)
    u = np.concatenate([system.x0 + 0.01 * rng.standard_normal(system.dof_count), rng.standard_normal(system.dof_count)])
    u[:system.dof_count][system.fixed_dofs] = system.x0[system.fixed_dofs]
    u[system.dof_count:][system.fixed_dofs] = 0.0
    direction = rng.standard_normal(u.size)
    step = 1e-6
    difference = (rate(0.0, u + step * direction) - rate(0.0, u - step * direction)) / (2.0 * step)
    product = jacobian(0.0, u) @ direction
    assert np.allclose(product, difference, rtol=1e-6, atol=1e-6 * np.max(np.abs(difference)))
    n = system.dof_count
    assert not np.any(product[n + system.fixed_dofs])
    dense = first_order_form(system, dense_jacobian=True)[1](0.0, u)
    assert isinstance(dense, np.ndarray) and np.allclose(dense @ direction, product)


@pytest.mark.parametrize("method", ["Radau", "BDF", "LSODA"])
def test_a_peer_run_on_the_cloth_lands_on_the_duration_and_counts_its_work(method):
    """The cloth hanging from two corners for 0.3 s at tolerance 1e-5: the steps' sizes sum to the duration, the last
    sample and frame are at it, and the counts are scipy's (force evaluations, Jacobians, LU factorisations)."""
    (run,) = runs_of({**CLOTH, "pinned": [0, 3]}, [{"type": "solve_ivp", "method": method}], [1e-5], 0.3)
    result = simulate(run)
    assert result.status == "ok", result.message
    assert np.isclose(np.sum(result.per_step["dt"]), 0.3, rtol=1e-12)
    assert result.samples["t"][-1] == pytest.approx(0.3, rel=1e-12)
    assert result.samples["frame_t"][-1] == pytest.approx(0.3, rel=1e-12)
    assert result.attrs["function_evaluations"] > result.steps
    if method != "LSODA":  # LSODA stays with its non-stiff Adams formulas here: no Jacobian, nothing factorised
        assert result.attrs["jacobian_evaluations"] >= 1
        assert result.attrs["factorisations"] >= 1
    assert result.attrs["dt"] == pytest.approx(0.3 / result.steps)


@pytest.mark.parametrize("raw, message", [
    ({"system": SPRING, "integrators": [{"type": "solve_ivp"}], "sweep": {"dt": [0.01]}},
     "integrators: solve_ivp chooses its own steps by a tolerance: give a step_control block"),
    ({"system": {**SPRING, "type": "spring_mass"}, "integrators": [{"type": "solve_ivp", "method": "Euler"}],
      "step_control": {"tolerance": 1e-6}},
     "integrators.0: solve_ivp: method: Input should be 'Radau', 'BDF', 'LSODA', 'RK45' or 'DOP853'"),
    ({"system": {**CLOTH, "contact": {"method": "penalty", "colliders": [{"shape": "plane", "normal": [0, 0, 1],
                                                                          "point": [0, 0, -1]}]}},
      "integrators": [{"type": "solve_ivp"}], "step_control": {"tolerance": 1e-6}},
     "integrators: solve_ivp: contact is no smooth force of an ODE"),
])
def test_what_a_peer_cannot_run_is_one_line(raw, message):
    with pytest.raises(ConfigError) as error:
        expand_runs(validate_experiment({"name": "bad", "duration": 1.0, **raw}))
    assert str(error.value).startswith(message), str(error.value)
    assert "\n" not in str(error.value)
