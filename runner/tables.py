"""The tables of a results file: one summary row per run, observed orders, stability limits, determinants.

``simrun show`` prints the summary (or writes it as CSV); the report renders every table as HTML. Rows
are computed from what the figures read (``simrun.figures.figure_data``: the file alone) and from
``simrun.analysis`` (amplification matrices of the integrators named in the file).
"""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass

import numpy as np

from simrun import analysis
from simrun.figures import FigureData
from simrun.figures.convergence import order_fits
from simrun.figures.theory import predictions_for, test_equation_runs
from simrun.results import Status

# Observed and declared order agree when they differ by at most this (the tests' tolerance).
ORDER_TOLERANCE = 0.15
# Measured and predicted damping agree when they differ by at most this fraction (or are both round-off).
DAMPING_TOLERANCE = 0.02
# A determinant matches its closed form to this relative accuracy (round-off of the probe).
DETERMINANT_TOLERANCE = 1e-12
# |d/w| below this is round-off of a method without artificial damping (rho = 1 to the last bits).
ROUND_OFF_DAMPING = 1e-12
# Without a closed form to check, determinant rows are listed only up to this many.
MAX_DETERMINANT_ROWS = 60


@dataclass
class SummaryRow:
    """One run as the summary table shows it."""

    index: int
    run_id: str
    integrator: str  # the label
    group: str
    dt: float  # s
    hw: float  # dt w on the test equation, else NaN
    status: str
    steps: int
    order: int  # the method's order of accuracy with these parameters
    max_rel_energy_drift: float
    final_rel_energy_drift: float
    final_error: float  # m
    mean_newton_iterations: float
    mean_linear_iterations: float
    wall_time: float  # s
    measured_damping: float  # d_method / w from the energy decay (NaN where not measured)
    measured_resolved: bool
    predicted_damping: float  # d_method / w from the amplification matrix at this h w

    @property
    def damping_difference(self) -> float:
        """(measured - predicted) / predicted; 0 when both are round-off (no damping)."""
        if not (np.isfinite(self.measured_damping) and np.isfinite(self.predicted_damping)):
            return math.nan
        if abs(self.predicted_damping) < 1e-9 and abs(self.measured_damping) < 1e-9:
            return 0.0
        return (self.measured_damping - self.predicted_damping) / abs(self.predicted_damping) if self.predicted_damping else math.inf


def summary_rows(data: FigureData) -> list[SummaryRow]:
    """One row per run, in sweep order; drift and iterations from the file's summary table."""
    stored = data.results.summary.set_index("run_id").to_dict("index")
    titles = {id(member): title for title, members in data.groups for member in members}
    rows = []
    for run in data.runs:
        row = stored[run.run_id]
        fit = run.damping_fit
        measured = fit.rate / run.frequency if fit is not None and np.isfinite(fit.rate) else math.nan
        predicted = math.nan
        if run.frequency is not None and run.method is not None:
            predicted = _predicted_damping(run.method, run.hw)
        rows.append(SummaryRow(
            index=run.index, run_id=run.run_id, integrator=run.label, group=titles.get(id(run), ""),
            dt=run.dt, hw=run.hw, status=str(run.status), steps=run.steps,
            order=run.method.order_of_accuracy if run.method is not None else run.order,
            max_rel_energy_drift=float(row["max_rel_energy_drift"]),
            final_rel_energy_drift=float(row["final_rel_energy_drift"]),
            final_error=run.final_error,
            mean_newton_iterations=float(row["mean_newton_iterations"]),
            mean_linear_iterations=float(row["mean_linear_iterations"]),
            wall_time=run.wall_time,
            measured_damping=measured, measured_resolved=bool(fit is not None and fit.resolved),
            predicted_damping=predicted,
        ))
    return rows


def _predicted_damping(method, hw: float) -> float:
    rho = analysis.spectral_radius(analysis.amplification_matrix(method, hw))
    return float(analysis.damping_over_frequency(rho, hw)) + 0.0


TABLE_COLUMNS = (  # heading, width, formatter
    ("#", 4, lambda row: str(row.index)),
    ("integrator", 34, lambda row: row.integrator),
    ("dt (s)", 9, lambda row: f"{row.dt:.4g}"),
    ("h w", 7, lambda row: "" if not np.isfinite(row.hw) else f"{row.hw:.3g}"),
    ("status", 13, lambda row: row.status),
    ("steps", 7, lambda row: str(row.steps)),
    ("max drift", 9, lambda row: number_text(row.max_rel_energy_drift)),
    ("error (m)", 9, lambda row: number_text(row.final_error)),
    ("Newton/step", 11, lambda row: f"{row.mean_newton_iterations:.2f}"),
    ("wall (s)", 8, lambda row: f"{row.wall_time:.3g}"),
    ("d/w meas.", 10, lambda row: damping_text(row.measured_damping) + ("" if row.measured_resolved or not np.isfinite(row.measured_damping) else "?")),
    ("d/w pred.", 10, lambda row: damping_text(row.predicted_damping)),
)


def format_table(rows: list[SummaryRow], name: str = "") -> str:
    """The summary as fixed-width text for the terminal; groups separated by a heading line."""
    header = "  ".join(f"{heading:<{width}}" if heading == "integrator" else f"{heading:>{width}}"
                       for heading, width, _ in TABLE_COLUMNS)
    lines = [f"{name}: {len(rows)} runs" if name else f"{len(rows)} runs", header, "-" * len(header)]
    group = None
    for row in rows:
        if row.group != group and any(other.group for other in rows):
            lines.append(f"[{row.group}]")
            group = row.group
        cells = []
        for heading, width, format_cell in TABLE_COLUMNS:
            text = format_cell(row)
            cells.append(f"{text:<{width}}" if heading == "integrator" else f"{text:>{width}}")
        lines.append("  ".join(cells))
    lines.append("drift: max |E - E0| / |E0|; d/w: artificial damping d_method / w (meas.: energy decay, "
                 "? = not resolved by the run; pred.: amplification matrix)")
    return "\n".join(lines)


def write_csv(rows: list[SummaryRow], stream) -> None:
    fields = list(SummaryRow.__dataclass_fields__) + ["damping_difference"]
    writer = csv.writer(stream)
    writer.writerow(fields)
    for row in rows:
        values = asdict(row)
        values["damping_difference"] = row.damping_difference
        writer.writerow([csv_number(values[field]) for field in fields])


def csv_number(value):
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer):
        return int(value)
    return value


def damping_text(value: float) -> str:
    """d/w with round-off shown as 0 (rho = 1 to the last bits gives |d/w| ~ 1e-15)."""
    return "0" if np.isfinite(value) and abs(value) < ROUND_OFF_DAMPING else number_text(value)


def number_text(value: float) -> str:
    if value is None or not np.isfinite(value):
        return "–" if value is None or np.isnan(value) else ("inf" if value > 0 else "-inf")
    if value == 0:
        return "0"
    if 1e-3 <= abs(value) < 1e4:
        return f"{value:.4g}"
    return f"{value:.2e}"


# ==================================================================================================
# Analysis tables of the report
# ==================================================================================================
@dataclass
class OrderRow:
    group: str
    integrator: str
    declared: int
    observed: float
    dt_range: str
    exact: bool

    @property
    def verdict(self) -> str:
        if self.exact:
            return "exact (errors at round-off)"
        if not np.isfinite(self.observed):
            return "not enough asymptotic points"
        return "agrees" if abs(self.observed - self.declared) <= ORDER_TOLERANCE else "differs"


def order_rows(data) -> list[OrderRow]:
    rows = []
    for (title, label), (fit, runs) in order_fits(data).items():
        method = runs[0].method
        declared = method.order_of_accuracy if method is not None else runs[0].order
        used = [run.dt for run, flag in zip(runs, fit.used) if flag]
        span = f"{min(used):.3g} – {max(used):.3g} s ({len(used)} dts)" if used else "–"
        rows.append(OrderRow(title, label, declared, fit.order, span, fit.exact))
    return rows


@dataclass
class StabilityRow:
    group: str
    integrator: str
    limit_hw: float  # predicted h w
    limit_dt: float  # s
    largest_ok_dt: float
    smallest_diverged_dt: float

    @property
    def verdict(self) -> str:
        if math.isinf(self.limit_dt):
            return "no divergence expected" + (" – but a run diverged" if np.isfinite(self.smallest_diverged_dt) else "")
        ok = not np.isfinite(self.largest_ok_dt) or self.largest_ok_dt <= self.limit_dt * (1 + 1e-9)
        diverged = not np.isfinite(self.smallest_diverged_dt) or self.smallest_diverged_dt > self.limit_dt * (1 - 1e-9)
        if ok and diverged:
            return "consistent"
        if not ok:
            return "ran beyond the limit (energy bound not reached in the run)"
        return "diverged below the limit"


def stability_rows(data) -> list[StabilityRow]:
    predictions = predictions_for(data) if test_equation_runs(data) else {}
    rows = []
    for title, runs in data.groups:
        frequency = next((run.frequency for run in runs if run.frequency is not None), None)
        if frequency is None:
            continue
        for label in data.labels:
            mine = [run for run in runs if run.label == label]
            if not mine or label not in predictions:
                continue
            limit = predictions[label].stability_limit
            ok = [run.dt for run in mine if not run.status.stopped]
            diverged = [run.dt for run in mine if run.status is Status.DIVERGED]
            rows.append(StabilityRow(title, label, limit, limit / frequency, max(ok, default=math.nan),
                                     min(diverged, default=math.nan)))
    return rows


# The lectures' closed forms for the determinant of the one-step map of the mass on a spring
# (undamped, written for any m with k/m = w^2; the lectures take m = 1): forward Euler 1 + k h^2,
# symplectic Euler 1 (area-preserving), backward Euler 1/(1 + k h^2). They are the claims the
# report checks against the probed amplification matrix, not inputs to any curve. Each is a
# function of (h w)^2 = k h^2 / m.
LECTURE_DETERMINANTS = {
    "forward_euler": ("1 + k h²/m", lambda hw2: 1.0 + hw2),
    "symplectic_euler": ("1", lambda hw2: 1.0),
    "backward_euler": ("1 / (1 + k h²/m)", lambda hw2: 1.0 / (1.0 + hw2)),
}


@dataclass
class DeterminantRow:
    group: str
    integrator: str
    dt: float
    stiffness: float
    mass: float
    probed: float
    formula: str
    closed_form: float

    @property
    def difference(self) -> float:
        return abs(self.probed - self.closed_form) / abs(self.closed_form) if np.isfinite(self.closed_form) else math.nan

    @property
    def verdict(self) -> str:
        if not np.isfinite(self.closed_form):
            return "–"
        return "agrees" if self.difference <= DETERMINANT_TOLERANCE else "differs"


def determinant_rows(data: FigureData) -> list[DeterminantRow]:
    """det of the probed one-step map for each (group, label, dt) of the runs with one degree of freedom
    (the mass on a spring), against the lectures' closed forms where the run is the undamped test equation."""
    rows = []
    for title, runs in data.groups:
        seen = set()
        for run in runs:
            if run.stored.dof_count != 1 or run.method is None or (run.label, run.dt) in seen:
                continue
            seen.add((run.label, run.dt))
            params = run.stored.system_params
            system = analysis.build_system(run.stored.system, params)
            formula, closed = "", math.nan
            if run.integrator in LECTURE_DETERMINANTS and run.frequency is not None:
                formula, form = LECTURE_DETERMINANTS[run.integrator]
                closed = form(run.hw ** 2)
            rows.append(DeterminantRow(title, run.label, run.dt, float(params.get("stiffness", math.nan)),
                                       float(params.get("mass", math.nan)),
                                       analysis.determinant(run.method, run.dt, system), formula, closed))
    checked = [row for row in rows if np.isfinite(row.closed_form)]
    return rows if len(rows) <= MAX_DETERMINANT_ROWS else checked
