"""The real-time factor, the wall time per frame and the solver's safeguards in the summary, the tables, the
report and its findings, on tiny sweeps that the real pipeline (simrun.run, one job) wrote.

- realtime: a 4 x 4 cloth, backward Euler, solver.type newton and vbd x solver.max_iterations 1 and 100 under
  on_not_converged: accept, at dt = 0.01 and 0.02 s. One iteration does not solve a step of the cloth (a
  nonlinear problem, tolerance 1e-8): those runs count every step as not converged and stay ok.
- troubled: forward Euler diverges (the stretch springs, k = 1000 N/m on 1/16 kg, have w ≈ 126 rad/s: h w ≈ 2.5 at
  dt = 0.02 s, beyond its stability); backward Euler with one Newton iteration and a projected_newton fallback
  does not converge from step 1 on, and every step ends in the fallback (safeguard bit 8).
- spring: backward Euler with Newton on the linear spring q'' + 4 q = 0: one full Newton step solves each step
  (the incremental potential is quadratic), so no safeguard fires.
- versus: the 4 x 4 cloth at dt = 0.01 s, backward Euler with solver.type newton and projective_dynamics, and
  XPBD (an explicit method: it reads no solver key, so its runs share no swept key with the others).

Wall times are whatever the machine took; the tests check the definitions (simulated time steps dt over wall
time; wall time per 1/60 s of simulated time) and where the numbers appear, never how fast anything ran.
"""

from __future__ import annotations

import csv
import io
import math
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import simrun
from simrun.analysis.rows import summary_rows
from simrun.analysis.units import frame_time_text, real_time_text
from simrun.cli import main
from simrun.figures import figure_data
from simrun.findings import findings
from simrun.findings.base import drift_text
from simrun.format.summary import Status
from simrun.report.page import write_report
from simrun.report.summary_table import NO_SWEPT_KEY, format_table, write_csv
from simrun.results import load

CLOTH = {"type": "cloth", "resolution": [4, 4], "stretch_stiffness": 1000.0, "shear_stiffness": 100.0,
         "bend_stiffness": 1.0, "damping": 0.0, "pinned": ["top_left", "top_right"]}
REALTIME = {
    "name": "realtime", "system": CLOTH, "integrators": ["backward_euler"],
    "solver": {"tolerance": 1.0e-8, "on_not_converged": "accept"},
    "duration": 0.04,
    "sweep": {"dt": [0.01, 0.02], "solver.type": ["newton", "vbd"], "solver.max_iterations": [1, 100]},
}
TROUBLED = {
    "name": "troubled", "system": CLOTH, "integrators": ["forward_euler", "backward_euler"],
    "solver": {"type": "newton", "tolerance": 1.0e-8, "max_iterations": 1, "fallback": ["projected_newton"]},
    "duration": 0.2, "divergence": {"energy_factor": 100.0},
    "sweep": {"dt": [0.02]},
}
VERSUS = {
    "name": "versus", "system": CLOTH, "integrators": ["backward_euler", {"type": "xpbd", "substeps": 5}],
    "solver": {"tolerance": 1.0e-8, "max_iterations": 50, "on_not_converged": "accept"},
    "duration": 0.05,
    "sweep": {"dt": [0.01], "solver.type": ["newton", "projective_dynamics"]},
}
SPRING = {
    "name": "spring", "system": {"type": "spring_mass", "stiffness": 4.0, "mass": 1.0, "x0": 1.0},
    "integrators": ["backward_euler"], "solver": {"type": "newton"}, "duration": 0.5,
    "sweep": {"dt": [0.01, 0.05]},
}


def simulated(folder: Path, experiment: dict) -> Path:
    """The sweep through simrun.run with one job, without figures; returns its results file."""
    return simrun.run(experiment, output=folder / experiment["name"], jobs=1, progress=False, figures=False).path


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("realtime")
    return {experiment["name"]: simulated(folder, experiment) for experiment in (REALTIME, TROUBLED, SPRING, VERSUS)}


@pytest.fixture(scope="module")
def pages(files) -> dict[str, "Page"]:
    """Each file's report (no reference solution: the cloth has no exact one, and none is needed here)."""
    result = {}
    for name, path in files.items():
        page = Page()
        page.feed(write_report(path, path.parent / "report.html", reference=None).read_text())
        result[name] = page
    return result


def rows_of(path: Path):
    results = load(path)
    with results.opened():
        data = figure_data(results)
        return data, summary_rows(data)


class Page(HTMLParser):
    """The runs table of a report (heading and cells as text), and the text of its findings."""

    def __init__(self):
        super().__init__()
        self.table: list[list[str]] = []
        self.findings = ""
        self._section, self._cell = None, False

    def handle_starttag(self, tag, attrs):
        if tag == "section":
            self._section = dict(attrs)["id"]
        if self._section == "summary" and tag == "tr":
            self.table.append([])
        if self._section == "summary" and tag in ("td", "th"):
            self._cell = True
            self.table[-1].append("")

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._cell = False

    def handle_data(self, text):
        if self._cell:
            self.table[-1][-1] += text.strip() + " "
        elif self._section == "findings":
            self.findings += text

    def column(self, heading: str) -> list[str]:
        """The cells of a column of the runs table, in run order."""
        number = [cell.strip() for cell in self.table[0]].index(heading)
        return [cells[number].strip() for cells in self.table[1:]]


# -- the summary ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["realtime", "troubled", "spring"])
def test_real_time_factor_and_wall_time_per_frame_are_their_definitions(files, name):
    """real_time_factor = steps dt / wall_time; wall_time_per_frame = wall_time / (60 steps dt), in the summary
    and on the stored runs alike."""
    results = load(files[name])
    for row in results.summary.itertuples():
        simulated_time = row.steps * row.dt
        assert row.wall_time > 0
        assert row.real_time_factor == pytest.approx(simulated_time / row.wall_time, rel=1e-12)
        assert row.wall_time_per_frame == pytest.approx(row.wall_time / (simulated_time * 60), rel=1e-12)
        run = results.runs[row.run_id]
        assert run.real_time_factor == pytest.approx(row.real_time_factor, rel=1e-12)
        assert run.wall_time_per_frame == pytest.approx(row.wall_time_per_frame, rel=1e-12)


def test_accept_keeps_a_run_ok_and_counts_its_steps(files):
    """Under on_not_converged: accept, one iteration per step leaves every step not converged, and the run ok."""
    results = load(files["realtime"])
    by_budget = {}
    for run in results.runs.values():
        by_budget.setdefault(run.params["solver.max_iterations"], []).append(run)
    assert len(by_budget[1]) == len(by_budget[100]) == 4
    for run in by_budget[1]:
        assert run.status is Status.OK, run.run_id
        assert run.attrs["not_converged_steps"] == run.steps == round(REALTIME["duration"] / run.dt)
        assert run.attrs["first_not_converged_step"] == 1
    for run in by_budget[100]:
        assert run.status is Status.OK
        if run.params["solver.type"] == "newton":  # Newton converges in a few iterations on this cloth
            assert run.attrs["not_converged_steps"] == 0 and run.attrs["first_not_converged_step"] == 0


def test_the_steps_where_runs_went_wrong_are_stored(files):
    results = load(files["troubled"])
    explicit, implicit = results.runs.values()
    assert explicit.status is Status.DIVERGED
    assert 1 <= explicit.attrs["diverged_step"] == explicit.steps
    assert explicit.attrs["diverged_step"] * explicit.dt == pytest.approx(explicit.attrs["t_diverged"], rel=1e-12)
    assert explicit.attrs["safeguard_steps"] == 0  # an explicit method solves nothing
    assert implicit.status is Status.NOT_CONVERGED and implicit.attrs["first_not_converged_step"] == 1
    assert implicit.attrs["safeguard_steps"] == implicit.steps  # every step fell back to projected_newton
    assert (implicit["safeguards"] & 8).all()


# -- the terminal table and the CSV -----------------------------------------------------------------
def table_line(table: str, row) -> list[str]:
    """The cells of a run's line of `simrun show`'s table."""
    return next(line.split() for line in table.splitlines() if line.split()[:2] == [str(row.index), row.integrator])


@pytest.mark.parametrize("name", ["realtime", "troubled", "spring"])
def test_the_text_table_and_csv_show_the_real_time_columns(files, name):
    data, rows = rows_of(files[name])
    summary = data.results.summary.set_index("run_id")
    table = format_table(rows, name, wide=True)
    header = table.splitlines()[1] + table.splitlines()[2]
    assert "real-time" in header and "wall/frame" in header
    for row in rows:
        assert row.real_time_factor == summary.loc[row.run_id, "real_time_factor"]
        assert row.wall_time_per_frame == summary.loc[row.run_id, "wall_time_per_frame"]
        cells = table_line(table, row)
        assert real_time_text(row.real_time_factor) in cells
        assert frame_time_text(row.wall_time_per_frame) in cells
    stream = io.StringIO()
    write_csv(rows, stream)
    exported = {line["run_id"]: line for line in csv.DictReader(io.StringIO(stream.getvalue()))}
    for row in rows:
        line = exported[row.run_id]
        assert float(line["real_time_factor"]) == row.real_time_factor  # full precision
        assert float(line["wall_time_per_frame_s"]) == row.wall_time_per_frame
        assert int(line["safeguard_steps"]) == row.safeguard_steps
        assert int(line["not_converged_steps"]) == data.results.runs[row.run_id].attrs["not_converged_steps"]


def test_real_time_text():
    assert real_time_text(0.3141) == "0.31x" and real_time_text(4.2) == "4.2x" and real_time_text(1234.4) == "1234x"
    assert real_time_text(math.nan) == "–" and frame_time_text(1 / 60) == "16.7" and frame_time_text(math.nan) == "–"


def test_the_safeguards_column_appears_only_when_a_run_has_safeguard_steps(files, pages):
    _, troubled = rows_of(files["troubled"])
    _, spring = rows_of(files["spring"])
    assert all(row.safeguard_steps == 0 for row in spring)
    assert "safeguards" not in format_table(spring, "spring", wide=True)
    assert all("safeguards" not in cell for cell in pages["spring"].table[0])
    table = format_table(troubled, "troubled", wide=True)
    assert "safeguards" in table.splitlines()[2]
    implicit = next(row for row in troubled if row.integrator == "backward_euler")
    assert f"{implicit.steps}/{implicit.steps}" in table_line(table, implicit)
    assert pages["troubled"].column("safeguards") == ["–", f"{implicit.steps}/{implicit.steps}"]


def test_the_status_says_where_a_run_went_wrong(files, pages):
    """The first step that diverged or did not converge (from the run's attributes), in the report's status cell
    and in `simrun show`'s status; an accepted run says how many steps it accepted."""
    results = load(files["troubled"])
    explicit, implicit = results.runs.values()
    status = pages["troubled"].column("status")
    assert status[0] == f"diverged at step {explicit.attrs['diverged_step']}"
    assert status[1] == f"not converged from step 1, {implicit.steps}/{implicit.steps} steps"
    _, rows = rows_of(files["troubled"])
    table = format_table(rows, "troubled", wide=True)
    assert f"diverged@{explicit.attrs['diverged_step']}" in table_line(table, rows[0])
    assert "not_converged@1" in table_line(table, rows[1])
    accepted = pages["realtime"].column("status")
    realtime = load(files["realtime"])
    for run, cell in zip(realtime.runs.values(), accepted):
        count = run.attrs["not_converged_steps"]
        assert cell == (f"ok {count}/{run.steps} steps accepted" if count else "ok"), run.run_id


def test_the_report_shows_the_real_time_columns(files, pages):
    for name, path in files.items():
        summary = load(path).summary
        assert pages[name].column("real-time") == [real_time_text(value) for value in summary["real_time_factor"]]
        assert pages[name].column("wall/frame (ms)") == [frame_time_text(value) for value in summary["wall_time_per_frame"]]


# -- the cost findings -----------------------------------------------------------------------------
def cost_findings(path: Path):
    """(the file's cost findings that lead, one per compared dt; each method's finding by (dt, method); the data)."""
    data, rows = rows_of(path)
    found = [finding for finding in findings(data, rows) if finding.topic == "cost"]
    leads = [finding for finding in found if "methods" in finding.evidence]
    each = {(finding.evidence["dt"], finding.evidence["method"]): finding for finding in found if "method" in finding.evidence}
    assert len(leads) + len(each) == len(found)
    return leads, each, data, rows


def distance(results, run_id: str, baseline_id: str) -> float:
    """m: max |x - x_baseline| at the error time, from the file's error_positions."""
    return float(np.max(np.abs(results.runs[run_id]["error_positions"] - results.runs[baseline_id]["error_positions"])))


def test_solvers_are_compared_at_equal_dt(files, pages):
    """A sweep of solver.type gets, per shared dt, a finding that names the baseline (the fastest converged Newton
    run: at max_iterations 1 no run converges, at 100 Newton does) and one per other method with its wall time per
    frame, real-time factor, energy change and distance max |x - x_baseline| at the error time; sweeps of one
    solver get none."""
    leads, each, data, rows = cost_findings(files["realtime"])
    by_id = {row.run_id: row for row in rows}
    results = data.results
    assert sorted(lead.evidence["dt"] for lead in leads) == [0.01, 0.02]
    for lead in leads:
        dt, methods = lead.evidence["dt"], lead.evidence["methods"]
        assert set(methods) == {f"{kind} (max_iterations = {budget})" for kind in ("newton", "vbd") for budget in (1, 100)}
        assert lead.evidence["measure"] == "max_rel_energy_drift"  # the cloth has no exact solution
        runs = {name: results.runs[numbers["run_id"]] for name, numbers in methods.items()}
        converged_newton = [name for name, run in runs.items()
                            if run.params["solver.type"] == "newton" and run.attrs["not_converged_steps"] == 0]
        assert converged_newton == ["newton (max_iterations = 100)"]
        baseline = lead.evidence["baseline"]
        assert baseline == "newton (max_iterations = 100)"
        assert lead.sentence.startswith(f"Cost at dt = {dt:g} s against {baseline}")
        for name, numbers in methods.items():
            row = by_id[numbers["run_id"]]
            assert row.dt == dt and row.solver == name.split()[0]
            assert numbers["wall_time_per_frame"] == row.wall_time_per_frame
            assert numbers["real_time_factor"] == row.real_time_factor
            assert numbers["measure"] == row.max_rel_energy_drift
            assert numbers["deviation"] == pytest.approx(distance(results, row.run_id, methods[baseline]["run_id"]),
                                                         rel=1e-12, abs=0)
            stated = f"{1e3 * row.wall_time_per_frame:.3g} ms per frame ({real_time_text(row.real_time_factor)} real time)"
            if name == baseline:
                assert f"{baseline} takes {stated}" in lead.sentence and (dt, name) not in each
                continue
            if name.endswith("(max_iterations = 1)"):  # one iteration per step does not reach the converged solve
                assert numbers["deviation"] > 1e-6
            sentence = each[(dt, name)].sentence
            assert sentence.startswith(f"At dt = {dt:g} s, {name}: {stated}")  # two dts: each finding says where
            assert f"{numbers['deviation']:.2g} m (" in sentence and sentence.count(f"from {baseline}") == 1
            assert sentence in pages["realtime"].findings
        fastest = min(methods, key=lambda name: methods[name]["wall_time_per_frame"])
        assert lead.evidence["fastest"] == fastest
        if fastest != baseline:
            assert lead.evidence["speedup"] == pytest.approx(
                methods[baseline]["wall_time_per_frame"] / methods[fastest]["wall_time_per_frame"], rel=1e-12)
        assert lead.sentence in pages["realtime"].findings
    for name in ("troubled", "spring"):
        data, rows = rows_of(files[name])
        assert not [finding for finding in findings(data, rows) if finding.topic == "cost"]


def test_an_explicit_method_is_compared_with_the_converged_newton_run(files, pages):
    """XPBD reads no solver key, yet it stands beside the implicit runs at its dt: its finding gives its wall time
    per frame, real-time factor, energy change and max |x - x_newton| at the error time, recomputed here from the
    file's error_positions."""
    leads, each, data, rows = cost_findings(files["versus"])
    results = data.results
    (lead,) = leads
    by_kind = {(row.integrator, row.solver): row for row in rows}
    (xpbd,) = [row for row in rows if results.runs[row.run_id].explicit]
    newton = by_kind[("backward_euler", "newton")]
    assert results.runs[newton.run_id].attrs["not_converged_steps"] == 0 and newton.status == Status.OK
    assert lead.evidence["baseline"] == "newton" and lead.evidence["methods"]["newton"]["run_id"] == newton.run_id
    assert set(lead.evidence["methods"]) == {"newton", "projective_dynamics", xpbd.integrator}
    assert lead.evidence["methods"][xpbd.integrator]["explicit"]
    apart = distance(results, xpbd.run_id, newton.run_id)
    assert apart > 0
    assert lead.evidence["methods"][xpbd.integrator]["deviation"] == pytest.approx(apart, rel=1e-12, abs=0)
    finding = each[(0.01, xpbd.integrator)]
    assert finding.evidence["run_id"] == xpbd.run_id and finding.evidence["baseline"] == "newton"
    scale = results.runs[newton.run_id].length_scale
    assert finding.sentence == (
        f"{xpbd.integrator}: {1e3 * xpbd.wall_time_per_frame:.3g} ms per frame ({real_time_text(xpbd.real_time_factor)} "
        f"real time), max drift {drift_text(xpbd.max_rel_energy_drift)}, {apart:.2g} m ({100 * apart / scale:.2g} % of "
        "the length scale) from newton.")  # one dt: no "At dt = ..."; XPBD solves nothing: no steps at max_iterations
    assert "a solver's name stands for backward_euler solved by it" in lead.sentence
    assert finding.sentence in pages["versus"].findings and lead.sentence in pages["versus"].findings


def test_show_gives_the_runs_without_swept_keys_a_heading(files, capsys):
    """The XPBD run shares no swept key (its title is ""): `simrun show` heads it with words, not with "[]"."""
    assert main(["show", str(files["versus"])]) == 0
    lines = capsys.readouterr().out.splitlines()
    headings = [number for number, line in enumerate(lines) if line.startswith("[")]
    assert [lines[number] for number in headings] == [
        "[solver.type = newton]", f"[{NO_SWEPT_KEY}]", "[solver.type = projective_dynamics]"]
    assert lines[headings[1] + 1].split()[1].startswith("xpbd")
