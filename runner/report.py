"""`simrun report`'s page: a results file as one self-contained HTML file.

Figures are embedded as base64 PNG, styles inline, no script, no link to any other file: the
experiment's config and provenance, a summary table of the runs (status, energy drift, iterations,
order, measured against predicted artificial damping), the observed orders, the predicted stability
limits against what the runs did, the determinant of each method's one-step map on the spring against
the lectures' closed forms, and every registered figure with its caption. Like the figures, it is made
from the results file alone (``simrun.results``); the tables come from ``simrun.tables``, the errors of
runs without an exact solution from ``simrun.reference`` on request.
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
from collections import Counter
from pathlib import Path

import numpy as np

from simrun.figures import FIGURES, Figure, FigureData, figure_data, render_figures
from simrun.reference import REFERENCE_RTOL, reference_errors
from simrun.results import Results, load
from simrun.tables import (DAMPING_TOLERANCE, DETERMINANT_TOLERANCE, ORDER_TOLERANCE, DeterminantRow, OrderRow,
                           StabilityRow, SummaryRow, damping_text, determinant_rows, number_text, order_rows,
                           stability_rows, summary_rows)

REPORT_DPI = 100  # the figures' inches become about as many CSS pixels at this resolution
# A summary table longer than this scrolls inside its box.
SCROLLING_TABLE_ROWS = 40

STYLE = """
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, Helvetica, Arial, sans-serif; margin: 0 auto;
       max-width: 1280px; padding: 1.5rem 2rem 4rem; color: #1d2330; line-height: 1.45; }
h1 { font-size: 1.7rem; margin-bottom: 0.2rem; } h2 { margin-top: 2.4rem; border-bottom: 1px solid #d8dce3; padding-bottom: 0.2rem; }
.subtitle { color: #5a6270; margin-top: 0; }
nav ul { columns: 3; list-style: none; padding-left: 0; } nav a { color: #2856a3; text-decoration: none; }
table { border-collapse: collapse; font-size: 0.82rem; font-variant-numeric: tabular-nums; }
th, td { padding: 0.25rem 0.55rem; border-bottom: 1px solid #e6e8ec; text-align: right; white-space: nowrap; }
th { background: #f3f5f8; position: sticky; top: 0; text-align: center; }
td.text, th.text { text-align: left; }
tbody tr:nth-child(even) { background: #fafbfc; }
.scroll { max-height: 34rem; overflow: auto; border: 1px solid #e6e8ec; }
.status { padding: 0.05rem 0.4rem; border-radius: 0.6rem; font-size: 0.75rem; }
.ok { background: #e3f4e8; color: #1c6b34; } .diverged { background: #fde6e4; color: #a1281c; }
.failed { background: #f2e3f7; color: #6d2a86; } .not_converged { background: #fff2d6; color: #8a5a00; }
.agrees { color: #1c6b34; } .differs { color: #a1281c; font-weight: 600; }
pre { background: #f6f8fa; padding: 0.8rem 1rem; overflow: auto; font-size: 0.8rem; border-radius: 4px; }
figure { margin: 1.6rem 0 2.4rem; } figure img { max-width: 100%; height: auto; border: 1px solid #eceef2; }
figcaption { color: #3c4452; font-size: 0.9rem; max-width: 70rem; margin-top: 0.4rem; }
figcaption b { color: #1d2330; }
dl { display: grid; grid-template-columns: max-content auto; gap: 0.2rem 1.2rem; font-size: 0.9rem; }
dt { color: #5a6270; } dd { margin: 0; }
.note { color: #5a6270; font-size: 0.85rem; max-width: 70rem; }
"""


def write_report(path: str | Path, output: str | Path, reference: str | None = "dop853", say=None) -> Path:
    """Write the report of the results file at path into output (an .html file); returns output.

    reference: what the errors of runs without an exact solution are measured against (see
    ``simrun.reference.reference_errors``), or None / "none" for no reference."""
    import matplotlib.pyplot as plt

    results = load(path)
    output = Path(output)
    without_exact = [run for run in results.runs.values() if not np.isfinite(run.final_error) and not run.status.stopped]
    errors: dict[str, float] = {}
    reference_note = ""
    if without_exact and reference and str(reference).lower() != "none":
        errors = reference_errors(results, reference, say=say)
        against = (f"run {reference}" if reference in results.runs
                   else f"scipy solve_ivp ({str(reference).upper()}, rtol {REFERENCE_RTOL:g})")
        reference_note = (f"{len(without_exact)} runs have no exact solution: their errors are measured against {against} "
                          f"on the system rebuilt from its stored parameters ({len(errors)} runs).")
    elif without_exact:
        reference_note = (f"{len(without_exact)} runs have no exact solution and no reference was asked for "
                          "(--reference none): no convergence for them.")
    figures = []
    with results.opened():
        data = figure_data(results, errors or None)
        rows = summary_rows(data)
        sections = [
            ("summary", "Runs", _summary_section(rows)),
            ("orders", "Observed order of convergence", _orders_section(order_rows(data), reference_note)),
            ("stability", "Stability limits: predicted and observed", _stability_section(stability_rows(data))),
            ("determinants", "Determinant of the one-step map (one degree of freedom: the mass on a spring)",
             _determinant_section(determinant_rows(data))),
        ]
        for entry, name, figure in render_figures(results, errors or None):
            try:
                figures.append((entry, name, _png_data(figure)))
            finally:
                plt.close(figure)
    sections.append(("figures", "Figures", _figures_section(figures)))
    sections.append(("provenance", "Provenance and config", _provenance_section(results, path)))
    page = _page(results, data, sections)
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(page, encoding="utf-8")
    return output


def _png_data(figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=REPORT_DPI)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _e(text) -> str:
    return html.escape(str(text), quote=True)


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


def _table(headings: list[tuple[str, bool]], body_rows: list[list[str]], scroll: bool = False) -> str:
    """headings: (text, is_text_column); cells are HTML already."""
    head = "".join(f'<th class="text">{_e(text)}</th>' if is_text else f"<th>{_e(text)}</th>" for text, is_text in headings)
    rows = []
    for cells in body_rows:
        rows.append("<tr>" + "".join(f'<td class="text">{cell}</td>' if headings[number][1] else f"<td>{cell}</td>"
                                     for number, cell in enumerate(cells)) + "</tr>")
    table = f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    return f'<div class="scroll">{table}</div>' if scroll else table


def _status(status: str) -> str:
    return f'<span class="status {_e(status)}">{_e(status.replace("_", " "))}</span>'


def _verdict(text: str) -> str:
    kind = "agrees" if text in ("agrees", "consistent") else ("differs" if text in ("differs",) or "below" in text or "beyond" in text else "")
    return f'<span class="{kind}">{_e(text)}</span>' if kind else _e(text)


def _summary_section(rows: list[SummaryRow]) -> str:
    several_groups = len({row.group for row in rows}) > 1
    headings = [("#", False), ("integrator", True)] + ([("group", True)] if several_groups else []) + [
        ("dt (s)", False), ("h w", False), ("status", True), ("steps", False), ("order", False),
        ("max drift", False), ("final drift", False), ("error (m)", False), ("Newton/step", False),
        ("linear/step", False), ("wall (s)", False), ("d/w measured", False), ("d/w predicted", False), ("difference", False)]
    body = []
    for row in rows:
        measured = damping_text(row.measured_damping)
        if np.isfinite(row.measured_damping) and not row.measured_resolved:
            measured += " (run too short to resolve)"
        difference = row.damping_difference
        if not np.isfinite(difference):
            difference_text = "–"
        else:
            difference_text = "0.00 %" if abs(difference) < 5e-5 else f"{100 * difference:+.2f} %"
        if np.isfinite(difference) and row.measured_resolved:
            kind = "agrees" if abs(difference) <= DAMPING_TOLERANCE else "differs"
            difference_text = f'<span class="{kind}">{difference_text}</span>'
        cells = [str(row.index), _e(row.integrator)] + ([_e(row.group)] if several_groups else []) + [
            f"{row.dt:.4g}", "–" if not np.isfinite(row.hw) else f"{row.hw:.3g}", _status(row.status), str(row.steps),
            str(row.order), number_text(row.max_rel_energy_drift), number_text(row.final_rel_energy_drift), number_text(row.final_error),
            f"{row.mean_newton_iterations:.2f}", number_text(row.mean_linear_iterations), f"{row.wall_time:.3g}",
            measured, damping_text(row.predicted_damping), difference_text]
        body.append(cells)
    note = ('<p class="note">drift: |E − E₀|/|E₀| (max over the run, and at its end); error: max |x − x_exact| at the '
            "last sample; d/w: the artificial damping d_method/w = −2 ln ρ/(h w), measured from the decay of ln E(t) of "
            "runs on the undamped test equation (spring, linear circular motion) and predicted from the probed "
            f"amplification matrix at the run's h w; the difference is relative to the prediction (±{100 * DAMPING_TOLERANCE:g} % "
            "marked as agreeing).</p>")
    return note + _table(headings, body, scroll=len(rows) > SCROLLING_TABLE_ROWS)


def _orders_section(rows: list[OrderRow], reference_note: str) -> str:
    note = f'<p class="note">{_e(reference_note)}</p>' if reference_note else ""
    if not rows:
        return note + '<p class="note">No run has a known error at its end time (no exact solution, no reference).</p>'
    several = len({row.group for row in rows}) > 1
    headings = ([("group", True)] if several else []) + [("integrator", True), ("declared order", False),
                                                           ("observed order", False), ("fitted over", False), ("", True)]
    body = [([_e(row.group)] if several else []) + [_e(row.integrator), str(row.declared),
            "–" if not np.isfinite(row.observed) else f"{row.observed:.2f}", _e(row.dt_range), _verdict(row.verdict)]
            for row in rows]
    explain = (f'<p class="note">Slope of log(error) against log(dt) over the consecutive smallest time steps whose '
               f"error lies between round-off (1e-10 of the length scale) and saturation (10 % of it), at most 4; "
               f"agreement within ±{ORDER_TOLERANCE:g}.</p>")
    return note + explain + _table(headings, body)


def _stability_section(rows: list[StabilityRow]) -> str:
    if not rows:
        return '<p class="note">No run is on the undamped test equation (spring, linear circular motion): no predicted limits.</p>'
    several = len({row.group for row in rows}) > 1

    def limit_text(row):
        if math.isinf(row.limit_hw):
            return "none"
        if row.limit_hw == 0:
            return "0 (unstable at every h)"
        return f"{row.limit_hw:.4g}"

    headings = ([("group", True)] if several else []) + [("integrator", True), ("limit h w", False), ("limit dt (s)", False),
                                                           ("largest dt that stayed bounded", False),
                                                           ("smallest dt that diverged", False), ("", True)]
    body = [([_e(row.group)] if several else []) + [_e(row.integrator), limit_text(row),
            "∞" if math.isinf(row.limit_dt) else f"{row.limit_dt:.4g}", number_text(row.largest_ok_dt),
            number_text(row.smallest_diverged_dt), _verdict(row.verdict)] for row in rows]
    explain = ('<p class="note">The predicted limit is the h w at which the spectral radius of the probed amplification '
               "matrix first exceeds 1 (+1e-8). A run beyond it grows, but is only marked diverged once its energy "
               "leaves the configured bound, which a short run may not reach.</p>")
    return explain + _table(headings, body)


def _determinant_section(rows: list[DeterminantRow]) -> str:
    if not rows:
        return '<p class="note">No run on the mass on a spring.</p>'
    several = len({row.group for row in rows}) > 1
    headings = ([("group", True)] if several else []) + [("integrator", True), ("dt (s)", False), ("k (N/m)", False),
                                                           ("m (kg)", False), ("det A (probed)", False),
                                                           ("lecture closed form", True), ("value", False),
                                                           ("relative difference", False), ("", True)]
    body = [([_e(row.group)] if several else []) + [
        _e(row.integrator), f"{row.dt:.4g}", f"{row.stiffness:g}", f"{row.mass:g}", f"{row.probed:.15g}",
        _e(row.formula or "–"), "–" if not np.isfinite(row.closed_form) else f"{row.closed_form:.15g}",
        "–" if not np.isfinite(row.difference) else f"{row.difference:.1e}", _verdict(row.verdict)] for row in rows]
    explain = ("<p class=\"note\">det A is the factor by which one step scales areas in the (x, v) phase plane: "
               "forward Euler 1 + k h² (the orbit spirals out), symplectic Euler 1 (area-preserving), backward Euler "
               "1/(1 + k h²) (spirals in), as in the lectures (m = 1; here k/m). A is probed by stepping the basis states "
               f"through each method on the run's spring; agreement to {DETERMINANT_TOLERANCE:g} relative.</p>")
    return explain + _table(headings, body, scroll=len(rows) > SCROLLING_TABLE_ROWS)


def _figures_section(figures: list[tuple[Figure, str, str]]) -> str:
    """Every drawn figure with its registry caption; the registered figures not drawn, with what they need."""
    if not figures:
        return '<p class="note">The file holds no run with data to draw.</p>'
    drawn = {entry.name for entry, _, _ in figures}
    missing = [f"{name.replace('_', ' ')} (needs {entry.needs})" for name, entry in FIGURES.items() if name not in drawn]
    parts = [f'<p class="note">Not drawn for this file: {_e("; ".join(missing))}.</p>'] if missing else []
    for entry, name, data in figures:
        title = name.replace("_", " ")
        parts.append(f'<figure id="figure-{_e(name)}"><img alt="{_e(title)}" src="data:image/png;base64,{data}">'
                     f"<figcaption><b>{_e(title)}.</b> {_e(entry.caption)}</figcaption></figure>")
    return "".join(parts)


def _provenance_section(results: Results, path: Path) -> str:
    provenance = results.provenance
    versions = provenance.pop("package_versions", {})
    if isinstance(versions, dict):
        versions = ", ".join(f"{name} {version}" for name, version in versions.items())
    items = [("results file", str(path))] + [(key.replace("_", " "), value) for key, value in provenance.items()]
    items.append(("package versions", versions))
    listing = "".join(f"<dt>{_e(key)}</dt><dd>{_e(value)}</dd>" for key, value in items)
    return f"<dl>{listing}</dl><h3>Config (after --set overrides)</h3><pre>{_e(results.config_text)}</pre>"

