"""Calibration against theory: sensitivities against finite differences, fits against the exact solution and
against the eigenvalue a method must have to reproduce the observed motion, standard errors against their coverage,
and `simrun fit` end to end.

The observed motion is the damped spring m q'' + d q' + k q = 0 (m = 1 kg, k = 100 N/m, d = 0.4 N s/m, q(0) = 1 m,
q'(0) = 0), whose exact solution is

    q(t) = exp(-a t) (cos(w_d t) + a / w_d sin(w_d t)),   a = d / (2 m),   w_d = sqrt(k/m - a^2),

and whose eigenvalue is lambda = -a + i w_d. A method's step advances a linear system by its amplification matrix;
on the first-order system (q, q') the methods below advance the eigenvalue lambda' of the fitted (k', d') by

    backward Euler   1 / (1 - lambda' h)                           forward Euler   1 + lambda' h
    implicit midpoint, trapezoidal Newmark, AVF  (1 + lambda' h/2) / (1 - lambda' h/2)
    exponential Rosenbrock Euler  exp(lambda' h)                   (exact for a linear system)

so that a fit over many periods lands at exp(lambda h) = that: lambda' h = 1 - exp(-lambda h) (backward Euler),
exp(lambda h) - 1 (forward Euler), 2 tanh(lambda h / 2) (the trapezoidal ones), lambda h (the exponential one),
and k' = m |lambda'|^2, d' = -2 m Re lambda' (the sum and product of the roots of m s^2 + d' s + k').

The observations of the spring are written as a CSV of the closed form above (the exact solution, independent of
the code under test) rather than `synthetic: {integrator: exact}`: the spring's exact_solution goes through batched
scipy.linalg.expm, which is slow on a busy machine with multithreaded BLAS (see the report of this suite).
"""

from __future__ import annotations

import cmath
import dataclasses
import json
import math
import textwrap

import h5py
import numpy as np
import pytest

from simrun.analysis.oscillator import amplification_matrix
from simrun.calibration.engine import Model, Status, fit_one, step_run
from simrun.calibration.keys import get_value, key_parts, system_at, system_mapping
from simrun.calibration.pipeline import fit, prepare
from simrun.calibration.predicted import continuous_eigenvalue, predicted_fit
from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment, validate_system
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS
from simrun.integrators.sensitivity import ForwardSensitivity, exact_refusal
from simrun.solvers import solver_params
from simrun.systems import SpringMassParams

MASS, STIFFNESS, DAMPING = 1.0, 100.0, 0.4  # w = 10 rad/s, so dt = 0.005 s is h w = 0.05
SPRING = SpringMassParams(mass=MASS, stiffness=STIFFNESS, damping=DAMPING, x0=1.0, v0=0.0)
SPRING_KEYS = ["system.stiffness", "system.damping"]
# a Newton solve to round-off: the sensitivities differentiate the exact minimiser of each step
TIGHT_SOLVER = solver_params(tolerance=1e-13, max_iterations=50)
# a central difference with step 1e-4 relative: truncation ~ (1e-4)^2 times the third derivative, round-off
# ~ 1e-16 / 1e-4; both far below the 1e-6 asked of the sensitivities
CENTRAL_STEP = 1e-4
SENSITIVITY_TOLERANCE = 1e-6
# the methods that offer exact forward sensitivities (the incremental-potential ones), from the registry
SENSITIVE = sorted(name for name, cls in INTEGRATORS.items() if exact_refusal(SPRING.build(), cls()) is None)
CLOTH = dict(type="cloth", resolution=[4, 4], size=[1.0, 1.0], mass=1.0, stretch_stiffness=1.0e3, shear_stiffness=1.0e2,
             bend_stiffness=1.0, damping=0.5, gravity=[0.0, 0.0, -9.81], pinned=["top_left", "top_right"])
CLOTH_KEYS = ["system.stretch_stiffness", "system.damping"]


# -- the observed motion ---------------------------------------------------------------------------------------
def exact_position(t, mass=MASS, stiffness=STIFFNESS, damping=DAMPING):
    """q(t) of the module docstring (q(0) = 1 m, q'(0) = 0)."""
    rate = damping / (2.0 * mass)
    frequency = math.sqrt(stiffness / mass - rate * rate)
    return np.exp(-rate * t) * (np.cos(frequency * t) + rate / frequency * np.sin(frequency * t))


def write_observations(path, every: float, duration: float, noise: float = 0.0, seed: int = 0) -> str:
    """The exact q every ``every`` s from 0 to ``duration`` (with Gaussian noise of ``noise`` m) as CSV t, x."""
    t = every * np.arange(int(round(duration / every)) + 1)
    x = exact_position(t) + noise * np.random.default_rng(seed).standard_normal(t.size)
    np.savetxt(path, np.column_stack([t, x]), delimiter=",", header="t,x", comments="", fmt="%.17g")
    return str(path)


def spring_config(observed, integrators, dt, duration, fit_lines: str = "", start=(80.0, 0.1)) -> str:
    """A calibration of the spring's k and d; ``observed`` a CSV path or a mapping (written as JSON, valid YAML)."""
    return f"""\
name: calibration_test
system: {{type: spring_mass, mass: {MASS}, stiffness: {STIFFNESS}, damping: {DAMPING}, x0: 1.0, v0: 0.0}}
integrators: {json.dumps(list(integrators))}
solver: {{type: newton, tolerance: 1.0e-12, max_iterations: 50}}
duration: {duration}
sweep: {{dt: {json.dumps(list(dt))}}}
fit:
  observed: {json.dumps(observed)}
  parameters:
    system.stiffness: {{start: {start[0]}, bounds: [1.0, 1.0e4]}}
    system.damping: {{start: {start[1]}, bounds: [-50.0, 50.0]}}
{fit_lines}"""


def method_tasks(config: str):
    """The fit tasks of the config's sweep, without the exact solution's."""
    experiment, _ = load_experiment(config)
    tasks, _ = prepare(experiment, expand_runs(experiment))
    return [task for task in tasks if task.integrator is not None]


def relative(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


# -- 1. forward sensitivities against central differences ----------------------------------------------------
def final_tangent(params, keys, name, dt, steps):
    """d(x, v)(t_end)/dtheta by the forward sensitivity (dofs, keys), and by central differences."""
    system = params.build()
    integrator = INTEGRATORS[name]()
    dofs = np.arange(system.dof_count)
    mapping = system_mapping(params)
    values = [float(get_value(mapping, key_parts(key))) for key in keys]
    derivatives = [system.parameter_derivative(system_at(params, [key], [value + 1.0]).build(), 1.0)
                   for key, value in zip(keys, values)]
    assert all(derivative is not None for derivative in derivatives)
    exact = step_run(system, integrator, TIGHT_SOLVER.build(), dt, steps, dofs,
                     ForwardSensitivity(system, integrator, derivatives))
    assert not exact.diverged_step
    differences = []
    for key, value in zip(keys, values):
        step = CENTRAL_STEP * abs(value)
        plus, minus = (step_run(system_at(params, [key], [value + sign * step]).build(), integrator,
                                TIGHT_SOLVER.build(), dt, steps, dofs) for sign in (1.0, -1.0))
        differences.append(((plus.x[-1] - minus.x[-1]) / (2 * step), (plus.v[-1] - minus.v[-1]) / (2 * step)))
    return exact, differences


def test_the_registry_offers_sensitivities_for_the_incremental_potential_methods():
    assert {"backward_euler", "implicit_midpoint", "bdf2", "newmark", "generalized_alpha"} <= set(SENSITIVE)


@pytest.mark.parametrize("name", SENSITIVE)
def test_spring_sensitivities_equal_central_differences(name):
    """dq(2 s)/dk and dq(2 s)/dd (and of q') of 200 steps of 10 ms, exact against central differences to 1e-6."""
    exact, differences = final_tangent(SPRING, SPRING_KEYS, name, 0.01, 200)
    for column, (dx, dv) in enumerate(differences):
        assert relative(exact.dx[-1, :, column], dx) < SENSITIVITY_TOLERANCE, SPRING_KEYS[column]
        assert relative(exact.dv[-1, :, column], dv) < SENSITIVITY_TOLERANCE, SPRING_KEYS[column]


@pytest.mark.parametrize("name", SENSITIVE)
def test_cloth_sensitivities_equal_central_differences(name):
    """A 4 x 4 cloth pinned at its top corners, 20 steps of 10 ms under gravity: d(x, v)/d(stretch stiffness) and
    d(x, v)/d(spring damping) at the end, exact against central differences to 1e-6 (the damping matrix moves
    with x here, so its derivative along the tangent enters too)."""
    params = validate_system(CLOTH)
    exact, differences = final_tangent(params, CLOTH_KEYS, name, 0.01, 20)
    for column, (dx, dv) in enumerate(differences):
        assert np.linalg.norm(dx) > 0
        assert relative(exact.dx[-1, :, column], dx) < SENSITIVITY_TOLERANCE, CLOTH_KEYS[column]
        assert relative(exact.dv[-1, :, column], dv) < SENSITIVITY_TOLERANCE, CLOTH_KEYS[column]
    pinned = params.build().fixed_dofs
    assert not exact.dx[-1, pinned].any()  # pinned vertices do not move, whatever theta is


def engine_jacobians(task, values):
    """The engine's Jacobian with exact columns, with forced forward differences, and central differences of the
    engine's own residual."""
    model = Model(task)
    motion = model.motion(values, with_jacobian=True)
    residual = model.residual_of(motion)
    exact, kind = model.jacobian_of(motion, values, residual)
    assert kind == "exact"
    forced = Model(dataclasses.replace(task, sensitivities="finite_differences"))
    motion = forced.motion(values, with_jacobian=True)
    assert motion[2] is None
    forward, kind = forced.jacobian_of(motion, values, forced.residual_of(motion))
    assert kind == "finite_differences"
    central = np.empty_like(exact)
    for column in range(values.size):
        step = CENTRAL_STEP * abs(values[column])
        plus, minus = values.copy(), values.copy()
        plus[column] += step
        minus[column] -= step
        central[:, column] = (model.residual_of(model.motion(plus)) - model.residual_of(model.motion(minus))) / (2 * step)
    return exact, forward, central


@pytest.mark.parametrize("compare", ["steps", "interpolated"])
@pytest.mark.parametrize("name", ["backward_euler", "implicit_midpoint", "newmark"])
def test_fit_jacobian_equals_finite_differences_on_the_spring(tmp_path, name, compare):
    """The fitted Jacobian d r/d(k, d) at the start, of positions and of positions with velocities, at the steps
    and interpolated between them (observations every 10 ms, steps of 20 ms): exact columns against central
    differences of the residual (1e-6) and against the engine's forward differences (sqrt(eps) steps: 1e-5)."""
    observed = write_observations(tmp_path / "q.csv", 0.01, 2.0)
    (task,) = method_tasks(spring_config(observed, [name], [0.02], 2.0, f"  compare: {compare}\n"))
    assert Model(task).times.size == (101 if compare == "steps" else 201)
    task = dataclasses.replace(task, solver=TIGHT_SOLVER)
    for weights in ("position", "position_and_velocity"):
        task = dataclasses.replace(task, weights=weights)
        if weights == "position_and_velocity":  # the CSV holds positions only: give the task velocities of its own
            task.observations = dataclasses.replace(task.observations, velocities=np.gradient(
                task.observations.positions, task.observations.t, axis=0))
        exact, forward, central = engine_jacobians(task, np.array([80.0, 0.1]))
        for column in range(2):
            assert relative(exact[:, column], central[:, column]) < SENSITIVITY_TOLERANCE, (weights, column)
            assert relative(exact[:, column], forward[:, column]) < 1e-5, (weights, column)


def test_fit_jacobian_equals_finite_differences_on_the_cloth():
    """The same on the 4 x 4 cloth observed at two free vertices (synthetic, backward Euler). The engine's forward
    differences are held to 1e-3 only: a step of sqrt(eps) theta moves x by ~1e-10 m, where the Newton solves' own
    round-off is no longer negligible (the central differences above, with steps of 1e-4 theta, are the reference)."""
    config = f"""\
name: cloth_jacobian
system: {json.dumps(CLOTH)}
integrators: [implicit_midpoint]
solver: {{type: newton, tolerance: 1.0e-13, max_iterations: 50}}
duration: 0.2
sweep: {{dt: [0.01]}}
fit:
  observed: {{synthetic: {{integrator: backward_euler, dt: 0.01}}}}
  markers: [0, 6]
  parameters:
    system.stretch_stiffness: {{start: 700.0, bounds: [1.0, 1.0e5]}}
    system.damping: {{start: 0.3, bounds: [0.01, 10.0]}}
"""
    (task,) = method_tasks(config)
    exact, forward, central = engine_jacobians(task, np.array([700.0, 0.3]))
    for column in range(2):
        assert relative(exact[:, column], central[:, column]) < SENSITIVITY_TOLERANCE, column
        assert relative(exact[:, column], forward[:, column]) < 1e-3, column


# -- 2., 3. fits against the exact solution and against theory -------------------------------------------------
def theory_fit(name: str, dt: float) -> tuple[float, float]:
    """(k', d') of the module docstring's closed forms for ``name``: exp(lambda h) = the method's own eigenvalue."""
    z = continuous_eigenvalue(MASS, STIFFNESS, DAMPING) * dt
    scaled = {"backward_euler": 1 - cmath.exp(-z), "forward_euler": cmath.exp(z) - 1, "implicit_midpoint": 2 * cmath.tanh(z / 2),
              "newmark": 2 * cmath.tanh(z / 2), "average_vector_field": 2 * cmath.tanh(z / 2),
              "exponential_rosenbrock_euler": z}[name]
    eigenvalue = scaled / dt
    return MASS * abs(eigenvalue) ** 2, -2 * MASS * eigenvalue.real


def test_implicit_midpoint_at_small_hw_recovers_k_and_d(tmp_path):
    """Noise-free exact data every 5 ms for 5 s, implicit midpoint at dt = 5 ms (h w = 0.05): k and d within 0.5 %.
    Its bias is the trapezoidal eigenvalue's: k' / k - 1 ~ (h w)^2 / 6 = 4e-4, d' / d - 1 ~ (h w)^2 / 4 = 6e-4, and
    the fit lands on the closed form to 1e-4."""
    observed = write_observations(tmp_path / "q.csv", 0.005, 5.0)
    (task,) = method_tasks(spring_config(observed, ["implicit_midpoint"], [0.005], 5.0))
    outcome = fit_one(task)
    assert outcome.status == Status.CONVERGED and outcome.jacobian == "exact"
    stiffness, damping = outcome.values
    assert stiffness == pytest.approx(STIFFNESS, rel=5e-3)
    assert damping == pytest.approx(DAMPING, rel=5e-3)
    assert outcome.values == pytest.approx(theory_fit("implicit_midpoint", 0.005), rel=1e-4)


@pytest.fixture(scope="module")
def backward_euler_fits(tmp_path_factory):
    """Backward Euler fitted at h w = 0.2, 0.5, 1 to noise-free exact data every 10 ms for 20 s."""
    observed = write_observations(tmp_path_factory.mktemp("be") / "q.csv", 0.01, 20.0)
    tasks = method_tasks(spring_config(observed, ["backward_euler"], [0.02, 0.05, 0.1], 20.0))
    return {task.dt: fit_one(task) for task in tasks}


@pytest.mark.parametrize("dt", [0.02, 0.05, 0.1])
def test_backward_euler_fit_equals_the_predicted_fit(backward_euler_fits, dt):
    """The fitted (k, d) is where backward Euler's eigenvalue is exp(lambda h) (predicted_fit, and the closed form
    1 - exp(-lambda h) = lambda' h): within 3 % (the fit also matches the start of the motion, not only its decay
    and phase per step). The artificial damping makes the fitted d negative from h w = 0.2 on."""
    outcome = backward_euler_fits[dt]
    assert outcome.status == Status.CONVERGED
    predicted = predicted_fit(INTEGRATORS["backward_euler"](), dt, MASS, STIFFNESS, DAMPING)
    assert predicted == pytest.approx(theory_fit("backward_euler", dt), rel=1e-8)
    assert outcome.values == pytest.approx(predicted, rel=3e-2)
    assert outcome.values[1] < 0


def test_backward_euler_at_hw_one_half_fits_a_negative_damping(backward_euler_fits):
    """h w = 0.5: d' = -2 Re(1 - exp(-lambda h)) / h = -4.54 N s/m: the method must pump energy in to decay as
    slowly as the motion."""
    assert backward_euler_fits[0.05].values[1] == pytest.approx(-4.5, abs=0.2)


def test_exact_sensitivities_and_finite_differences_fit_the_same_values(tmp_path):
    """The Jacobian changes the path of the least-squares solver, not its minimum: backward Euler and implicit
    midpoint at h w = 0.5, fitted with exact sensitivities and with finite differences, agree to 1e-6."""
    observed = write_observations(tmp_path / "q.csv", 0.01, 5.0)
    for task in method_tasks(spring_config(observed, ["backward_euler", "implicit_midpoint"], [0.05], 5.0)):
        exact = fit_one(task)
        differences = fit_one(dataclasses.replace(task, sensitivities="finite_differences"))
        assert (exact.jacobian, differences.jacobian) == ("exact", "finite_differences")
        assert exact.status == differences.status == Status.CONVERGED
        assert differences.values == pytest.approx(exact.values, rel=1e-6), task.label


# -- 4. standard errors against their coverage ---------------------------------------------------------------
COVERAGE_SEEDS = 50
COVERAGE_NOISE = 0.02  # m: large enough that implicit midpoint's bias at h w = 0.02 is ~0.1 standard error


def coverage_task(noise: float, seed: int):
    """Implicit midpoint at h w = 0.02 fitted to exact data every 20 ms for 2 s (the code's own synthetic noise)."""
    observed = {"synthetic": {"integrator": "exact", "dt": 0.02, "noise": noise, "seed": seed}}
    (task,) = method_tasks(spring_config(observed, ["implicit_midpoint"], [0.002], 2.0))
    return task


@pytest.mark.slow
def test_standard_errors_cover_the_truth():
    """With 2 cm of noise on 101 observations, |fit - truth| <= 1.96 stderr for k and for d in at least 90 % of 50
    seeds. 1.96 is the two-sided 95 % quantile of the normal distribution: the residual variance is estimated from
    99 degrees of freedom (Student's t quantile 1.98, as good as normal) and the model is linear in the noise at
    this size (stderr / k ~ 6e-4), so the nominal coverage is 95 %; 90 % leaves room for 50 draws (a binomial
    standard deviation of 3 %). The method's bias (the noise-free fit's distance from the truth) is checked to be
    below a fifth of a standard error first, so that the intervals are about the noise, not about the method."""
    truth = np.array([STIFFNESS, DAMPING])
    clean = fit_one(coverage_task(0.0, 0))
    assert clean.status == Status.CONVERGED
    outcomes = [fit_one(coverage_task(COVERAGE_NOISE, seed)) for seed in range(COVERAGE_SEEDS)]
    assert all(outcome.status == Status.CONVERGED for outcome in outcomes)
    errors = np.array([outcome.standard_errors for outcome in outcomes])
    assert np.all(np.isfinite(errors)) and np.all(errors > 0)
    typical = np.median(errors, axis=0)
    assert np.all(np.abs(clean.values - truth) < 0.2 * typical), (clean.values - truth, typical)
    values = np.array([outcome.values for outcome in outcomes])
    covered = np.mean(np.abs(values - truth) <= 1.96 * errors, axis=0)
    assert np.all(covered >= 0.9), covered
    # the reported errors are the spread they claim: the scatter of the fits over the seeds is within 30 % of them
    assert np.std(values, axis=0, ddof=1) == pytest.approx(typical, rel=0.3)


def test_synthetic_noise_has_the_declared_standard_deviation():
    """synthetic: {noise: 2 cm}: the observed positions minus the exact solution have standard deviation 2 cm
    (within 20 % for 101 draws) and mean ~0; the same seed gives the same data."""
    observations = coverage_task(COVERAGE_NOISE, 3).observations
    deviation = observations.positions[:, 0] - exact_position(observations.t)
    assert np.std(deviation) == pytest.approx(COVERAGE_NOISE, rel=0.2)
    assert abs(np.mean(deviation)) < 3 * COVERAGE_NOISE / math.sqrt(deviation.size)
    assert np.array_equal(coverage_task(COVERAGE_NOISE, 3).observations.positions, observations.positions)


def test_synthetic_truth_overrides_the_system():
    """synthetic: {system: {stiffness: 120}} (or system.stiffness): the data are of k = 120 N/m, the truth says so,
    and a fit with the data's own method and dt finds it (the truth is a zero-residual minimum)."""
    for key in ("stiffness", "system.stiffness"):
        observed = {"synthetic": {"integrator": "implicit_midpoint", "dt": 0.01, "system": {key: 120.0}}}
        (task,) = method_tasks(spring_config(observed, ["implicit_midpoint"], [0.01], 1.0))
        assert task.observations.truth == {"system.stiffness": 120.0, "system.damping": DAMPING}
        positions = task.observations.positions[:, 0]  # midpoint at h w = 0.11 over 1 s: a phase error of ~1e-2
        assert positions == pytest.approx(exact_position(task.observations.t, stiffness=120.0), abs=2e-2)
        assert np.max(np.abs(positions - exact_position(task.observations.t))) > 0.3
    outcome = fit_one(task)
    assert outcome.values == pytest.approx([120.0, DAMPING], rel=1e-6)


# -- 5. a cloth fit --------------------------------------------------------------------------------------------
def test_cloth_fit_recovers_the_stretch_stiffness():
    """Markers of a 4 x 4 cloth stepped by backward Euler at the sweep's dt (noise-free): the same method and dt,
    started 30 % off, recovers the stretch stiffness within 2 % (the truth is a zero-residual minimum)."""
    config = f"""\
name: cloth_fit
system: {json.dumps(CLOTH)}
integrators: [backward_euler]
solver: {{type: newton, tolerance: 1.0e-12, max_iterations: 50}}
duration: 0.3
sweep: {{dt: [0.01]}}
fit:
  observed: {{synthetic: {{integrator: backward_euler, dt: 0.01}}}}
  markers: [0, 3, 5]
  parameters:
    system.stretch_stiffness: {{start: 700.0, bounds: [1.0, 1.0e5]}}
"""
    (task,) = method_tasks(config)
    assert task.observations.truth == {"system.stretch_stiffness": CLOTH["stretch_stiffness"]}
    outcome = fit_one(task)
    assert outcome.status == Status.CONVERGED and outcome.jacobian == "exact"
    assert outcome.values[0] == pytest.approx(CLOTH["stretch_stiffness"], rel=2e-2)
    assert outcome.rms_residual < 1e-6


# -- 7. the predicted fit --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["backward_euler", "forward_euler", "implicit_midpoint", "newmark", "average_vector_field",
                                  "exponential_rosenbrock_euler"])
@pytest.mark.parametrize("hw", [0.05, 0.2, 0.5, 1.0])
def test_predicted_fit_equals_the_closed_form(name, hw):
    """predicted_fit's root-find against the closed forms of the module docstring, to 1e-8."""
    dt = hw / math.sqrt(STIFFNESS / MASS)
    assert predicted_fit(INTEGRATORS[name](), dt, MASS, STIFFNESS, DAMPING) == pytest.approx(theory_fit(name, dt), rel=1e-8)


@pytest.mark.parametrize("name", ["implicit_midpoint", "newmark"])
def test_methods_without_artificial_damping_predict_the_true_damping(name):
    """Implicit midpoint and the trapezoidal Newmark have |mu| = 1 on the undamped spring: at h w = 0.05 the
    predicted d is the truth within 1e-3 (its offset is (h w)^2 / 4 = 6e-4), and k within (h w)^2 / 6 + 1e-5."""
    stiffness, damping = predicted_fit(INTEGRATORS[name](), 0.005, MASS, STIFFNESS, DAMPING)
    assert damping == pytest.approx(DAMPING, rel=1e-3)
    assert abs(stiffness / STIFFNESS - 1) < 0.05 ** 2 / 6 + 1e-5


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
@pytest.mark.parametrize("hw", [0.05, 0.5])
def test_predicted_fit_has_the_observed_eigenvalue(name, hw):
    """The probed amplification matrix of the spring with the predicted (k', d') has an eigenvalue mu with
    log mu = lambda h (to 1e-8 of |lambda h|): the prediction is what it claims to be."""
    dt = hw / math.sqrt(STIFFNESS / MASS)
    integrator = INTEGRATORS[name]()
    stiffness, damping = predicted_fit(integrator, dt, MASS, STIFFNESS, DAMPING)
    assert math.isfinite(stiffness) and math.isfinite(damping)
    target = continuous_eigenvalue(MASS, STIFFNESS, DAMPING) * dt
    system = SpringMassParams(mass=MASS, stiffness=stiffness, damping=damping).build()
    eigenvalues = np.linalg.eigvals(amplification_matrix(integrator, dt, system))
    logs = [complex(math.log(abs(value)), abs(cmath.phase(value))) for value in eigenvalues if abs(value) > 0]
    assert min(abs(value - target) for value in logs) < 1e-8 * abs(target)


# -- 8. `simrun fit` end to end --------------------------------------------------------------------------------
def fit_groups(path) -> dict:
    """Every fit group's attributes, as stored (repr: NaN equals NaN)."""
    with h5py.File(path, "r") as file:
        return {name: {key: repr(np.asarray(value).tolist()) for key, value in group.attrs.items()}
                for name, group in file["fits"].items() if isinstance(group, h5py.Group)}


def test_fit_end_to_end_writes_every_fit_and_resumes(tmp_path):
    """2 integrators x 2 steps, 2 s: one row per fit plus the exact solution's, all converged, each method fit's
    run in the file with its fitted values; the same call again commits no new fit."""
    observed = write_observations(tmp_path / "q.csv", 0.1, 2.0)  # 21 times: few, for the exact fit's expm
    config = tmp_path / "calibrate.yaml"
    config.write_text(spring_config(observed, ["backward_euler", "implicit_midpoint"], [0.02, 0.1], 2.0))
    output = tmp_path / "out"
    results = fit(config, output=output, jobs=1, progress=False, figures=False)
    table = results.fits.table
    method_ids = {run.run_id for run in expand_runs(load_experiment(config)[0])}
    assert len(table) == 5 and set(table["fit_id"]) == method_ids | {"exact"}
    assert set(table["status"]) == {"converged"}, table[["fit_id", "status", "message"]]
    assert table.loc[table["fit_id"] == "exact", SPRING_KEYS].to_numpy()[0] == pytest.approx([STIFFNESS, DAMPING], rel=1e-6)
    assert set(results.runs) == method_ids
    for fit_id in method_ids:
        row = table[table["fit_id"] == fit_id].iloc[0]
        system = results.runs[fit_id].system_params
        assert [system["stiffness"], system["damping"]] == pytest.approx([row[key] for key in SPRING_KEYS], rel=1e-12)
        assert not math.isnan(row["system.damping predicted"])
    before = fit_groups(output / "results.h5")
    again = fit(config, output=output, jobs=1, progress=False, figures=False)
    assert fit_groups(output / "results.h5") == before  # wall times included: nothing was fitted again
    assert len(again.fits.table) == 5 and set(again.runs) == method_ids


def test_changed_observations_are_not_resumed_as_if_unchanged(tmp_path):
    """The resume digest covers the content of the observation file: after the CSV changes (here to the motion of
    k = 150 N/m), the same `simrun fit` must not "resume" and return the fits to the old data (and the old
    observations in the file). Either refit or refuse (as a changed config is refused) would do."""
    observed = tmp_path / "q.csv"
    write_observations(observed, 0.1, 2.0)
    config = tmp_path / "calibrate.yaml"
    config.write_text(spring_config(str(observed), ["backward_euler"], [0.1], 2.0))
    fit(config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    t = 0.1 * np.arange(21)
    moved = exact_position(t, stiffness=150.0)
    np.savetxt(observed, np.column_stack([t, moved]), delimiter=",", header="t,x", comments="", fmt="%.17g")
    try:
        again = fit(config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    except ConfigError:
        return  # refused: the folder holds the results of other observations
    assert again.fits.observed_positions[:, 0] == pytest.approx(moved, abs=1e-12)
    exact_row = again.fits.table.set_index("fit_id").loc["exact"]
    assert exact_row["system.stiffness"] == pytest.approx(150.0, rel=1e-6)


def test_a_start_that_diverges_is_a_result(tmp_path):
    """Forward Euler on the 4 x 4 cloth from a stretch stiffness of 1e8 N/m at dt = 10 ms (h w ~ 400: the step
    multiplies the motion by ~400) overflows within 100 steps: the fit's result is `diverged`, with no values and no
    run, the other fit goes on, and `simrun fit` finishes. (A cloth has no exact solution, so no exact fit.)"""
    config = tmp_path / "diverges.yaml"
    config.write_text(f"""\
name: cloth_diverges
system: {json.dumps(CLOTH)}
integrators: [forward_euler, backward_euler]
duration: 1.0
sweep: {{dt: [0.01]}}
fit:
  observed: {{synthetic: {{integrator: backward_euler, dt: 0.01}}}}
  markers: [0, 3]
  parameters:
    system.stretch_stiffness: {{start: 1.0e8, bounds: [1.0, 1.0e9]}}
  max_evaluations: 3
""")
    results = fit(config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    table = results.fits.table.set_index("label")
    assert list(table.index) == ["forward_euler", "backward_euler"]
    row = table.loc["forward_euler"]
    assert row["status"] == "diverged" and "the start diverged" in row["message"]
    assert math.isnan(row["system.stretch_stiffness"])
    assert row["fit_id"] not in results.runs
    assert table.loc["backward_euler", "status"] in {"converged", "not_converged"}
    assert table.loc["backward_euler", "fit_id"] in results.runs


def test_fit_accepts_yaml_text(tmp_path):
    """simrun.fit takes "a path, YAML text or a dict": YAML text with a line longer than a file name may be
    (255 bytes) once raised OSError [Errno 36] File name too long, from testing it as a path."""
    observed = write_observations(tmp_path / "q.csv", 0.1, 2.0)
    text = spring_config(observed, ["backward_euler"], [0.1], 2.0)
    results = fit(text, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    assert len(results.fits.table) == 2


# -- found in review ---------------------------------------------------------------------------------------------
def test_rayleigh_damping_with_a_fitted_stiffness_falls_back_to_differences():
    """Rayleigh damping's beta K_rest moves with the stiffness: the system gives no exact derivative for a stiffness
    then (finite differences follow it), while beta itself still has one."""
    params = {"type": "mass_spring", "model": {"grid": {"resolution": [3, 3], "size": [1.0, 1.0]}}, "stiffness": 1000.0,
              "damping": [{"model": "rayleigh", "alpha": 0.1, "beta": 0.01}], "pinned": [6, 8]}
    system = validate_system(params).build()
    stiffer = validate_system({**params, "stiffness": 1001.0}).build()
    assert system.parameter_derivative(stiffer, 1.0) is None
    more_beta = validate_system({**params, "damping": [{"model": "rayleigh", "alpha": 0.1, "beta": 1.01}]}).build()
    assert system.parameter_derivative(more_beta, 1.0) is not None


def test_a_trial_the_model_refuses_is_penalised_not_a_failed_fit():
    """Without bounds a trust-region step can ask for k < 0, which the model refuses: that trial gets the divergence
    penalty and the fit goes on to the minimum."""
    experiment, _ = load_experiment(textwrap.dedent("""\
        name: unbounded
        system: {type: spring_mass, mass: 1.0, stiffness: 100.0, damping: 0.4}
        integrators: [implicit_midpoint]
        duration: 2.0
        sweep: {dt: [0.01]}
        fit:
          observed: {synthetic: {integrator: exact, dt: 0.01}}
          parameters:
            system.stiffness: {start: 1000.0}
            system.damping: {start: 0.1}
        """))
    tasks, _ = prepare(experiment, expand_runs(experiment))
    outcome = fit_one(tasks[1])
    assert outcome.status == "converged", outcome.message
    predicted = predicted_fit(INTEGRATORS["implicit_midpoint"](), 0.01, 1.0, 100.0, 0.4)
    assert outcome.values == pytest.approx(predicted, rel=2e-3)  # where the method's eigenvalue is the motion's


def test_data_made_by_a_method_are_predicted_as_that_methods_motion():
    """Synthetic data stepped by backward Euler at h are backward Euler's motion: fitting them with the same method
    and h recovers the truth, and the prediction says so (it targets the data method's eigenvalue, not exp(lambda h))."""
    backward = INTEGRATORS["backward_euler"]()
    assert predicted_fit(backward, 0.05, 1.0, 100.0, 0.4, (backward, 0.05)) == pytest.approx((100.0, 0.4), rel=1e-9)
    assert predicted_fit(backward, 0.05, 1.0, 100.0, 0.4)[1] == pytest.approx(-4.54, abs=0.01)


def test_observations_past_the_last_step_are_stepped_to_not_extrapolated():
    """A dt that does not divide the duration: the run takes the steps that reach the last observation."""
    from simrun.calibration.engine import steps_covering

    assert steps_covering(1.0, 0.3333334, 1.0) == 3  # 3 steps end at 1.0000002 s
    assert steps_covering(1.0, 0.3, 1.0) == 4  # 3 steps end at 0.9 s: a fourth reaches 1.0 s
    assert steps_covering(1.0, 0.25, 1.0) == 4


def test_a_fit_is_done_by_the_executor_it_names(tmp_path, monkeypatch):
    """simrun.fit runs its fits and its transfer table through the executors' registry (EXECUTOR_FUNCTIONS), as a
    sweep does: an executor planted there under a new name does every task, and the fits equal the serial ones."""
    import simrun.execution.executors as executors

    done = []

    def recording(tasks, work, runs, options):
        for task in tasks:
            done.append(work.__name__)
            yield task, work(task)

    monkeypatch.setitem(executors.EXECUTOR_FUNCTIONS, "recording", recording)
    observed = write_observations(tmp_path / "q.csv", 0.1, 2.0)
    text = spring_config(observed, ["backward_euler"], [0.1], 2.0)
    planted = fit(text, output=tmp_path / "planted", jobs=2, executor="recording", progress=False, figures=False)
    serial = fit(text, output=tmp_path / "serial", jobs=1, progress=False, figures=False)
    # the exact solution's fit and the method's, then the transfer table's rows of each
    assert done == ["fit_pair", "fit_pair", "transfer_task", "transfer_task"]
    keys = ["fit_id", *SPRING_KEYS]
    assert planted.fits.table[keys].equals(serial.fits.table[keys])
    with pytest.raises(ConfigError, match=r"--executor: unknown 'threads'; valid: process, dask, recording"):
        fit(text, output=tmp_path / "refused", executor="threads", progress=False, figures=False)
    assert not (tmp_path / "refused").exists()
