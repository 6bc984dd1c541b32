"""The k-step BDF (integrators/multistep.py BDF) against theory: observed order k on the spring and on Kepler's
orbit for k = 1..5, the start that keeps it (a naive start raising the order one step at a time at the full step
loses it), and BDF3-5's growth on the undamped spring at small h w, at the root locus's value.

Its variable-step form (step control): at constant steps it is the fixed-step BDF; its estimate is the step's own
local error at even and uneven past steps; step-controlled runs start with TR-BDF2, reject O(1) steps on the spring,
and their error falls as tol^(k/(k+1)) (a local error of tol per step, tol^(-1/(k+1)) steps)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simrun.analysis.oscillator import amplification_matrix, spectral_radius
from simrun.integrators import INTEGRATORS, State
from simrun.integrators.multistep import bdf_coefficients
from simrun.solvers import solver_params
from simrun.systems import CircularMotionParams, SpringMassParams

SOLVER = solver_params(tolerance=1e-14, max_iterations=50).build()


def final_error(method, system, exact, duration, count, naive=False):
    """|x - exact| after ``count`` steps; ``naive``: BDF1, BDF2, ... at the full step while the history fills, instead
    of the method's own start."""
    state = method.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    dt = duration / count
    past = []  # (x, v) of the earlier steps, the newest first
    for number in range(count):
        if naive:
            order = min(number + 1, method.order)
            history = tuple(part for pair in past[:order - 1] for part in pair)
            new, _ = INTEGRATORS["bdf"](order=order)._bdf_step(system, State(state.t, state.x, state.v, history), dt,
                                                               SOLVER)
            past.insert(0, (state.x, state.v))
            state = new
            continue
        state, _ = method.step(system, state, dt, SOLVER)
    return np.linalg.norm(state.x - exact)


def slopes(errors):
    return np.log2(np.array(errors[:-1]) / np.array(errors[1:]))


KEPLER_STEPS = {1: [1600, 3200, 6400], 2: [1600, 3200, 6400], 3: [400, 800, 1600], 4: [200, 400, 800],
                5: [150, 300, 600]}


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_observed_order_is_k_on_the_spring_and_on_kepler(k):
    """Halving dt divides the final error by 2^k (within 0.15) in the asymptotic range."""
    method = INTEGRATORS["bdf"](order=k)
    spring = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.0).build()
    counts = [400, 800, 1600] if k > 1 else [1600, 3200, 6400]
    errors = [final_error(method, spring, np.array([math.cos(10.0)]), 1.0, count) for count in counts]
    assert np.all(np.abs(slopes(errors) - k) < 0.15), (k, slopes(errors))
    kepler = CircularMotionParams(force="gravity").build()
    exact = kepler.exact_solution(2 * math.pi)[0][0]
    counts = KEPLER_STEPS[k]  # asymptotic, and above the round-off (about 1e-10 after a revolution)
    errors = [final_error(method, kepler, exact, 2 * math.pi, count) for count in counts]
    assert np.all(np.abs(slopes(errors) - k) < 0.15), (k, slopes(errors))


@pytest.mark.parametrize("k", [3, 4])
def test_raising_the_order_one_step_at_a_time_loses_order(k):
    """BDF1, then BDF2, ... at the full step leaves the first steps' local errors O(h^j + 1), j < k: the global error
    is then O(h^2) (BDF1's O(h^2) local error) instead of O(h^k)."""
    method = INTEGRATORS["bdf"](order=k)
    spring = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.0).build()
    exact = np.array([math.cos(10.0)])
    naive = [final_error(method, spring, exact, 1.0, count, naive=True) for count in (400, 800, 1600)]
    started = [final_error(method, spring, exact, 1.0, count) for count in (400, 800, 1600)]
    assert np.all(np.abs(slopes(naive) - 2.0) < 0.2), slopes(naive)
    assert np.all(np.abs(slopes(started) - k) < 0.15), slopes(started)


def root_locus_radius(k, hw):
    alpha, beta = bdf_coefficients(k)
    polynomial = alpha.astype(complex)
    polynomial[0] -= 1j * hw * beta
    return np.abs(np.roots(polynomial)).max()


# where each grows (the root locus's |r| > 1 on the imaginary axis, z = i h w): BDF3 for h w < 1.94, BDF4 for
# h w < 4.71, BDF5 for 0.71 < h w < 9.39 (it damps below: its region holds the axis near 0)
GROWTH = {1: [], 2: [], 3: [0.05, 0.2, 1.0], 4: [0.2, 1.0, 4.0], 5: [1.0, 2.4, 9.0]}
DAMPED = {1: [0.05, 0.2, 1.0, 50.0], 2: [0.05, 0.2, 1.0, 50.0], 3: [2.0, 50.0], 4: [5.0, 50.0], 5: [0.2, 0.5, 10.0, 50.0]}


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_bdf3_to_5_grow_on_the_undamped_spring_where_the_root_locus_says(k):
    """The probed amplification matrix's spectral radius equals the root locus's largest |r| of rho(r) = z sigma(r) at
    z = i h w; BDF1-2 (A-stable) never exceed 1; BDF3 and BDF4 grow at small h w, BDF5 from h w = 0.71, and each
    damps again beyond its interval."""
    method = INTEGRATORS["bdf"](order=k)
    for hw in GROWTH[k] + DAMPED[k]:
        radius = spectral_radius(amplification_matrix(method, hw))
        assert radius == pytest.approx(root_locus_radius(k, hw), rel=1e-9, abs=1e-12)
        assert (radius > 1.0 + 1e-12) == (hw in GROWTH[k]), (k, hw, radius)


def test_the_analyses_say_where_each_grows():
    """The phrase the figures, the analyze table and the findings use: BDF3 and BDF4 grow only below their crossing,
    BDF5 grows between two; forward Euler everywhere; backward Euler nowhere."""
    from simrun.analysis.oscillator import growth_phrase, predict

    assert growth_phrase(predict(INTEGRATORS["bdf"](order=3))) == "grows for h w < 1.94"
    assert growth_phrase(predict(INTEGRATORS["bdf"](order=4))) == "grows for h w < 4.71"
    assert growth_phrase(predict(INTEGRATORS["bdf"](order=5))) == "stable for h w < 0.711 and above 9.39"
    assert growth_phrase(predict(INTEGRATORS["forward_euler"]())) == "grows at every h"
    assert growth_phrase(predict(INTEGRATORS["backward_euler"]())) is None


def exact_history(system, k, gaps):
    """A variable-step state at t = 0 with the exact states at t = -cumsum(gaps) as its history."""
    times = -np.cumsum(gaps)
    x, v = system.exact_solution(np.concatenate([[0.0], times]))
    return State(0.0, x[0].copy(), v[0].copy(), (times, *[part for j in range(1, k + 1) for part in (x[j], v[j])]))


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_at_constant_steps_the_variable_step_form_is_the_fixed_step_bdf(k):
    system = SpringMassParams(stiffness=4.0, x0=1.0, v0=0.3).build()
    h = 0.01
    method = INTEGRATORS["bdf"](order=k)
    variable = exact_history(system, k, np.full(k, h))
    fixed = State(0.0, variable.x, variable.v, variable.aux[1:2 * k - 1])
    one, _ = method.step(system, fixed, h, SOLVER)
    other, _, _ = method.step_with_error(system, variable, h, SOLVER)
    np.testing.assert_allclose(other.x, one.x, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(other.v, one.v, rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(other.aux[0], np.concatenate([[0.0], variable.aux[0][:k - 1]]))


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("uneven", [False, True])
def test_the_estimate_is_the_steps_local_error(k, uneven):
    """On Kepler's orbit from exact past states (past steps of 0.6 to 1.6 h when uneven), h = 0.02 and 0.01: the
    estimate's norm is the local error's (the step's distance from the exact solution) within 2 %."""
    system = CircularMotionParams(force="gravity").build()
    rng = np.random.default_rng(k)
    method = INTEGRATORS["bdf"](order=k)
    for h in (0.02, 0.01):
        gaps = h * (rng.uniform(0.6, 1.6, k) if uneven else np.ones(k))
        new, _, estimate = method.step_with_error(system, exact_history(system, k, gaps), h, SOLVER)
        x, v = system.exact_solution(np.array([h]))
        local = np.concatenate([new.x - x[0], new.v - v[0]])
        assert np.linalg.norm(estimate) == pytest.approx(np.linalg.norm(local), rel=0.02), (h, gaps)


def controlled(k, tolerances, duration=2.0):
    from simrun.execution.simulate import simulate
    from simrun.experiment.config import validate_experiment
    from simrun.experiment.sweep import expand_runs

    raw = {"name": "test", "system": {"type": "spring_mass", "stiffness": 100.0, "x0": 1.0, "v0": 0.0},
           "integrators": [{"type": "bdf", "order": k}], "duration": duration,
           "solver": {"type": "newton", "tolerance": 1e-12}, "step_control": {"tolerance": tolerances[0]},
           "sweep": {"step_control.tolerance": tolerances}}
    return [simulate(run) for run in expand_runs(validate_experiment(raw))]


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_step_controlled_bdf_on_the_spring(k):
    """On the undamped spring (w = 10 rad/s, the error at 2.125 periods), tolerances 1e-3 to 1e-9: every run ok, at
    most 3 rejected steps; the error falls with slope k/(k + 1) in the tolerance (within 0.15)."""
    tolerances = [1e-3, 1e-5, 1e-7, 1e-9]
    results = controlled(k, tolerances)
    assert all(result.status == "ok" for result in results)
    assert all(result.attrs["rejected_steps"] <= 3 for result in results), [r.attrs["rejected_steps"] for r in results]
    errors = np.array([result.attrs["error"] for result in results])
    slope = np.polyfit(np.log(tolerances), np.log(errors), 1)[0]
    assert abs(slope - k / (k + 1)) < 0.15, (slope, errors)


def test_a_step_controlled_run_starts_with_tr_bdf2():
    """The first k steps are TR-BDF2's (the same states as trbdf2's own controlled steps), then BDF's."""
    from simrun.integrators.dirk import TRBDF2

    system = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.0).build()
    method = INTEGRATORS["bdf"](order=3)
    state = State(0.0, system.x0.copy(), system.v0.copy())
    reference = state
    for h in (1e-3, 2e-3, 1.5e-3):
        assert method.estimate_order_from(state) == 3
        state, _, error = method.step_with_error(system, state, h, SOLVER)
        reference, _, reference_error = TRBDF2().step_with_error(system, reference, h, SOLVER)
        np.testing.assert_array_equal(state.x, reference.x)
        np.testing.assert_array_equal(error, reference_error)
    assert method.estimate_order_from(state) == 4
    np.testing.assert_allclose(state.aux[0], [3e-3, 1e-3, 0.0], rtol=1e-12, atol=1e-15)
