"""`simrun report`'s page: a results file as one self-contained HTML file.

Figures are embedded as base64 PNG, styles inline, no script, no link to any other file. The page answers first:
at most ANSWER_FINDINGS findings (``simrun.findings``: each linked to the table or figure that shows it), ranked
by topic, with every finding and the error and cost of every run behind <details>; then every figure the file
supports with its caption (the cloth's snapshots as one grid of runs x times); then the tables that apply to the
file, each collapsed when longer than COLLAPSE_ROWS rows: the summary of the runs, the observed orders (runs with a
known error), the predicted stability limits against what the runs did (runs on the undamped test equation), the
determinant of each method's one-step map on the spring against the lectures' closed forms (runs with one degree
of freedom); and the provenance, with the config as written beside the resolved one (collapsed). A map of 42,000
runs is then about three screens long before what is collapsed (tests/test_report_scale.py). Like the figures, it
is made from the results file alone (``simrun.results``); the tables are written by ``simrun.report.tables`` from
the rows of ``simrun.analysis.rows``, the errors of runs without an exact solution come from
``simrun.analysis.reference`` on request.
"""

from __future__ import annotations

import base64
import datetime
import io
import json
from collections import Counter
from pathlib import Path

import numpy as np

from simrun.analysis.reference import reference_errors
from simrun.analysis.rows import (SummaryRow, determinant_rows, energy_reference_text, error_time_text, order_rows,
                                  stability_rows, summary_rows)
from simrun.analysis.units import number_text, real_time_text
from simrun.figures import CALIBRATION, FIGURES, Figure, FigureData, figure_data, figures_for, frames as frame_figures
from simrun.findings import findings
from simrun.findings.base import Finding, drift_text
from simrun.format.summary import Status
from simrun.report.tables import (MAX_RUN_ROWS, SCROLLING_TABLE_ROWS, determinant_section as _determinant_section,
                                   escape as _e, orders_section as _orders_section,
                                   stability_section as _stability_section, status_badge as _status,
                                   status_cell as _status_cell, summary_section as _summary_section, table as _table)
from simrun.results import Results, load

REPORT_DPI = 100  # the figures' inches become about as many CSS pixels at this resolution

STYLE = """
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, Helvetica, Arial, sans-serif; margin: 0 auto;
       max-width: 1280px; padding: 1.5rem 2rem 4rem; color: #1d2330; line-height: 1.45; box-sizing: border-box; }
h1 { font-size: 1.7rem; margin-bottom: 0.2rem; } h2 { margin-top: 2.4rem; border-bottom: 1px solid #d8dce3; padding-bottom: 0.2rem; }
h3 { font-size: 1.02rem; margin: 1.4rem 0 0.5rem; }
.subtitle { color: #5a6270; margin-top: 0; }
nav ul { columns: 3; list-style: none; padding-left: 0; } nav a, a { color: #2856a3; text-decoration: none; }
table { border-collapse: collapse; font-size: 0.8rem; font-variant-numeric: tabular-nums; }
th, td { padding: 0.25rem 0.38rem; border-bottom: 1px solid #e6e8ec; text-align: right; white-space: nowrap; }
th { background: #f3f5f8; position: sticky; top: 0; text-align: center; white-space: normal; min-width: 2.4rem; }
td.text, th.text { text-align: left; }
td.label { white-space: normal; overflow-wrap: anywhere; min-width: 7rem; max-width: 14rem; }
td.wrap { white-space: normal; min-width: 12rem; max-width: 26rem; text-align: left; }
tbody tr:nth-child(even) { background: #fafbfc; }
.box { max-width: 100%; overflow-x: auto; }
.scroll { max-height: 34rem; overflow: auto; border: 1px solid #e6e8ec; }
.status { padding: 0.05rem 0.4rem; border-radius: 0.6rem; font-size: 0.75rem; }
.ok { background: #e3f4e8; color: #1c6b34; } .diverged { background: #fde6e4; color: #a1281c; }
.failed { background: #f2e3f7; color: #6d2a86; } .not_converged { background: #fff2d6; color: #8a5a00; }
.agrees { color: #1c6b34; } .differs { color: #a1281c; font-weight: 600; }
.sub { color: #5a6270; font-size: 0.74rem; }
pre { background: #f6f8fa; padding: 0.8rem 1rem; overflow: auto; font-size: 0.8rem; border-radius: 4px; max-height: 40rem; margin: 0; }
.configs { display: grid; grid-template-columns: minmax(0, 1fr) minmax(0, 1fr); gap: 1rem; }
.configs pre { white-space: pre-wrap; overflow-wrap: anywhere; }
figure { margin: 1.6rem 0 2.4rem; }
figure img { max-width: 100%; max-height: 85vh; width: auto; height: auto; border: 1px solid #eceef2; }
figcaption { color: #3c4452; font-size: 0.9rem; max-width: 70rem; margin-top: 0.4rem; }
figcaption b { color: #1d2330; }
dl { display: grid; grid-template-columns: max-content minmax(0, 1fr); gap: 0.2rem 1.2rem; font-size: 0.9rem; }
dt { color: #5a6270; } dd { margin: 0; overflow-wrap: anywhere; }
.note { color: #5a6270; font-size: 0.85rem; max-width: 70rem; }
.missing { color: #8a5a00; }
ul.findings { padding-left: 1.2rem; max-width: 72rem; } ul.findings li { margin: 0.35rem 0; }
ul.findings a.see { font-size: 0.8rem; white-space: nowrap; }
.topic { color: #5a6270; font-size: 0.75rem; text-transform: uppercase; letter-spacing: 0.04em; margin-right: 0.3rem; }
details { margin: 0.8rem 0; } details > summary { cursor: pointer; color: #2856a3; font-size: 0.9rem; }
details[open] > summary { margin-bottom: 0.5rem; }
"""
# Tables longer than this many rows are collapsed (HTML <details>) below the answer and the figures: the page opens on
# what the file answers, and a map's 42,000 rows are one click away, not 100,000 pixels of scrolling.
COLLAPSE_ROWS = 30
# The answer at the top of the page: at most this many findings, the first of each topic first (in reading order).
ANSWER_FINDINGS = 10


def write_report(path: str | Path, output: str | Path, reference: str | None = "dop853", say=None) -> Path:
    """Write the report of the results file at path into output (an .html file); returns output.

    reference: what the errors of runs without an exact solution are measured against (see
    ``simrun.analysis.reference.reference_errors``), or None / "none" for no reference. (``simrun report`` checks
    the output before any work and hands a temporary file here, renamed when the page is complete.)"""
    import matplotlib.pyplot as plt

    output = Path(output)
    results = load(path)
    without_exact = [run for run in results.runs.values() if not np.isfinite(run.error) and not run.status.stopped]
    errors: dict[str, float] = {}
    reference_note = ""
    if without_exact and reference and str(reference).lower() != "none":
        errors = reference_errors(results, reference, say=say)
        below = errors.below_accuracy()
        reference_note = (f"{len(without_exact)} runs have no exact solution: their errors are measured against "
                          f"{errors.statement()}, on the system rebuilt from its stored parameters ({len(errors)} runs)."
                          + (f" {len(below)} of them are at or below that accuracy, so that their errors are not theirs: "
                             f"{', '.join(below)}." if below else ""))
    elif without_exact:
        reference_note = (f"{len(without_exact)} runs have no exact solution and no reference was asked for "
                          "(--reference none): no convergence for them.")
    figures = []
    with results.opened():
        data = figure_data(results, errors or None)
        rows = summary_rows(data)
        orders = order_rows(data)
        stability = stability_rows(data)
        determinants = determinant_rows(data)
        for entry, name, figure in _render(data):
            try:
                figures.append((entry, name, _png_data(figure)))
            finally:
                plt.close(figure)
        found = findings(data, rows, orders)
    test_equation = any(np.isfinite(row.hw) for row in rows)
    # where no order is fitted (step-controlled runs: the work-precision figure), the runs' table says what the
    # errors without an exact solution are measured against
    runs_note = f'<p class="note">{_e(reference_note)}</p>' if reference_note and not orders else ""
    sections = [("figures", "Figures", _figures_section(figures, test_equation)),
                ("summary", "Runs", runs_note + _collapsed(_summary_section(rows), len(rows), "the table of runs"))]
    if orders:
        sections.append(("orders", "Observed order of convergence",
                         _collapsed(_orders_section(orders, reference_note, error_time_text(rows)), len(orders),
                                    "the observed orders")))
    if stability:
        sections.append(("stability", "Stability limits: predicted and observed",
                         _collapsed(_stability_section(stability), len(stability), "the stability limits")))
    if determinants:
        sections.append(("determinants", "Determinant of the one-step map (one degree of freedom: the mass on a spring)",
                         _collapsed(_determinant_section(determinants), len(determinants), "the determinants")))
    sections.append(("provenance", "Provenance and config", _provenance_section(results, path)))
    anchors = {f"#{key}" for key, _, _ in sections} | {f"#figure-{name}" for _, name, _ in figures}
    sections.insert(0, ("findings", "Findings", _findings_section(found, anchors, rows, data.dt_names)))
    if results.fits is not None:  # a calibration answers its own question first; its runs each have their own values
        sections[0] = ("findings", "Findings on the fitted runs (each simulated with its own fit's values)", sections[0][2])
        sections.insert(0, ("calibration", "Calibration", _calibration_section(results)))
    page = _page(results, data, sections)
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(page, encoding="utf-8")
    return output


def _render(data: FigureData):
    """(registry entry, name, matplotlib Figure) for every figure the file supports; the snapshots as one grid."""
    for entry in figures_for(data):
        if entry.name == "snapshots":
            grid = frame_figures.snapshot_grid(data)
            if grid is not None:
                yield entry, entry.name, grid
            continue
        drawn = entry.draw(data)
        if drawn is None:
            continue
        for name, figure in drawn if isinstance(drawn, list) else [(entry.name, drawn)]:
            yield entry, name, figure


def _png_data(figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=REPORT_DPI)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _page(results: Results, data: FigureData, sections: list[tuple[str, str, str]]) -> str:
    counts = Counter(str(run.status) for run in results.runs.values())
    status_text = ", ".join(f"{count} {status}" for status, count in sorted(counts.items())) or "no runs"
    provenance = results.provenance
    created = provenance.get("created", "")
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    navigation = "".join(f'<li><a href="#{key}">{_e(title)}</a></li>' for key, title, _ in sections)
    body = "".join(f'<section id="{key}"><h2>{_e(title)}</h2>{content}</section>' for key, title, content in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>simrun report: {_e(results.name)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{_e(results.name)}</h1>"
        f"<p class=\"subtitle\">{len(results.runs)} runs ({_e(status_text)}) · {len(data.labels)} integrators · "
        f"results written {_e(created)} by simrun {_e(provenance.get('simrun_version', '?'))} · report made {_e(now)}</p>"
        f"<nav><ul>{navigation}</ul></nav>{body}</body></html>\n"
    )


# -- findings ---------------------------------------------------------------------------------------
def _anchor_name(anchor: str) -> str:
    names = {"#summary": "runs table", "#orders": "orders table", "#stability": "stability table",
             "#determinants": "determinants table", "#calibration": "fitted values", "#calibration-transfer": "transfer table"}
    return names.get(anchor, "figure: " + anchor.removeprefix("#figure-").replace("_", " "))


def _findings_section(found: list[Finding], anchors: set[str], rows: list[SummaryRow], dt_names: dict[float, str]) -> str:
    """The answer: at most ANSWER_FINDINGS findings (``answer``), each linked to what shows it (the runs table when
    that is not on the page); every finding, when there are more, and the error (or energy change) and cost of every
    run as one integrators x dt table follow, collapsed where long."""
    def item(finding: Finding) -> str:
        anchor = finding.link_anchor if finding.link_anchor in anchors else "#summary"
        kind = ' class="missing"' if finding.topic == "not measured" else ""
        topic = f'<span class="topic">{_e(finding.topic)}</span>' if finding.topic and finding.topic != "not measured" else ""
        return (f'<li{kind}>{topic}{_e(finding.sentence)} '
                f'<a class="see" href="{_e(anchor)}">→ {_e(_anchor_name(anchor))}</a></li>')

    if not found:
        parts = ['<p class="note">The file holds no runs.</p>']
    else:
        first = answer(found)
        parts = [f'<ul class="findings">{"".join(item(finding) for finding in first)}</ul>']
        if len(first) < len(found):
            parts.append(f'<details><summary>Every finding ({len(found)}, in reading order)</summary>'
                         f'<ul class="findings">{"".join(item(finding) for finding in found)}</ul></details>')
    if rows:
        keys = len({(row.group, row.integrator) for row in rows})
        each = "tolerance" if all(np.isfinite(row.tolerance) for row in rows) else "dt"  # _glance's columns
        parts.append(_collapsed(_glance(rows, dt_names), keys, f"the error and cost of every run at each {each}"))
    return "".join(parts)


def answer(found: list[Finding]) -> list[Finding]:
    """The findings the page opens with, in reading order (a map's finding first): the first of each topic, then the
    second of each, and so on, at most ANSWER_FINDINGS in all. The counts of findings left out ("… and N more") stay
    in the full list, and so does what could not be measured, unless the file answers little else."""
    said = [finding for finding in found if "more" not in finding.evidence]
    answers = [finding for finding in said if finding.topic != "not measured"]
    if len(answers) >= ANSWER_FINDINGS // 2:  # what could not be measured is a caveat: the full list says it
        said = answers
    by_topic: dict[str, list[Finding]] = {}
    for finding in said:
        by_topic.setdefault(finding.topic, []).append(finding)
    chosen: set[int] = set()
    for rank in range(max((len(items) for items in by_topic.values()), default=0)):  # round by round over the topics
        for items in by_topic.values():
            if rank < len(items) and len(chosen) < ANSWER_FINDINGS:
                chosen.add(id(items[rank]))
    return [finding for finding in said if id(finding) in chosen]


def _collapsed(content: str, rows: int, what: str) -> str:
    """``content`` as it is, or inside a closed <details> when it holds more than COLLAPSE_ROWS rows."""
    if rows <= COLLAPSE_ROWS:
        return content
    return f"<details><summary>Show {_e(what)} ({rows:,} rows)</summary>{content}</details>"


def _glance(rows: list[SummaryRow], dt_names: dict[float, str]) -> str:
    """Integrators (rows) x dt (columns): each run's error and wall time, or its status when it stopped."""
    errors = any(np.isfinite(row.error) for row in rows)
    several = len({row.group for row in rows}) > 1
    # a step-controlled file's columns are its tolerances (each run's mean step differs from every other's)
    controlled = all(np.isfinite(row.tolerance) for row in rows)
    column_of = (lambda row: row.tolerance) if controlled else (lambda row: row.dt)
    dts = sorted({column_of(row) for row in rows}, reverse=controlled)
    hw = {}
    for row in rows:
        if np.isfinite(row.hw) and not controlled:
            hw.setdefault(row.dt, set()).add(f"{row.hw:.3g}")
    keys = list(dict.fromkeys((row.group, row.integrator) for row in rows))
    cells = {(row.group, row.integrator, column_of(row)): row for row in rows}

    def heading(dt: float) -> str:
        return f"tol = {dt:g}" if controlled else f"dt = {_e(dt_names.get(dt, f'{dt:g}'))} s"

    head = (("<th class=\"text\">group</th>" if several else "") + "<th class=\"text\">integrator</th>"
            + "".join(f"<th>{heading(dt)}" + (f"<br><span class=\"sub\">h w = {_e(', '.join(sorted(hw[dt])))}</span>"
                                              if dt in hw else "") + "</th>" for dt in dts))
    body = []
    for group, label in keys[:MAX_RUN_ROWS]:
        line = (f'<td class="text">{_e(group)}</td>' if several else "") + f'<td class="text">{_e(label)}</td>'
        for dt in dts:
            row = cells.get((group, label, dt))
            if row is None:
                line += "<td></td>"
            elif row.status in (Status.DIVERGED, Status.FAILED):
                line += f"<td>{_status_cell(row)}</td>"
            else:
                top = ((number_text(row.error) + " m" if np.isfinite(row.error) else "–") if errors
                       else drift_text(row.max_rel_energy_drift))
                flag = "" if row.status == Status.OK else f" {_status(row.status, row.message)}"
                cost = f"{row.wall_time:.3g} s" + (f" · {real_time_text(row.real_time_factor)}"
                                                   if np.isfinite(row.real_time_factor) else "")
                if controlled:
                    cost += f" · {row.steps:,} steps"
                line += f'<td>{_e(top)}{flag}<br><span class="sub">{_e(cost)}</span></td>'
        body.append(f"<tr>{line}</tr>")
    what = (f"the error at {error_time_text(rows)} (against the "
            + ("reference" if any(row.error_from_reference for row in rows) else "exact") + " solution)"
            if errors else f"the largest energy change max |E − E0| / E_ref ({energy_reference_text(rows)})")
    note = (f'<h3>Error and cost at each {"tolerance" if controlled else "dt"}</h3><p class="note">Each cell: {_e(what)}; '
            "below it the wall time of the whole run and its real-time factor (simulated over wall time, > 1x faster "
            f"than real time){' and its accepted steps' if controlled else ''}. Stopped runs "
            "show their status and the step at which they stopped."
            + (f" The first {MAX_RUN_ROWS:,} of {len(keys):,} rows, in sweep order." if len(keys) > MAX_RUN_ROWS else "")
            + "</p>")
    return note + f'<div class="box"><table><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table></div>'


# -- calibration (simrun fit) -----------------------------------------------------------------------
def _calibration_section(results: Results) -> str:
    """What the fits were fitted to, their findings, the fitted values (integrators x dt) and the transfer table."""
    from simrun.findings import calibration

    fits = results.fits
    items = "".join(f'<li>{_e(finding.sentence)} <a class="see" href="{_e(finding.link_anchor)}">→ '
                    f"{_e(_anchor_name(finding.link_anchor))}</a></li>" for finding in calibration.calibration_findings(results))
    parts = [f'<p class="note">Observed: {_e(calibration.source_text(fits))}.</p>', f'<ul class="findings">{items}</ul>']
    for table in calibration.fitted_tables(results):
        head = [("integrator", "label")] + [(f"dt = {dt:g} s" + (f" (h w = {hw:.3g})" if np.isfinite(hw) else ""), False)
                                            for dt, hw in zip(table.dts, table.hws)]
        body = [[_e(label)] + ["" if cell is None else _e(cell.value_text()) + (
            f'<br><span class="sub">({_e(cell.predicted_text())})</span>' if cell.predicted_text() else "") + (
            "" if cell.status == "converged" else f"<br>{_status(cell.status)}") for cell in cells]
            for label, cells in table.rows]
        anchor = (f"; {table.anchor_name}: {table.anchor:g} {table.unit}" if np.isfinite(table.anchor) else "")
        exact = f"; the exact-solution fit: {table.reference.text()}" if table.reference is not None else ""
        predicted = any(cell is not None and cell.predicted_text() for _, cells in table.rows for cell in cells)
        explained = (", below it (the predicted value: where the method's own step has the observed eigenvalue)"
                     if predicted else "")
        parts.append(f"<h3>{_e(table.key)}" + (f" ({_e(table.unit)})" if table.unit else "") + "</h3>"
                     f'<p class="note">Each cell: the fitted value ± its standard error{_e(explained + anchor + exact)}.</p>'
                     + _table(head, body))
    transfer = calibration.transfer_table(fits)
    if transfer is not None:
        head = [("fitted with", "label"), ("dt (s)", False)] + [(f"{name} at dt = {dt:g} s", False) for name, dt in transfer.targets]
        body = [[_e(row.label), "–" if not np.isfinite(row.dt) else f"{row.dt:g}"] + [
            "" if cell is None else f'<span class="{"agrees" if cell.within else ""}">{_e(cell.text())}</span>'
            for cell in row.cells] for row in transfer.rows]
        parts.append('<h3 id="calibration-transfer">Fitted parameters simulated with other integrators</h3><p class="note">'
                     "Each cell: the relative rms error |x − x_obs|_rms / |x_obs|_rms of the fit's parameters simulated "
                     f"with the column's integrator and dt (green: within {100 * calibration.TRANSFER_TOLERANCE:g} %).</p>"
                     + _table(head, body, scroll=len(body) > SCROLLING_TABLE_ROWS))
    return "".join(parts)


# -- figures ----------------------------------------------------------------------------------------
def caption(entry: Figure, test_equation: bool) -> str:
    """The registry's caption for this file: with its test-equation part only when the file has runs on it."""
    return f"{entry.caption} {entry.test_equation_caption}" if test_equation and entry.test_equation_caption else entry.caption


def _figures_section(figures: list[tuple[Figure, str, str]], test_equation: bool) -> str:
    """Every drawn figure with its caption; the registered figures not drawn, with what they need."""
    if not figures:
        return '<p class="note">The file holds no run with data to draw.</p>'
    drawn = {entry.name for entry, _, _ in figures}
    calibrated = any(FIGURES[name].needs == CALIBRATION for name in drawn)  # else its figures are not this file's kind
    missing = [f"{name.replace('_', ' ')} (needs {entry.needs})" for name, entry in FIGURES.items()
               if name not in drawn and (calibrated or entry.needs != CALIBRATION)]
    parts = []
    for entry, name, data in figures:
        title = name.replace("_", " ")
        text = caption(entry, test_equation)
        if entry.name == "snapshots":
            text += " Rows: the runs shown; columns: times spread over the run, all at one scale."
        parts.append(f'<figure id="figure-{_e(name)}"><img alt="{_e(title)}" src="data:image/png;base64,{data}">'
                     f"<figcaption><b>{_e(title)}.</b> {_e(text)}</figcaption></figure>")
    if missing:
        parts.append(f'<details><summary>Figures not drawn for this file ({len(missing)})</summary>'
                     f'<p class="note">Not drawn for this file: {_e("; ".join(missing))}.</p></details>')
    return "".join(parts)


# -- provenance -------------------------------------------------------------------------------------
NOT_RECORDED = "not recorded"
# Root attributes shown under these names, in this order (the rest after them, by their own names).
PROVENANCE_ITEMS = (("simrun_version", "simrun version"), ("format_version", "format version"), ("created", "created"),
                    ("config_hash", "config hash"), ("host", "host"), ("cpu", "CPU"),
                    ("config_git_commit", "git commit of the config's folder"), ("command_line", "command line"))
NOT_PROVENANCE = ("config", "resolved_config", "package_versions")


def _provenance_section(results: Results, path: Path) -> str:
    provenance = results.provenance
    versions = provenance.get("package_versions", {})
    if isinstance(versions, dict):
        versions = ", ".join(f"{name} {version}" for name, version in versions.items())
    items = [("results file", str(path))]
    for key, name in PROVENANCE_ITEMS:
        items.append((name, _attribute_text(provenance[key]) if key in provenance else None))
    known = {key for key, _ in PROVENANCE_ITEMS} | set(NOT_PROVENANCE)
    items += [(key.replace("_", " "), _attribute_text(value)) for key, value in provenance.items() if key not in known]
    items.append(("package versions", versions or None))
    listing = "".join(f"<dt>{_e(key)}</dt><dd>{_e(value) if value not in (None, '') else _missing()}</dd>"
                      for key, value in items)
    written = f"<pre>{_e(results.config_text)}</pre>"
    resolved = _resolved_config(results)
    if resolved is None:
        configs = (f"<h3>Config as written (after --set overrides)</h3>{written}<p class=\"note\">The resolved config "
                   "(every default filled in) is not recorded in this file (written by an older simrun).</p>")
    else:
        configs = ('<div class="configs"><div><h3>Config as written (after --set overrides)</h3>'
                   f"{written}</div><div><h3>Resolved (every default filled in)</h3><pre>{_e(resolved)}</pre></div></div>")
    return f"<dl>{listing}</dl><details><summary>Show the config (as written, and resolved)</summary>{configs}</details>"


def _missing() -> str:
    return f'<span class="missing">{NOT_RECORDED}</span>'


def _attribute_text(value) -> str:
    """A root attribute as text: lists (a command line) joined with spaces, JSON lists likewise."""
    if isinstance(value, str) and value.startswith("["):
        try:
            value = json.loads(value)
        except ValueError:
            return value
    if isinstance(value, (list, tuple, np.ndarray)):
        import shlex

        return shlex.join(str(item) for item in value)
    return str(value)


def _resolved_config(results: Results) -> str | None:
    """The resolved config (root attribute ``resolved_config``) as YAML text; None when the file has none."""
    value = results.attrs.get("resolved_config")
    if value is None or value == "":
        return None
    text = value.decode() if isinstance(value, bytes) else str(value)
    try:
        parsed = json.loads(text)
    except ValueError:
        return text
    import yaml

    return yaml.safe_dump(parsed, sort_keys=False, allow_unicode=True) if isinstance(parsed, dict) else text
