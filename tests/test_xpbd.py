"""XPBD with small steps (integrators/xpbd.py) and the springs systems declare as compliant constraints
(systems/compliant.py): the one-step map against the hand-derived one, the predicted artificial damping
against the damping measured from runs, stability, momentum, constraints and refusals.

Notation: the spring m q'' + beta q' + k q = 0, w = sqrt(k/m), a step h = dt, s substeps of h_s = h/s.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import run_one
from simrun.analysis import oscillator as analysis
from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment, validate_system
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.solvers import EXPLICIT_STEP
from simrun.systems import CircularMotionParams, SpringMassParams, System
from simrun.systems.compliant import ANCHORED, CompliantSprings
from simrun.systems.constraints import SlidingFilter

XPBD = INTEGRATORS["xpbd"]
CONFIGS = Path(__file__).resolve().parent.parent / "configs"
ULP = np.finfo(float).eps
UNIT_SPRING = {"type": "spring_mass", "mass": 1.0, "stiffness": 1.0, "damping": 0.0, "x0": 1.0, "v0": 0.0}


# ------------------------------------------------------------------------------------------------
# The one-step map on the spring
# ------------------------------------------------------------------------------------------------
def hand_derived_map(m: float, k: float, beta: float, h: float) -> np.ndarray:
    """One substep of one iteration on the spring C = q, compliance 1/k, damper beta, by hand:
    x_p = q + h v, Delta lambda = (-k h^2 x_p - beta h (x_p - q)) / ((k h^2 + beta h)/m + 1) (lambda = 0 before),
    q' = x_p + Delta lambda / m, v' = (q' - q)/h. With c = (k h^2 + beta h)/m + 1:
    q' = (1 - k h^2/(m c)) q + (h/c) v,  v' = -(k h/(m c)) q + (1/c) v
    (undamped: q' = (q + h v)/(1 + h^2 w^2), backward Euler's map)."""
    c = (k * h * h + beta * h) / m + 1.0
    return np.array([[1.0 - k * h * h / (m * c), h / c], [-k * h / (m * c), 1.0 / c]])


@pytest.mark.parametrize("m, k, beta, dt", [(1.0, 1.0, 0.0, 0.7), (1.0, 1.0, 0.0, 30.0), (2.0, 8.0, 0.0, 0.3),
                                            (2.0, 8.0, 0.5, 0.3), (0.5, 100.0, 3.0, 0.05)])
def test_the_probe_of_one_substep_is_the_hand_derived_map(m, k, beta, dt):
    """analysis.amplification_matrix of xpbd (1 substep, 1 iteration) equals hand_derived_map to round-off: the
    correction cancels most of the prediction x_p = q + h v (|x_p| <= 1 + h for the unit states), 4 eps (1 + h)."""
    system = SpringMassParams(mass=m, stiffness=k, damping=beta).build()
    probed = analysis.amplification_matrix(XPBD(substeps=1), dt, system)
    assert np.max(np.abs(probed - hand_derived_map(m, k, beta, dt))) <= 4 * ULP * (1.0 + dt)


@pytest.mark.parametrize("substeps", [1, 5, 20])
@pytest.mark.parametrize("iterations", [1, 3])
@pytest.mark.parametrize("beta", [0.0, 0.4])
def test_a_step_is_substeps_of_backward_euler(substeps, iterations, beta):
    """On the linear constraint one projection is exact (more iterations change nothing: the residual
    -C - lambda/(k h^2) is already 0), so a step is the s-th power of the one-substep map at h/s (to 1e-13), and
    that map is backward Euler's, damper included (to backward Euler's own round-off, 16 eps / h_s in v: its
    velocity is (x_{n+1} - x_n)/h_s)."""
    system = SpringMassParams(mass=2.0, stiffness=8.0, damping=beta).build()
    for dt in (0.05, 0.7, 4.0):
        h = dt / substeps
        probed = analysis.amplification_matrix(XPBD(substeps=substeps, iterations=iterations), dt, system)
        assert np.max(np.abs(probed - np.linalg.matrix_power(hand_derived_map(2.0, 8.0, beta, h), substeps))) < 1e-13
        backward = analysis.amplification_matrix(INTEGRATORS["backward_euler"](), h, system)
        assert np.max(np.abs(backward - hand_derived_map(2.0, 8.0, beta, h))) <= 16 * ULP * (1.0 + 1.0 / h)


def test_xpbd_never_calls_the_solver():
    """Explicit in the runner's sense: no nonlinear solve, EXPLICIT_STEP reported."""
    system = SpringMassParams().build()
    state, stats = XPBD().step(system, State(0.0, system.x0.copy(), system.v0.copy()), 0.01, solver=None)
    assert stats is EXPLICIT_STEP and XPBD.explicit
    assert state.t == 0.01 and np.isfinite(state.x).all()


# ------------------------------------------------------------------------------------------------
# The distance constraint (l0 > 0) with its damper
# ------------------------------------------------------------------------------------------------
class TwoParticlesOnASpring(System):
    """Two particles (masses m1, m2) in 3-D joined by one spring of rest length l0 > 0, stiffness k and damper
    beta along it, no other force: the distance constraint C = |x_1 - x_2| - l0 (test-local)."""

    dim, dof_count = 3, 6

    def __init__(self, m1, m2, stiffness, beta, rest_length):
        self.mass = np.repeat([m1, m2], 3).astype(float)
        self.springs = CompliantSprings(first=np.array([0]), second=np.array([1]), anchor=np.zeros((1, 3)),
                                        rest_length=np.array([rest_length]), stiffness=np.array([stiffness]),
                                        damping=np.array([beta]), vertex_count=2, other_forces=False)

    def compliant_form(self):
        return self.springs

    def potential_energy(self, x):
        return self.springs.energy(x)

    def gradient(self, x):
        return -self.springs.force(x, np.zeros_like(x))

    def hessian(self, x, project_spd=False):
        """The Hookean block B = k [u u^T + (1 - l0/L)(I - u u^T)] in [[B, -B], [-B, B]] (the contract's primitive;
        XPBD itself never asks for it). Its transverse factor is clamped at 0 when projected."""
        delta = x[:3] - x[3:]
        length = float(np.linalg.norm(delta))
        u = delta / length
        outer = np.outer(u, u)
        transverse = 1.0 - float(self.springs.rest_length[0]) / length
        if project_spd:
            transverse = abs(transverse) if project_spd == "abs" else max(transverse, 0.0)
        block = float(self.springs.stiffness[0]) * (outer + transverse * (np.eye(3) - outer))
        return np.block([[block, -block], [-block, block]])


def test_the_two_particle_springs_hessian_is_the_derivative_of_its_gradient():
    """The test system's Hessian against central differences of its gradient (h = 1e-6 m)."""
    system = TwoParticlesOnASpring(0.3, 0.7, 50.0, 0.8, 0.5)
    x = np.array([0.1, -0.2, 0.05, 0.55, 0.1, -0.1])
    step = 1e-6
    numeric = np.column_stack([(system.gradient(x + step * e) - system.gradient(x - step * e)) / (2 * step) for e in np.eye(6)])
    assert np.allclose(system.hessian(x), numeric, rtol=1e-7, atol=1e-6)


def macklin_eq26_substep(x, v, masses, k, beta, rest_length, h, iterations):
    """One substep of ``iterations`` projections by MMC 2016 eqs. 18 and 26, unscaled: x_n = x, x = x_n + h v,
    lambda = 0; then C = |x_1 - x_2| - l0, grad_1 C = n = (x_1 - x_2)/|x_1 - x_2| = -grad_2 C, a = 1/(k h^2),
    g = a b / h with b = h^2 beta (so g = beta / (k h)),
    Delta lambda = (-C - a lambda - g grad C (x - x_n)) / ((1 + g) sum_i w_i |grad_i C|^2 + a),
    x_i += w_i grad_i C Delta lambda, lambda += Delta lambda; v = (x - x_n) / h. Returns (x, v, x_n + h v)."""
    start = x.reshape(2, 3)
    predicted = start + h * v.reshape(2, 3)
    positions, multiplier = predicted.copy(), 0.0
    weights = 1.0 / np.asarray(masses, float)
    compliance = 1.0 / (k * h * h)
    gamma = compliance * (h * h * beta) / h
    for _ in range(iterations):
        delta = positions[0] - positions[1]
        normal = delta / np.linalg.norm(delta)
        gradient = np.array([normal, -normal])
        constraint = np.linalg.norm(delta) - rest_length
        change = ((-constraint - compliance * multiplier - gamma * np.sum(gradient * (positions - start)))
                  / ((1.0 + gamma) * np.sum(weights * np.sum(gradient * gradient, axis=1)) + compliance))
        positions += weights[:, None] * gradient * change
        multiplier += change
    return positions.ravel(), ((positions - start) / h).ravel(), predicted.ravel()


@pytest.mark.parametrize("iterations", [1, 2])
def test_a_damped_distance_constraint_is_macklins_eq_26(iterations):
    """Two particles (0.3 and 0.7 kg) on a spring l0 = 0.5 m, k = 50 N/m, beta = 0.8 N s/m (g = 0.32), stretched
    to 0.61 m and moving across and along it; one substep of h = 0.05 s: positions and velocities are those of
    macklin_eq26_substep to round-off (one iteration: lambda = 0; two: one projection along n solves a single
    distance constraint, so the second Delta lambda is 0, but only with the -a lambda term, ~1e-2 m without), the damper
    matters (it moves the result by > 1e-3 m), and the correction keeps sum m_i x_i of the prediction and
    sum m_i v_i (momentum) to round-off: w_1 m_1 n Delta lambda - w_2 m_2 n Delta lambda = 0."""
    m1, m2, k, beta, rest_length, h = 0.3, 0.7, 50.0, 0.8, 0.5, 0.05
    x = np.array([0.0, 0.0, 0.0, 0.6, 0.1, -0.05])
    v = np.array([0.3, -0.2, 0.5, -0.4, 0.6, 0.1])
    system = TwoParticlesOnASpring(m1, m2, k, beta, rest_length)
    new, _ = XPBD(substeps=1, iterations=iterations).step(system, State(0.0, x.copy(), v.copy()), h, None)
    x_expected, v_expected, predicted = macklin_eq26_substep(x, v, [m1, m2], k, beta, rest_length, h, iterations)
    assert np.abs(new.x - x_expected).max() <= 4 * ULP * np.abs(x_expected).max()
    assert np.abs(new.v - v_expected).max() <= 16 * ULP * np.abs(v_expected).max()
    undamped, _, _ = macklin_eq26_substep(x, v, [m1, m2], k, 0.0, rest_length, h, iterations)
    assert np.abs(undamped - x_expected).max() > 1e-3
    masses = np.array([m1, m2])[:, None]
    weighted = lambda values: (masses * values.reshape(2, 3)).sum(axis=0)  # sum_i m_i (.)_i, (3,)
    assert np.abs(weighted(new.x) - weighted(predicted)).max() <= 4 * ULP * weighted(np.abs(predicted)).max()
    assert np.abs(weighted(new.v) - weighted(v)).max() <= 4 * ULP * weighted(np.abs(v)).max()


# ------------------------------------------------------------------------------------------------
# Predicted against measured artificial damping
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("substeps", [1, 5, 20])
@pytest.mark.parametrize("hw", [0.1, 0.5, 1.0, 2.0])
def test_measured_damping_agrees_with_the_probed_prediction(substeps, hw):
    """The decay rate of ln E(t) of a run on the unit spring (w = 1, 40 s, every step sampled), fitted by
    analysis.measure_damping as the artificial_damping figure does, within 2 % of the probed
    d/w = -2 ln(rho)/(h w); the closed form (1 + (h w/s)^2)^(-s/2) pins the probe."""
    result = run_one(UNIT_SPRING, {"type": "xpbd", "substeps": substeps}, hw, 40.0, record={"every": 1})
    assert result.status == "ok"
    fit = analysis.measure_damping(result.samples["t"], result.samples["energy"], result.samples["positions"][:, 0], 1.0)
    rho, predicted = analysis.predict(XPBD(substeps=substeps)).at(hw)
    assert rho == pytest.approx((1.0 + (hw / substeps) ** 2) ** (-substeps / 2), rel=1e-13)
    assert fit.resolved
    assert abs(fit.rate - predicted) <= 0.02 * predicted, (fit.rate, predicted)


@pytest.mark.parametrize("substeps, iterations", [(1, 1), (3, 1), (10, 2)])
def test_the_energy_of_the_undamped_spring_never_grows(substeps, iterations):
    """The step scales the energy by exactly (1 + (h w / s)^2)^(-s) <= 1 at every h (the map is rho times a
    rotation in the energy norm): stable for all h, h w from 1e-2 to 1e3; also the linear circular orbit. To
    round-off: the correction cancels all but 1/(1 + (h w/s)^2) of the prediction, so the new state is good to
    eps (1 + (h w/s)^2) relative."""
    for system in (SpringMassParams(stiffness=4.0, x0=1.0, v0=0.3).build(),
                   CircularMotionParams(dimension=3, angular_velocity=2.0).build()):
        w = 2.0
        for hw in np.logspace(-2, 3, 11):
            integrator, dt = XPBD(substeps=substeps, iterations=iterations), hw / w
            state = State(0.0, system.x0.copy(), system.v0.copy())
            energies = [system.total_energy(state.x, state.v)]
            for _ in range(5):  # 5 steps: (1 + 1e4)^-50 at h w = 1e3 with 10 substeps, still above underflow
                state, _ = integrator.step(system, state, dt, None)
                energies.append(system.total_energy(state.x, state.v))
            factors = np.array(energies[1:]) / np.array(energies[:-1])
            expected = (1.0 + (hw / substeps) ** 2) ** (-substeps)
            tolerance = 16 * ULP * substeps * (1.0 + (hw / substeps) ** 2)
            assert np.all(factors <= 1.0) and np.allclose(factors, expected, rtol=tolerance, atol=0.0), (hw, factors, expected)


# ------------------------------------------------------------------------------------------------
# Mass-spring models: the cloth, momentum, constraints
# ------------------------------------------------------------------------------------------------
def test_the_hanging_cloth_runs_with_ten_substeps():
    """configs/cloth_hang.yaml's 12x12 cloth (k = 1e4 N/m on 1/144 kg vertices: w ~ 2400 rad/s, so h_s w ~ 2.4 at
    dt = 0.01 s) hangs for 0.5 s under XPBD with 10 substeps: the run passes the runner's divergence check, the
    pinned corners never move, and the cloth falls and swings (its lowest vertex below -0.8 m)."""
    system = yaml.safe_load((CONFIGS / "cloth_hang.yaml").read_text())["system"]
    assert system["resolution"] == [12, 12]
    result = run_one(system, {"type": "xpbd", "substeps": 10}, 0.01, 0.5, record={"frames_every": 1})
    assert result.status == "ok", result.message
    frames = result.samples["frames"]
    assert np.isfinite(frames).all()
    pinned = validate_system(system).build().pinned_vertices
    assert pinned.size == 2
    assert np.array_equal(frames[:, pinned], np.broadcast_to(frames[0, pinned], frames[:, pinned].shape))
    assert frames[-1, :, 2].min() < -0.8


FREE_MODELS = {
    # spring damping only: the springs and a zero external field are all the forces
    "cloth": {"type": "cloth", "resolution": [12, 12], "size": [1.0, 1.0], "mass": 1.0, "stretch_stiffness": 1.0e4,
              "shear_stiffness": 1.0e3, "bend_stiffness": 10.0, "damping": 0.05, "pinned": [], "gravity": [0.0, 0.0, 0.0],
              "initial_spin": [0.4, -0.2, 1.5], "initial_velocity": [0.1, 0.0, 0.3]},
    # relative damping too: applied explicitly as f - f_springs at each substep's start
    "relative_damping": {"type": "mass_spring", "model": {"grid": {"resolution": [6, 5], "size": [0.3, 0.2]}},
                         "stiffness": {"stretch": 500.0, "shear": 100.0, "bend": 1.0}, "mass": {"total": 0.12},
                         "gravity": [0.0, 0.0, 0.0], "damping": [{"model": "spring", "coefficient": 0.02},
                                                                 {"model": "relative", "coefficient": 0.01}],
                         "initial": {"scale": [1.2, 0.9, 1.0], "velocity": [0.3, -0.2, 0.5], "spin": [0.5, 1.0, 2.0]}},
}


@pytest.mark.parametrize("model", sorted(FREE_MODELS))
def test_a_free_model_keeps_its_momentum_to_round_off_every_step(model):
    """No pins, no gravity: each correction moves the two ends of a spring by m-weighted opposite amounts
    (W_i grad_i C Delta lambda and -W_j grad_i C Delta lambda), and the explicit remainder (relative damping) acts in
    pairs, so sum m v changes per step by round-off only: at most 64 eps sum_i m_i |v_i| <= 64 eps sqrt(2 M KE)
    (Cauchy-Schwarz), M the total mass."""
    result = run_one(FREE_MODELS[model], {"type": "xpbd", "substeps": 10}, 0.01, 0.5, record={"every": 1})
    assert result.status == "ok"
    momentum = result.samples["momentum"]
    total_mass = float(np.sum(validate_system(FREE_MODELS[model]).build().mass)) / 3.0
    bound = 64 * ULP * math.sqrt(2.0 * total_mass * result.samples["kinetic_energy"].max())
    assert np.linalg.norm(momentum[0]) > 0.01
    assert np.max(np.abs(np.diff(momentum, axis=0))) <= bound
    assert result.samples["spring_energy"].max() > 1e-5  # J: the springs work


class SlidingAnchoredParticle(System):
    """A particle in the plane that slides along the unit direction u, on a zero-length spring to an anchor a off
    its line (P = k/2 |x - a|^2, damper beta along the spring): the vector constraint with a full inverse-mass
    block S/m = u u^T / m. Along the line, q = u . (x - a) obeys m q'' + beta q' + k q = 0 (test-local)."""

    dim = dof_count = 2

    def __init__(self, mass, stiffness, beta, anchor, direction, x0, v0):
        self.mass, self.stiffness, self.beta, self.anchor = np.full(2, mass), stiffness, beta, np.asarray(anchor, float)
        self.direction = np.asarray(direction, float) / np.linalg.norm(direction)
        self.x0, self.v0 = np.asarray(x0, float), (np.asarray(v0, float) @ self.direction) * self.direction
        self.sliding = SlidingFilter(np.array([0]), np.outer(self.direction, self.direction)[None], 2)

    def potential_energy(self, x):
        return 0.5 * self.stiffness * float((x - self.anchor) @ (x - self.anchor))

    def gradient(self, x):
        return self.stiffness * (x - self.anchor)

    def hessian(self, x, project_spd=False):
        return self.stiffness * np.eye(2)

    def damping_matrix(self, x):
        return self.beta * np.eye(2) if self.beta > 0 else None

    def compliant_form(self):
        return CompliantSprings(first=np.zeros(1, np.intp), second=np.full(1, ANCHORED, np.intp), anchor=self.anchor[None],
                                rest_length=np.zeros(1), stiffness=np.array([self.stiffness]), damping=np.array([self.beta]),
                                vertex_count=1, other_forces=False)


@pytest.mark.parametrize("beta", [0.0, 0.3])
def test_a_sliding_vertex_on_a_zero_length_spring_moves_like_the_spring_along_its_line(beta):
    """The projection through S/m (a d x d solve per spring) keeps the particle on its line, and q = u . (x - a)
    follows xpbd on the 1-D spring with q0 = u . (x0 - a), v0 = u . v0, step for step (to 1e-12)."""
    particle = SlidingAnchoredParticle(0.5, 8.0, beta, anchor=[0.3, -0.2], direction=[1.0, 2.0], x0=[1.0, 0.4], v0=[0.2, 0.5])
    u, a = particle.direction, particle.anchor
    spring = SpringMassParams(mass=0.5, stiffness=8.0, damping=beta, x0=float(u @ (particle.x0 - a)),
                              v0=float(u @ particle.v0)).build()
    integrator = XPBD(substeps=4, iterations=2)
    state, reference = State(0.0, particle.x0.copy(), particle.v0.copy()), State(0.0, spring.x0.copy(), spring.v0.copy())
    normal = np.array([-u[1], u[0]])
    for _ in range(100):
        state, _ = integrator.step(particle, state, 0.05, None)
        reference, _ = integrator.step(spring, reference, 0.05, None)
        assert abs(normal @ (state.x - particle.x0)) < 1e-14 and abs(normal @ state.v) < 1e-14
        assert u @ (state.x - a) == pytest.approx(reference.x[0], abs=1e-12)
        assert u @ state.v == pytest.approx(reference.v[0], abs=1e-12)


# ------------------------------------------------------------------------------------------------
# What systems declare
# ------------------------------------------------------------------------------------------------
DECLARING = {
    "spring_mass": {"type": "spring_mass", "mass": 2.0, "stiffness": 8.0, "damping": 0.5},
    "circular_motion": {"type": "circular_motion", "dimension": 3, "angular_velocity": 2.0, "mass": 1.5},
    "cloth": {**FREE_MODELS["cloth"], "resolution": [4, 3]},
    "mass_spring": {"type": "mass_spring", "model": {"rope": {"count": 5, "length": 1.0}}, "stiffness": 300.0,
                    "gravity": [0.0, 0.0, 0.0], "damping": [{"model": "spring", "coefficient": 0.1}]},
}


@pytest.mark.parametrize("name", sorted(DECLARING))
def test_declared_springs_are_the_whole_force_and_energy(name):
    """Where a system's springs (and dampers) are all its forces, f_springs(x, v) = f(x, v) and the springs'
    energy = P(x), at a random state (no gravity, no pins: nothing else acts)."""
    system = validate_system(DECLARING[name]).build()
    springs = system.compliant_form()
    assert springs and not springs.other_forces
    rng = np.random.default_rng(7)
    x = system.x0 + 0.05 * rng.standard_normal(system.dof_count)
    v = rng.standard_normal(system.dof_count)
    assert np.allclose(springs.force(x, v), system.force(x, v), rtol=1e-12, atol=1e-12 * np.abs(system.force(x, v)).max())
    assert springs.energy(x) == pytest.approx(system.potential_energy(x), rel=1e-12)


def test_forces_that_are_not_springs_are_flagged():
    """Relative damping, drag and penalty contact are not along-the-spring dampers or Hookean springs: the
    springs say other forces exist, and their force is f minus those."""
    base = {"type": "mass_spring", "model": {"rope": {"count": 4, "length": 1.0}}, "stiffness": 300.0, "gravity": [0.0, 0.0, 0.0]}
    for extra in ({"damping": [{"model": "relative", "coefficient": 0.1}]}, {"damping": [{"model": "drag", "coefficient": 0.1}]},
                  {"contact": {"ground": {"height": -5.0, "stiffness": 1e3}}}):
        assert validate_system({**base, **extra}).build().compliant_form().other_forces, extra


@pytest.mark.parametrize("system, reason", [
    ({"type": "mass_spring", "model": {"rope": {"count": 3, "length": 1.0}}, "spring_law": "squared_length"},
     "spring_law squared_length is not a Hookean spring (XPBD needs k/2 (L - l0)^2)"),
    ({"type": "circular_motion", "force": "gravity"}, "the gravitational law -GMm/|x| is not a Hookean spring"),
])
def test_a_system_without_compliant_springs_is_refused_in_one_line(system, reason):
    """At config time (exit status 2, one line, before any run), and by the step itself if built past that."""
    with pytest.raises(ConfigError) as refused:
        run_one(system, "xpbd", 0.01, 0.05)
    assert str(refused.value) == f"integrators: xpbd: xpbd needs the system's springs as compliant constraints: {reason}"
    built = validate_system(system).build()
    with pytest.raises(ValueError, match="^xpbd needs the system's springs as compliant constraints: "):
        INTEGRATORS["xpbd"]().step(built, State(0.0, built.x0, built.v0), 0.01, None)


def test_the_colouring_separates_springs_that_share_a_vertex():
    """Every spring in exactly one colour, no vertex twice in a colour, at most 2 Delta - 1 colours (greedy)."""
    system = yaml.safe_load((CONFIGS / "cloth_hang.yaml").read_text())["system"]
    springs = validate_system(system).build().compliant_form()
    colours = springs.colours
    assert np.array_equal(np.sort(np.concatenate(colours)), np.arange(springs.spring_count))
    for colour in colours:
        ends = np.concatenate([springs.first[colour], springs.second[colour]])
        assert np.unique(ends).size == ends.size
    degree = np.bincount(np.concatenate([springs.first, springs.second])).max()
    assert len(colours) <= 2 * degree - 1


def test_the_damping_config_sweeps_xpbd_beside_backward_euler():
    """configs/xpbd_damping.yaml: the unit spring, xpbd at 1, 5 and 20 substeps labelled with them, h w from 0.05 to 3."""
    experiment, _ = load_experiment(CONFIGS / "xpbd_damping.yaml")
    runs = expand_runs(experiment)
    labels = list(dict.fromkeys(run.integrator_label for run in runs))
    assert labels == ["xpbd[substeps=1]", "xpbd[substeps=5]", "xpbd[substeps=20]", "backward_euler", "implicit_midpoint"]
    frequency = math.sqrt(experiment.system.stiffness / experiment.system.mass)
    hw = sorted({run.dt * frequency for run in runs})
    assert hw[0] == pytest.approx(0.05) and hw[-1] == pytest.approx(3.0)
    assert {0.1, 0.5, 1.0, 2.0} <= set(hw)
