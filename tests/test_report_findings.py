"""The findings that open the report (simrun.findings), checked against known right answers, and the
report of the quickstart sweep: it opens with them, each links to something on the page, and its runs
table has no column that every run leaves empty.

The spring is the quickstart's (m = 1 kg, k = 100 N/m: w = 10 rad/s) over 3 s at h w = 0.01 ... 2.5.
On the undamped test equation the energy of one step scales by rho^2, and a period T = 2 pi / w is
2 pi / (h w) steps, so the energy lost per period is 1 - rho^(4 pi / (h w)):

- forward Euler: rho^2 = 1 + (h w)^2 > 1 at every h w (unstable at every step size, predicted limit 0);
  it gains 1 - (1 + (h w)^2)^(2 pi / (h w)) per period;
- symplectic Euler: rho = 1 up to h w = 2 (its limit), beyond it grows; dt = 0.25 s (h w = 2.5) diverges;
- backward Euler: rho^2 = 1 / (1 + (h w)^2) < 1 at every h w: never diverges; it loses
  1 - (1 + (h w)^2)^(-2 pi / (h w)) per period (98.7 % at h w = 1).
"""

from __future__ import annotations

import argparse
import math
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from simrun.analysis.rows import order_rows, summary_rows
from simrun.cli import main
from simrun.commands import report as report_command
from simrun.figures import figure_data
from simrun.findings import findings
from simrun.findings.base import energy_lost_per_period
from simrun.findings.integrators import DAMPING_BUDGET, largest_hw_within
from simrun.format.summary import Status
from simrun.results import load

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
W = 10.0  # rad/s, the quickstart spring


@pytest.fixture(scope="module")
def quickstart(tmp_path_factory) -> Path:
    """configs/quickstart.yaml over 3 s instead of 10 (the same six time steps)."""
    output = tmp_path_factory.mktemp("quickstart") / "quickstart"
    assert main([str(CONFIGS / "quickstart.yaml"), "-q", "--no-plots", "--set", "duration=3.0",
                 "--output", str(output), "-j", "1"]) == 0
    return output / "results.h5"


@pytest.fixture(scope="module")
def data(quickstart):
    results = load(quickstart)
    with results.opened():
        yield figure_data(results)


@pytest.fixture(scope="module")
def found(data):
    return findings(data)


def by_topic(found, topic: str, **evidence):
    return [finding for finding in found if finding.topic == topic
            and all(finding.evidence.get(key) == value for key, value in evidence.items())]


def test_stability_findings_match_the_lectures_and_the_runs(data, found):
    """Forward Euler: unstable at every h; symplectic Euler: h w < 2; backward Euler: never diverges; the measured
    part of each sentence comes from the runs at those dts and nothing else."""
    (forward,) = by_topic(found, "stability", integrator="forward_euler")
    (symplectic,) = by_topic(found, "stability", integrator="symplectic_euler")
    (backward,) = by_topic(found, "stability", integrator="backward_euler")
    assert forward.evidence["predicted_limit_hw"] == 0 and "unstable at every step size" in forward.sentence
    assert symplectic.evidence["predicted_limit_hw"] == pytest.approx(2.0, rel=1e-6)
    assert symplectic.evidence["predicted_limit_dt"] == pytest.approx(0.2, rel=1e-6)
    assert math.isinf(backward.evidence["predicted_limit_hw"]) and backward.evidence["diverged_dts"] == []
    for finding in (forward, symplectic, backward):
        runs = [run for run in data.runs if run.label == finding.evidence["integrator"]]
        assert finding.evidence["bounded_dts"] == sorted(run.dt for run in runs if not run.status.stopped)
        assert finding.evidence["diverged_dts"] == sorted(run.dt for run in runs if run.status is Status.DIVERGED)
        assert finding.link_anchor == "#stability"
        assert "measured" in finding.sentence and "predicted" in finding.sentence
    assert symplectic.evidence["smallest_diverged_dt"] == 0.25 and symplectic.evidence["largest_bounded_dt"] == 0.1
    assert backward.evidence["largest_bounded_dt"] == 0.25


def test_only_runs_at_the_largest_dt_say_who_survives_it(data, found):
    (largest,) = [finding for finding in by_topic(found, "stability") if "dt" in finding.evidence]
    at = [run for run in data.runs if run.dt == 0.25]
    assert largest.evidence["dt"] == 0.25
    assert largest.evidence["bounded"] == [run.label for run in at if not run.status.stopped] == ["backward_euler"]
    assert set(largest.evidence["diverged"]) == {"forward_euler", "symplectic_euler"}
    assert "only backward_euler" in largest.sentence and largest.link_anchor == "#figure-stability_map"


@pytest.mark.parametrize("label, energy_per_period", [
    ("backward_euler", lambda hw: (1 + hw ** 2) ** (-2 * math.pi / hw)),
    ("forward_euler", lambda hw: (1 + hw ** 2) ** (2 * math.pi / hw)),
    ("symplectic_euler", lambda hw: 1.0),  # below its limit h w = 2
])
def test_damping_per_period_is_the_closed_form(found, label, energy_per_period):
    """Predicted energy lost per period at the sweep's h w = 1 - (energy factor per step)^(steps per period)."""
    (finding,) = by_topic(found, "damping", integrator=label)
    assert finding.evidence["hw"] == pytest.approx([W * dt for dt in (0.001, 0.003, 0.01, 0.03, 0.1, 0.25)])
    for hw, lost in zip(finding.evidence["hw"], finding.evidence["energy_lost_per_period"]):
        if label == "symplectic_euler" and hw > 2:
            assert lost < 0  # past its limit: a gain
            continue
        assert lost == pytest.approx(1 - energy_per_period(hw), rel=1e-9, abs=1e-12)
    assert "predicted" in finding.sentence and finding.link_anchor == "#figure-artificial_damping"
    if label == "backward_euler":
        assert "98.7 % at 1" in finding.sentence  # 1 - 2^(-2 pi)
        assert energy_lost_per_period(math.log(2.0)) == pytest.approx(1 - 2 ** (-2 * math.pi), rel=1e-12)


def test_measured_damping_agrees_with_the_prediction(data, found):
    (finding,) = [finding for finding in by_topic(found, "damping") if "resolved" in finding.evidence]
    rows = summary_rows(data)
    fitted = [row for row in rows if np.isfinite(row.measured_damping)]
    assert finding.evidence["resolved"] == sum(row.measured_resolved for row in fitted) > 0
    assert finding.evidence["agree"] == finding.evidence["resolved"] and finding.evidence["differ"] == []
    assert finding.evidence["not_measured"] == sum(row.status in ("diverged", "failed") for row in rows)


def test_damping_budget_ranking(data, found):
    """Largest h w with at most 1 % of the energy lost or gained per period: backward Euler where
    1 - (1 + x^2)^(-2 pi / x) = 0.01, symplectic Euler its limit 2, forward Euler none (unstable)."""
    (finding,) = [finding for finding in by_topic(found, "damping") if "budget" in finding.evidence]
    largest = finding.evidence["largest_hw"]
    x = largest["backward_euler"]
    assert 1 - (1 + x * x) ** (-2 * math.pi / x) == pytest.approx(DAMPING_BUDGET, rel=1e-6)
    assert x == pytest.approx(0.0016, rel=0.01)
    assert largest["symplectic_euler"] == pytest.approx(2.0, rel=1e-6)
    assert largest["forward_euler"] == 0
    assert finding.sentence.index("symplectic_euler") < finding.sentence.index("backward_euler")


def test_accuracy_ranking_only_among_runs_that_reached_the_end_with_a_known_error(data, found):
    ranked = by_topic(found, "accuracy")
    budgets = [finding for finding in ranked if "budget" in finding.evidence]
    assert budgets and budgets[0].evidence["budget"] == pytest.approx(0.1)  # 10 % of the length scale x0 = 1 m
    for finding in budgets:
        budget = finding.evidence["budget"]
        walls = [wall for _, wall, _, _ in finding.evidence["ranking"]]
        assert walls == sorted(walls)
        for label, wall, dt, error in finding.evidence["ranking"]:
            run = next(run for run in data.runs if run.label == label and run.dt == dt)
            assert not run.status.stopped and error == run.stored.error <= budget and wall == run.wall_time
            cheaper = [other for other in data.runs if other.label == label and not other.status.stopped
                       and other.stored.error <= budget and other.wall_time < wall]
            assert not cheaper
        for label in finding.evidence["not_reached"]:
            assert not any(run.stored.error <= budget for run in data.runs if run.label == label and not run.status.stopped)
        assert finding.link_anchor == "#figure-work_precision" and "measured" in finding.sentence


def test_orders_and_what_could_not_be_measured(data, found):
    """Every order row is said once: a slope among the measured orders, or its reason among what could not be measured."""
    rows = order_rows(data)
    slopes = [finding for finding in by_topic(found, "accuracy") if "orders" in finding.evidence]
    said = dict(slopes[0].evidence["orders"]) if slopes else {}
    missing = [label for finding in by_topic(found, "not measured") for label in finding.evidence.get("integrators", [])]
    for row in rows:
        if np.isfinite(row.observed):
            assert said[(row.group, row.integrator)] == row.observed
        else:
            assert row.integrator in missing and row.reason
    assert not any("test equation" in finding.sentence for finding in by_topic(found, "not measured"))


def test_largest_hw_within_a_budget_is_where_the_curve_crosses_it():
    from simrun.analysis import oscillator as analysis

    prediction = analysis.predict(analysis.parse_integrator("generalized_alpha:rho_inf=0.5"))
    x = largest_hw_within(prediction, 0.05)
    _, damping = prediction.at(x)
    assert energy_lost_per_period(damping) == pytest.approx(0.05, rel=1e-6)
    assert math.isinf(largest_hw_within(analysis.predict(analysis.parse_integrator("implicit_midpoint"))))


# -- the quickstart report -----------------------------------------------------------------------------
class Page(HTMLParser):
    """Section ids in order, every id and href, and the cells of the runs table."""

    def __init__(self):
        super().__init__()
        self.sections, self.ids, self.hrefs = [], set(), []
        self.summary_rows: list[list[str]] = []
        self._section, self._in_cell, self._table_depth = None, False, 0

    def handle_starttag(self, tag, attrs):
        attributes = dict(attrs)
        if "id" in attributes:
            self.ids.add(attributes["id"])
        if tag == "section":
            self._section = attributes["id"]
            self.sections.append(self._section)
        if tag == "a" and "href" in attributes:
            self.hrefs.append(attributes["href"])
        if self._section == "summary" and tag == "tr":
            self.summary_rows.append([])
        if self._section == "summary" and tag in ("td", "th"):
            self._in_cell = True
            self.summary_rows[-1].append("")

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._in_cell = False

    def handle_data(self, text):
        if self._in_cell and self._section == "summary":
            self.summary_rows[-1][-1] += text.strip()


@pytest.fixture(scope="module")
def quickstart_page(quickstart) -> Page:
    output = quickstart.parent / "report.html"
    assert report_command.handle(argparse.Namespace(results=str(quickstart), output=str(output), reference="dop853")) == 0
    page = Page()
    page.feed(output.read_text())
    return page


def test_the_report_opens_with_findings_linked_to_what_shows_them(quickstart_page, found):
    assert quickstart_page.sections[0] == "findings"
    assert quickstart_page.sections[:6] == ["findings", "figures", "summary", "orders", "stability", "determinants"]
    for finding in found:
        assert finding.link_anchor.removeprefix("#") in quickstart_page.ids, finding.sentence
    for href in quickstart_page.hrefs:
        assert href.startswith("#") and href[1:] in quickstart_page.ids


def test_the_runs_table_has_no_column_empty_for_every_run(quickstart_page):
    heading, *rows = quickstart_page.summary_rows
    assert len(rows) == 18 and len(set(map(len, rows))) == 1 and len(heading) == len(rows[0])
    for number, name in enumerate(heading):
        cells = {row[number] for row in rows}
        assert cells - {"", "–", "0", "nan"}, f"column {name!r} is empty for every run"
    assert "Newton it/step" in heading and "h w" in heading


def test_energy_reference_is_stated_in_the_column_note(quickstart, quickstart_page):
    text = (quickstart.parent / "report.html").read_text()
    assert re.search(r"\|E − E0\| / E_ref.*E_ref = E0 \(initial energy\) = 50 J", text)
