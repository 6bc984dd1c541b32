"""Predicted and measured behaviour of the integrators: simrun.analysis.oscillator against theory.

Notation: the undamped test spring q'' + w^2 q = 0, x = h w. The predictions come from the
amplification matrix that simrun.analysis.oscillator probes by stepping basis states through each method; the
closed forms below come from the literature (not from the code). The measurements come from real
runs made by simrun.execution.simulate.simulate, fitted by simrun.analysis.oscillator.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simrun.analysis import oscillator as analysis
from simrun.analysis.reference import reference_positions
from simrun.execution.simulate import simulate
from simrun.integrators import INTEGRATORS
from simrun.systems import SpringMassParams

from conftest import make_runs


def leapfrog_radius(x):
    # Stoermer-Verlet on the spring: trace 2 - x^2, determinant 1 (Hairer, Lubich & Wanner, GNI 2006, ch. I)
    return 1.0 if x <= 2.0 else (x * x - 2.0 + x * math.sqrt(x * x - 4.0)) / 2.0


CLOSED_FORM_RADII = {
    # R(z) = 1/(1 - z): |R(i x)| = 1/sqrt(1 + x^2) (lecture 1; Hairer & Wanner II, ch. IV)
    "backward_euler": lambda x: 1.0 / math.sqrt(1.0 + x * x),
    # R(z) = (1 + z/2)/(1 - z/2): |R(i x)| = 1 (Hairer, Lubich & Wanner 2006)
    "implicit_midpoint": lambda x: 1.0,
    # Newmark beta = 1/4, gamma = 1/2, the trapezoidal rule: spectral radius 1 (Hughes 2000, sec. 9.1)
    "newmark": lambda x: 1.0,
    "leapfrog": leapfrog_radius,
}


@pytest.mark.parametrize("name", sorted(CLOSED_FORM_RADII))
def test_probed_spectral_radius_equals_the_closed_form(name):
    """rho(x) on the prediction grid (x in [1e-2, 1e2]) equals the closed form to 1e-12 (relative above 1)."""
    prediction = analysis.predict(INTEGRATORS[name]())
    expected = np.array([CLOSED_FORM_RADII[name](x) for x in prediction.hw])
    # the leapfrog's double root at x = 2 is defective: its eigenvalues are good to sqrt(eps) only there
    away = np.abs(prediction.hw - 2.0) > 1e-2 if name == "leapfrog" else np.ones(prediction.hw.size, bool)
    assert np.all(np.abs(prediction.rho - expected)[away] <= 1e-12 * np.maximum(1.0, expected[away]))


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_one_step_of_a_spring_bank_gives_every_point_s_amplification_matrix(name):
    """The predicted curves probe a bank of uncoupled springs (k_i = (h w_i)^2, h = 1 s) in one step per state slot.
    Its matrices are the test spring's at h w_i up to the scaling of v by w, so their eigenvalues are those of the
    point-by-point probe (dt = h w, w = 1) to round-off: 1e-12 relative, 1e-10 for the exponential integrator,
    whose expm_multiply stops at its own tolerance for the bank's larger matrix."""
    method = INTEGRATORS[name]()
    hw = np.geomspace(1e-2, 1e3, 16)
    bank = analysis.bank_matrices(method, hw)
    assert bank is not None and bank.shape[0] == hw.size
    points = np.stack([analysis.amplification_matrix(method, value) for value in hw])
    assert bank.shape == points.shape
    bank_values = np.sort_complex(np.linalg.eigvals(bank))
    point_values = np.sort_complex(np.linalg.eigvals(points))
    tolerance = 1e-10 if name == "exponential_rosenbrock_euler" else 1e-12
    scale = np.maximum(1.0, np.abs(point_values).max(axis=1, keepdims=True))
    # the leapfrog's defective double root at h w = 2 is not on this grid
    assert np.all(np.abs(bank_values - point_values) <= tolerance * scale), name


@pytest.mark.parametrize("rho_inf", [0.0, 0.25, 0.5, 0.75, 1.0])
def test_generalized_alpha_high_frequency_limit_is_rho_inf(rho_inf):
    """Chung & Hulbert (1993) chose alpha_m, alpha_f so that all three roots meet at -rho_inf as h w -> infinity:
    the probed limit map's spectral radius is rho_inf to 1e-12."""
    radius = analysis.high_frequency_radius(INTEGRATORS["generalized_alpha"](rho_inf=rho_inf))
    assert radius == pytest.approx(rho_inf, abs=1e-12)


@pytest.mark.parametrize("theta", [0.0, 0.5, 1.0])
def test_the_mix_high_frequency_limit(theta):
    """rho_inf of the BDF2/midpoint mix is 3 (1 - theta)/(3 + theta) (0 for BDF2, 1 for implicit midpoint)."""
    radius = analysis.high_frequency_radius(INTEGRATORS["bdf2_midpoint_mix"](theta=theta))
    assert radius == pytest.approx(3 * (1 - theta) / (3 + theta), abs=1e-12)


@pytest.mark.parametrize("name, limit", [
    ("forward_euler", 0.0),  # rho = sqrt(1 + x^2) > 1 at every x
    ("explicit_midpoint", 0.0),  # rho = sqrt(1 + x^4/4) > 1 at every x
    ("symplectic_euler", 2.0),  # trace 2 - x^2, det 1: complex roots on the unit circle while |2 - x^2| <= 2
    ("leapfrog", 2.0),
    ("rk4", 2.0 * math.sqrt(2.0)),  # rho^2 = 1 - x^6/72 + x^8/576
    ("backward_euler", math.inf),
    ("implicit_midpoint", math.inf),
    ("bdf2", math.inf),
    ("generalized_alpha", math.inf),
])
def test_predicted_stability_limit(name, limit):
    """The first h w where rho exceeds 1 (+1e-8), from the probe alone, against the known limits."""
    found = analysis.predict(INTEGRATORS[name]()).stability_limit
    if math.isinf(limit) or limit == 0.0:
        assert found == limit
    else:
        assert found == pytest.approx(limit, rel=1e-6)


def test_backward_euler_damping_curve():
    """d_method / w = -2 ln(rho) / x = ln(1 + x^2) / x for backward Euler: ~ x at small x, largest near x = 2."""
    prediction = analysis.predict(INTEGRATORS["backward_euler"]())
    x = prediction.hw
    assert np.allclose(prediction.damping, np.log1p(x * x) / x, rtol=1e-10, atol=1e-14)
    assert 1.8 < x[np.argmax(prediction.damping)] < 2.2  # the maximum of ln(1 + x^2)/x is at x = 1.98


@pytest.mark.parametrize("name, period", [
    # the phase per step of the principal eigenvalue: 2 atan(x/2) (Cayley), atan(x), acos(1 - x^2/2), x (exact)
    ("implicit_midpoint", lambda x: x / (2.0 * math.atan(x / 2.0)) - 1.0),
    ("backward_euler", lambda x: x / math.atan(x) - 1.0),
    ("leapfrog", lambda x: x / math.acos(1.0 - x * x / 2.0) - 1.0 if x < 2.0 else math.nan),
    ("exponential_rosenbrock_euler", lambda x: 0.0),
])
def test_predicted_relative_period_error(name, period):
    prediction = analysis.predict(INTEGRATORS[name]())
    shown = prediction.hw < math.pi
    expected = np.array([period(x) for x in prediction.hw[shown]])
    assert np.all(np.isnan(prediction.period_error[~shown]))
    finite = np.isfinite(expected) & (np.abs(prediction.hw[shown] - 2.0) > 1e-2)
    assert np.allclose(prediction.period_error[shown][finite], expected[finite], rtol=1e-9, atol=1e-11)


def test_lecture_determinants_of_the_euler_methods():
    """det A = 1 + k h^2 (forward), 1 (symplectic), 1/(1 + k h^2) (backward) for m = 1 (lecture 1)."""
    system = SpringMassParams(stiffness=100.0, mass=1.0).build()
    for dt in (0.001, 0.05, 0.3):
        kh2 = 100.0 * dt * dt
        assert analysis.determinant(INTEGRATORS["forward_euler"](), dt, system) == pytest.approx(1 + kh2, rel=1e-12)
        assert analysis.determinant(INTEGRATORS["symplectic_euler"](), dt, system) == pytest.approx(1.0, rel=1e-12)
        assert analysis.determinant(INTEGRATORS["backward_euler"](), dt, system) == pytest.approx(1 / (1 + kh2), rel=1e-12)


# ------------------------------------------------------------------------------------------------
# Measured against predicted
# ------------------------------------------------------------------------------------------------
IMPLICIT = [cls() for cls in INTEGRATORS.values() if not cls.explicit] + [
    INTEGRATORS["generalized_alpha"](rho_inf=0.0), INTEGRATORS["bdf2_midpoint_mix"](theta=1.0),
    INTEGRATORS["newmark"](beta=0.3025, gamma=0.6)]
X_MEASURED = (0.1, 0.5, 1.0, 2.0)
STEPS_MEASURED = 300
SPRING = {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0, "v0": 0.0}  # w = 1 rad/s: dt = h w


@pytest.fixture(scope="module")
def measured_runs():
    """One real run (simrun.execution.simulate.simulate) per implicit method and h w, 300 steps each."""
    results = {}
    for x in X_MEASURED:
        integrators = [{"type": method.name, **method.model_dump()} for method in IMPLICIT]
        for run in make_runs(SPRING, integrators, [x], duration=STEPS_MEASURED * x, record={"every": 1}):
            results[(run.integrator.label, x)] = simulate(run)
    return results


@pytest.mark.parametrize("x", X_MEASURED)
@pytest.mark.parametrize("method", IMPLICIT, ids=[method.label for method in IMPLICIT])
def test_measured_damping_agrees_with_the_prediction(measured_runs, method, x):
    """The damping fitted to a run's energy decay is the predicted -2 ln(rho)/h within 2 %; methods with
    rho = 1 (no artificial damping) measure zero (|d|/w below 1e-9)."""
    result = measured_runs[(method.label, x)]
    assert result.status == "ok"
    samples = result.samples
    fit = analysis.measure_damping(samples["t"], samples["energy"], samples["positions"][:, 0], angular_frequency=1.0)
    rho, predicted = analysis.predict(method).at(x)
    if abs(predicted) < 1e-9:
        assert abs(fit.rate) < 1e-9 and fit.resolved
    else:
        assert fit.resolved
        assert fit.rate == pytest.approx(predicted, rel=0.02)


@pytest.mark.parametrize("name", ["implicit_midpoint", "backward_euler", "bdf2"])
def test_measured_period_agrees_with_the_prediction(measured_runs, name):
    """The period from the zero crossings of x(t) is the principal eigenvalue's within 1 % of T (x <= 1)."""
    method = INTEGRATORS[name]()
    prediction = analysis.predict(method, 0.05, 5.0, 400)
    for x in (0.1, 0.5, 1.0):
        samples = measured_runs[(method.label, x)].samples
        measured = analysis.measure_period_error(samples["t"], samples["positions"][:, 0], 1.0)
        expected = float(np.interp(x, prediction.hw, prediction.period_error))
        assert measured == pytest.approx(expected, abs=0.01)


def test_damping_fit_of_a_pure_exponential():
    """ln E = -d t exactly: the fit returns d to round-off, resolved; too few samples: not measurable."""
    t = np.linspace(0.0, 10.0, 101)
    fit = analysis.measure_damping(t, 3.0 * np.exp(-0.7 * t))
    assert fit.rate == pytest.approx(0.7, rel=1e-12) and fit.resolved
    assert math.isnan(analysis.measure_damping(t[:3], np.ones(3)).rate)
    assert math.isnan(analysis.measure_damping(t, np.zeros_like(t)).rate)  # no energy to decay


def test_damping_fit_removes_the_energy_ripple():
    """E = e^{-d t} (1 + 0.3 cos 2 w t): the ripple at twice the frequency of x = cos(w t) is fitted out."""
    t = np.linspace(0.0, 60.0, 3001)
    w, d = 1.3, 1e-4
    fit = analysis.measure_damping(t, np.exp(-d * t) * (1 + 0.3 * np.cos(2 * w * t)), np.cos(w * t), angular_frequency=w)
    assert fit.rate == pytest.approx(d, rel=0.02)


def test_observed_order_uses_the_asymptotic_points_only():
    """error = 3 dt^2 between a round-off point and saturated ones: slope 2 exactly, from those points only."""
    dts = np.array([1e-4, 1e-3, 2e-3, 4e-3, 8e-3, 1e-1, 1.0])
    errors = 3.0 * dts ** 2
    errors[0] = 1e-14  # round-off
    errors[-2:] = [0.5, 0.02]  # saturated, then a lucky small error that is not asymptotic
    fit = analysis.observed_order(dts, errors, scale=1.0)
    assert fit.order == pytest.approx(2.0, abs=1e-12)
    assert fit.used.tolist() == [False, True, True, True, True, False, False]
    assert analysis.observed_order(dts[:3], [1e-15, 1e-16, 1e-15]).exact


# ------------------------------------------------------------------------------------------------
# Names, parameters and systems
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("spec, label", [
    ("backward_euler", "backward_euler"),
    ("generalized_alpha:rho_inf=0.5", "generalized_alpha"),
    ("generalized_alpha:rho_inf=0", "generalized_alpha[rho_inf=0]"),
    ("generalized_alpha[rho_inf=0.25]", "generalized_alpha[rho_inf=0.25]"),
    ("newmark:beta=0.3025,gamma=0.6", "newmark[beta=0.3025,gamma=0.6]"),
    ("average_vector_field:quadrature_points=2", "average_vector_field[quadrature_points=2]"),
])
def test_parse_integrator(spec, label):
    assert analysis.parse_integrator(spec).label == label


@pytest.mark.parametrize("spec, message", [
    ("bdf3", "unknown integrator 'bdf3' (did you mean 'bdf'?); valid: forward_euler".replace("(", r"\(")
     .replace(")", r"\)").replace("?", r"\?")),
    ("generalized_alpha:rho=0.5", "unknown parameter 'rho'; allowed: rho_inf"),
    ("generalized_alpha:rho_inf=2", "rho_inf"),
    ("generalized_alpha:rho_inf", "expected name:key=value"),
])
def test_parse_integrator_errors_name_what_is_allowed(spec, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[")):
        analysis.parse_integrator(spec)


def test_integrator_from_stored_params():
    """The file stores integrator.* params; the object rebuilt from them has the run's label."""
    method = analysis.integrator_from_params("bdf2_midpoint_mix", {"dt": 0.1, "integrator.theta": 1.0, "system.k": 3})
    assert method.label == "bdf2_midpoint_mix[theta=1]"


def test_reference_solution_on_the_spring():
    """solve_ivp (DOP853, rtol 1e-10) on the rebuilt damped spring matches its exact solution to 1e-8."""
    params = {"stiffness": 4.0, "mass": 1.0, "damping": 0.3, "x0": 1.0, "v0": 0.2}
    system = analysis.build_system("spring_mass", params)
    reference = reference_positions(system, [0.5, 2.0])
    exact, _ = system.exact_solution(np.array([0.5, 2.0]))
    assert np.allclose([reference[0.5][0], reference[2.0][0]], exact[:, 0], atol=1e-8)
    with pytest.raises(ValueError, match="valid: DOP853"):
        reference_positions(system, [1.0], method="Euler")
