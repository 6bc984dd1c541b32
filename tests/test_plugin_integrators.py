"""A researcher's own method joins without editing simrun: by its path in `integrators:` (``bathe:Bathe``, or a
mapping with its parameters) or by an entry point of group ``simrun.integrators``. It runs serially, on the process
pool and on a Dask cluster with the same bytes; its runs record the class and the sha256 of its source; the analyses
that predict (the damping and spectral figures, the damping map) probe it as they probe the built-ins; a method that
cannot be had is one line, exit 2, nothing written.

The example is Bathe's composite scheme (tests/plugins/bathe.py, docs/integrators.md).
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import simrun
from conftest import assert_runs_alike
from simrun.analysis.runs import predictions_for, run_set
from simrun.cli import main
from simrun.errors import ConfigError
from simrun.execution.lanes import lane_chunks
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, plugins

PLUGIN_FOLDER = Path(__file__).parent / "plugins"
SITE = PLUGIN_FOLDER / "site"  # simrun-demo-plugin 0.1: entry points demo_bathe and demo_broken
BATHE = "bathe:Bathe"


def spring_config(output: Path, integrators: list, **extra) -> dict:
    return {"name": "own_method", "system": {"type": "spring_mass", "stiffness": 100.0},
            "integrators": integrators, "duration": 1.0, "sweep": {"dt": [0.01, 0.005]}, "output": str(output), **extra}


# -- joining ---------------------------------------------------------------------------------------------------
def test_a_plugin_method_runs_beside_the_built_ins_and_records_its_source(on_path, tmp_path):
    """"bathe:Bathe" and {type: bathe:Bathe, gamma: 0.6} run beside backward Euler; each run records the method's name,
    class path and the sha256 of tests/plugins/bathe.py; the parameters are in params and the labels (both members of
    the family named by the gamma they differ in)."""
    results = simrun.run(spring_config(tmp_path / "out", ["backward_euler", BATHE, {"type": BATHE, "gamma": 0.6}]),
                         jobs=1, progress=False, figures=False)
    assert results.ran == {"ok": 6}
    digest = hashlib.sha256((PLUGIN_FOLDER / "bathe.py").read_bytes()).hexdigest()
    by_label = {}
    for run in results.runs.values():
        by_label.setdefault(run.label, []).append(run)
    assert sorted(by_label) == ["backward_euler", "bathe[gamma=0.5]", "bathe[gamma=0.6]"]
    for label in ("bathe[gamma=0.5]", "bathe[gamma=0.6]"):
        for run in by_label[label]:
            assert run.integrator == "bathe" and run.integrator_class == BATHE
            assert run.integrator_source_sha256 == digest
    assert {run.integrator_params["gamma"] for run in by_label["bathe[gamma=0.6]"]} == {0.6}
    built_in = by_label["backward_euler"][0]
    assert built_in.integrator_class == "simrun.integrators.euler:BackwardEuler"
    assert len(built_in.integrator_source_sha256) == 64
    assert list(results.summary["integrator.gamma"].dropna().unique()) == [0.5, 0.6]


def test_bathe_is_second_order_and_damps_less_than_backward_euler(on_path, tmp_path):
    """Physics, from the runs: Bathe's error falls by 4 when dt halves; it keeps far more of the spring's energy than
    backward Euler at the same step (its damping is O((h w)^4), backward Euler's O(h w))."""
    results = simrun.run(spring_config(tmp_path / "out", ["backward_euler", BATHE]), jobs=1, progress=False,
                         figures=False)
    summary = results.summary.set_index(["integrator", "dt"])
    ratio = summary.loc[("bathe", 0.01), "error"] / summary.loc[("bathe", 0.005), "error"]
    assert 3.6 < ratio < 4.4
    assert abs(summary.loc[("bathe", 0.01), "final_rel_energy_drift"]) < 1e-3
    assert abs(summary.loc[("backward_euler", 0.01), "final_rel_energy_drift"]) > 0.3


def test_a_plugin_without_a_name_is_labelled_by_its_path(on_path, tmp_path):
    results = simrun.run(spring_config(tmp_path / "out", ["own_methods:Unnamed"]), jobs=1, progress=False,
                         figures=False)
    assert {run.label for run in results.runs.values()} == {"own_methods:Unnamed"}
    assert results.ran == {"ok": 2}


def test_a_plugin_method_gives_the_same_bytes_serially_on_the_pool_and_on_dask(on_path, tmp_path):
    """Serial, a process pool of two, and a real Dask LocalCluster of two process workers: the same file."""
    pytest.importorskip("distributed")
    methods = [BATHE, {"type": BATHE, "gamma": 0.6}]
    serial = simrun.run(spring_config(tmp_path / "serial", methods), jobs=1, progress=False, figures=False)
    pool = simrun.run(spring_config(tmp_path / "pool", methods), jobs=2, progress=False, figures=False)
    dask = simrun.run(spring_config(tmp_path / "dask", methods), executor="dask", jobs=2, progress=False, figures=False)
    assert serial.ran == pool.ran == dask.ran == {"ok": 4}
    assert_runs_alike(serial, pool)
    assert_runs_alike(serial, dask)


def test_a_plugin_method_on_the_process_pool(on_path, tmp_path):
    """Without Dask installed too: the pool's workers import the plug-in and give the serial bytes."""
    serial = simrun.run(spring_config(tmp_path / "serial", [BATHE]), jobs=1, progress=False, figures=False)
    pool = simrun.run(spring_config(tmp_path / "pool", [BATHE]), jobs=2, progress=False, figures=False)
    assert_runs_alike(serial, pool)


def test_the_command_line_runs_a_config_beside_its_plugin(tmp_path, monkeypatch, capsys):
    """`simrun CONFIG` in the plug-in's folder: the module is found there, as `python -m` would."""
    folder = tmp_path / "project"
    folder.mkdir()
    (folder / "my_bathe.py").write_bytes((PLUGIN_FOLDER / "bathe.py").read_bytes())
    (folder / "config.yaml").write_text(yaml.safe_dump(spring_config(folder / "out", ["my_bathe:Bathe"])))
    monkeypatch.chdir(folder)
    monkeypatch.setattr(sys, "path", [entry for entry in sys.path if entry not in ("", ".", str(folder))])
    monkeypatch.delitem(sys.modules, "my_bathe", raising=False)
    plugins.clear_cache()
    try:
        assert main(["config.yaml", "--no-plots", "-j", "1", "-q"]) == 0
    finally:
        plugins.clear_cache()
    assert {run.integrator_class for run in simrun.load(folder / "out" / "results.h5").runs.values()} == {"my_bathe:Bathe"}


def test_an_installed_plugin_method_joins_by_its_entry_point_name(on_path, monkeypatch, tmp_path):
    """simrun-demo-plugin registers demo_bathe = bathe:Bathe in group simrun.integrators: the name runs and is
    offered among the valid names; a broken entry point names its distribution."""
    monkeypatch.syspath_prepend(str(SITE))
    assert plugins.installed()["demo_bathe"] == BATHE and "demo_bathe" in plugins.names()
    results = simrun.run(spring_config(tmp_path / "out", ["demo_bathe"]), jobs=1, progress=False, figures=False)
    assert {run.integrator_class for run in results.runs.values()} == {BATHE}
    with pytest.raises(ConfigError) as error:
        load_experiment(spring_config(tmp_path, ["demo_broken"]))
    assert str(error.value) == ("integrators.0: 'demo_broken' (entry point of simrun-demo-plugin 0.1: simrun.integrators "
                                "demo_broken = 'own_methods:NoOrder') -> 'own_methods:NoOrder': NoOrder does not "
                                "declare 'order'; give it  order: ClassVar[int] = ...  (its order of accuracy at the "
                                "default parameters)")


def test_lanes_take_a_plugin_only_where_it_declares_them(on_path, tmp_path):
    """A built-in's subclass declared steppable as lanes is stepped as lanes, with the built-in's numbers; Bathe,
    which declares nothing, is stepped run by run."""
    sweep = {"dt": [0.01], "system.stiffness": np.linspace(50.0, 150.0, 16).tolist()}
    methods = ["backward_euler", "own_methods:LaneBackwardEuler", BATHE]
    experiment, _ = load_experiment(spring_config(tmp_path, methods, sweep=sweep))
    chunks, alone = lane_chunks(expand_runs(experiment))
    assert {run.integrator.name for chunk in chunks for run in chunk} == {"backward_euler", "lane_backward_euler"}
    assert {run.integrator.name for run in alone} == {"bathe"}
    results = simrun.run(spring_config(tmp_path / "out", methods[:2], sweep=sweep), jobs=1, progress=False,
                         figures=False)
    summary = results.summary
    mine = summary[summary["integrator"] == "lane_backward_euler"]["final_error"].to_numpy()
    theirs = summary[summary["integrator"] == "backward_euler"]["final_error"].to_numpy()
    np.testing.assert_array_equal(mine, theirs)


# -- the analyses that predict ---------------------------------------------------------------------------------
def test_figures_predict_a_plugin_method_from_its_amplification(on_path, tmp_path):
    """The predicted curves of a Bathe run come from the class its run recorded: rho = 1 as h w -> 0, falling to the
    closed form's values; the damping map's predicted contours probe it as a bank of springs."""
    from simrun.analysis.damping_map import predicted_decades

    results = simrun.run(spring_config(tmp_path / "out", [BATHE]), jobs=1, progress=False, figures=False)
    data = run_set(results)
    prediction = predictions_for(data)["bathe"]
    np.testing.assert_allclose(prediction.rho, bathe_radius(prediction.hw), rtol=1e-12, atol=0.0)
    hw, zeta = np.geomspace(0.01, 10.0, 7), np.full(7, 0.0)
    decades = predicted_decades(data, "bathe", hw, zeta)
    # log10(rho) near rho = 1 is the eigenvalue's round-off (1e-16) times 2 pi / (h w): 1e-12 absolute
    np.testing.assert_allclose(decades, np.log10(bathe_radius(hw)) * 2.0 * np.pi / hw, rtol=1e-9, atol=1e-12)


def bathe_radius(hw: np.ndarray) -> np.ndarray:
    """The closed form the plug-in declares (its sub-steps' matrices written out)."""
    return plugins.resolve(BATHE)().closed_form_spectral_radius(hw)


def test_a_method_declared_nonlinear_is_measured_only(on_path, tmp_path):
    """linear = False: no curve is predicted for it anywhere; its runs are drawn and stated as measured only."""
    from simrun.figures.theory import artificial_damping
    from simrun.figures._data import figure_data
    from simrun.findings import findings

    results = simrun.run(spring_config(tmp_path / "out", ["own_methods:DeclaredNonlinear", "symplectic_euler"],
                                       duration=20.0), jobs=1, progress=False, figures=False)
    data = run_set(results)
    assert set(predictions_for(data)) == {"symplectic_euler"}
    assert all(run.method is None for run in data.runs if run.label == "declared_nonlinear")
    told = [finding.sentence for finding in findings(data)]
    assert any(text.startswith("Measured only") and "declared_nonlinear at h w = 0.1" in text for text in told), told
    figure = artificial_damping(figure_data(results))
    notes = " ".join(text.get_text() for text in figure.texts)
    assert "measured only, no curve" in notes and "declared_nonlinear" in notes


def test_a_file_read_where_the_plugin_does_not_import_still_draws(on_path, tmp_path, monkeypatch):
    """Read elsewhere (the module not importable, and never imported from the current folder by a reader), the runs
    have no prediction, and the figures draw without it."""
    from simrun.figures import draw_figures

    results = simrun.run(spring_config(tmp_path / "out", [BATHE, "backward_euler"]), jobs=1, progress=False,
                         figures=False)
    monkeypatch.setattr(sys, "path", [entry for entry in sys.path if entry != str(PLUGIN_FOLDER)])
    monkeypatch.delitem(sys.modules, "bathe")
    monkeypatch.chdir(PLUGIN_FOLDER)  # a reader never imports from the current folder
    plugins.clear_cache()
    reread = simrun.load(results.path)
    predictions = predictions_for(run_set(reread))
    assert "bathe" not in predictions and "backward_euler" in predictions
    assert draw_figures(reread, tmp_path / "figures")


# -- bad input -------------------------------------------------------------------------------------------------
BAD_METHODS = [
    ("nosuchmodule:X", "integrators.0: 'nosuchmodule:X': cannot import module 'nosuchmodule': No module named "
                       "'nosuchmodule'; install it, or put its folder on PYTHONPATH"),
    ("json:JSONDecoder", "integrators.0: 'json:JSONDecoder' names the class JSONDecoder, which is not a subclass of "
                         "simrun.integrators.Integrator"),
    ("own_methods:NotAMethod", "which is not a subclass of simrun.integrators.Integrator"),
    ("own_methods:NoOrder", "integrators.0: 'own_methods:NoOrder': NoOrder does not declare 'order'"),
    ("own_methods:OrderAsText", "OrderAsText.order is 'two', not a int"),
    ("own_methods:NoStep", "NoStep does not define step"),
    ("own_methods:TakesABuiltInName", "TakesABuiltInName.name is 'backward_euler', which is simrun's own BackwardEuler"),
    ("own_methods:Nope", "module 'own_methods' has no attribute 'Nope'"),
    ({"type": BATHE, "gamma": 1.5}, "integrators.0: bathe:Bathe: gamma: Input should be less than 1"),
    ({"type": BATHE, "gama": 0.6}, "integrators.0: bathe:Bathe: gama: unknown key (did you mean 'gamma'?)"),
]


@pytest.mark.parametrize("method, message", BAD_METHODS, ids=[str(method) for method, _ in BAD_METHODS])
def test_a_bad_plugin_method_is_one_line_exit_2_and_nothing_written(on_path, tmp_path, capsys, method, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(spring_config(tmp_path / "never", [method])))
    assert main([str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: ") and message in lines[0], captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert not (tmp_path / "never").exists()


def test_the_registry_is_unchanged_by_plugins(on_path):
    """Resolving plug-ins adds nothing to INTEGRATORS (the built-ins' table)."""
    before = dict(INTEGRATORS)
    plugins.resolve(BATHE)
    plugins.resolve("own_methods:LaneBackwardEuler")
    assert INTEGRATORS == before
    assert plugins.resolve("simrun.integrators.euler:BackwardEuler") is INTEGRATORS["backward_euler"]


# -- every solver its problem kind allows, simrun fit, simrun analyze ---------------------------------------------
def test_a_plugin_method_runs_with_every_solver_of_its_problem_kind(on_path, tmp_path):
    """Bathe hands the solver incremental potentials: Newton, projected Newton, L-BFGS and gradient descent all
    minimise them; on the linear spring they agree with Newton's run to their tolerance."""
    sweep = {"dt": [0.01], "solver.type": ["newton", "projected_newton", "lbfgs", "gradient_descent"]}
    config = spring_config(tmp_path / "out", [BATHE], sweep=sweep, duration=0.5, solver={"tolerance": 1e-10})
    results = simrun.run(config, jobs=1, progress=False, figures=False)
    assert results.ran == {"ok": 4}
    errors = results.summary.set_index("solver.type")["final_error"]
    assert errors.max() - errors.min() < 1e-8 * errors.max()


def test_simrun_fit_calibrates_with_a_plugin_method(on_path, tmp_path):
    """Ascher's spring fitted with Bathe at h w = 0.5: the fit moves k and d to where Bathe's probed amplification
    matrix has the observed eigenvalue (its period error of about 1 % at this step raises k by about 2 %), so the
    fitted values are the predicted ones; the exact solution's fit finds the truth."""
    config = {"name": "fit_bathe", "system": {"type": "spring_mass", "mass": 1.0, "stiffness": 100.0, "damping": 0.4},
              "integrators": [BATHE], "solver": {"tolerance": 1e-12}, "duration": 5.0, "sweep": {"dt": [0.05]},
              "output": str(tmp_path / "fit"),
              "fit": {"observed": {"synthetic": {"integrator": "exact", "dt": 0.005, "noise": 1e-3, "seed": 1}},
                      "parameters": {"system.stiffness": {"start": 80.0, "bounds": [1.0, 1e4]},
                                     "system.damping": {"start": 0.1, "bounds": [-50.0, 50.0]}}}}
    fits = simrun.fit(config, jobs=1, progress=False, figures=False).fits
    row = fits.method_fits.iloc[0]
    assert row["integrator"] == "bathe" and 101.0 < row["system.stiffness"] < 104.0
    assert row["system.stiffness"] == pytest.approx(row["system.stiffness predicted"], rel=2e-3)
    assert row["system.damping"] == pytest.approx(row["system.damping predicted"], abs=0.02)


def test_simrun_analyze_takes_a_plugin_path(on_path, tmp_path, capsys):
    """`simrun analyze --integrators bathe:Bathe 'bathe:Bathe[gamma=0.6]'`: the predicted curves of a plug-in."""
    assert main(["analyze", "--integrators", BATHE, "bathe:Bathe[gamma=0.6]", "--output", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert "bathe" in out and "bathe[gamma=0.6]" in out
    rows = (tmp_path / "a" / "predicted.csv").read_text().splitlines()
    assert sum(row.startswith("bathe[gamma=0.6],") for row in rows) == sum(row.startswith("bathe,") for row in rows) > 100
