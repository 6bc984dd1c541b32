"""Adaptive steps (runner/execution/step_control.py) against theory: each method's error estimate has its
local order, TR-BDF2's estimates its own local error, the runs meet their tolerance on the spring and on Kepler's
orbit over four decades with O(1) rejected steps, land exactly on the duration and the error time, refine at
contact, retry the steps that do not converge, count every evaluation, and end `failed` below dt_min; bad input is
one line."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from simrun.errors import ConfigError
from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.integrators.rosenbrock import SCHEMES
from simrun.solvers import NewtonParams
from test_integrators import DampedChain

SPRING = {"type": "spring_mass", "mass": 1.0, "stiffness": 100.0, "damping": 0.0, "x0": 1.0, "v0": 0.0}
KEPLER = {"type": "circular_motion", "force": "gravity"}
# the methods with an estimate of their own, and the order q of that estimate (err = O(h^q))
ESTIMATES = [("dopri5", {}, 5), ("trbdf2", {}, 3), ("rosenbrock", {"scheme": "ros2"}, 2),
             ("rosenbrock", {"scheme": "ros3p"}, 3), ("rosenbrock", {"scheme": "rodas3"}, 3),
             ("radau_iia", {"stages": 3}, 4)]


def controlled_runs(system: dict, integrators: list, tolerances: list[float], duration: float, **step_control):
    raw = {"name": "test", "system": system, "integrators": integrators, "duration": duration,
           "solver": {"type": "newton", "tolerance": 1e-12}, "step_control": {"tolerance": tolerances[0], **step_control},
           "sweep": {"step_control.tolerance": tolerances}}
    return expand_runs(validate_experiment(raw))


@pytest.mark.parametrize("name, params, order", ESTIMATES, ids=[f"{n}-{p.get('scheme', '')}" for n, p, _ in ESTIMATES])
def test_each_estimate_has_its_local_order(name, params, order):
    """On the damped nonlinear chain, the estimate of one step from the same state at h = 0.01, 0.005, 0.0025 falls as
    h^q: log2 of the ratios within 0.35 of q (ros2 and ros3p approach theirs from above)."""
    system = DampedChain(sparse=True)
    method = INTEGRATORS[name](**params)
    assert method.estimate_order == order
    state = method.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    solver = NewtonParams(tolerance=1e-13).build()
    sizes = [0.01, 0.005, 0.0025]
    estimates = [np.max(np.abs(method.step_with_error(system, state, h, solver)[2])) for h in sizes]
    slopes = np.log2(np.array(estimates[:-1]) / np.array(estimates[1:]))
    assert np.all(np.abs(slopes - order) < 0.35), slopes


def test_trbdf2s_estimate_is_its_own_local_error():
    """TR-BDF2 (order 2) with Hosea and Shampine's order-3 weights: the estimate is the local error of the step
    itself, u_{n+1} - u(t_n + h), within 5 % at h = 0.005 on the chain (the exact step from scipy's DOP853 at rtol
    1e-13)."""
    import scipy.integrate

    system = DampedChain(sparse=True)
    method = INTEGRATORS["trbdf2"]()
    h = 0.005
    state = State(0.0, system.x0.copy(), system.v0.copy())
    new, _, estimate = method.step_with_error(system, state, h, NewtonParams(tolerance=1e-14).build())
    n = system.dof_count

    def rate(t, u):
        return np.concatenate([u[n:], system.acceleration(u[:n], u[n:])])

    exact = scipy.integrate.solve_ivp(rate, (0.0, h), np.concatenate([system.x0, system.v0]), method="DOP853",
                                      rtol=1e-13, atol=1e-15).y[:, -1]
    error = np.concatenate([new.x, new.v]) - exact
    assert np.allclose(estimate.ravel(), error, rtol=0.05, atol=0.05 * np.max(np.abs(error)))


def test_ros3ps_embedded_pair_is_blind_to_linear_problems():
    """Lang and Verwer's embedded weights give ros3p's own stability function: on y' = lambda y its second stage is
    (1 - 1/gamma) times its first, and (m - m_hat) . (1, 1 - 1/gamma, 0) = 0. So on a linear system (the spring) the
    estimate is round-off and only dt_max bounds the step; on a nonlinear one it has its order (above)."""
    scheme = SCHEMES["ros3p"]
    embedded = dataclasses.replace(scheme, m=scheme.m_hat)
    for z in (0.1j, 1.0j, -2.0, 3.0 + 1.0j):
        assert abs(scheme.stability_function(z) - embedded.stability_function(z)) < 1e-14
    gamma = scheme.gamma
    assert abs((scheme.m[0] - scheme.m_hat[0]) + (scheme.m[1] - scheme.m_hat[1]) * (1.0 - 1.0 / gamma)) < 1e-14


TOLERANCES = [1e-3, 1e-5, 1e-7, 1e-9]


@pytest.mark.parametrize("integrator", ["dopri5", {"type": "rosenbrock", "scheme": "rodas3"}, "radau_iia"],
                         ids=["dopri5", "rodas3", "radau_iia"])
def test_adaptive_runs_meet_their_tolerance_on_the_spring(integrator):
    """Over four decades of tolerance, the error at the error time (2.125 periods) against the exact motion is at most
    10 times the tolerance and falls with it, and at most 3 steps are rejected in a run: a smooth problem costs the
    controller O(1) rejections."""
    results = [simulate(run) for run in controlled_runs(SPRING, [integrator], TOLERANCES, 2.0)]
    errors = [result.attrs["error"] for result in results]
    assert all(result.status == "ok" for result in results)
    for tolerance, error in zip(TOLERANCES, errors):
        assert error <= 10.0 * tolerance, (tolerance, error)
    assert all(later < earlier for earlier, later in zip(errors, errors[1:])), errors
    assert all(result.attrs["rejected_steps"] <= 3 for result in results), [r.attrs["rejected_steps"] for r in results]


# m: the smallest error over 2.5 of Kepler's orbits (radius 1 m) that thousands of steps' round-off leaves
ROUND_OFF_FLOOR = 1e-10


@pytest.mark.parametrize("integrator", ["dopri5", {"type": "rosenbrock", "scheme": "ros3p"}, "radau_iia"],
                         ids=["dopri5", "ros3p", "radau_iia"])
def test_the_error_on_keplers_orbit_is_proportional_to_the_tolerance(integrator):
    """Per-step control bounds each step's local error, not the global one: over two orbits of Kepler's problem
    the error at the error time is tens to hundreds of tolerances (dopri5 13-200, ros3p 330, measured), but it falls
    in proportion: each 100-fold tighter tolerance from 1e-5 to 1e-9 cuts it at least 30-fold, and the last (to
    1e-11) at least 5-fold or down to the floor that round-off sets over thousands of steps, 1e-10 m (radau_iia: 1e-11
    m at 1e-9 over 1,311 steps, 4e-11 m at 1e-11 over 4,141), with no rejected step."""
    tolerances = [1e-5, 1e-7, 1e-9, 1e-11]
    results = [simulate(run) for run in controlled_runs(KEPLER, [integrator], tolerances, 2.0 * math.pi * 2.5)]
    errors = np.array([result.attrs["error"] for result in results])
    assert all(result.status == "ok" for result in results)
    cuts = errors[:-1] / errors[1:]
    assert np.all(cuts[:2] > 30.0) and (cuts[2] > 5.0 or errors[3] <= ROUND_OFF_FLOOR), (cuts, errors)
    assert all(result.attrs["rejected_steps"] <= 3 for result in results)


def test_dopri5_tracks_its_tolerance_and_counts_its_evaluations():
    """dopri5's error on the spring stays within a factor 10 of the tolerance both ways; it evaluates the force twice
    for the starting step, 7 times for its first try and 6 for every other (its last stage, at the new point, is the
    next try's first: first same as last, a rejected try's retry included); it solves nothing."""
    for result, tolerance in zip([simulate(run) for run in controlled_runs(SPRING, ["dopri5"], TOLERANCES, 2.0)],
                                 TOLERANCES):
        assert tolerance / 10.0 <= result.attrs["error"] <= 10.0 * tolerance
        tries = result.attrs["accepted_steps"] + result.attrs["rejected_steps"]
        assert result.attrs["function_evaluations"] == 2 + 7 + 6 * (tries - 1)
        assert result.attrs["jacobian_evaluations"] == 0


def test_steps_land_on_the_error_time_and_the_duration():
    """The per-step sizes sum to the duration, the last sample is at the duration exactly, and the error is measured at
    the error time exactly (both are stops of the controller); the stored dt is the mean accepted step."""
    (run,) = controlled_runs(SPRING, ["trbdf2"], [1e-6], 1.7)
    result = simulate(run)
    error_time = 2.125 * 2.0 * math.pi / 10.0
    assert result.samples["t"][-1] == 1.7
    assert result.attrs["error_time"] == error_time
    assert math.isclose(float(np.sum(result.per_step["dt"])), 1.7, rel_tol=1e-12)
    assert result.steps == result.attrs["accepted_steps"] == result.per_step["dt"].size
    assert math.isclose(result.attrs["dt"], 1.7 / result.steps)
    assert np.all(result.per_step["error_estimate"] <= 1.0)


def test_richardson_for_a_method_without_an_estimate():
    """Backward Euler (order 1) with Richardson's estimate: the error at the error time falls as the tolerance does,
    at the rate of a first-order method under per-step control (the steps shrink as tol^(1/2))."""
    runs = controlled_runs(SPRING, ["backward_euler"], [1e-3, 1e-5], 2.0, estimate="richardson")
    coarse, fine = (simulate(run) for run in runs)
    assert coarse.status == fine.status == "ok"
    assert fine.attrs["error"] < coarse.attrs["error"] / 5.0
    assert 6.0 < fine.steps / coarse.steps < 16.0  # 10 = (100)^(1/2)


def test_auto_takes_each_methods_own_estimate_else_richardsons():
    """estimate: auto gives dopri5 its embedded pair (6 force evaluations a try after the first) and backward Euler
    Richardson's (three steps a try: one whole and two halves)."""
    embedded, richardson = (simulate(run) for run in controlled_runs(SPRING, ["dopri5", "backward_euler"], [1e-5], 2.0,
                                                                      estimate="auto"))
    tries = embedded.attrs["accepted_steps"] + embedded.attrs["rejected_steps"]
    assert embedded.attrs["function_evaluations"] == 2 + 7 + 6 * (tries - 1)  # first same as last
    assert richardson.status == "ok" and richardson.attrs["error"] < 0.05  # first order: ~2000 tolerances at the end
    tries = richardson.attrs["accepted_steps"] + richardson.attrs["rejected_steps"]
    assert np.sum(richardson.per_step["newton_iterations"]) >= 3 * tries


def test_the_controller_refines_at_contact():
    """A 3 x 3 cloth falls onto a penalty plane: the steps of TR-BDF2 during the landing (the cloth first touches at
    t = sqrt(2 h / g) = 0.143 s) are at least 5 times smaller than those of the free fall before it."""
    cloth = {"type": "cloth", "resolution": [3, 3], "size": [0.2, 0.2], "mass": 0.1, "stretch_stiffness": 100.0,
             "shear_stiffness": 10.0, "bend_stiffness": 0.0, "damping": 0.0, "gravity": [0.0, 0.0, -9.81],
             "pinned": [], "height": 0.1,
             "contact": {"method": "penalty", "stiffness": 1e4,
                         "colliders": [{"shape": "plane", "normal": [0, 0, 1], "point": [0, 0, 0]}]}}
    (run,) = controlled_runs(cloth, ["trbdf2"], [1e-5], 0.25)
    result = simulate(run)
    assert result.status == "ok", result.message
    t = np.cumsum(result.per_step["dt"])
    touch = math.sqrt(2.0 * 0.1 / 9.81)
    falling = result.per_step["dt"][(t > 0.05) & (t < touch - 0.02)]
    landing = result.per_step["dt"][(t > touch) & (t < touch + 0.03)]
    assert landing.size and falling.size
    assert np.min(landing) < np.median(falling) / 5.0


def test_steps_that_do_not_converge_are_taken_again_smaller():
    """Newton capped at one iteration on Kepler's (nonlinear) orbit from a first step of 0.2 s: some tries do not
    converge, each is taken again at a quarter of the step, and the run ends ok with every accepted step converged."""
    raw = {"name": "test", "system": KEPLER, "integrators": ["trbdf2"], "duration": 1.0,
           "solver": {"type": "newton", "tolerance": 1e-12, "max_iterations": 1},
           "step_control": {"tolerance": 1e-6, "dt_initial": 0.2}}
    (run,) = expand_runs(validate_experiment(raw))
    result = simulate(run)
    assert result.status == "ok", result.message
    assert result.attrs["not_converged_attempts"] > 0
    assert result.attrs["not_converged_steps"] == 0


def test_a_step_below_dt_min_fails_the_run_and_the_sweep_goes_on(tmp_path):
    """dt_min above what the tolerance needs: the run ends failed, its message names dt_min; the sweep's other run
    (a loose tolerance) is ok."""
    from simrun.cli import main
    from simrun.results.reader import load
    import yaml

    config = {"name": "floor", "system": SPRING, "integrators": ["dopri5"], "duration": 1.0,
              "step_control": {"tolerance": 1e-6, "dt_min": 0.02}, "sweep": {"step_control.tolerance": [1e-1, 1e-10]}}
    path = tmp_path / "floor.yaml"
    path.write_text(yaml.safe_dump(config))
    assert main([str(path), "--output", str(tmp_path / "out"), "-q", "--no-plots"]) == 0
    runs = sorted(load(tmp_path / "out" / "results.h5").runs.values(), key=lambda run: run.run_id)
    assert [str(run.status) for run in runs] == ["ok", "failed"]
    assert "below dt_min 0.02 s" in runs[1].message


@pytest.mark.parametrize("step_control, sweep, integrators, message", [
    ({"tolerance": 0.0}, {}, ["dopri5"], "step_control.tolerance: Input should be greater than 0"),
    ({"tolerance": 1e-6, "dt_min": 0.1, "dt_max": 0.01}, {}, ["dopri5"], "step_control.dt_min: 0.1 s is more than dt_max"),
    ({"tolerance": 1e-6}, {}, ["backward_euler"], "step_control.estimate: backward_euler has no error estimate of its own"),
    ({"tolerance": 1e-6, "estimate": "richardson"}, {}, ["bdf2"], "step_control.estimate: bdf2 carries a history"),
    ({"tolerance": 1e-6}, {}, ["bdf2"], "step_control.estimate: bdf2 has no error estimate of its own"),
    ({"tolerance": 1e-6, "estimate": "richardson"}, {}, [{"type": "bdf", "order": 3}],
     "step_control.estimate: bdf[order=3] carries a history"),
    ({"tolerance": 1e-6}, {"dt": [0.01]}, ["dopri5"], "sweep.dt: step_control chooses every step"),
    (None, {"step_control.tolerance": [1e-3]}, ["dopri5"], "sweep: needs 'dt'"),
    ({"tolerance": 1e-6, "controller": "pid"}, {}, ["dopri5"], "step_control.controller: Input should be 'pi' or 'i'"),
])
def test_bad_step_control_is_one_line(step_control, sweep, integrators, message):
    raw = {"name": "test", "system": SPRING, "integrators": integrators, "duration": 1.0, "sweep": sweep}
    if step_control is not None:
        raw["step_control"] = step_control
    with pytest.raises(ConfigError) as error:
        expand_runs(validate_experiment(raw))
    assert str(error.value).startswith(message), str(error.value)
    assert "\n" not in str(error.value)


def test_bad_step_control_exits_2_and_writes_nothing(tmp_path, capsys):
    from simrun.cli import main
    import yaml

    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"name": "bad", "system": SPRING, "integrators": ["backward_euler"],
                                    "step_control": {"tolerance": 1e-6}, "sweep": {}}))
    assert main([str(path), "--output", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "step_control.estimate" in lines[0]
