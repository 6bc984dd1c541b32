"""Where convergence and energy are measured: one error time per sweep, one energy reference per run.

Known right answers: the observed order of every method whose error is in the asymptotic range equals
its declared order within ORDER_TOLERANCE (0.15), on the spring (exact solution) and on the cloth
(against DOP853); a cloth at rest nudged by 1e-8 m/s drifts by a fraction of M g L, never by 1e16.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import simrun
from simrun.analysis.oscillator import observed_order
from simrun.analysis.reference import reference_errors
from simrun.analysis.rows import ORDER_TOLERANCE
from simrun.experiment.config import ERROR_PERIODS, load_experiment
from simrun.experiment.sweep import expand_runs

CONFIGS = simrun.__path__[0] + "/../configs"


def orders(results, errors=None) -> dict[str, object]:
    """label -> the observed-order fit of its runs (errors at the sweep's error time)."""
    fits = {}
    for label in dict.fromkeys(run.label for run in results.runs.values()):
        runs = sorted((run for run in results.runs.values() if run.label == label), key=lambda run: run.dt)
        values = [errors.get(run.run_id, math.nan) if errors is not None else run.error for run in runs]
        fits[label] = (observed_order([run.dt for run in runs], values, runs[0].length_scale), runs[0].order)
    return fits


def test_every_run_of_a_sweep_measures_its_error_at_the_same_time_and_ends_within_the_duration(tmp_path):
    """Spring w = 1 rad/s: error_time = ERROR_PERIODS * 2 pi / w at the nearest step (within dt / 2), for every dt;
    no run steps past the duration (the last sample at most one dt before it)."""
    results = simrun.run({"name": "times", "system": {"type": "spring_mass", "stiffness": 1.0},
                          "integrators": ["symplectic_euler", "implicit_midpoint"], "duration": 20.0,
                          "sweep": {"dt": [0.03, 0.07, 0.3, 0.7]}}, output=tmp_path, progress=False, figures=False)
    horizon = ERROR_PERIODS * 2 * math.pi
    for run in results.runs.values():
        assert abs(run.error_time - horizon) <= run.dt / 2 + 1e-12, run.run_id
        t_end = run["t"][-1]
        assert 20.0 - run.dt < t_end <= 20.0 + 1e-9, run.run_id
        # the error is the phase-space distance from the exact solution cos(t), at least the position's part
        assert run.error >= abs(run["error_positions"][0] - math.cos(run.error_time)) - 1e-15


def test_error_time_can_be_set_and_is_refused_when_not_positive(tmp_path):
    base = {"name": "set", "system": {"type": "spring_mass"}, "integrators": ["implicit_midpoint"],
            "duration": 2.0, "sweep": {"dt": [0.01, 0.02]}}
    results = simrun.run({**base, "record": {"error_time": 0.5}}, output=tmp_path, progress=False, figures=False)
    assert {round(run.error_time, 12) for run in results.runs.values()} == {0.5}
    with pytest.raises(simrun.errors.ConfigError, match="record.error_time"):
        load_experiment({**base, "record": {"error_time": -1.0}})


def test_damping_curves_give_the_declared_order_wherever_it_is_measurable(tmp_path):
    """configs/damping_curves.yaml (w = 1 rad/s, h w = 0.1 ... 10): at the error time (2.125 periods) the
    second-order methods without strong damping are in the asymptotic range at the smallest steps; every
    fitted slope is the declared order within 0.15, and where none is fitted the reason names the cause.
    The runs are cut at 14 s, just past the error time: what is measured does not change."""
    experiment, _ = load_experiment(f"{CONFIGS}/damping_curves.yaml", ["duration=14"])
    results = simrun.run(f"{CONFIGS}/damping_curves.yaml", overrides=["duration=14"], output=tmp_path, jobs=2,
                         progress=False, figures=False)
    assert len(results.runs) == len(expand_runs(experiment))
    fitted = set()
    for label, (fit, declared) in orders(results).items():
        if np.isfinite(fit.order):
            assert abs(fit.order - declared) <= ORDER_TOLERANCE, (label, fit.order)
            fitted.add(label)
        else:
            assert fit.reason, label
            assert fit.exact or "saturated" in fit.reason, (label, fit.reason)
    assert {"implicit_midpoint", "newmark", "generalized_alpha[rho_inf=1]", "bdf2_midpoint_mix[theta=0.25]"} <= fitted
    assert orders(results)["exponential_rosenbrock_euler"][0].exact  # exact on the linear spring


@pytest.mark.slow
def test_the_cloth_converges_at_the_declared_orders_against_a_reference(tmp_path):
    """configs/cloth_convergence.yaml, its three smallest steps and three methods: errors at the end time
    against DOP853 (rtol 1e-10) give slopes 1 (backward Euler) and 2 (implicit midpoint, BDF2) within 0.15."""
    results = simrun.run(f"{CONFIGS}/cloth_convergence.yaml", output=tmp_path, jobs=2, progress=False, figures=False,
                         overrides=["sweep.dt={logspace: [-3.6, -2.8, 3]}",
                                    "integrators=[backward_euler, implicit_midpoint, bdf2]"])
    errors = reference_errors(results, "dop853")
    assert set(errors) == set(results.runs)
    for label, (fit, declared) in orders(results, errors).items():
        assert abs(fit.order - declared) <= ORDER_TOLERANCE, (label, fit.order, fit.reason)


def test_a_cloth_nudged_at_rest_is_measured_against_m_g_l(tmp_path):
    """cloth_hang's cloth: at rest with a 1e-8 m/s nudge E0 ~ 1e-18 J. Its drift is relative to the cloth's
    declared reference max(M |g| L, |KE0| + |PE0|) = 9.81 J (M = 1 kg, L = 1 m): below 1, and no run diverges."""
    results = simrun.run(f"{CONFIGS}/cloth_hang.yaml", output=tmp_path, jobs=2, progress=False, figures=False,
                         overrides=["system.resolution=[6,6]", "system.initial_velocity=[0,0,1.0e-8]",
                                    "duration=0.5", "sweep.dt=[0.01]"])
    summary = results.summary
    assert set(summary["status"]) == {"ok"}
    assert (summary["max_rel_energy_drift"] < 1.0).all()
    for run in results.runs.values():
        assert run.energy_reference == pytest.approx(9.81) and "M |g| L" in run.energy_reference_name
        assert abs(run["energy"][0]) < 1e-12  # the E0 that format 1 divided by


def test_the_error_is_the_phase_space_distance_from_the_exact_motion(tmp_path):
    """Backward Euler on q'' = -q (w = 1 rad/s, q0 = 1, v0 = 0): u = q - i v is multiplied by 1/(1 - i h) per
    step while the exact u(t) = e^{i t}; the stored error after n steps is |(1 - i h)^-n - e^{i n h}| exactly."""
    results = simrun.run({"name": "be", "system": {"type": "spring_mass", "stiffness": 1.0},
                          "integrators": ["backward_euler"], "duration": 15.0, "sweep": {"dt": [0.05, 0.2]},
                          "solver": {"tolerance": 1e-13}}, output=tmp_path, progress=False, figures=False)
    for run in results.runs.values():
        steps = round(run.error_time / run.dt)
        expected = abs((1 - 1j * run.dt) ** -steps - np.exp(1j * steps * run.dt))
        assert run.error == pytest.approx(expected, rel=1e-9), run.run_id


def test_a_convergence_study_without_an_exact_solution_draws_its_convergence_by_default(tmp_path):
    """cloth_convergence.yaml (a cloth, no exact solution) at three time steps: `simrun run` draws the convergence
    figure against DOP853 without being asked (reference auto), and so does `simrun plot`; a file of one or two time
    steps, or with contact, gets no reference (auto is none there: a reference costs more than the runs)."""
    from pathlib import Path

    import simrun
    from simrun.analysis.reference import automatic_reference
    from simrun.cli import main

    config = Path(__file__).resolve().parents[1] / "configs" / "cloth_convergence.yaml"
    results = simrun.run(config, output=tmp_path / "conv", jobs=1, progress=False,
                         overrides=["system.resolution=[4,4]", "duration=0.02", "sweep.dt=[0.0025,0.005,0.01]",
                                    "integrators=[backward_euler, implicit_midpoint]"])
    assert automatic_reference(results) == "DOP853"
    assert {path.stem for path in results.figure_files} >= {"convergence", "work_precision"}
    assert main(["plot", str(results.path), "--output", str(tmp_path / "again")]) == 0
    assert (tmp_path / "again" / "convergence.png").is_file()
    two = simrun.run(config, output=tmp_path / "two", jobs=1, progress=False, figures=False,
                     overrides=["system.resolution=[4,4]", "duration=0.02", "sweep.dt=[0.005,0.01]"])
    assert automatic_reference(two) is None
