"""`simrun report`, `simrun show` and `simrun analyze`: a results file as one HTML page, as a table, and
the predicted curves of any integrators without runs.

The report is one self-contained HTML file (figures embedded as base64 PNG, styles inline, no
script, no link to any other file): the experiment's config and provenance, a summary table of the
runs (status, energy drift, iterations, order, measured against predicted artificial damping), the
observed orders, the predicted stability limits against what the runs did, the determinant of each
method's one-step map on the spring against the lectures' closed forms, and every figure with a
caption that says what to look for. Like the figures, it is made from the results file alone; the
only computation beyond reading it is ``simrun.analysis`` (amplification matrices of the
integrators named in the file, and, for cloth, a reference solution rebuilt from the stored system
parameters).
"""

from __future__ import annotations

import base64
import csv
import datetime
import html
import io
import json
import math
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

REPORT_NAME = "report.html"
REPORT_DPI = 100  # the figures' inches become about as many CSS pixels at this resolution
# A summary table longer than this scrolls inside its box.
SCROLLING_TABLE_ROWS = 40
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
REFERENCE_CHOICES = "none, dop853, radau, bdf, lsoda, rk45, or a run_id of the file"
DEFAULT_ANALYZE_OUTPUT = Path("results") / "analysis"


# ==================================================================================================
# Command-line parsers (wired into simrun.cli by `add_*_parser(commands)`)
# ==================================================================================================
def add_report_parser(commands) -> None:
    report = commands.add_parser(
        "report", help="write OUTPUT/report.html: config, provenance, summary table and every figure in one page",
        description="Write one self-contained HTML page (figures embedded, no external files) from a results file: "
                    "config, provenance, summary of the runs, observed orders, stability limits, determinants, "
                    "and every figure with a caption.")
    report.add_argument("results", help="a results file, e.g. results/damping_curves/results.h5")
    report.add_argument("--output", help=f"the HTML file (default: {REPORT_NAME} beside the results file)")
    add_reference_option(report, default="dop853")
    report.set_defaults(handler=command_report)


def add_show_parser(commands) -> None:
    show = commands.add_parser("show", help="print the summary table of a results file (or write it as CSV)",
                               description="Print one row per run: status, drift, error, iterations, cost, "
                                           "and measured against predicted artificial damping.")
    show.add_argument("results", help="a results file, e.g. results/quickstart/results.h5")
    show.add_argument("--csv", nargs="?", const="-", metavar="FILE",
                      help="write the table as CSV to FILE (to standard output without FILE)")
    show.set_defaults(handler=command_show)


def add_analyze_parser(commands) -> None:
    analyze = commands.add_parser(
        "analyze", help="predicted damping, spectral radius, period error and stability limits of integrators (no runs)",
        description="Probe each integrator's amplification matrix on the test spring q'' + w^2 q = 0 and draw its "
                    "artificial damping, spectral radius and period error against h w; no runs needed.")
    analyze.add_argument("--integrators", nargs="+", metavar="SPEC",
                         help="names, with parameters as name:key=value[,key=value] or name[key=value], e.g. "
                              "backward_euler implicit_midpoint 'generalized_alpha:rho_inf=0.5' (default: every integrator)")
    analyze.add_argument("--range", nargs=2, type=float, metavar=("LOW", "HIGH"), default=None,
                         help="the h w range of the curves (default: 0.01 100)")
    analyze.add_argument("--output", help=f"folder for the figures and predicted.csv (default: {DEFAULT_ANALYZE_OUTPUT})")
    analyze.set_defaults(handler=command_analyze)


def add_reference_option(parser, default: str | None = None) -> None:
    """``--reference``: what the error of runs without an exact solution (cloth) is measured against."""
    parser.add_argument(
        "--reference", nargs="?", const="dop853", default=default, metavar="METHOD_OR_RUN",
        help="reference for the convergence of runs without an exact solution (cloth): scipy solve_ivp with "
             f"DOP853 at rtol 1e-10 (default{' here' if default else ' with the bare option'}), another method, a run_id "
             f"of the file (e.g. the smallest dt), or none; one of {REFERENCE_CHOICES}")


# ==================================================================================================
# Handlers
# ==================================================================================================
def command_report(args) -> int:
    path = _results_path(args.results)
    output = Path(args.output) if args.output else path.parent / REPORT_NAME
    written = write_report(path, output, reference=args.reference, say=_stderr)
    print(f"report: {written}")
    return 0


def command_show(args) -> int:
    from simrun import plots

    path = _results_path(args.results)
    results = plots.load_results(path)
    rows = summary_rows(results)
    if args.csv is not None:
        if args.csv == "-":
            _to_stdout(lambda: write_csv(rows, sys.stdout))
        else:
            target = Path(args.csv)
            target.parent.mkdir(parents=True, exist_ok=True)
            with open(target, "w", newline="") as stream:
                write_csv(rows, stream)
            print(f"summary: {target}  ({len(rows)} runs)")
        return 0
    _to_stdout(lambda: print(format_table(rows, results.name)))
    return 0


def _to_stdout(write) -> None:
    """Write to standard output; a reader that stops early (`simrun show ... | head`) is not an error."""
    try:
        write()
        sys.stdout.flush()
    except BrokenPipeError:
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit


def command_analyze(args) -> int:
    from simrun import analysis
    from simrun.config import ConfigError
    from simrun.integrators import INTEGRATORS

    specs = args.integrators or list(INTEGRATORS)
    integrators = []
    for spec in specs:
        try:
            integrators.append(analysis.parse_integrator(spec))
        except ValueError as error:
            raise ConfigError(f"--integrators: {error}") from None
    low, high = args.range if args.range else analysis.X_RANGE
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low < high):
        raise ConfigError(f"--range: expected 0 < LOW < HIGH, got {low:g} {high:g}")
    if math.log10(high / low) > 12:
        raise ConfigError(f"--range: at most 12 decades, got {low:g} to {high:g}")
    output = Path(args.output) if args.output else DEFAULT_ANALYZE_OUTPUT
    output.mkdir(parents=True, exist_ok=True)
    predictions = {}
    for integrator in integrators:
        predictions.setdefault(integrator.label, analysis.predict(integrator, low, high))
    written = draw_predicted_figures(predictions, output)
    table = output / "predicted.csv"
    with open(table, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["integrator", "h_w", "spectral_radius", "damping_over_w", "relative_period_error"])
        for label, prediction in predictions.items():
            for row in zip(prediction.x, prediction.rho, prediction.damping, prediction.period_error):
                writer.writerow([label] + [_csv_number(value) for value in row])
    print(format_predictions(predictions))
    print(f"figures: {output}  ({len(written)} files); curves: {table}")
    return 0


def draw_predicted_figures(predictions: dict, output: Path) -> list[Path]:
    """The damping and the spectral radius/period figures of predictions alone, as PNG and SVG."""
    import matplotlib.pyplot as plt

    from simrun import plots

    labels = list(predictions)
    colours = plots.label_colours(labels)
    markers = {label: plots.LABEL_MARKERS[number % len(plots.LABEL_MARKERS)] for number, label in enumerate(labels)}
    figures = {
        "artificial_damping": plots.damping_figure(predictions, colours, markers, "predicted artificial damping"),
        "spectral_radius_and_period": plots.spectral_figure(predictions, colours, markers,
                                                            "predicted spectral radius and period error"),
    }
    written = []
    for name, figure in figures.items():
        try:
            written += plots.save_figure(figure, output / name)
        finally:
            plt.close(figure)
    return written


def format_predictions(predictions: dict) -> str:
    """One line per integrator: order, stability limit, rho as h w -> infinity (implicit methods) and d/w at three h w."""
    from simrun import analysis

    lines = [f"{'integrator':<36} {'order':>5}  {'stability limit h w':>20}  {'rho(inf)':>8}  "
             f"{'d/w at h w = 0.1':>16}  {'1':>9}  {'10':>9}"]
    for label, prediction in predictions.items():
        limit = prediction.stability_limit
        limit_text = f"none ≤ {prediction.x[-1]:g}" if math.isinf(limit) else ("unstable at every h" if limit == 0 else f"{limit:.6g}")
        # the limit map of an explicit method is not defined (it grows without bound), nor cheap for the exponential one
        radius = "–" if prediction.integrator.explicit else _damping(analysis.high_frequency_radius(prediction.integrator))
        damping = [prediction.at(x)[1] for x in (0.1, 1.0, 10.0)]
        lines.append(f"{label:<36} {prediction.integrator.order_of_accuracy:>5}  {limit_text:>20}  {radius:>8}  "
                     f"{_damping(damping[0]):>16}  {_damping(damping[1]):>9}  {_damping(damping[2]):>9}")
    return "\n".join(lines)


def plot_reference_errors(path: str | Path, reference: str | None, say=None) -> dict[str, float] | None:
    """For `simrun plot --reference`: the errors to hand to ``plots.draw_figures(..., reference_errors=...)``."""
    from simrun import plots

    if reference is None or reference.lower() == "none":
        return None
    return reference_errors(Path(path), plots.load_results(path), reference, say=say)


def _results_path(text: str) -> Path:
    import h5py

    from simrun.config import ConfigError

    path = Path(text)
    if not path.is_file() or not h5py.is_hdf5(path):
        raise ConfigError(f"results: {str(path)!r} is not a results file (expected e.g. results/quickstart/results.h5)")
    with h5py.File(path, "r") as file:
        if "runs" not in file:
            raise ConfigError(f"results: {str(path)!r} is an HDF5 file without /runs: not a simrun results file")
    return path


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# ==================================================================================================
# The summary table
# ==================================================================================================
@dataclass
class SummaryRow:
    """One run as the summary table shows it."""

    index: int
    run_id: str
    integrator: str  # the label
    group: str
    dt: float  # s
    h_w: float  # dt w on the test equation, else NaN
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


def summary_rows(results) -> list[SummaryRow]:
    """One row per run, in sweep order; drift and iterations from the file's summary table where it has them."""
    stored = _stored_summary(results.path) if results.path is not None else {}
    titles = {id(member): title for title, members in results.groups for member in members}
    rows = []
    for run in results.runs:
        row = stored.get(run.run_id, {})
        fit = run.damping_fit
        measured = fit.rate / run.frequency if fit is not None and np.isfinite(fit.rate) else math.nan
        predicted = math.nan
        if run.frequency is not None and run.method is not None:
            predicted = _predicted_damping(run.method, run.x)
        max_drift, final_drift = _drifts(run)
        rows.append(SummaryRow(
            index=run.index, run_id=run.run_id, integrator=run.label, group=titles.get(id(run), ""),
            dt=run.dt, h_w=run.x, status=run.status, steps=run.steps,
            order=run.method.order_of_accuracy if run.method is not None else run.order,
            max_rel_energy_drift=float(row.get("max_rel_energy_drift", max_drift)),
            final_rel_energy_drift=float(row.get("final_rel_energy_drift", final_drift)),
            final_error=run.final_error,
            mean_newton_iterations=float(row.get("mean_newton_iterations",
                                                 run.newton_iterations.mean() if run.newton_iterations.size else 0.0)),
            mean_linear_iterations=float(row.get("mean_linear_iterations", math.nan)),
            wall_time=run.wall_time,
            measured_damping=measured, measured_resolved=bool(fit is not None and fit.resolved),
            predicted_damping=predicted,
        ))
    return rows


def _predicted_damping(method, x: float) -> float:
    from simrun import analysis

    rho = analysis.spectral_radius(analysis.amplification_matrix(method, x))
    return float(analysis.damping_over_frequency(rho, x)) + 0.0


def _drifts(run) -> tuple[float, float]:
    energy = run.energy[np.isfinite(run.energy)]
    if energy.size == 0:
        return math.nan, math.nan
    drift = (energy - energy[0]) / run.energy_ref
    return float(np.max(np.abs(drift))), float(drift[-1])


def _stored_summary(path: Path) -> dict[str, dict]:
    """run_id -> the file's /summary row as a dict (strings decoded); {} when there is none."""
    import h5py

    with h5py.File(path, "r") as file:
        if "summary" not in file:
            return {}
        table = file["summary"][()]
    rows = {}
    for record in table:
        row = {}
        for name in table.dtype.names:
            value = record[name]
            row[name] = value.decode() if isinstance(value, bytes) else (value.item() if hasattr(value, "item") else value)
        rows[str(row.get("run_id", ""))] = row
    return rows


TABLE_COLUMNS = (  # heading, width, formatter
    ("#", 4, lambda row: str(row.index)),
    ("integrator", 34, lambda row: row.integrator),
    ("dt (s)", 9, lambda row: f"{row.dt:.4g}"),
    ("h w", 7, lambda row: "" if not np.isfinite(row.h_w) else f"{row.h_w:.3g}"),
    ("status", 13, lambda row: row.status),
    ("steps", 7, lambda row: str(row.steps)),
    ("max drift", 9, lambda row: _number(row.max_rel_energy_drift)),
    ("error (m)", 9, lambda row: _number(row.final_error)),
    ("Newton/step", 11, lambda row: f"{row.mean_newton_iterations:.2f}"),
    ("wall (s)", 8, lambda row: f"{row.wall_time:.3g}"),
    ("d/w meas.", 10, lambda row: _damping(row.measured_damping) + ("" if row.measured_resolved or not np.isfinite(row.measured_damping) else "?")),
    ("d/w pred.", 10, lambda row: _damping(row.predicted_damping)),
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
        writer.writerow([_csv_number(values[field]) for field in fields])


def _csv_number(value):
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer):
        return int(value)
    return value


def _damping(value: float) -> str:
    """d/w with round-off shown as 0 (rho = 1 to the last bits gives |d/w| ~ 1e-15)."""
    return "0" if np.isfinite(value) and abs(value) < ROUND_OFF_DAMPING else _number(value)


def _number(value: float) -> str:
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


def order_rows(results) -> list[OrderRow]:
    from simrun import plots

    rows = []
    for (title, label), (fit, runs) in plots.order_fits(results).items():
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
    limit_x: float  # predicted h w
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


def stability_rows(results) -> list[StabilityRow]:
    from simrun import plots

    predictions = plots.predictions_for(results) if plots.test_equation_runs(results) else {}
    rows = []
    for title, runs in results.groups:
        frequency = next((run.frequency for run in runs if run.frequency is not None), None)
        if frequency is None:
            continue
        for label in results.labels:
            mine = [run for run in runs if run.label == label]
            if not mine or label not in predictions:
                continue
            limit = predictions[label].stability_limit
            ok = [run.dt for run in mine if run.status not in ("diverged", "failed")]
            diverged = [run.dt for run in mine if run.status == "diverged"]
            rows.append(StabilityRow(title, label, limit, limit / frequency, max(ok, default=math.nan),
                                     min(diverged, default=math.nan)))
    return rows


# The lectures' closed forms for the determinant of the one-step map of the mass on a spring
# (undamped, written for any m with k/m; the lectures take m = 1): forward Euler 1 + k h^2,
# symplectic Euler 1 (area-preserving), backward Euler 1/(1 + k h^2). They are the claims the
# report checks against the probed amplification matrix, not inputs to any curve.
LECTURE_DETERMINANTS = {
    "forward_euler": ("1 + k h²/m", lambda k, m, h: 1.0 + k * h * h / m),
    "symplectic_euler": ("1", lambda k, m, h: 1.0),
    "backward_euler": ("1 / (1 + k h²/m)", lambda k, m, h: 1.0 / (1.0 + k * h * h / m)),
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


def determinant_rows(results) -> list[DeterminantRow]:
    """det of the probed one-step map for each (group, label, dt) of the spring runs, against the lectures' forms."""
    from simrun import analysis

    rows = []
    for title, runs in results.groups:
        seen = set()
        for run in runs:
            if run.system != "spring_mass" or run.method is None or (run.label, run.dt) in seen:
                continue
            seen.add((run.label, run.dt))
            params = run.system_params
            system = analysis.build_system("spring_mass", params)
            k, m, damping = float(params.get("stiffness")), float(params.get("mass", 1.0)), float(params.get("damping", 0.0))
            formula, closed = "", math.nan
            if run.integrator in LECTURE_DETERMINANTS and damping == 0.0:
                formula, form = LECTURE_DETERMINANTS[run.integrator]
                closed = form(k, m, run.dt)
            rows.append(DeterminantRow(title, run.label, run.dt, k, m, analysis.determinant(run.method, run.dt, system),
                                       formula, closed))
    checked = [row for row in rows if np.isfinite(row.closed_form)]
    return rows if len(rows) <= MAX_DETERMINANT_ROWS else checked


# ==================================================================================================
# Reference solutions (cloth)
# ==================================================================================================
def reference_errors(path: Path, results, reference: str, say=None) -> dict[str, float]:
    """run_id -> max |x - x_ref| (m) at the run's last frame, for runs without an exact solution (NaN final_error).

    ``reference``: a scipy solve_ivp method (dop853 by default: explicit, 8th order; at rtol 1e-10
    it is far more accurate than any run) solved on the system rebuilt from the stored
    ``system_params``, or a run_id of the file whose last frame serves as the reference for runs
    of the same system and end time. Runs whose last state is not stored are skipped.
    """
    import h5py

    from simrun import analysis
    from simrun.config import ConfigError

    needing = [run for run in results.runs if not np.isfinite(run.final_error) and run.status not in ("diverged", "failed")]
    if not needing:
        return {}
    by_id = {run.run_id: run for run in results.runs}
    finals, anchor_final = {}, None
    with h5py.File(path, "r") as file:
        for run in needing:
            final = _final_positions(file["runs"][run.run_id])
            if final is not None:
                finals[run.run_id] = final
        if reference in by_id:
            anchor_final = _final_positions(file["runs"][reference])
            if anchor_final is None:
                raise ConfigError(f"--reference: run {reference!r} has no stored final state to compare with")
    errors: dict[str, float] = {}
    if anchor_final is not None:  # another run (e.g. the smallest dt) as the reference
        anchor = by_id[reference]
        for run in needing:
            if run.run_id == reference or run.run_id not in finals:
                continue
            t_end, x_end = finals[run.run_id]
            if run.system_params == anchor.system_params and math.isclose(t_end, anchor_final[0], rel_tol=1e-9):
                errors[run.run_id] = float(np.max(np.abs(x_end - anchor_final[1])))
        return errors
    method = {name.lower(): name for name in analysis.REFERENCE_METHODS}.get(str(reference).lower())
    if method is None:
        raise ConfigError(f"--reference: {reference!r} is neither a method nor a run of this file; valid: {REFERENCE_CHOICES}")
    systems: dict[str, list] = {}
    for run in needing:
        if run.run_id in finals:
            systems.setdefault(json.dumps([run.system, run.system_params], sort_keys=True), []).append(run)
    for key, runs in systems.items():
        system_type, params = json.loads(key)
        times = sorted({finals[run.run_id][0] for run in runs})
        if say:
            say(f"reference solution ({method}, rtol {analysis.REFERENCE_RTOL:g}) for {system_type} to t = {times[-1]:g} s ...")
        try:
            solution = analysis.reference_positions(analysis.build_system(system_type, params), times, method)
        except (RuntimeError, ValueError) as error:
            if say:
                say(f"reference solution failed ({error}); no convergence figure for these runs")
            continue
        for run in runs:
            t_end, x_end = finals[run.run_id]
            reference_x = solution[min(solution, key=lambda t: abs(t - t_end))]
            errors[run.run_id] = float(np.max(np.abs(x_end - reference_x)))
    return errors


def _final_positions(group) -> tuple[float, np.ndarray] | None:
    """(t, x) of the run's last stored state: the last frame (cloth) or the last positions sample."""
    if "frames" in group and group["frames"].shape[0]:
        return float(group["frame_t"][-1]), np.asarray(group["frames"][-1], dtype=float).ravel()
    if "positions" in group and group["positions"].shape[0]:
        return float(group["t"][-1]), np.asarray(group["positions"][-1], dtype=float).ravel()
    return None


# ==================================================================================================
# The HTML page
# ==================================================================================================
FIGURE_CAPTIONS = {
    "energy_over_time": "E/E₀ against time, one panel per time step. Look for: growth (forward Euler: by "
                        "1 + (h w)² per step), decay (backward Euler and the damped implicit methods), and a bounded "
                        "oscillation around E₀ (symplectic and energy-conserving methods). An ✕ ends a run that diverged.",
    "energy_drift_vs_dt": "The largest relative energy change over each run against dt (log-log). Look for the slope "
                          "(the drift shrinks like dt^p) and for methods at round-off (energy-conserving on this problem).",
    "stability_map": "Integrators × dt, coloured by the largest energy growth in decades (blue: lost, red: gained). "
                     "The black bar in a row is the predicted stability limit dt = (h w)*/w from the amplification matrix: "
                     "cells right of it should be red or diverged (✕), cells left of it not.",
    "newton_iterations_vs_dt": "Mean (solid) and largest (dotted) Newton iterations per step of the implicit methods. "
                               "Look for the growth with dt: larger steps start Newton farther from the solution.",
    "orbits": "Trajectories of circular motion against the exact circle. Look for forward Euler spiralling out, "
              "backward Euler spiralling in, and symplectic Euler staying on a (slightly deformed) closed orbit.",
    "artificial_damping": "d_method/w = −2 ln ρ/(h w) against h w (Ascher's damping curves). Lines: predicted from the "
                          "probed amplification matrix of each method; markers: measured from each run's energy decay "
                          "(hollow where the run is too short to resolve it). Look for markers on their lines, backward "
                          "Euler's damping ~ h w at small steps (peak near h w = 2), second-order methods damping only at "
                          "large h w, and the generalized-α and θ families ordered by their parameter.",
    "spectral_radius_and_period": "Top: the spectral radius ρ(h w); ρ < 1 damps, ρ > 1 grows (a hollow circle marks a "
                                  "stability limit). Bottom: the relative period error T_h/T − 1 of the principal "
                                  "eigenvalue (up to h w = π), with the periods measured from the runs' zero crossings. "
                                  "Look for methods with ρ = 1 that still lag in phase (implicit midpoint).",
    "convergence": "The error at the end time against dt (log-log), with the least-squares slope over the smallest "
                   "time steps (dashed) in the legend. Look for slopes equal to each method's order; runs at "
                   "round-off are exact on this problem, saturated ones (error ~ amplitude) are left out of the fit.",
    "work_precision": "The same error against the wall time of each run. Lower left is better: a higher-order or "
                      "cheaper method reaches a given accuracy sooner.",
    "wall_time_per_step_vs_dt": "Wall time per step against dt, per integrator (and per group, e.g. per solver). Look "
                                "for implicit methods getting dearer at large dt (more Newton iterations).",
    "energy_budget": "Where the energy goes, at one time step: kinetic and potential energy (each potential term), the "
                     "work done by the physical damping, stacked; the grey gap up to the initial energy (dashed) is the "
                     "integrator's own numerical dissipation, an orange band above it a numerical gain. With damping 0 "
                     "the gap is all of the drift; with damping it separates the model's loss from the method's.",
}
CLOTH_CAPTION = "The cloth at four times of the run (from its stored frames)."

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


def write_report(path: Path, output: Path, reference: str | None = "dop853", say=None) -> Path:
    """Write the report of the results file at path into output (an .html file); returns output."""
    import h5py
    import matplotlib.pyplot as plt

    from simrun import plots

    results = plots.load_results(path)
    with h5py.File(path, "r") as file:
        provenance = {key: _attr_text(value) for key, value in file.attrs.items()}
    errors = {}
    reference_note = ""
    if reference and str(reference).lower() != "none" and any(run.system == "cloth" for run in results.runs):
        errors = reference_errors(path, results, reference, say=say)
        reference_note = (f"Cloth runs have no exact solution: their errors are measured against "
                          f"{'run ' + reference if reference in {run.run_id for run in results.runs} else 'scipy solve_ivp (' + str(reference).upper() + ', rtol 1e-10)'} "
                          f"on the system rebuilt from its stored parameters ({len(errors)} runs).")
    elif any(run.system == "cloth" for run in results.runs):
        reference_note = "Cloth runs have no exact solution and no reference was asked for (--reference none): no convergence for them."
    if errors:
        results = plots.with_reference_errors(results, errors)

    rows = summary_rows(results)
    sections = [
        ("summary", "Runs", _summary_section(rows)),
        ("orders", "Observed order of convergence", _orders_section(order_rows(results), reference_note)),
        ("stability", "Stability limits: predicted and observed", _stability_section(stability_rows(results))),
        ("determinants", "Determinant of the one-step map (mass on a spring)", _determinant_section(determinant_rows(results))),
    ]
    figures = []
    for name, figure in plots.render_figures(path, errors or None):
        try:
            figures.append((name, _png_data(figure), FIGURE_CAPTIONS.get(name, "")))
        finally:
            plt.close(figure)
    if any(run.system == "cloth" for run in results.runs):
        from simrun.cloth_figures import draw_cloth_snapshots

        with tempfile.TemporaryDirectory() as folder, h5py.File(path, "r") as file:
            for image in draw_cloth_snapshots(file, Path(folder)):
                if image.suffix == ".png":
                    figures.append((image.stem, base64.b64encode(image.read_bytes()).decode("ascii"), CLOTH_CAPTION))
    sections.append(("figures", "Figures", _figures_section(figures)))
    sections.append(("provenance", "Provenance and config", _provenance_section(provenance, path)))
    page = _page(results, provenance, sections)
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(page, encoding="utf-8")
    return output


def _attr_text(value) -> str:
    if isinstance(value, bytes):
        return value.decode()
    if hasattr(value, "item"):
        value = value.item()
    return str(value)


def _png_data(figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=REPORT_DPI)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _page(results, provenance: dict, sections: list[tuple[str, str, str]]) -> str:
    counts: dict[str, int] = {}
    for run in results.runs:
        counts[run.status] = counts.get(run.status, 0) + 1
    status_text = ", ".join(f"{count} {status}" for status, count in sorted(counts.items())) or "no runs"
    created = provenance.get("created", "")
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    navigation = "".join(f'<li><a href="#{key}">{_e(title)}</a></li>' for key, title, _ in sections)
    body = "".join(f'<section id="{key}"><h2>{_e(title)}</h2>{content}</section>' for key, title, content in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>simrun report: {_e(results.name)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{_e(results.name)}</h1>"
        f"<p class=\"subtitle\">{len(results.runs)} runs ({_e(status_text)}) · {len(results.labels)} integrators · "
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
        measured = _damping(row.measured_damping)
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
            f"{row.dt:.4g}", "–" if not np.isfinite(row.h_w) else f"{row.h_w:.3g}", _status(row.status), str(row.steps),
            str(row.order), _number(row.max_rel_energy_drift), _number(row.final_rel_energy_drift), _number(row.final_error),
            f"{row.mean_newton_iterations:.2f}", _number(row.mean_linear_iterations), f"{row.wall_time:.3g}",
            measured, _damping(row.predicted_damping), difference_text]
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
        if math.isinf(row.limit_x):
            return "none"
        if row.limit_x == 0:
            return "0 (unstable at every h)"
        return f"{row.limit_x:.4g}"

    headings = ([("group", True)] if several else []) + [("integrator", True), ("limit h w", False), ("limit dt (s)", False),
                                                           ("largest dt that stayed bounded", False),
                                                           ("smallest dt that diverged", False), ("", True)]
    body = [([_e(row.group)] if several else []) + [_e(row.integrator), limit_text(row),
            "∞" if math.isinf(row.limit_dt) else f"{row.limit_dt:.4g}", _number(row.largest_ok_dt),
            _number(row.smallest_diverged_dt), _verdict(row.verdict)] for row in rows]
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


# Why a figure may be missing from a file's report.
FIGURE_REQUIREMENTS = {
    "newton_iterations_vs_dt": "implicit methods only",
    "orbits": "circular motion only",
    "artificial_damping": "runs on the undamped test equation only (spring without damping, linear circular motion)",
    "spectral_radius_and_period": "runs on the undamped test equation only",
    "convergence": "runs with an exact solution, or a reference (cloth: --reference)",
    "work_precision": "runs with an exact solution, or a reference (cloth: --reference)",
}


def _figures_section(figures: list[tuple[str, str, str]]) -> str:
    from simrun import plots

    if not figures:
        return '<p class="note">The file holds no run with data to draw.</p>'
    drawn = {name for name, _, _ in figures}
    missing = [f"{name.replace('_', ' ')} ({FIGURE_REQUIREMENTS.get(name, 'no data for it')})"
               for name in plots.FIGURES if name not in drawn]
    parts = [f'<p class="note">Not drawn for this file: {_e("; ".join(missing))}.</p>'] if missing else []
    for name, data, caption in figures:
        title = name.replace("_", " ")
        parts.append(f'<figure id="figure-{_e(name)}"><img alt="{_e(title)}" src="data:image/png;base64,{data}">'
                     f"<figcaption><b>{_e(title)}.</b> {_e(caption)}</figcaption></figure>")
    return "".join(parts)


def _provenance_section(provenance: dict, path: Path) -> str:
    versions = provenance.pop("package_versions", "{}")
    config = provenance.pop("config", "")
    try:
        versions = ", ".join(f"{name} {version}" for name, version in json.loads(versions).items())
    except (ValueError, AttributeError):
        pass
    items = [("results file", str(path))] + [(key.replace("_", " "), value) for key, value in provenance.items()]
    items.append(("package versions", versions))
    listing = "".join(f"<dt>{_e(key)}</dt><dd>{_e(value)}</dd>" for key, value in items)
    return f"<dl>{listing}</dl><h3>Config (after --set overrides)</h3><pre>{_e(config)}</pre>"
