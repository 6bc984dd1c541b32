"""The tables of `simrun report`'s page as HTML (the runs, the observed orders, the stability limits, the one-step
maps' determinants) and the pieces every section of the page is written with: escaping, a table, a status badge."""

from __future__ import annotations

import html
import math

import numpy as np

from simrun.analysis.rows import (DAMPING_TOLERANCE, DETERMINANT_TOLERANCE, ORDER_TOLERANCE, DeterminantRow, OrderRow,
                                  StabilityRow, SummaryRow, any_safeguards, energy_reference_differs,
                                  energy_reference_text, error_time_text, iteration_name, mixed_solvers,
                                  any_dissipated, remainder_differs, steps_text, varied_parameters)
from simrun.analysis.units import damping_text, distance_text, frame_time_text, number_text, real_time_text
from simrun.format.summary import FRAME_TIME

# A summary table longer than this scrolls inside its box.
SCROLLING_TABLE_ROWS = 40


def escape(text) -> str:
    return html.escape(str(text), quote=True)


def table(headings: list[tuple[str, bool | str]], body_rows: list[list[str]], scroll: bool = False) -> str:
    """headings: (text, kind): False a number column, True a text column, "label" a text column that wraps
    (integrator labels), "wrap" a prose column; cells are HTML already. The table scrolls sideways inside
    its box when it is wider than the page, and down when ``scroll``."""
    classes = {True: ' class="text"', "label": ' class="text label"', "wrap": ' class="text wrap"', False: ""}
    head = "".join(f'<th class="text">{escape(text)}</th>' if kind else f"<th>{escape(text)}</th>" for text, kind in headings)
    rows = ["<tr>" + "".join(f"<td{classes[headings[number][1]]}>{cell}</td>" for number, cell in enumerate(cells)) + "</tr>"
            for cells in body_rows]
    table = f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    return f'<div class="box{" scroll" if scroll else ""}">{table}</div>'


def status_badge(status: str, message: str = "") -> str:
    title = f' title="{escape(message)}"' if message else ""
    return f'<span class="status {escape(status)}"{title}>{escape(status.replace("_", " "))}</span>'


def status_cell(row: SummaryRow) -> str:
    """The run's status, its message on hover, and below it where it went wrong (``SummaryRow.status_detail``)."""
    detail = row.status_detail
    return status_badge(row.status, row.message) + (f'<br><span class="sub">{escape(detail)}</span>' if detail else "")


def verdict(text: str) -> str:
    kind = "agrees" if text in ("agrees", "consistent") else ("differs" if text in ("differs",) or "below" in text or "beyond" in text else "")
    return f'<span class="{kind}">{escape(text)}</span>' if kind else escape(text)


# -- the tables ------------------------------------------------------------------------------------
# the Runs table shows at most this many rows (a map of 10^4 runs would make a page of megabytes); the findings and
# the figures use every run
MAX_RUN_ROWS = 1000


def summary_section(rows: list[SummaryRow]) -> str:
    """The runs, one row each; a column every run leaves empty (NaN, zero or not applicable) is left out."""
    def finite(value) -> bool:
        return value is not None and np.isfinite(value) and value != 0

    iterations = iteration_name(rows)
    swept = [name for name in varied_parameters(rows) if not name.startswith("integrator.")]
    split = remainder_differs(rows)
    columns = [  # heading, kind, cell, shown
        ("#", False, lambda row: str(row.index), True),
        ("integrator", "label", lambda row: escape(row.integrator), True),
        # the swept keys, a column each (the integrator's own parameters are in its label); the group where there are none
        *((name, not _numeric(rows, name), lambda row, name=name: parameter_cell(row.parameters.get(name)), True)
          for name in swept),
        ("group", "wrap", lambda row: escape(row.group), not swept and len({row.group for row in rows}) > 1),
        ("solver", True, lambda row: escape(row.solver or "–"), mixed_solvers(rows)),
        ("dt (s)", False, lambda row: f"{row.dt:.4g}", True),
        ("h w", False, lambda row: "–" if not np.isfinite(row.hw) else f"{row.hw:.3g}", any(finite(row.hw) for row in rows)),
        ("status", True, status_cell, True),
        ("steps", False, lambda row: str(row.steps), True),
        ("order", False, lambda row: str(row.order), True),
        ("E_ref (J)", False, lambda row: number_text(row.energy_reference), energy_reference_differs(rows)),
        ("max drift", False, lambda row: number_text(row.max_rel_energy_drift), True),
        ("final drift", False, lambda row: number_text(row.final_rel_energy_drift), True),
        ("integrator remainder", False, lambda row: number_text(row.max_rel_energy_remainder), split),
        ("dissipated", False, lambda row: number_text(row.final_rel_dissipated_energy), any_dissipated(rows)),
        ("error (m)", False, lambda row: number_text(row.error), any(finite(row.error) for row in rows)),
        (f"{iterations} it/step", False, lambda row: f"{row.mean_newton_iterations:.2f}" if row.solver else "–",
         any(finite(row.mean_newton_iterations) for row in rows)),
        ("linear it/step", False, lambda row: number_text(row.mean_linear_iterations) if row.solver else "–",
         any(finite(row.mean_linear_iterations) for row in rows)),
        ("wall (s)", False, lambda row: f"{row.wall_time:.3g}", True),
        ("real-time", False, lambda row: real_time_text(row.real_time_factor),
         any(finite(row.real_time_factor) for row in rows)),
        ("wall/frame (ms)", False, lambda row: frame_time_text(row.wall_time_per_frame),
         any(finite(row.wall_time_per_frame) for row in rows)),
        ("safeguards", False, lambda row: steps_text(row.safeguard_steps, row) or "–", any_safeguards(rows)),
        ("min contact distance", False, lambda row: distance_text(row.min_contact_distance),
         any(finite(row.min_contact_distance) for row in rows)),
        ("contacts", False, lambda row: str(row.max_active_contacts), any(finite(row.min_contact_distance) for row in rows)),
        ("friction loss (J)", False, lambda row: number_text(row.friction_work),
         any(finite(row.friction_work) and row.friction_work > 0 for row in rows)),
        ("d/w measured", False, _measured_cell, any(np.isfinite(row.measured_damping) for row in rows)),
        ("d/w predicted", False, lambda row: damping_text(row.predicted_damping),
         any(np.isfinite(row.predicted_damping) for row in rows)),
        ("difference", False, _difference_cell, any(np.isfinite(row.damping_difference) for row in rows)),
    ]
    columns = [column for column in columns if column[3]]
    body = [[cell(row) for _, _, cell, _ in columns] for row in rows[:MAX_RUN_ROWS]]
    shown = {heading for heading, _, _, _ in columns}
    notes = [f"the first {MAX_RUN_ROWS:,} of {len(rows):,} runs, in sweep order (every run: simrun show RESULTS --csv)"
             ] if len(rows) > MAX_RUN_ROWS else []
    notes += [f"drift: |E − E0| / E_ref (the largest over the run, and at its end), {energy_reference_text(rows)}"]
    if split:
        notes.append("integrator remainder: the part of the drift the method itself made, the largest "
                     "|E + E_dissipated − W − E0| / E_ref (W: work of prescribed vertices), once the physical losses are "
                     "counted" + ("; dissipated: what damping and friction took out by the end, over E_ref"
                                  if any_dissipated(rows) else ""))
    if "error (m)" in shown:
        reference = any(row.error_from_reference for row in rows)
        notes.append(f"error: distance from the {'reference' if reference else 'exact'} solution at "
                     f"{error_time_text(rows)} (record.error_time, at the step nearest it"
                     + ("; on the test equation in phase space, √(|x − x_exact|² + |v − v_exact|²/w²)"
                        if any(np.isfinite(row.hw) for row in rows) and not reference else "") + ")")
    if any(heading.endswith("it/step") for heading in shown):
        notes.append(f"{iterations} it/step: the solver's iterations per step"
                     + (" (the solver column says which)" if mixed_solvers(rows) else "")
                     + "; – for explicit methods, which solve nothing")
    if "real-time" in shown or "wall/frame (ms)" in shown:
        notes.append("real-time: simulated time (steps × dt) over the wall time of the stepping loop, > 1x faster than "
                     f"real time; wall/frame: wall time per 1/{1 / FRAME_TIME:g} s of simulated time (an animation "
                     f"frame: real time needs it below {1e3 * FRAME_TIME:.3g} ms)")
    if any(row.status_detail for row in rows):
        notes.append("status: below it, the step at which a run diverged, or the first step that did not converge and "
                     "how many did (under on_not_converged: accept such steps are the price of a real-time budget and "
                     "the run stays ok)")
    if "safeguards" in shown:
        notes.append("safeguards: steps where a solver safeguard fired (the line search cut the step, the Hessian was "
                     "SPD-projected or regularised, or a fallback solver took the step over)")
    if "d/w measured" in shown or "d/w predicted" in shown:
        notes.append("d/w: the artificial damping d_method/w = −2 ln ρ/(h w), measured from the decay of ln E(t) of runs "
                     "on the undamped test equation and predicted from the probed amplification matrix at the run's h w; "
                     f"the difference is relative to the prediction (±{100 * DAMPING_TOLERANCE:g} % agrees), or where "
                     "none is predicted the measured d/w itself, without %, agreeing within the fit's resolution 1e-3)")
    hidden = [name for name, present in (("h w", "h w" in shown), ("error", "error (m)" in shown),
                                         ("solver iterations", any(h.endswith("it/step") for h in shown)),
                                         ("d/w", "d/w measured" in shown)) if not present]
    if hidden:
        notes.append("not shown, empty for every run: " + ", ".join(hidden))
    note = '<p class="note">' + "<br>".join(escape(text[0].upper() + text[1:]) + "." for text in notes) + "</p>"
    return note + table([(heading, kind) for heading, kind, _, _ in columns], body, scroll=len(rows) > SCROLLING_TABLE_ROWS)


def _numeric(rows: list[SummaryRow], name: str) -> bool:
    values = [row.parameters.get(name) for row in rows]
    return all(value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)) for value in values)


def parameter_cell(value) -> str:
    """A swept key's or method parameter's value; – where the run does not read it."""
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, tuple):
        return escape("[" + ", ".join(str(item) for item in value) + "]")
    return escape(str(value))


def _measured_cell(row: SummaryRow) -> str:
    text = escape(damping_text(row.measured_damping))
    if np.isfinite(row.measured_damping) and not row.measured_resolved:
        text += ' <span class="sub">(unresolved)</span>'
    return text


def _difference_cell(row: SummaryRow) -> str:
    difference = row.damping_difference
    if not np.isfinite(difference):
        return "–"
    if row.damping_relative:
        text = "0.00 %" if abs(difference) < 5e-5 else f"{100 * difference:+.2f} %"
    else:
        text = "0" if abs(difference) < 1e-12 else f"{difference:+.1e}"
    if row.measured_resolved:
        text = f'<span class="{"agrees" if row.damping_agrees else "differs"}">{text}</span>'
    return text


def orders_section(rows: list[OrderRow], reference_note: str, when: str) -> str:
    note = f'<p class="note">{escape(reference_note)}</p>' if reference_note else ""
    several = len({row.group for row in rows}) > 1
    headings = ([("group", True)] if several else []) + [("integrator", "label"), ("declared order", False),
                                                           ("observed order", False), ("fitted over", False), ("", "wrap")]
    body = [([escape(row.group)] if several else []) + [escape(row.integrator), str(row.declared),
            "–" if not np.isfinite(row.observed) else f"{row.observed:.2f}", escape(row.dt_range), verdict(row.verdict)]
            for row in rows[:MAX_RUN_ROWS]]
    if len(rows) > MAX_RUN_ROWS:
        note += f'<p class="note">The first {MAX_RUN_ROWS:,} of {len(rows):,} rows, in sweep order.</p>'
    explain = ('<p class="note">Slope of log(error) against log(dt), the error measured at a fixed time'
               + (f" ({escape(when)}, record.error_time)" if when else "")
               + ", over the consecutive smallest time steps whose error lies between round-off (1e-10 of the length "
               f"scale) and saturation (10 % of it), at most 4 and at least 3; agreement within ±{ORDER_TOLERANCE:g}.</p>")
    return note + explain + table(headings, body)


def stability_section(rows: list[StabilityRow]) -> str:
    several = len({row.group for row in rows}) > 1

    def limit_text(row):
        if math.isinf(row.limit_hw):
            return "none"
        if row.limit_hw == 0:
            return "0 (grows as h -> 0)"
        return f"{row.limit_hw:.4g}"

    headings = ([("group", True)] if several else []) + [("integrator", "label"), ("limit h w", False), ("limit dt (s)", False),
                                                           ("largest dt that did not diverge", False),
                                                           ("smallest dt that diverged", False), ("", "wrap")]
    body = [([escape(row.group)] if several else []) + [escape(row.integrator), limit_text(row),
            "∞" if math.isinf(row.limit_dt) else f"{row.limit_dt:.4g}", number_text(row.largest_ok_dt),
            number_text(row.smallest_diverged_dt), verdict(row.verdict)] for row in rows]
    explain = ('<p class="note">Predicted: the h w at which the spectral radius of the probed amplification matrix first '
               "exceeds 1 (+1e-8). Measured: the runs at each dt. A run beyond the limit grows, but is only marked diverged "
               "once its energy leaves the configured bound, which a short run may not reach.</p>")
    return explain + table(headings, body)


def determinant_section(rows: list[DeterminantRow]) -> str:
    several = len({row.group for row in rows}) > 1
    headings = ([("group", True)] if several else []) + [("integrator", "label"), ("dt (s)", False), ("k (N/m)", False),
                                                           ("m (kg)", False), ("det A (probed)", False),
                                                           ("lecture closed form", True), ("value", False),
                                                           ("relative difference", False), ("", True)]
    body = [([escape(row.group)] if several else []) + [
        escape(row.integrator), f"{row.dt:.4g}", f"{row.stiffness:g}", f"{row.mass:g}", f"{row.probed:.15g}",
        escape(row.formula or "–"), "–" if not np.isfinite(row.closed_form) else f"{row.closed_form:.15g}",
        "–" if not np.isfinite(row.difference) else f"{row.difference:.1e}", verdict(row.verdict)] for row in rows]
    explain = ("<p class=\"note\">det A is the factor by which one step scales areas in the (x, v) phase plane: "
               "forward Euler 1 + k h² (the orbit spirals out), symplectic Euler 1 (area-preserving), backward Euler "
               "1/(1 + k h²) (spirals in), as in the lectures (m = 1; here k/m). A is probed by stepping the basis states "
               f"through each method on the run's spring; agreement to {DETERMINANT_TOLERANCE:g} relative.</p>")
    return explain + table(headings, body, scroll=len(rows) > SCROLLING_TABLE_ROWS)
