"""The energy budget split in the summary: the integrator's remainder max |E + E_dissipated - W - E0| / E_ref beside
the physical losses E_dissipated / E_ref (simrun.format.summary.energy_remainder), checked where the answer is known."""

from __future__ import annotations

import math

import numpy as np
import pytest

import simrun
from simrun.format.summary import energy_remainder

SPRING = """
name: damped_spring
system: {type: spring_mass, mass: 1.0, stiffness: 100.0, damping: DAMPING, x0: 1.0, v0: 0.0}
integrators: [implicit_midpoint, backward_euler, symplectic_euler]
duration: 2.0
sweep:
  dt: [0.01, 0.05]
record: {series: SERIES}
"""


def run_spring(tmp_path, damping: float, lanes: str = "off", series: bool = True):
    config = SPRING.replace("DAMPING", str(damping)).replace("SERIES", str(series).lower())
    return simrun.run(config, output=tmp_path / f"{damping}-{lanes}-{series}", jobs=1, figures=False, progress=False,
                      lanes=lanes).summary.set_index("run_id")


def test_implicit_midpoint_closes_a_damped_springs_budget_to_round_off(tmp_path):
    """For a quadratic energy the midpoint rule's discrete balance is exact: E_{n+1} - E_n = -h v_bar d v_bar, the
    damping's work as the run books it. Its remainder is round-off, and what left is all dissipation; backward Euler
    and symplectic Euler take energy of their own as well."""
    summary = run_spring(tmp_path, 1.0)
    midpoint = summary[summary["integrator"] == "implicit_midpoint"]
    assert (midpoint["max_rel_energy_remainder"] < 1e-13).all()
    # nothing of its own: the dissipated energy is the whole loss, E0 - E_end
    assert np.allclose(midpoint["final_rel_dissipated_energy"], -midpoint["final_rel_energy_drift"], rtol=1e-12)
    assert (midpoint["max_rel_energy_drift"] > 0.8).all()
    backward = summary[summary["integrator"] == "backward_euler"]
    assert (backward["max_rel_energy_remainder"] > 0.4).all()
    # backward Euler's numerical loss removes energy that damping would have taken: less is dissipated
    assert (backward["final_rel_dissipated_energy"].to_numpy() < midpoint["final_rel_dissipated_energy"].to_numpy()).all()


def test_without_losses_the_remainder_is_the_drift_and_nothing_is_dissipated(tmp_path):
    summary = run_spring(tmp_path, 0.0)
    assert (summary["max_rel_energy_remainder"] == summary["max_rel_energy_drift"]).all()
    assert (summary["final_rel_dissipated_energy"] == 0.0).all()


@pytest.mark.parametrize("series", [True, False], ids=["series", "summary only"])
def test_lanes_split_the_budget_as_runs_alone_do(tmp_path, series):
    alone = run_spring(tmp_path, 1.0, "off", series)
    lanes = run_spring(tmp_path, 1.0, "auto", series)
    for column in ("max_rel_energy_remainder", "final_rel_dissipated_energy"):
        assert np.array_equal(alone[column].to_numpy(), lanes[column].to_numpy()), column


def test_the_remainder_counts_the_work_of_prescribed_vertices_and_starts_at_the_first_finite_sample():
    energy = np.array([np.nan, 10.0, 12.0, 13.0])
    dissipated = np.array([0.0, 0.0, 1.0, 2.0])
    work = np.array([0.0, 0.0, 3.0, 5.0])
    remainder, lost = energy_remainder(energy, dissipated, work, 2.0)
    assert remainder == pytest.approx(0.0) and lost == pytest.approx(1.0)
    assert energy_remainder(energy, dissipated, np.zeros(4), 2.0) == pytest.approx((2.5, 1.0))
    assert all(math.isnan(value) for value in energy_remainder(np.full(3, np.nan), np.zeros(3), np.zeros(3), 1.0))


def test_show_splits_the_drift_where_energy_leaves_physically(tmp_path, capsys):
    from simrun.cli import main

    run_spring(tmp_path, 1.0)
    assert main(["show", str(tmp_path / "1.0-off-True" / "results.h5")]) == 0
    out = capsys.readouterr().out
    assert "remainder" in out and "dissipated" in out and "integrator remainder: the energy the method" in out
    run_spring(tmp_path, 0.0)
    assert main(["show", str(tmp_path / "0.0-off-True" / "results.h5")]) == 0
    out = capsys.readouterr().out
    assert "remainder" not in out and "drift: max |E - E0| / E_ref" in out
