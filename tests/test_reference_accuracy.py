"""A reference solution's own accuracy (runner/analysis/reference.py): a second reference (DOP853 at rtol 1e-13)
solved at the same times estimates the first's (DOP853 at rtol 1e-10) error by max |x_ref - x_check|, which is
stated with the errors, and compared with them.

The small cloth: 4 x 4 vertices, hanging from two corners, no damping, over 0.3 s. DOP853's global error at
rtol 1e-10 is of order 1e-10 of the motion (a few cm here), so the two references agree to ~1e-11 m, while implicit
midpoint at dt = 0.01 s misses by ~1e-4 m: the stated accuracy is many decades below the compared runs' errors.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from simrun.analysis.oscillator import build_system
from simrun.analysis.reference import (CHECK_ATOL, CHECK_METHOD, CHECK_RTOL, REFERENCE_RTOL, ReferenceErrors,
                                       reference_errors, reference_positions, reference_states)
from simrun.cli import main
from simrun.figures import render_figures
from simrun.results import load

CLOTH = {"type": "cloth", "resolution": [4, 4], "stretch_stiffness": 1000.0, "shear_stiffness": 100.0,
         "bend_stiffness": 1.0, "damping": 0.0, "pinned": ["top_left", "top_right"]}


def run_config(folder, name: str, experiment: dict):
    folder.mkdir(parents=True, exist_ok=True)
    config = folder / f"{name}.yaml"
    config.write_text(yaml.safe_dump({"name": name, **experiment}))
    assert main([str(config), "-q", "--no-plots", "--output", str(folder / name)]) == 0
    return load(folder / name / "results.h5")


@pytest.fixture(scope="module")
def cloth(tmp_path_factory):
    return run_config(tmp_path_factory.mktemp("cloth"), "cloth", {
        "system": CLOTH, "integrators": ["implicit_midpoint", "backward_euler"], "solver": {"tolerance": 1e-10},
        "duration": 0.3, "sweep": {"dt": [0.005, 0.01]}})


def test_the_stated_accuracy_is_the_distance_between_the_two_references(cloth):
    errors = reference_errors(cloth, "dop853")
    assert isinstance(errors, ReferenceErrors) and set(errors) == set(cloth.runs)
    system = build_system("cloth", next(iter(cloth.runs.values())).system_params)
    first = reference_states(system, [0.3])[0.3]
    second = reference_states(system, [0.3], CHECK_METHOD, CHECK_RTOL, CHECK_ATOL)[0.3]
    expected = float(np.max(np.abs(first[0] - second[0])))
    assert set(errors.accuracy.values()) == {expected}
    assert set(errors.velocity_accuracy.values()) == {float(np.max(np.abs(first[1] - second[1])))}
    # the two agree within what DOP853 at rtol 1e-10 promises for a motion of a few centimetres, and not exactly
    assert 0.0 < expected < 100 * REFERENCE_RTOL
    # the accuracy is small against every compared run's error: none is at or below it
    assert min(errors.values()) > 1e3 * expected
    assert errors.below_accuracy() == []
    # reference_positions stays the x of reference_states
    assert np.array_equal(reference_positions(system, [0.3])[0.3], first[0])


def test_the_velocity_errors_at_the_error_time_are_measured_against_the_reference(cloth):
    errors = reference_errors(cloth, "dop853")
    system = build_system("cloth", next(iter(cloth.runs.values())).system_params)
    _, reference_v = reference_states(system, [0.3])[0.3]
    for run_id, run in cloth.runs.items():
        assert errors.velocity_errors[run_id] == pytest.approx(float(np.max(np.abs(run["error_velocities"] - reference_v))))
    # backward Euler damps: its velocity error is larger than implicit midpoint's at the same dt
    by_label = {(run.label, run.dt): errors.velocity_errors[run_id] for run_id, run in cloth.runs.items()}
    assert by_label[("backward_euler", 0.01)] > by_label[("implicit_midpoint", 0.01)]


def test_the_statement_names_both_references_and_the_accuracy(cloth):
    errors = reference_errors(cloth, "dop853")
    said = errors.statement()
    accuracy = max(errors.accuracy.values())
    assert "DOP853, rtol 1e-10" in said and f"{CHECK_METHOD}, rtol {CHECK_RTOL:g}" in said and f"{accuracy:.2g} m" in said
    against_run = reference_errors(cloth, next(iter(cloth.runs)))
    assert against_run.accuracy == {} and against_run.statement().startswith("run ")


def test_runs_at_or_below_the_accuracy_are_named():
    errors = ReferenceErrors({"a": 1e-6, "b": 1e-11, "c": 2e-10}, source="scipy solve_ivp (DOP853, rtol 1e-10)",
                             check="DOP853, rtol 1e-13", accuracy={"a": 2e-10, "b": 2e-10, "c": 2e-10})
    assert errors.below_accuracy() == ["b", "c"]
    assert errors.accuracy_of(["a"]) == 2e-10


def test_the_work_precision_figure_states_the_reference_and_its_accuracy(cloth, tmp_path):
    controlled = run_config(tmp_path, "controlled", {
        "system": CLOTH, "integrators": ["trbdf2", {"type": "solve_ivp", "method": "DOP853"}], "duration": 0.3,
        "step_control": {"tolerance": 1e-4}, "sweep": {"step_control.tolerance": [1e-3, 1e-10]}})
    errors = reference_errors(controlled, "dop853")
    # scipy's DOP853 at tolerance 1e-10 is the reference's own computation: said so
    assert errors.coinciding == ["solve_ivp[method=DOP853]"]
    assert "not independent" in errors.statement()
    figures = dict((name, figure) for _, name, figure in render_figures(controlled, errors, ["work_precision"]))
    note = figures["work_precision"].get_supxlabel().replace("\n", " ")
    accuracy = max(errors.accuracy.values())
    assert "errors vs reference" in note and f"{accuracy:.2g} m" in note
    # the coinciding run is nearly the reference's computation (its atol is 1e-10, the reference's 1e-12)
    coinciding = [run_id for run_id, run in controlled.runs.items() if run.label == "solve_ivp[method=DOP853]"
                  and run.params["step_control.tolerance"] == 1e-10]
    assert errors[coinciding[0]] < 1e-9
    assert "every drawn run's error is above it" in note
    # a run at or below the accuracy is named in the note as no measure of its method
    errors[coinciding[0]] = 0.5 * accuracy
    figures.update((name, figure) for _, name, figure in render_figures(controlled, errors, ["work_precision"]))
    note = figures["work_precision"].get_supxlabel().replace("\n", " ")
    assert "at or below it, so no measure of the method: solve_ivp[method=DOP853] (tol 1e-10)" in note
    import matplotlib.pyplot as plt

    plt.close("all")
