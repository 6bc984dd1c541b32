"""`simrun report`, `show` and `analyze`, on results files the real pipeline wrote into tmp_path.

The handlers are called directly (simrun.commands.<name>.handle), with the arguments their parsers give.
"""

from __future__ import annotations

import argparse
import base64
import csv
import io
import math
import re
from html.parser import HTMLParser
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from simrun.analysis import rows as tables
from simrun.analysis.reference import reference_errors
from simrun.cli import main
from simrun.commands import analyze as analyze_command, report as report_command, show as show_command
from simrun.experiment.config import ConfigError, load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.figures import CALIBRATION, FIGURES, figure_data, render_figures
from simrun.results import load

CONFIGS = Path(__file__).resolve().parent.parent / "configs"

# The spring q'' + 4 q = 0 (w = 2 rad/s) over 1 s at h w from 0.006 to 0.06: every method is in
# its asymptotic range there, above round-off (the exponential method is exact: errors at round-off).
ORDERS = {
    "system": {"type": "spring_mass", "stiffness": 4.0, "mass": 1.0, "x0": 1.0, "v0": 0.3},
    "integrators": ["forward_euler", "symplectic_euler", "backward_euler", "leapfrog", "explicit_midpoint", "rk4",
                    "implicit_midpoint", "bdf2", "generalized_alpha", {"type": "newmark", "beta": 0.3025, "gamma": 0.6},
                    "bdf2_midpoint_mix", "semi_implicit_backward_euler", "average_vector_field",
                    "exponential_rosenbrock_euler"],
    "solver": {"tolerance": 1.0e-12},
    "duration": 1.0,
    "sweep": {"dt": {"logspace": [-2.5, -1.5, 5]}},
}
# A small undamped cloth: no exact solution, so its errors come from a reference solution.
CLOTH = {
    "system": {"type": "cloth", "resolution": [4, 4], "stretch_stiffness": 1000.0, "shear_stiffness": 100.0,
               "bend_stiffness": 1.0, "damping": 0.0, "pinned": ["top_left", "top_right"]},
    "integrators": ["implicit_midpoint", "bdf2"],
    "solver": {"type": "projected_newton", "tolerance": 1.0e-10},
    "duration": 0.3,
    "sweep": {"dt": [0.0025, 0.005, 0.01, 0.02]},
}


def run_pipeline(folder: Path, name: str, experiment: dict | Path, *overrides: str) -> Path:
    """`simrun CONFIG --no-plots` into folder (a dict is written as CONFIG first); returns the results file."""
    folder.mkdir(parents=True, exist_ok=True)
    output = folder / name
    if isinstance(experiment, dict):
        config = folder / f"{name}.yaml"
        config.write_text(yaml.safe_dump({"name": name, **experiment}))
    else:
        config = experiment
    assert main([str(config), "-q", "--no-plots", "--output", str(output), *overrides]) == 0
    return output / "results.h5"


def report_args(results: Path, **options) -> argparse.Namespace:
    return argparse.Namespace(results=str(results), output=options.get("output"), reference=options.get("reference", "dop853"))


@pytest.fixture(scope="module")
def orders(tmp_path_factory) -> Path:
    return run_pipeline(tmp_path_factory.mktemp("orders"), "orders", ORDERS)


@pytest.fixture(scope="module")
def orders_report(orders) -> str:
    assert report_command.handle(report_args(orders)) == 0
    return (orders.parent / "report.html").read_text()


class PageParser(HTMLParser):
    """Every tag with its attributes, and the text of each <section> by id."""

    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.sections: dict[str, list[str]] = {}
        self.current = None

    def handle_starttag(self, tag, attrs):
        attributes = dict(attrs)
        self.tags.append((tag, attributes))
        if tag == "section":
            self.current = attributes["id"]
            self.sections[self.current] = []

    def handle_data(self, data):
        if self.current:
            self.sections[self.current].append(data)


def parse(page: str) -> PageParser:
    parser = PageParser()
    parser.feed(page)
    parser.close()
    return parser


def test_report_is_one_self_contained_html_page(orders, orders_report):
    """It parses; every figure the file supports is embedded as a PNG data URI; nothing refers to another file or URL."""
    page = parse(orders_report)
    assert page.tags[0][0] == "html" and orders_report.lstrip().lower().startswith("<!doctype html>")
    for tag, attributes in page.tags:
        assert tag not in ("script", "link", "iframe", "object", "embed", "base")
        for key, value in attributes.items():
            if key == "src":
                assert value.startswith("data:image/png;base64,")
                assert base64.b64decode(value.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
            if key == "href":
                assert value.startswith("#")  # links within the page only
            assert "url(" not in str(value)
    assert "url(" not in orders_report and "@import" not in orders_report
    embedded = {attributes["id"].removeprefix("figure-") for tag, attributes in page.tags if tag == "figure"}
    images = [attributes for tag, attributes in page.tags if tag == "img"]
    assert len(images) == len(embedded)
    # a spring with implicit methods and exact errors: every figure but the orbits
    calibration = {name for name, entry in FIGURES.items() if entry.needs == CALIBRATION}  # files of `simrun fit`
    # not drawn here: orbits, snapshots, a map (tests/test_lanes.py), the cost of solvers (a sweep of solver.type) and
    # the contact distance (runs with contact) and the volume ratio (finite elements)
    assert embedded == set(FIGURES) - calibration - {"orbits", "snapshots", "damping_map", "cost_vs_accuracy",
                                                              "contact_distance", "volume_ratio"}
    text = " ".join(" ".join(part) for part in page.sections.values())
    for caption in (FIGURES[name].caption for name in embedded):
        assert caption.split(".")[0] in text
    with h5py.File(orders, "r") as file:  # config and provenance are on the page
        assert file.attrs["config_hash"] in orders_report
    assert list(page.sections) == ["findings", "figures", "summary", "orders", "stability", "determinants", "provenance"]


def test_observed_orders_in_the_report_equal_the_methods_orders(orders, orders_report):
    """Least-squares slope of the end-time error against dt: each method's order within 0.15
    (the exponential Rosenbrock-Euler method is exact on the linear spring: errors at round-off)."""
    rows = {row.integrator: row for row in tables.order_rows(figure_data(load(orders)))}
    assert len(rows) == len(ORDERS["integrators"])
    for label, row in rows.items():
        if label == "exponential_rosenbrock_euler":
            assert row.exact and row.verdict.startswith("exact")
            continue
        assert abs(row.observed - row.declared) <= 0.15, (label, row.observed)
        assert row.verdict == "agrees"
    section = " ".join(parse(orders_report).sections["orders"])
    for row in rows.values():
        if np.isfinite(row.observed):
            assert f"{row.observed:.2f}" in section
    assert "differs" not in section
    assert rows["newmark[beta=0.3025,gamma=0.6]"].declared == 1  # gamma != 1/2: first order


def test_spring_stability_config_checks_the_lecture_determinants(tmp_path):
    """configs/spring_stability.yaml: det A = 1 + k h^2, 1, 1/(1 + k h^2) for the three Euler methods
    (m = 1), from the probed matrices; the predicted limits match the runs that diverged."""
    results_path = run_pipeline(tmp_path, "spring_stability", CONFIGS / "spring_stability.yaml")
    results = figure_data(load(results_path))
    rows = tables.determinant_rows(results)
    assert {row.integrator for row in rows} == {"forward_euler", "symplectic_euler", "backward_euler"}
    assert len(rows) == len(results.runs)
    for row in rows:
        k_h2 = row.stiffness * row.dt ** 2
        expected = {"forward_euler": 1 + k_h2, "symplectic_euler": 1.0, "backward_euler": 1 / (1 + k_h2)}[row.integrator]
        assert row.closed_form == pytest.approx(expected, rel=1e-15)
        assert row.verdict == "agrees" and row.difference <= 1e-12
    stability = {row.integrator: row for row in tables.stability_rows(results)}
    assert stability["forward_euler"].limit_hw == 0.0
    assert stability["symplectic_euler"].limit_dt == pytest.approx(0.2, rel=1e-6)  # h w < 2, w = 10 rad/s
    assert math.isinf(stability["backward_euler"].limit_hw)
    assert stability["symplectic_euler"].verdict == "consistent"
    assert stability["symplectic_euler"].smallest_diverged_dt == 0.21 and stability["symplectic_euler"].largest_ok_dt == 0.19
    output = tmp_path / "elsewhere" / "stability.html"
    assert report_command.handle(report_args(results_path, output=str(output))) == 0
    section = " ".join(parse(output.read_text()).sections["determinants"])
    assert section.count("agrees") == len(rows) and "differs" not in section
    assert "1 + k h²/m" in section


def test_damping_curves_config_measures_the_predicted_damping(tmp_path):
    """configs/damping_curves.yaml at three of its step sizes (h w = 0.1, 0.5, 2): every measured damping
    is resolved by its run and is the predicted one within 2 %."""
    experiment, _ = load_experiment(CONFIGS / "damping_curves.yaml")
    assert len(experiment.sweep["dt"]) >= 20
    labels = {integrator.label for integrator in experiment.integrators}
    assert {"backward_euler", "semi_implicit_backward_euler", "implicit_midpoint", "newmark", "bdf2",
            "exponential_rosenbrock_euler"} <= labels
    assert sum(label.startswith("generalized_alpha") for label in labels) == 5
    assert sum(label.startswith("bdf2_midpoint_mix") for label in labels) == 5
    results_path = run_pipeline(tmp_path, "damping", CONFIGS / "damping_curves.yaml", "--set", "sweep.dt=[0.1,0.5,2.0]")
    rows = tables.summary_rows(figure_data(load(results_path)))
    assert len(rows) == 3 * len(labels)
    for row in rows:
        assert row.measured_resolved, (row.integrator, row.hw)
        assert abs(row.damping_difference) <= 0.02, (row.integrator, row.hw, row.measured_damping, row.predicted_damping)


def test_the_shipped_configs_are_valid():
    for name in ("damping_curves", "circular_orbits", "spring_stability"):
        experiment, _ = load_experiment(CONFIGS / f"{name}.yaml")
        assert expand_runs(experiment)
    orbits, _ = load_experiment(CONFIGS / "circular_orbits.yaml")
    assert [integrator.name for integrator in orbits.integrators] == ["forward_euler", "symplectic_euler", "backward_euler"]


def show_args(results: Path, **options) -> argparse.Namespace:
    return argparse.Namespace(**{"results": str(results), "csv": False, "output": None, "wide": False, **options})


def test_show_prints_the_summary_and_writes_csv(orders, capsys, tmp_path):
    assert show_command.handle(show_args(orders, wide=True)) == 0
    table = capsys.readouterr().out
    count = len(ORDERS["integrators"]) * 5
    assert f"orders: {count} runs" in table and "rk4" in table and "meas." in table
    assert show_command.handle(show_args(orders, csv=True)) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(rows) == count
    assert {"run_id", "integrator", "dt_s", "status", "max_rel_energy_drift", "measured_damping_over_w",
            "predicted_damping_over_w"} <= set(rows[0])
    be = next(row for row in rows if row["integrator"] == "backward_euler")
    # backward Euler on the undamped spring: d/w = ln(1 + x^2)/x exactly, measured and predicted
    x = float(be["hw"])
    assert float(be["predicted_damping_over_w"]) == pytest.approx(math.log1p(x * x) / x, rel=1e-10)
    assert float(be["measured_damping_over_w"]) == pytest.approx(math.log1p(x * x) / x, rel=1e-6)
    target = tmp_path / "table" / "summary.csv"
    assert show_command.handle(show_args(orders, output=str(target))) == 0
    assert len(list(csv.DictReader(target.open()))) == count


def test_analyze_draws_the_predicted_curves_without_runs(tmp_path, capsys):
    args = argparse.Namespace(integrators=["backward_euler", "implicit_midpoint", "generalized_alpha:rho_inf=0.5", "leapfrog"],
                              range=[0.01, 100.0], output=str(tmp_path / "curves"), svg=True)
    assert analyze_command.handle(args) == 0
    out = capsys.readouterr().out
    assert "leapfrog" in out and "unstable" not in out.split("leapfrog")[1].splitlines()[0]
    names = {path.name for path in (tmp_path / "curves").iterdir()}
    assert {"artificial_damping.png", "artificial_damping.svg", "spectral_radius_and_period.png",
            "spectral_radius_and_period.svg", "predicted.csv"} <= names
    rows = list(csv.DictReader((tmp_path / "curves" / "predicted.csv").open()))
    assert {row["integrator"] for row in rows} == {"backward_euler", "implicit_midpoint", "generalized_alpha", "leapfrog"}
    for row in rows:
        if row["integrator"] == "backward_euler":
            x = float(row["hw"])
            assert float(row["spectral_radius"]) == pytest.approx(1 / math.sqrt(1 + x * x), rel=1e-12)


@pytest.mark.parametrize("options, message", [
    ({"integrators": ["bdf3"]}, "--integrators: unknown integrator 'bdf3'"),
    ({"integrators": ["generalized_alpha:rho_inf=1.5"]}, "--integrators: generalized_alpha: rho_inf"),
    ({"range": [1.0, 0.1]}, "--range: expected 0 < LOW < HIGH"),
    ({"range": [0.0, 1.0]}, "--range"),
])
def test_analyze_rejects_bad_input_in_one_line(tmp_path, options, message):
    args = argparse.Namespace(**{"integrators": None, "range": None, "output": str(tmp_path), "svg": False, **options})
    with pytest.raises(ConfigError, match=message.replace("[", r"\[")) as error:
        analyze_command.handle(args)
    assert "\n" not in str(error.value)


def test_report_and_show_refuse_what_is_not_a_results_file(tmp_path):
    (tmp_path / "notes.txt").write_text("not hdf5")
    with h5py.File(tmp_path / "empty.h5", "w"):
        pass
    for path in (tmp_path / "missing.h5", tmp_path / "notes.txt", tmp_path / "empty.h5"):
        with pytest.raises(ConfigError, match="results"):
            report_command.handle(report_args(path))
        with pytest.raises(ConfigError, match="results"):
            show_command.handle(show_args(path))


def test_parsers_register_their_handlers():
    parser = argparse.ArgumentParser(prog="simrun")
    commands = parser.add_subparsers(dest="command")
    report_command.add_parser(commands)
    show_command.add_parser(commands)
    analyze_command.add_parser(commands)
    args = parser.parse_args(["report", "r.h5", "--reference", "none"])
    assert args.handler is report_command.handle and args.reference == "none"
    assert parser.parse_args(["report", "r.h5"]).reference == "dop853"
    assert parser.parse_args(["show", "r.h5", "--csv"]).csv is True
    args = parser.parse_args(["show", "--csv", "r.h5"])  # the flag leaves the results file alone
    assert args.csv is True and args.results == "r.h5"
    assert parser.parse_args(["show", "r.h5", "--output", "t.csv"]).output == "t.csv"
    args = parser.parse_args(["analyze", "--integrators", "backward_euler", "generalized_alpha:rho_inf=0.5", "--output", "d"])
    assert args.handler is analyze_command.handle and args.integrators == ["backward_euler", "generalized_alpha:rho_inf=0.5"]


@pytest.fixture(scope="module")
def cloth(tmp_path_factory) -> Path:
    return run_pipeline(tmp_path_factory.mktemp("cloth"), "cloth", CLOTH)


def test_cloth_convergence_against_a_reference_solution(cloth):
    """No exact solution: DOP853 (rtol 1e-10) on the cloth rebuilt from system_params; implicit
    midpoint and BDF2 (undamped, so second order) show slope 2 within 0.15."""
    results = load(cloth)
    assert all(not np.isfinite(run.final_error) for run in results.runs.values())
    errors = reference_errors(results, "dop853")
    assert set(errors) == set(results.runs)
    rows = tables.order_rows(figure_data(results, errors))
    assert {row.integrator for row in rows} == {"implicit_midpoint", "bdf2"}
    for row in rows:
        assert abs(row.observed - 2.0) <= 0.15, (row.integrator, row.observed)
    assert "convergence" in {name for name, _ in _closed(render_figures(cloth, errors))}
    assert "convergence" not in {name for name, _ in _closed(render_figures(cloth))}  # not without a reference
    # another run as the reference: the smallest dt of implicit midpoint; every other run is compared with it
    anchor = next(iter(results.runs))
    against_run = reference_errors(results, anchor)
    assert set(against_run) == set(results.runs) - {anchor}
    with pytest.raises(ConfigError, match="--reference"):
        reference_errors(results, "no_such_method")


def _closed(figures):
    import matplotlib.pyplot as plt

    for _, name, figure in figures:
        plt.close(figure)
        yield name, figure


def test_a_cloth_report_leaves_out_what_does_not_apply(cloth, tmp_path):
    """No test equation: no stability limits, no determinants, no h w or d/w columns, captions without the
    spring's h w; no reference: no orders, and Findings say once what could not be measured and why. The
    snapshots are one grid of runs x times."""
    output = tmp_path / "cloth.html"
    assert report_command.handle(report_args(cloth, output=str(output), reference="none")) == 0
    page = parse(output.read_text())
    assert list(page.sections) == ["findings", "figures", "summary", "provenance"]
    findings_text = " ".join(page.sections["findings"])
    assert "no run is on the undamped test equation" in findings_text
    assert "no exact solution and no reference solution was asked for" in findings_text
    summary = " ".join(page.sections["summary"])
    assert "Not shown, empty for every run: h w, error, d/w." in summary and "E_ref = max(M |g| L" in summary
    assert summary.count("h w") == 1 and "d/w measured" not in summary  # only in that note
    figures_text = " ".join(page.sections["figures"])
    assert FIGURES["stability_map"].test_equation_caption not in figures_text and "(h w)" not in figures_text
    figures = [attributes["id"] for tag, attributes in page.tags if tag == "figure"]
    assert "figure-snapshots" in figures and not any(name.startswith("figure-cloth_") for name in figures)
    provenance = " ".join(page.sections["provenance"])
    assert "host" in provenance and "command line" in provenance
    # with a reference the errors are known: orders (against it) come back, stability and determinants do not
    assert report_command.handle(report_args(cloth, output=str(output))) == 0
    page = parse(output.read_text())
    assert list(page.sections) == ["findings", "figures", "summary", "orders", "provenance"]
    assert "reference" in " ".join(page.sections["findings"])


def test_captions_drop_what_holds_only_on_the_test_equation():
    """The registry's captions speak of h w (the test equation) only in their test-equation part, which the
    report adds for files with runs on the test equation (the theory figures are drawn only for those)."""
    from simrun.report.page import caption

    # and the damping map, drawn only for oscillators, whose natural frequency w gives its h w axis
    theory = {"artificial_damping", "spectral_radius_and_period", "damping_map"}
    for name, entry in FIGURES.items():
        assert caption(entry, False) == entry.caption
        assert caption(entry, True).startswith(entry.caption)
        if name not in theory:
            assert not re.search(r"\bh w\b", entry.caption), name
    # the limit from the amplification matrix at the test frequency only with such runs; off the test equation
    # the one from the system's stiffest (explicit) frequency
    assert "dt = (h w)*/w" in caption(FIGURES["stability_map"], True)
    assert "dt = (h w)*/w" not in caption(FIGURES["stability_map"], False)
    assert "stiffest frequency" in caption(FIGURES["stability_map"], False)
