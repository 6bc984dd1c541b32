"""The summary table as text: fixed-width for the terminal (``simrun show``, at most 100 columns unless
--wide) and CSV with units in the headers (``simrun show``); the number formats are ``simrun.analysis.units``."""

from __future__ import annotations

import csv
import math
import textwrap
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from simrun.analysis.rows import (SummaryRow, any_dissipated, any_not_converged, any_safeguards,
                                  energy_reference_differs, energy_reference_text, error_time_text, iteration_name,
                                  mixed_solvers, parameter_names, remainder_differs, steps_text)
from simrun.analysis.units import damping_text, distance_text, frame_time_text, number_text, real_time_text
from simrun.format.summary import FRAME_TIME

# `simrun show` fits a terminal this wide by default (--wide: every column).
TERMINAL_WIDTH = 100
# The heading of the runs that read none of the swept keys (an explicit method reads no solver.* key).
NO_SWEPT_KEY = "none of the swept keys applies"
# Longer integrator labels are cut (with an ellipsis) in the terminal table unless --wide.
MAX_LABEL_WIDTH = 32


# -- the terminal table -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Column:
    """A column of the terminal table: two heading lines, its cells, and when it is shown."""

    key: str
    heading: tuple[str, str]
    cell: Callable[[SummaryRow], str]
    keep: int  # columns of lower rank are hidden first when the table is narrowed to TERMINAL_WIDTH
    text: bool = False  # left-aligned
    shown: Callable[[list[SummaryRow]], bool] = lambda rows: True


def _any(value: Callable[[SummaryRow], float]) -> Callable[[list[SummaryRow]], bool]:
    """Shown when some row has a finite, non-zero value."""
    return lambda rows: any(np.isfinite(value(row)) and value(row) != 0 for row in rows)


def _measured_text(row: SummaryRow) -> str:
    unresolved = np.isfinite(row.measured_damping) and not row.measured_resolved
    return damping_text(row.measured_damping).replace("–", "") + ("?" if unresolved else "")


def _status_text(row: SummaryRow) -> str:
    """The status with the first step that went wrong: "diverged@37", "not_converged@3"."""
    step = row.diverged_step if row.status == "diverged" else row.first_not_converged_step if row.status == "not_converged" else 0
    return f"{row.status}@{step}" if step else row.status


def terminal_columns(rows: list[SummaryRow]) -> list[Column]:
    """The columns of `simrun show`, each named by what it counts; those with nothing to show are left out."""
    iterations = iteration_name(rows)
    columns = [
        Column("index", ("", "#"), lambda row: str(row.index), 9),
        Column("integrator", ("", "integrator"), lambda row: row.integrator, 9, text=True),
        Column("solver", ("", "solver"), lambda row: row.solver or "–", 8, text=True, shown=mixed_solvers),
        Column("dt", ("dt", "(s)"), lambda row: f"{row.dt:.4g}", 9),
        Column("hw", ("", "h w"), lambda row: "" if not np.isfinite(row.hw) else f"{row.hw:.3g}", 3, shown=_any(lambda row: row.hw)),
        Column("status", ("", "status"), _status_text, 9, text=True),
        Column("steps", ("", "steps"), lambda row: str(row.steps), 1),
        Column("max_drift", ("max", "drift"), lambda row: number_text(row.max_rel_energy_drift), 8,
               shown=lambda rows: not remainder_differs(rows)),
        # where energy left or entered physically, the drift is split: the integrator's remainder, and the losses
        Column("remainder", ("integrator", "remainder"), lambda row: number_text(row.max_rel_energy_remainder), 8,
               shown=remainder_differs),
        Column("dissipated", ("", "dissipated"), lambda row: number_text(row.final_rel_dissipated_energy), 7,
               shown=any_dissipated),
        Column("drift_with_losses", ("max", "|E-E0|"), lambda row: number_text(row.max_rel_energy_drift), 2,
               shown=remainder_differs),
        Column("e_ref", ("E_ref", "(J)"), lambda row: number_text(row.energy_reference), 2,
               shown=energy_reference_differs),
        Column("error", ("error", "(m)"), lambda row: number_text(row.error).replace("–", ""), 8,
               shown=_any(lambda row: row.error)),
        Column("iterations", (iterations, "it/step"), lambda row: f"{row.mean_newton_iterations:.2f}" if row.solver else "",
               7, shown=_any(lambda row: row.mean_newton_iterations)),
        Column("linear", ("linear", "it/step"), lambda row: number_text(row.mean_linear_iterations) if row.solver else "",
               4, shown=_any(lambda row: row.mean_linear_iterations)),
        Column("wall", ("wall", "(s)"), lambda row: f"{row.wall_time:.3g}", 8),
        Column("real_time", ("", "real-time"), lambda row: real_time_text(row.real_time_factor), 7,
               shown=_any(lambda row: row.real_time_factor)),
        Column("wall_per_frame", ("wall/frame", "(ms)"), lambda row: frame_time_text(row.wall_time_per_frame), 3,
               shown=_any(lambda row: row.wall_time_per_frame)),
        Column("not_converged", ("not conv.", "steps"), lambda row: steps_text(row.not_converged_steps, row), 6,
               shown=any_not_converged),
        Column("safeguards", ("", "safeguards"), lambda row: steps_text(row.safeguard_steps, row), 5,
               shown=any_safeguards),
        Column("contact", ("min contact", "dist."), lambda row: distance_text(row.min_contact_distance), 5,
               shown=_any(lambda row: row.min_contact_distance)),
        Column("measured", ("d/w", "meas."), _measured_text, 6, shown=_any(lambda row: row.measured_damping)),
        Column("predicted", ("d/w", "pred."), lambda row: damping_text(row.predicted_damping).replace("–", ""), 5,
               shown=_any(lambda row: row.predicted_damping)),
    ]
    return [column for column in columns if column.shown(rows)]


def format_table(rows: list[SummaryRow], name: str = "", wide: bool = False, width: int = TERMINAL_WIDTH) -> str:
    """The summary as fixed-width text for the terminal; groups separated by a heading line.

    Columns with nothing to show are left out; unless ``wide``, the least needed ones are hidden (and
    long labels cut) until a line fits ``width`` characters, and a last line says which."""
    columns = terminal_columns(rows)
    label_width = max([len("integrator")] + [len(row.integrator) for row in rows])
    if not wide:
        label_width = min(label_width, MAX_LABEL_WIDTH)

    def cells(column: Column, row: SummaryRow) -> str:
        text = column.cell(row)
        if column.key == "integrator" and len(text) > label_width:
            text = text[:label_width - 1] + "…"
        return text

    def widths(shown: list[Column]) -> list[int]:
        return [max([len(part) for part in column.heading] + [len(cells(column, row)) for row in rows]) for column in shown]

    hidden: list[Column] = []
    if not wide:
        while sum(widths(columns)) + 2 * (len(columns) - 1) > width:
            candidates = [column for column in columns if column.keep < 9]
            if not candidates:
                break
            dropped = min(candidates, key=lambda column: column.keep)
            columns.remove(dropped)
            hidden.append(dropped)
    sizes = widths(columns)

    def line(texts: list[str]) -> str:
        return "  ".join(f"{text:<{size}}" if column.text else f"{text:>{size}}"
                         for column, text, size in zip(columns, texts, sizes)).rstrip()

    header = [line([column.heading[0] for column in columns]), line([column.heading[1] for column in columns])]
    rule = "-" * max(len(text) for text in header)
    lines = [f"{name}: {len(rows)} runs" if name else f"{len(rows)} runs"]
    frequencies = sorted({row.hw / row.dt for row in rows if np.isfinite(row.hw) and row.dt > 0})
    if frequencies and any(column.key == "hw" for column in hidden):
        lines.append("w = " + ", ".join(f"{value:.4g}" for value in frequencies) + " rad/s (h w = dt w)")
    lines += [header[0], header[1], rule] if header[0].strip() else [header[1], rule]
    group = None
    for row in rows:
        if row.group != group and any(other.group for other in rows):  # "": runs that read none of the swept keys
            lines.append(f"[{row.group or NO_SWEPT_KEY}]")
            group = row.group
        lines.append(line([cells(column, row) for column in columns]))
    lines.append(rule)
    if any(column.key == "remainder" for column in columns):
        notes = [f"integrator remainder: the energy the method itself removed or added, max |E + E_dissipated - W - E0| "
                 f"/ E_ref (W: work of prescribed vertices), {energy_reference_text(rows)}"]
        if any(column.key == "dissipated" for column in columns):
            notes.append("dissipated: what damping and friction took out by the end, E_dissipated / E_ref")
        if any(column.key == "drift_with_losses" for column in columns):
            notes.append("|E-E0|: the largest change of the energy, both together")
    else:
        notes = [f"drift: max |E - E0| / E_ref, {energy_reference_text(rows)}"]
    if any(column.key == "error" for column in columns):
        reference = any(row.error_from_reference for row in rows)
        notes.append(f"error: distance from the {'reference' if reference else 'exact'} solution at "
                     f"{error_time_text(rows)}")
    if any(column.key == "real_time" for column in columns):
        notes.append("real-time: simulated time (steps dt) over wall time, > 1x faster than real time")
    if any(column.key == "wall_per_frame" for column in columns):
        notes.append(f"wall/frame: wall time per 1/{1 / FRAME_TIME:g} s of simulated time (real time: below "
                     f"{1e3 * FRAME_TIME:.3g} ms)")
    if any(column.key == "status" for column in columns) and any(_status_text(row) != row.status for row in rows):
        notes.append("status@n: the first step that diverged or did not converge")
    if any(column.key == "not_converged" for column in columns):
        notes.append("not conv.: steps that used up max_iterations (or their solver's time_budget)"
                     + (" (an ok run accepted them: on_not_converged accept)" if any(row.accepted for row in rows) else ""))
    if any(column.key == "safeguards" for column in columns):
        notes.append("safeguards: steps where the solver cut a step by line search, projected or regularised the "
                     "Hessian, or fell back to another solver")
    if any(column.key in ("measured", "predicted") for column in columns):
        notes.append("d/w: artificial damping d_method / w (meas.: energy decay, ? = not resolved by the run; "
                     "pred.: amplification matrix)")
    if hidden:
        notes.append("not shown: " + ", ".join(" ".join(filter(None, column.heading)) for column in hidden)
                     + " (--wide: every column)")
    if not wide:  # the notes fit the width too
        notes = [textwrap.fill(note, width, subsequent_indent="  ", break_on_hyphens=False) for note in notes]
    return "\n".join(lines + notes)


# -- CSV: every column, full precision, units in the headers --------------------------------------
CSV_COLUMNS = (  # header (with its unit), value
    ("index", lambda row: row.index),
    ("run_id", lambda row: row.run_id),
    ("integrator", lambda row: row.integrator),
    ("group", lambda row: row.group),
    ("solver", lambda row: row.solver),
    ("dt_s", lambda row: row.dt),
    ("hw", lambda row: row.hw),  # dimensionless: dt times the test frequency
    ("status", lambda row: row.status),
    ("steps", lambda row: row.steps),
    ("order", lambda row: row.order),
    ("energy_reference_J", lambda row: row.energy_reference),
    ("energy_reference_name", lambda row: row.energy_reference_name),
    ("max_rel_energy_drift", lambda row: row.max_rel_energy_drift),  # dimensionless: max |E - E0| / E_ref
    ("final_rel_energy_drift", lambda row: row.final_rel_energy_drift),  # (E_end - E0) / E_ref
    ("max_rel_energy_remainder", lambda row: row.max_rel_energy_remainder),  # max |E + E_diss - W - E0| / E_ref
    ("final_rel_dissipated_energy", lambda row: row.final_rel_dissipated_energy),  # E_diss(end) / E_ref
    ("error_time_s", lambda row: row.error_time),
    ("error_m", lambda row: row.error),
    ("error_from_reference", lambda row: row.error_from_reference),
    ("final_error_m", lambda row: row.final_error),
    ("final_velocity_error_m_per_s", lambda row: row.final_velocity_error),
    ("max_error_m", lambda row: row.max_error),  # over the stored samples
    ("max_velocity_error_m_per_s", lambda row: row.max_velocity_error),
    ("velocity_error_m_per_s", lambda row: row.velocity_error),  # against a reference, at error_time
    ("solver_iterations_per_step", lambda row: row.mean_newton_iterations),
    ("linear_iterations_per_step", lambda row: row.mean_linear_iterations),
    ("wall_time_s", lambda row: row.wall_time),
    ("real_time_factor", lambda row: row.real_time_factor),  # dimensionless: steps dt / wall_time
    ("wall_time_per_frame_s", lambda row: row.wall_time_per_frame),  # per 1/60 s of simulated time
    ("not_converged_steps", lambda row: row.not_converged_steps),
    ("first_not_converged_step", lambda row: row.first_not_converged_step),  # 1-based; 0: none
    ("diverged_step", lambda row: row.diverged_step),  # 1-based; 0: none
    ("safeguard_steps", lambda row: row.safeguard_steps),
    ("min_contact_distance_m", lambda row: row.min_contact_distance),  # < 0: a penetration
    ("max_active_contacts", lambda row: row.max_active_contacts),
    ("friction_work_J", lambda row: row.friction_work),
    ("measured_damping_over_w", lambda row: row.measured_damping),  # dimensionless: d_method / w
    ("measured_damping_resolved", lambda row: row.measured_resolved),
    ("predicted_damping_over_w", lambda row: row.predicted_damping),
    ("damping_relative_difference", lambda row: row.damping_difference),
)


# the parameter columns (a swept key, a method parameter, named by the key) come after this one
PARAMETERS_AFTER = "solver"


def csv_columns(rows: list[SummaryRow]) -> list[tuple[str, Callable[[SummaryRow], object]]]:
    """CSV_COLUMNS with the rows' parameter columns (``step_control.tolerance``, ``system.label``,
    ``integrator.order``: simrun.results.parameters) after PARAMETERS_AFTER; empty where a run does not read the key."""
    place = next(number for number, (header, _) in enumerate(CSV_COLUMNS) if header == PARAMETERS_AFTER) + 1
    parameters = [(name, lambda row, name=name: row.parameters.get(name)) for name in parameter_names(rows)]
    return [*CSV_COLUMNS[:place], *parameters, *CSV_COLUMNS[place:]]


def write_csv(rows: list[SummaryRow], stream) -> None:
    """Every column at full precision; a header names its unit (dt_s, wall_time_s, error_m, energy_reference_J)
    or is a dimensionless ratio (max_rel_energy_drift, hw, *_damping_over_w), or is a parameter's key."""
    columns = csv_columns(rows)
    writer = csv.writer(stream)
    writer.writerow([header for header, _ in columns])
    for row in rows:
        writer.writerow([csv_number(value(row)) for _, value in columns])


def csv_number(value):
    if value is None:
        return ""
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else repr(float(value))
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    if isinstance(value, tuple):  # a swept list, as the config writes it
        return "[" + ", ".join(str(csv_number(item)) for item in value) + "]"
    return value


