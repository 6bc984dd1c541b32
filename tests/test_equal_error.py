"""simrun's Radau IIA against scipy's Radau at equal error: the interpolation of a method's costs against
its error (simrun.analysis.equal_error), the overlap of two methods' error ranges, and the finding on a small sweep.

On a power law cost = a error^(-b), log(cost) is linear in log(error), so the piecewise-linear interpolation in
log-log is exact: two methods a1 e^(-b1) and a2 e^(-b2) cost, at an error e between the sampled ones, in the ratio
(a2 / a1) e^(b1 - b2).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import simrun
from simrun.analysis.equal_error import comparison_errors, cost_at_error, equal_error, error_overlap
from simrun.figures import figure_data
from simrun.findings import findings
from simrun.findings.peers import peer_findings
from simrun.format.summary import Status
from simrun.results import load


def power_law(a: float, b: float, errors: np.ndarray) -> np.ndarray:
    return a * errors ** -b


@pytest.mark.parametrize("at", [3e-7, 1e-6, 4.2e-5, 1e-4])
def test_the_ratio_of_two_power_laws_is_their_closed_form(at):
    """cost_1 = 2 e^(-1/5) (order 5), cost_2 = 0.5 e^(-1/3) (order 3), each sampled at its own errors: at e the
    ratio is (0.5 / 2) e^(1/5 - 1/3)."""
    first = np.logspace(-8, -3, 6)
    second = np.array([3.1e-8, 2e-7, 9e-6, 5e-4, 2e-3])
    ours = cost_at_error(first, power_law(2.0, 0.2, first), [at])
    theirs = cost_at_error(second, power_law(0.5, 1 / 3, second), [at])
    assert ours[0] == pytest.approx(power_law(2.0, 0.2, np.array(at)), rel=1e-12)
    assert theirs[0] / ours[0] == pytest.approx(0.25 * at ** (0.2 - 1 / 3), rel=1e-12)


def test_costs_are_read_inside_the_runs_errors_only():
    """No extrapolation: NaN outside [smallest, largest] error; the ends themselves and unsorted input are fine."""
    errors = np.array([1e-4, 1e-8, 1e-6])
    costs = power_law(1.0, 0.25, errors)
    read = cost_at_error(errors, costs, [1e-9, 1e-8, 1e-4, 1e-3])
    assert np.isnan(read[0]) and np.isnan(read[3])
    assert read[1] == pytest.approx(costs[1]) and read[2] == pytest.approx(costs[0])


def test_a_count_with_a_zero_is_interpolated_linearly():
    """Zero has no logarithm: such costs are linear in the count against log(error), half way at the log midpoint."""
    read = cost_at_error([1e-6, 1e-4], [0.0, 10.0], [1e-5])
    assert read[0] == pytest.approx(5.0)


def test_overlap_of_error_ranges():
    assert error_overlap([1e-8, 1e-5, 1e-6], [1e-7, 1e-3]) == (1e-7, 1e-5)
    assert error_overlap([1e-8, 1e-7], [1e-6, 1e-3]) is None
    assert error_overlap([1e-8, math.nan], []) is None


def test_comparison_errors_are_decades_inside_the_overlap():
    """Decades inside the range (at most three: loosest, tightest, one between), else the geometric midpoint."""
    assert comparison_errors(2.9e-9, 8.5e-6) == pytest.approx([1e-6, 1e-7, 1e-8])
    assert comparison_errors(1e-6, 1e-6) == pytest.approx([1e-6])
    assert comparison_errors(2e-6, 8e-6) == pytest.approx([4e-6])
    five = comparison_errors(1e-9, 1e-4)
    assert len(five) == 3 and five[0] == pytest.approx(1e-4) and five[-1] == pytest.approx(1e-9)


# -- the finding on runs made up to order ------------------------------------------------------------
def fake_run(integrator: str, tolerance: float, error: float, wall_time: float, status=Status.OK, message=""):
    params = {"method": "Radau"} if integrator == "solve_ivp" else {}
    attrs = {"accepted_steps": 10 / tolerance ** 0.2, "jacobian_evaluations": 3.0}
    stored = SimpleNamespace(attrs=attrs, message=message, swept={"system": "spring"}, system="spring_mass")
    return SimpleNamespace(integrator=integrator, integrator_params=params, label=integrator, tolerance=tolerance,
                           error=error, wall_time=wall_time, status=status, error_from_reference=False, error_time=1.0,
                           stored=stored, run_id=f"{integrator}-{tolerance:g}")


def fake_data(runs):
    return SimpleNamespace(groups=[("system = spring", runs)], reference=None)


def test_disjoint_error_ranges_give_no_number():
    """simrun's runs reach 1e-9 ... 1e-7 m, scipy's 1e-5 ... 1e-3 m: no error both reach, so no ratio."""
    ours = [fake_run("radau_iia", tol, 1e-2 * tol, 0.1) for tol in (1e-5, 1e-7)]
    theirs = [fake_run("solve_ivp", tol, 10 * tol, 0.1) for tol in (1e-4, 1e-6)]
    compared = equal_error(("radau_iia", ours), ("solve_ivp", theirs))
    assert compared.overlap is None and compared.errors == []
    (finding,) = peer_findings(fake_data(ours + theirs))
    assert finding.topic == "equal error" and finding.evidence["errors"] == []
    assert "no error that both reach" in finding.sentence and "x faster" not in finding.sentence
    assert "1e-9 to 1e-7 m" in finding.sentence and "1e-5 to 1e-3 m" in finding.sentence


def test_runs_that_did_not_end_ok_are_left_out_and_named():
    ours = [fake_run("radau_iia", tol, tol, 0.01 * tol ** -0.2) for tol in (1e-4, 1e-6)]
    ours.append(fake_run("radau_iia", 1e-8, 1e-8, 0.01, Status.DIVERGED))
    theirs = [fake_run("solve_ivp", tol, tol, 0.04 * tol ** -0.2) for tol in (1e-4, 1e-6)]
    theirs.append(fake_run("solve_ivp", 1e-8, math.nan, 20.0, Status.NOT_CONVERGED,
                           "stopped at t = 0.5 s: 20 s of wall time, over record.max_wall_time 20 s"))
    (finding,) = peer_findings(fake_data(ours + theirs))
    assert finding.evidence["errors"] == pytest.approx([1e-4, 1e-5, 1e-6])
    assert finding.evidence["ratios"]["wall_time"] == pytest.approx([4.0] * 3)
    assert "radau_iia 4x faster" in finding.sentence
    assert "simrun's radau_iia at tol 1e-8 (diverged)" in finding.sentence
    assert "scipy's Radau at tol 1e-8 (over record.max_wall_time)" in finding.sentence


def test_no_known_error_gives_one_not_measured_line():
    ours = [fake_run("radau_iia", tol, math.nan, 0.1) for tol in (1e-4, 1e-6)]
    theirs = [fake_run("solve_ivp", tol, math.nan, 0.1) for tol in (1e-4, 1e-6)]
    (finding,) = peer_findings(fake_data(ours + theirs))
    assert finding.topic == "not measured" and "no run has a known error" in finding.sentence


# -- end to end on the spring -------------------------------------------------------------------------
SPRING = {
    "name": "equal_error_spring",
    "system": {"type": "spring_mass", "stiffness": 100.0, "mass": 1.0, "x0": 1.0},
    "integrators": ["radau_iia", {"type": "solve_ivp", "method": "Radau"}],
    "duration": 1.0,
    "step_control": {"tolerance": 1e-4},
    "sweep": {"step_control.tolerance": {"logspace": [-3, -7, 3]}},
}


def by_hand(runs, measure: str, error: float) -> float:
    """The cost at ``error`` on the straight line in log-log between the two runs whose errors bracket it."""
    points = sorted((run.error, measure(run)) for run in runs)
    for (e0, c0), (e1, c1) in zip(points, points[1:]):
        if e0 <= error <= e1:
            w = math.log(error / e0) / math.log(e1 / e0)
            return math.exp((1 - w) * math.log(c0) + w * math.log(c1))
    raise AssertionError(f"{error} outside the runs' errors")


def test_the_finding_on_the_spring_states_the_stored_runs(tmp_path):
    """On the spring (w = 10 rad/s, exact solution) at tolerances 1e-3, 1e-5, 1e-7: the finding's costs at its first
    error are the stored runs' wall times and accepted steps interpolated by hand, its ratio their quotient."""
    results = simrun.run(SPRING, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    results = load(results.path)
    with results.opened():
        data = figure_data(results)
        (finding,) = [finding for finding in findings(data) if finding.topic == "equal error"]
    ours = [run for run in data.runs if run.integrator == "radau_iia"]
    theirs = [run for run in data.runs if run.integrator == "solve_ivp"]
    assert len(ours) == len(theirs) == 3 and all(run.status is Status.OK for run in data.runs)
    low = max(min(run.error for run in ours), min(run.error for run in theirs))
    high = min(max(run.error for run in ours), max(run.error for run in theirs))
    errors = finding.evidence["errors"]
    assert errors and all(low <= error <= high for error in errors)
    error = errors[0]
    wall_ours, wall_theirs = (by_hand(runs, lambda run: run.wall_time, error) for runs in (ours, theirs))
    steps_ours = by_hand(ours, lambda run: run.stored.attrs["accepted_steps"], error)
    costs = finding.evidence["costs"]
    assert costs["radau_iia"]["wall_time"][0] == pytest.approx(wall_ours, rel=1e-9)
    assert costs["solve_ivp"]["wall_time"][0] == pytest.approx(wall_theirs, rel=1e-9)
    assert costs["radau_iia"]["accepted_steps"][0] == pytest.approx(steps_ours, rel=1e-9)
    assert finding.evidence["ratios"]["wall_time"][0] == pytest.approx(wall_theirs / wall_ours, rel=1e-9)
    assert f"{steps_ours:,.0f} steps" in finding.sentence and "scipy's Radau" in finding.sentence
    assert "left out" not in finding.sentence
