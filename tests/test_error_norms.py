"""The error norms every run with an exact solution stores (runner/execution/measures.py, ``error_norms``): the velocity
error at the last sample and the largest position and velocity errors over the stored samples, against theory.

The spring: q'' = -w^2 q, w = 10 rad/s (k = 100 N/m, m = 1 kg), q0 = 1 m, v0 = 0; exact q(t) = cos(w t), v(t) = -w sin(w t).
Forward Euler's step is, in (q, v/w), [[1, h w], [-h w, 1]] = r R(-theta) with r = sqrt(1 + (h w)^2) and
theta = atan(h w), so q_n = r^n cos(n theta) and v_n = -w r^n sin(n theta): its errors follow by hand.
"""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

import simrun
from simrun.execution.lanes import MIN_LANES, simulate_lanes
from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.format.layout import ERROR_NORMS, RESULTS_NAME
from simrun.format.summary import SUMMARY_DTYPE
from simrun.results import load

W, DT, DURATION = 10.0, 1e-3, 1.0


def spring_runs(integrators, dts=(DT,), **extra):
    config = {"name": "norms", "system": {"type": "spring_mass", "stiffness": W * W, "mass": 1.0, "x0": 1.0, "v0": 0.0},
              "integrators": list(integrators), "duration": DURATION, "sweep": {"dt": list(dts)}, **extra}
    return expand_runs(validate_experiment(config))


def forward_euler(n: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(q_n (m), v_n (m/s)) of forward Euler on the spring, from its closed form."""
    r, theta = math.sqrt(1.0 + (h * W) ** 2), math.atan(h * W)
    return r ** n * np.cos(n * theta), -W * r ** n * np.sin(n * theta)


def test_forward_euler_s_error_norms_are_its_closed_form_s():
    (run,) = spring_runs(["forward_euler"], record={"every": 1})
    result = simulate(run)
    n = np.arange(run.step_count + 1)
    q, v = forward_euler(n, DT)
    t = n * DT
    assert np.allclose(result.samples["t"], t, rtol=0, atol=1e-12)
    position_error, velocity_error = np.abs(q - np.cos(W * t)), np.abs(v + W * np.sin(W * t))
    # the closed form against the stepped recursion: round-off of a thousand steps, far below the errors (~0.3 m)
    assert result.attrs["final_velocity_error"] == pytest.approx(velocity_error[-1], rel=1e-9)
    assert result.attrs["max_error"] == pytest.approx(position_error.max(), rel=1e-9)
    assert result.attrs["max_velocity_error"] == pytest.approx(velocity_error.max(), rel=1e-9)
    assert result.attrs["final_error"] == pytest.approx(position_error[-1], rel=1e-9)
    # forward Euler gains energy: its amplitude grows as r^n, so the largest error is near the end, and large
    assert result.attrs["max_error"] >= result.attrs["final_error"] > 0.01


def test_the_norms_over_the_run_are_the_largest_over_the_stored_series():
    """Strided samples (every 7th step): the norms over the run are those of the samples stored, not of every step."""
    (run,) = spring_runs(["symplectic_euler"], record={"every": 7})
    result = simulate(run)
    samples = result.samples
    exact_x, exact_v = run.system.build().exact_solution(samples["t"])
    assert result.attrs["max_error"] == np.max(np.abs(samples["positions"] - exact_x))
    assert result.attrs["max_velocity_error"] == np.max(np.abs(samples["velocities"] - exact_v))
    assert result.attrs["final_velocity_error"] == np.max(np.abs(samples["velocities"][-1] - exact_v[-1]))
    # symplectic Euler keeps a modified energy: its error stays of order h w (a phase error, growing like t)
    assert result.attrs["max_error"] < 0.1


@pytest.mark.parametrize("series", [True, False])
def test_lanes_store_the_norms_their_runs_store_alone(series):
    """A lane chunk (with and without series) stores the same error norms as each run stepped alone, bit for bit."""
    stiffnesses = np.geomspace(1.0, 1e7, MIN_LANES).tolist()  # h w = 0.001 to 3.2: the stiffest lanes diverge
    config = {"name": "norms", "system": {"type": "spring_mass", "x0": 1.0, "v0": 0.5}, "integrators": ["symplectic_euler"],
              "duration": DURATION, "record": {"every": 3, "series": series},
              "sweep": {"dt": [DT], "system.stiffness": stiffnesses}}
    runs = expand_runs(validate_experiment(config))
    batch = simulate_lanes(runs)
    assert batch.results_alone is None
    for run, lane in zip(runs, batch.results()):
        alone = simulate(run).attrs
        assert {key for key in ERROR_NORMS if key in alone} == {key for key in ERROR_NORMS if key in lane.attrs}
        for key in ERROR_NORMS:
            if key in alone:
                assert lane.attrs[key] == alone[key], (run.run_id, key)
    stable = [lane.attrs for lane in batch.results() if str(lane.status) == "ok"]
    assert stable and all(set(ERROR_NORMS) <= set(attrs) for attrs in stable)


def test_a_system_without_an_exact_solution_stores_no_norms_but_its_velocities_at_the_error_time():
    config = {"name": "cloth", "system": {"type": "cloth", "resolution": [3, 3], "pinned": ["top_left", "top_right"]},
              "integrators": ["backward_euler"], "duration": 0.05, "sweep": {"dt": [0.01]}}
    (run,) = expand_runs(validate_experiment(config))
    result = simulate(run)
    assert not set(ERROR_NORMS) & set(result.attrs)
    assert result.samples["error_velocities"].shape == result.samples["error_positions"].shape == (27,)


def test_a_file_written_before_the_norms_reads_them_as_nan(tmp_path):
    """Old files: no norm attributes and a summary table without their columns; the reader gives NaN for both."""
    config = {"name": "norms", "system": {"type": "spring_mass", "stiffness": 100.0, "x0": 1.0},
              "integrators": ["symplectic_euler", "rk4"], "duration": 0.5, "sweep": {"dt": [0.01, 0.02]}}
    simrun.run(config, output=tmp_path, progress=False, figures=False, lanes="off")
    path = tmp_path / RESULTS_NAME
    fresh = load(path)
    assert all(np.isfinite(run.max_velocity_error) for run in fresh.runs.values())
    assert np.isfinite(fresh.summary["max_error"]).all()
    with h5py.File(path, "r+") as file:
        for group in file["runs"].values():
            for key in ERROR_NORMS:
                del group.attrs[key]
        table = file["summary"][()]
        old = np.dtype([(name, SUMMARY_DTYPE[name]) for name in SUMMARY_DTYPE.names if name not in ERROR_NORMS])
        rows = np.empty(table.shape, dtype=old)
        for name in old.names:
            rows[name] = table[name]
        del file["summary"]
        file.create_dataset("summary", data=rows, maxshape=(None,), chunks=True)
    results = load(path)
    for run in results.runs.values():
        assert math.isnan(run.final_velocity_error) and math.isnan(run.max_error) and math.isnan(run.max_velocity_error)
        assert np.isfinite(run.final_error)
    summary = results.summary
    assert list(summary.columns) == list(SUMMARY_DTYPE.names)
    assert summary[list(ERROR_NORMS)].isna().all().all()


def test_near_critical_motion_is_the_propagator_and_lanes_store_what_runs_store():
    """Where the two roots of m l^2 + d l + k nearly coincide, the spring's exact motion is exp(t A) (q0, p0) in closed
    form (systems/oscillator.py near_critical_states): within 1e-13 of scipy's expm at and either side of critical damping;
    and lanes at those damping ratios store the error norms their runs store alone, bit for bit."""
    import scipy.linalg

    from simrun.systems.oscillator import near_critical_states

    m, k, q0, p0 = 1.3, 57.0, 0.7, -0.4
    t = np.array([0.0, 0.01, 0.3, 2.0, 10.0])
    for ratio in (1.0, 1.0 - 1e-8, 1.0 + 1e-8, 1.0 - 1e-4):
        d = ratio * 2.0 * math.sqrt(k * m)
        q, p = near_critical_states(*(np.array([value]) for value in (m, k, d, q0, p0)), t)
        generator = np.array([[0.0, 1.0], [-k / m, -d / m]])
        expected = np.array([scipy.linalg.expm(generator * time) @ [q0, p0] for time in t])
        np.testing.assert_allclose(q, expected[:, 0], rtol=0, atol=1e-13 * np.abs(expected[:, 0]).max())
        np.testing.assert_allclose(p, expected[:, 1], rtol=0, atol=1e-13 * np.abs(expected[:, 1]).max())
    # roots within DISTINCT_ROOTS of each other at |ratio - 1| below about 1e-7: those lanes take the closed form
    ratios = [0.5, 1.0 - 1e-8, 1.0, 1.0 + 1e-8, 2.0] * (MIN_LANES // 5 + 1)
    config = {"name": "critical", "system": {"type": "spring_mass", "stiffness": W * W, "x0": 1.0, "v0": 0.5},
              "integrators": ["backward_euler"], "duration": DURATION, "record": {"every": 3, "series": False},
              "sweep": {"dt": [DT], "system.damping_ratio": ratios[:MIN_LANES]}}
    runs = expand_runs(validate_experiment(config))
    batch = simulate_lanes(runs)
    for run, lane in zip(runs, batch.results()):
        alone = simulate(run).attrs
        for key in ERROR_NORMS:
            assert lane.attrs[key] == alone[key], (run.run_id, key)
