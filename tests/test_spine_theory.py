"""The three Euler methods against theory, on the spring and on circular motion.

On the undamped spring q'' + w^2 q = 0 with x = h w, one step of
- forward Euler multiplies the energy by exactly (1 + x^2),
- backward Euler by exactly 1 / (1 + x^2),
- symplectic Euler conserves the modified energy w^2 q^2 + v^2 - h w^2 q v (the determinant of its
  map is 1), so the energy stays bounded;
(lecture 1, "mass on a spring": determinants 1 + k h^2, 1, 1/(1 + k h^2) for m = 1).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import make_runs, run_one
from simrun.execution.simulate import simulate

NO_DIVERGENCE = {"divergence": {"energy_factor": 1e300}, "record": {"every": 1}}


@pytest.mark.parametrize("x", [0.05, 0.3, 1.0, 2.5])
@pytest.mark.parametrize("method, factor", [
    ("forward_euler", lambda x: 1.0 + x * x),
    ("backward_euler", lambda x: 1.0 / (1.0 + x * x)),
])
def test_euler_energy_factor_per_step_on_the_spring(method, factor, x):
    """E_n / E_0 = factor(x)^n exactly; relative error < 1e-9 after 100 steps."""
    stiffness, mass = 100.0, 1.0
    w = np.sqrt(stiffness / mass)
    dt = x / w
    result = run_one({"type": "spring_mass", "stiffness": stiffness, "mass": mass, "x0": 0.7, "v0": -2.0},
                     method, dt, duration=100 * dt, **NO_DIVERGENCE)
    assert result.status == "ok" and result.steps == 100
    energy = result.samples["energy"]
    expected = energy[0] * factor(x) ** np.arange(101)
    assert np.max(np.abs(energy / expected - 1.0)) < 1e-9


@pytest.mark.parametrize("x", [0.1, 1.0, 1.9])
def test_symplectic_euler_energy_bounded_on_the_spring(x):
    """Over 10^4 steps the modified energy w^2 q^2 + v^2 - h w^2 q v stays constant to round-off,
    so E oscillates inside [E~/(1 + x/2), E~/(1 - x/2)] and never grows."""
    stiffness = 4.0
    w = 2.0
    dt = x / w
    result = run_one({"type": "spring_mass", "stiffness": stiffness, "x0": 1.0, "v0": 0.5}, "symplectic_euler",
                     dt, duration=10_000 * dt, **NO_DIVERGENCE)
    assert result.steps == 10_000
    q, v = result.samples["positions"][:, 0], result.samples["velocities"][:, 0]
    modified = w * w * q * q + v * v - dt * w * w * q * v
    assert np.max(np.abs(modified / modified[0] - 1.0)) < 1e-10
    energy = result.samples["energy"]
    modified_energy = 0.5 * modified[0]
    assert energy.max() <= modified_energy / (1.0 - x / 2.0) * (1 + 1e-9)
    assert energy.min() >= modified_energy / (1.0 + x / 2.0) * (1 - 1e-9)


@pytest.mark.parametrize("method, factor", [
    ("forward_euler", lambda x: 1.0 + x * x),
    ("backward_euler", lambda x: 1.0 / (1.0 + x * x)),
])
@pytest.mark.parametrize("dimension", [2, 3])
def test_euler_energy_factor_on_linear_circular_motion(method, factor, dimension):
    """Each coordinate is a spring of frequency w, so the same exact factor per step holds."""
    w, dt = 2.0, 0.2
    x = w * dt
    result = run_one({"type": "circular_motion", "force": "linear", "angular_velocity": w, "radius": 1.5,
                      "dimension": dimension}, method, dt, duration=100 * dt, **NO_DIVERGENCE)
    energy = result.samples["energy"]
    assert np.max(np.abs(energy / (energy[0] * factor(x) ** np.arange(101)) - 1.0)) < 1e-9


@pytest.mark.parametrize("force", ["linear", "gravity"])
def test_symplectic_euler_conserves_angular_momentum(force):
    """A central kick changes v along x and the drift moves x along the new v: x x v is unchanged."""
    result = run_one({"type": "circular_motion", "force": force, "angular_velocity": 1.3, "radius": 2.0},
                     "symplectic_euler", 0.05, duration=50.0, **NO_DIVERGENCE)
    lz = result.samples["angular_momentum"][:, 2]
    assert result.samples["angular_momentum"][:, :2].max() == 0.0
    assert np.max(np.abs(lz - lz[0])) <= 1e-13 * abs(lz[0]) * 10


@pytest.mark.parametrize("force", ["linear", "gravity"])
def test_forward_euler_spirals_out_backward_euler_spirals_in(force):
    """Radius of forward Euler grows monotonically; backward Euler's shrinks (lecture 1's orbits)."""
    system = {"type": "circular_motion", "force": force, "radius": 1.0, "angular_velocity": 1.0}
    forward = run_one(system, "forward_euler", 0.01, duration=6.0, **NO_DIVERGENCE).samples["radius"]
    backward = run_one(system, "backward_euler", 0.01, duration=6.0, **NO_DIVERGENCE).samples["radius"]
    assert np.all(np.diff(forward) > 0) and forward[-1] > 1.02
    assert np.all(np.diff(backward) < 0) and backward[-1] < 0.98


@pytest.mark.parametrize("method", ["forward_euler", "symplectic_euler", "backward_euler"])
@pytest.mark.parametrize("system", [
    {"type": "spring_mass", "stiffness": 4.0, "x0": 1.0, "v0": 0.3},
    {"type": "spring_mass", "stiffness": 4.0, "damping": 0.5, "x0": 1.0, "v0": 0.3},
    {"type": "circular_motion", "force": "gravity", "angular_velocity": 1.0},
], ids=["spring", "damped-spring", "kepler"])
def test_observed_order_is_one(method, system):
    """Global error at t = 2 s shrinks like dt**1 against the exact solution (slope within 0.15)."""
    dts = [0.004, 0.002, 0.001, 0.0005]
    errors = [run_one(system, method, dt, duration=2.0).attrs["final_error"] for dt in dts]
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert abs(slope - 1.0) < 0.15, (slope, errors)


@pytest.mark.parametrize("damping", [0.0, 3.0])
def test_backward_euler_takes_one_newton_iteration_on_the_linear_spring(damping):
    """The backward Euler residual is linear in x_{n+1}: one Newton step solves it exactly.

    (h w = 1.3 here: at h w = 1 the start x_n is itself the solution every fourth step, and Newton
    rightly takes no iteration there.)"""
    result = run_one({"type": "spring_mass", "stiffness": 1e4, "damping": damping}, "backward_euler", 0.013, 2.0)
    assert result.status == "ok"
    assert np.all(result.per_step["newton_iterations"] == 1)
    assert np.all(result.per_step["linear_iterations"] == 1)


def test_newton_converges_on_kepler_with_several_iterations():
    """Gravity is nonlinear: Newton needs more than one iteration, and ends below its tolerance."""
    result = run_one({"type": "circular_motion", "force": "gravity"}, "backward_euler", 0.02, 5.0,
                     solver={"tolerance": 1e-12})
    iterations = result.per_step["newton_iterations"]
    assert result.status == "ok" and iterations.min() >= 2 and iterations.max() <= 6
    assert np.all(result.per_step["residual"] <= 1e-12)


def test_huge_dt_diverges_and_records_when():
    """Forward Euler at h w = 50 multiplies the energy by 2501 per step: past 1e6 in the second step."""
    result = run_one({"type": "spring_mass", "stiffness": 100.0}, "forward_euler", 5.0, 100.0)
    assert result.status == "diverged"
    assert result.t_diverged == pytest.approx(10.0)
    assert result.steps == 2


def test_not_converged_policy():
    """One Newton iteration cannot solve Kepler's step to 1e-14: status not_converged, counts kept."""
    system = {"type": "circular_motion", "force": "gravity"}
    going_on = run_one(system, "backward_euler", 0.1, 1.0, solver={"max_iterations": 1, "tolerance": 1e-14})
    assert going_on.status == "not_converged" and going_on.steps == 10
    assert np.all(going_on.per_step["newton_iterations"] == 1)
    stopping = run_one(system, "backward_euler", 0.1, 1.0,
                       solver={"max_iterations": 1, "tolerance": 1e-14, "on_not_converged": "stop"})
    assert stopping.status == "not_converged" and stopping.steps == 1


def test_recording_cadence_keeps_the_last_step():
    (run,) = make_runs({"type": "spring_mass"}, ["symplectic_euler"], [0.01], duration=1.0, record={"every": 30})
    result = simulate(run)
    t = result.samples["t"]
    assert result.steps == 100
    assert np.allclose(t, np.r_[np.arange(0, 100, 30), 100] * 0.01)
    (capped,) = make_runs({"type": "spring_mass"}, ["symplectic_euler"], [0.001], duration=10.0,
                          record={"max_samples": 101})
    assert simulate(capped).samples["t"].shape == (101,)


def test_exact_solution_of_the_damped_spring_solves_the_equation():
    """q'' + (d/m) q' + (k/m) q = 0 checked by finite differences of the exact solution."""
    from simrun.systems import SpringMassParams

    for damping in (0.0, 1.0, 4.0, 10.0):  # under-, critically (d = 2 sqrt(k m) = 4) and over-damped
        system = SpringMassParams(stiffness=4.0, damping=damping, x0=1.0, v0=0.5).build()
        t = np.linspace(0.1, 3.0, 50)
        h = 1e-4
        q = lambda s: system.exact_solution(s)[0][:, 0]
        acceleration = (q(t + h) - 2 * q(t) + q(t - h)) / h ** 2
        velocity = system.exact_solution(t)[1][:, 0]
        assert np.allclose(acceleration + damping * velocity + 4.0 * q(t), 0.0, atol=1e-5)


def test_dissipated_energy_closes_implicit_midpoints_budget_on_the_damped_spring():
    """Implicit midpoint on q'' + d q' + k q = 0: E_{n+1} - E_n = -h v_{n+1/2} d v_{n+1/2} exactly, so the
    recorded dissipated energy plus the energy is constant to round-off; backward Euler loses more."""
    system = {"type": "spring_mass", "stiffness": 50.0, "damping": 0.7, "x0": 1.0, "v0": 2.0}
    midpoint = run_one(system, "implicit_midpoint", 0.05, 5.0, solver={"tolerance": 1e-13})
    budget = midpoint.samples["energy"] + midpoint.samples["dissipated_energy"]
    assert midpoint.samples["dissipated_energy"][-1] > 0.5 * budget[0]
    assert np.max(np.abs(budget - budget[0])) < 1e-12 * budget[0]
    backward = run_one(system, "backward_euler", 0.05, 5.0)
    remainder = backward.samples["energy"] + backward.samples["dissipated_energy"] - budget[0]
    assert remainder[-1] < -1e-3 * budget[0]  # the method's own (artificial) dissipation
