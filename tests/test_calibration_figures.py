"""The calibration's figures, findings and report section (``simrun fit``), from configs/calibrate_spring.yaml
shortened (five integrators x three dts on the damped spring k = 100 N/m, d = 0.4 N s/m, m = 1 kg, w = 10 rad/s),
fitted into a temporary folder; and from a file without fits.

Backward Euler on its own shrinks the amplitude by 1/sqrt(1 + (h w)^2) ~ 1 - (h w)^2/2 per step, more than the
motion's exp(-d h / 2m) ~ 1 - d h/2m once h > d/(m w^2) = 4 ms: at every dt of the example its fit must lower d below
zero. Every number the tests compare is read from the file.
"""

from __future__ import annotations

import warnings
from html.parser import HTMLParser
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.text import Text

import simrun
from simrun.figures import CALIBRATION, FIGURES, figure_data
from simrun.findings.calibration import (calibration_findings, fit_rows, fitted_tables, key_unit, transfer_table,
                                         value_text)
from simrun.report.page import write_report
from simrun.results import load

ROOT = Path(__file__).parents[1]
CALIBRATION_FIGURES = sorted(name for name, entry in FIGURES.items() if entry.needs == CALIBRATION)


# configs/calibrate_spring.yaml shortened: explicit and implicit, damped and undamped methods at three steps over 3 s
SHORT_CALIBRATION = ["integrators=[symplectic_euler, rk4, backward_euler, implicit_midpoint, bdf2]", "duration=3.0",
                     "sweep.dt=[0.005,0.05,0.2]"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> Path:
    """The shipped spring calibration, shortened (SHORT_CALIBRATION), fitted into a temporary folder."""
    output = tmp_path_factory.mktemp("calibrated") / "calibrate_spring"
    simrun.fit(ROOT / "configs" / "calibrate_spring.yaml", output=output, jobs=1, progress=False, figures=False,
               overrides=SHORT_CALIBRATION)
    return output / "results.h5"


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    """The quickstart's results (shortened): runs, no fits."""
    output = tmp_path_factory.mktemp("plain") / "quickstart"
    simrun.run(ROOT / "configs" / "quickstart.yaml", output=output, jobs=1, progress=False, figures=False,
               overrides=["duration=1.0", "sweep.dt=[0.01,0.1]"])
    return output / "results.h5"


@pytest.fixture(scope="module")
def fitted_report(fitted) -> str:
    return write_report(fitted, fitted.parent / "report.html").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def plain_report(plain) -> str:
    return write_report(plain, plain.parent / "report.html").read_text(encoding="utf-8")


def texts(figure) -> str:
    return "\n".join(artist.get_text() for artist in figure.findobj(Text) if artist.get_visible() and artist.get_text())


def test_the_calibration_figures_are_registered():
    assert CALIBRATION_FIGURES == ["fitted_parameters_vs_dt", "observed_vs_fitted", "transfer_errors"]
    for name in CALIBRATION_FIGURES:
        assert FIGURES[name].caption.split(".")[0]


@pytest.mark.parametrize("name", CALIBRATION_FIGURES)
def test_each_calibration_figure_is_drawn_without_warnings_and_names_every_integrator(fitted, tmp_path, name):
    results = load(fitted)
    labels = set(results.fits.method_fits["label"])
    with results.opened(), warnings.catch_warnings():
        warnings.simplefilter("error")  # no figure may warn
        figure = FIGURES[name].draw(figure_data(results))
        assert figure is not None
        try:
            words = texts(figure)
            absent = sorted(label for label in labels if label not in words)
            assert not absent, f"{name} leaves out {absent}"
            figure.savefig(tmp_path / f"{name}.png", dpi=60)
        finally:
            plt.close(figure)
    assert (tmp_path / f"{name}.png").stat().st_size > 10_000


def test_the_fitted_parameters_figure_has_units_the_truth_and_marks_the_fit_that_did_not_converge(fitted):
    results = load(fitted)
    with results.opened():
        figure = FIGURES["fitted_parameters_vs_dt"].draw(figure_data(results))
    try:
        words = texts(figure)
        for key in results.fits.parameters:
            assert f"{key} ({key_unit(key)})" in words
        assert "truth" in words and "dashed: predicted" in words and "time step dt (s)" in words
        assert "h w" in words  # the spring's top axis
        statuses = set(results.fits.method_fits["status"])
        assert ("hollow: fit not converged" in words) == ("not_converged" in statuses)
    finally:
        plt.close(figure)


def test_a_file_without_fits_gives_no_calibration_figures(plain):
    results = load(plain)
    assert results.fits is None
    with results.opened():
        data = figure_data(results)
        for name in CALIBRATION_FIGURES:
            assert FIGURES[name].draw(data) is None


def test_findings_state_backward_eulers_negative_damping_from_the_files_numbers(fitted):
    """Backward Euler's fitted d is negative at the file's dts, and the finding says so with those very values."""
    results = load(fitted)
    table = results.fits.method_fits
    mine = table[table["integrator"] == "backward_euler"].sort_values("dt")
    negative = mine[mine["system.damping"] < 0]
    assert not negative.empty, "the example's backward Euler fits should need a negative damping"
    found = [finding for finding in calibration_findings(results)
             if finding.evidence.get("case") == "negative" and "backward_euler" in finding.evidence["values"]]
    assert len(found) == 1
    finding = found[0]
    stated = finding.evidence["values"]["backward_euler"]
    assert stated == {float(dt): float(value) for dt, value in zip(negative["dt"], negative["system.damping"])}
    truth = results.fits.truth["system.damping"]
    assert finding.evidence["motion"] == truth
    for value in (negative["system.damping"].iloc[0], negative["system.damping"].iloc[-1], truth):
        assert value_text(float(value)) in finding.sentence
    assert "pumping energy in" in finding.sentence


def test_findings_name_the_methods_that_recover_the_truth(fitted):
    """Every method fit within 1 % of the truth at its smallest dt or not, as the table says."""
    results = load(fitted)
    (recovered,) = [finding for finding in calibration_findings(results) if "within" in finding.evidence
                    and "tolerance" in finding.evidence]
    truth = results.fits.truth
    for row in fit_rows(results.fits):
        good = all(abs(row.values[key] - value) <= 0.01 * abs(value) for key, value in truth.items())
        assert (row.dt in recovered.evidence["within"][row.label]) == (good and row.shown)


def test_the_report_has_a_calibration_section_first_with_both_tables(fitted, fitted_report):
    page = Page()
    page.feed(fitted_report)
    assert page.sections[:2] == ["calibration", "findings"]  # the calibration's own answer first
    section = fitted_report.split('<section id="calibration">', 1)[1].split("</section>", 1)[0]
    results = load(fitted)
    assert results.fits.source.split(";")[0].split(",")[0] in section
    for table in fitted_tables(results):
        assert f"<h3>{table.key} ({table.unit})</h3>" in section
        label, cells = table.rows[0]
        assert cells[0].value_text() in section and cells[0].predicted_text() in section
    transfer = transfer_table(results.fits)
    assert 'id="calibration-transfer"' in section
    for integrator, dt in transfer.targets:
        assert f"{integrator} at dt = {dt:g} s" in section
    assert "pumping energy in" in section
    for name in CALIBRATION_FIGURES:
        assert f'id="figure-{name}"' in fitted_report


def test_a_report_without_fits_has_no_calibration(plain_report):
    page = Page()
    page.feed(plain_report)
    assert "calibration" not in page.sections
    assert CALIBRATION not in plain_report  # not even in the note of figures not drawn
    assert not any(f'id="figure-{name}"' in plain_report for name in CALIBRATION_FIGURES)


def test_the_transfer_table_holds_every_row_of_the_file(fitted):
    results = load(fitted)
    transfer = transfer_table(results.fits)
    stored = results.fits.transfer
    cells = {(row.fit_id, target): cell for row in transfer.rows for target, cell in zip(transfer.targets, row.cells)}
    assert len(cells) == len(stored)
    for record in stored.to_dict("records"):
        cell = cells[(record["fit_id"], (record["integrator"], float(record["dt"])))]
        assert cell.status == record["status"]
        assert cell.relative_error == pytest.approx(float(record["relative_error"]), nan_ok=True) or np.isinf(cell.relative_error)


class Page(HTMLParser):
    """The ids of the page's sections, in order."""

    def __init__(self):
        super().__init__()
        self.sections: list[str] = []

    def handle_starttag(self, tag, attrs):
        if tag == "section":
            self.sections.append(dict(attrs)["id"])
