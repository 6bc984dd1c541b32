"""The tables of a results file: one summary row per run, observed orders, stability limits, determinants.

``simrun show`` prints the summary (or writes it as CSV); the report renders every table as HTML. Rows
are computed from the file alone (``simrun.analysis.runs.run_set``) and from ``simrun.analysis.oscillator``
(amplification matrices of the integrators named in the file).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from simrun.format.record import run_attribute
from simrun.analysis import oscillator as analysis
from simrun.analysis.runs import (SOLVER_ITERATION_NAMES, RunSet, predictions_for, solver_text,
                                  test_equation_runs)
from simrun.format.summary import SUMMARY_COLUMNS, Status

# Observed and declared order agree when they differ by at most this (the tests' tolerance).
ORDER_TOLERANCE = 0.15
# Measured and predicted damping agree when they differ by at most this fraction (or are both round-off).
DAMPING_TOLERANCE = 0.02
# A determinant matches its closed form to this relative accuracy (round-off of the probe).
DETERMINANT_TOLERANCE = 1e-12
# |d/w| below this is round-off of a method without artificial damping (rho = 1 to the last bits).
ROUND_OFF_DAMPING = 1e-12
# A predicted |d/w| below this is no damping: a measured rate is compared with it absolutely, not relatively.
ZERO_DAMPING = 1e-9
# Without a closed form to check, determinant rows are listed only up to this many.
MAX_DETERMINANT_ROWS = 60



@dataclass
class SummaryRow:
    """One run as the summary table shows it."""

    index: int
    run_id: str
    integrator: str  # the label
    group: str
    solver: str  # the solver type of an implicit method, "+" its fallbacks ("" for explicit methods: they solve nothing)
    dt: float  # s (a step-controlled run: its mean step)
    hw: float  # dt w on the test equation, else NaN
    status: str
    steps: int
    order: int  # the method's order of accuracy with these parameters
    energy_reference: float  # J: E_ref, what the drifts are relative to
    energy_reference_name: str  # what E_ref is, e.g. "E0 (initial energy)"
    max_rel_energy_drift: float  # max |E - E0| / E_ref
    final_rel_energy_drift: float  # (E_end - E0) / E_ref
    max_rel_energy_remainder: float  # the integrator's share: max |E + E_dissipated - W - E0| / E_ref
    final_rel_dissipated_energy: float  # what damping and friction took out by the end, over E_ref
    error_time: float  # s, when `error` was measured (NaN: the run stopped before it)
    error: float  # m, distance from the exact solution (or the reference) at error_time
    error_from_reference: bool  # error against a reference solution, not an exact one
    final_error: float  # m, max |x - x_exact| at the last sample (NaN without an exact solution)
    mean_newton_iterations: float  # the solver's iterations per step (Newton, L-BFGS, ... per `solver`)
    mean_linear_iterations: float
    wall_time: float  # s
    measured_damping: float  # d_method / w from the energy decay (NaN where not measured)
    measured_resolved: bool
    predicted_damping: float  # d_method / w from the amplification matrix at this h w
    real_time_factor: float = math.nan  # steps dt / wall_time: > 1 faster than real time
    wall_time_per_frame: float = math.nan  # s of wall time per FRAME_TIME (1/60 s) of simulated time
    not_converged_steps: int = 0  # steps whose solver used up max_iterations or its time budget (accepted ones too)
    accepted: bool = False  # solver.on_not_converged is accept: such steps leave the run ok
    first_not_converged_step: int = 0  # 1-based; 0: none (or not recorded, files before it)
    diverged_step: int = 0  # 1-based step at which the energy left the bound; 0: none (or not recorded)
    t_diverged: float = math.nan  # s, when the energy left the bound
    safeguard_steps: int = 0  # steps where any of the solver's safeguards fired (solvers.newton.SAFEGUARDS)
    min_contact_distance: float = math.nan  # m, the smallest signed contact distance over the steps (< 0: penetration)
    max_active_contacts: int = 0  # the most contacts acting in one step
    friction_work: float = math.nan  # J, the energy friction took out over the run (NaN: no contact)
    message: str = ""  # why the run is not ok (the run's attribute)
    tolerance: float = math.nan  # a step-controlled run's tolerance (NaN: fixed steps of dt)
    # the other error norms: against the exact solution (NaN without one, and in files before them) ...
    final_velocity_error: float = math.nan  # m/s, max |v - v_exact| at the last sample
    max_error: float = math.nan  # m, max |x - x_exact| over the stored samples
    max_velocity_error: float = math.nan  # m/s, max |v - v_exact| over the stored samples
    # ... and against a reference: m/s, max |v - v_ref| at error_time (NaN: no reference, or no velocities stored there)
    velocity_error: float = math.nan
    period_error: float = math.nan  # T_h / T - 1 from the zero crossings of a test-equation run (NaN: not measured)
    # the swept keys and method parameters this run reads, by column name (simrun.results.parameters); None: not read
    parameters: dict = field(default_factory=dict)

    @property
    def status_detail(self) -> str:
        """Where the run went wrong, in a few words: "at step 37" (diverged), "from step 3, 12/200 steps"
        (not converged), "12/200 steps accepted" (ok under on_not_converged: accept); "" otherwise."""
        parts = []
        if self.status == Status.DIVERGED:
            if self.diverged_step:
                parts.append(f"at step {self.diverged_step}")
            elif np.isfinite(self.t_diverged):
                parts.append(f"at t = {self.t_diverged:.4g} s")
        if self.not_converged_steps:
            counted = f"{self.not_converged_steps}/{self.steps} steps"
            if self.status == Status.OK:
                parts.append(f"{counted} accepted")
            elif self.first_not_converged_step:
                parts.append(("not converged " if self.status == Status.DIVERGED else "")
                             + f"from step {self.first_not_converged_step}, {counted}")
            else:
                parts.append(("not converged: " if self.status == Status.DIVERGED else "") + counted)
        return "; ".join(parts)

    @property
    def damping_difference(self) -> float:
        """(measured - predicted) / |predicted|; where the prediction is no damping (|d/w| below
        ZERO_DAMPING), there is nothing to be relative to: then measured - predicted (in units of w)."""
        if not (np.isfinite(self.measured_damping) and np.isfinite(self.predicted_damping)):
            return math.nan
        if abs(self.predicted_damping) < ZERO_DAMPING:
            return self.measured_damping - self.predicted_damping
        return (self.measured_damping - self.predicted_damping) / abs(self.predicted_damping)

    @property
    def damping_relative(self) -> bool:
        """damping_difference is relative (False: absolute, the prediction being no damping)."""
        return abs(self.predicted_damping) >= ZERO_DAMPING

    @property
    def damping_agrees(self) -> bool | None:
        """Measured and predicted damping agree (within DAMPING_TOLERANCE relative, or, where no damping is
        predicted, within the resolution of a fit, analysis.RESOLVED_ABSOLUTE_ERROR); None when not both known."""
        difference = self.damping_difference
        if not np.isfinite(difference):
            return None if math.isnan(difference) else False
        tolerance = DAMPING_TOLERANCE if self.damping_relative else analysis.RESOLVED_ABSOLUTE_ERROR
        return abs(difference) <= tolerance


def summary_rows(data: RunSet) -> list[SummaryRow]:
    """One row per run, in sweep order; drift and iterations from the file's summary table."""
    summary = data.results.summary
    parameter_names = [name for name in summary.columns if name not in SUMMARY_COLUMNS]
    stored = summary.set_index("run_id").to_dict("index")
    titles = {id(member): title for title, members in data.groups for member in members}
    velocity_errors = data.reference.velocity_errors if data.reference is not None else {}
    rows = []
    for run in data.runs:
        row = stored[run.run_id]
        fit = run.damping_fit
        measured = fit.rate / run.frequency if fit is not None and np.isfinite(fit.rate) else math.nan
        predicted = math.nan
        if run.frequency is not None and run.method is not None:
            predicted = _predicted_damping(run.method, run.hw)
        error, error_time, from_reference = run.error, run.error_time, run.error_from_reference
        attrs = run.stored.attrs
        rows.append(SummaryRow(
            index=run.index, run_id=run.run_id, integrator=run.label, group=titles.get(id(run), ""),
            solver="" if run.explicit else solver_text(run.stored.solver),
            dt=run.dt, hw=run.hw, status=str(run.status), steps=run.steps,
            order=run.method.order_of_accuracy if run.method is not None else run.order,
            energy_reference=_energy_reference(run.stored)[0], energy_reference_name=_energy_reference(run.stored)[1],
            max_rel_energy_drift=float(row["max_rel_energy_drift"]),
            final_rel_energy_drift=float(row["final_rel_energy_drift"]),
            max_rel_energy_remainder=float(row["max_rel_energy_remainder"]),
            final_rel_dissipated_energy=float(row["final_rel_dissipated_energy"]),
            error_time=error_time, error=error, error_from_reference=from_reference,
            final_error=run.stored.final_error,
            mean_newton_iterations=float(row["mean_newton_iterations"]),
            mean_linear_iterations=float(row["mean_linear_iterations"]),
            wall_time=run.wall_time,
            measured_damping=measured, measured_resolved=bool(fit is not None and fit.resolved),
            predicted_damping=predicted,
            real_time_factor=float(row["real_time_factor"]), wall_time_per_frame=float(row["wall_time_per_frame"]),
            not_converged_steps=int(run_attribute(attrs, "not_converged_steps")),
            accepted=run.stored.solver.get("on_not_converged") == "accept" and not run.explicit,
            first_not_converged_step=int(run_attribute(attrs, "first_not_converged_step")),
            diverged_step=int(run_attribute(attrs, "diverged_step")), t_diverged=float(run_attribute(attrs, "t_diverged")),
            safeguard_steps=int(run_attribute(attrs, "safeguard_steps")),
            min_contact_distance=float(run_attribute(attrs, "min_contact_distance")),
            max_active_contacts=int(run_attribute(attrs, "max_active_contacts")),
            friction_work=float(run_attribute(attrs, "friction_work")), message=run.stored.message,
            tolerance=run.tolerance, final_velocity_error=float(row["final_velocity_error"]),
            max_error=float(row["max_error"]), max_velocity_error=float(row["max_velocity_error"]),
            velocity_error=velocity_errors.get(run.run_id, math.nan), period_error=run.period_error,
            parameters={name: _cell(row[name]) for name in parameter_names},
        ))
    return rows


def _cell(value):
    """A parameter cell as Python: None where the run does not read the key (pandas' NA, or NaN)."""
    import pandas

    if isinstance(value, (str, tuple)):
        return value
    if value is None or pandas.isna(value):
        return None
    return value.item() if isinstance(value, np.generic) else value


def parameter_names(rows: list[SummaryRow]) -> list[str]:
    """The parameter columns of these rows, in the summary's order."""
    return list(dict.fromkeys(name for row in rows for name in row.parameters))


def varied_parameters(rows: list[SummaryRow]) -> list[str]:
    """The parameter columns that tell some of these runs apart (more than one value, a missing one counted)."""
    return [name for name in parameter_names(rows) if len({repr(row.parameters.get(name)) for row in rows}) > 1]


def _energy_reference(stored) -> tuple[float, str]:
    """(E_ref (J), its name) of a stored run; a reader without ``energy_reference`` (older simrun) has energy_scale."""
    if hasattr(stored, "energy_reference_name"):
        return float(stored.energy_reference), str(stored.energy_reference_name)
    return float(stored.energy_scale), str(run_attribute(stored.attrs, "energy_reference_name"))


def _predicted_damping(method, hw: float) -> float:
    return analysis.probed_damping(method, hw)[1]


# -- what the columns are called --------------------------------------------------------------------

def _iteration_kinds(rows: list[SummaryRow]) -> set[str]:
    return {SOLVER_ITERATION_NAMES.get(kind, kind) for row in rows for kind in row.solver.split("+") if kind}


def iteration_name(rows: list[SummaryRow]) -> str:
    """What the solver iterations of these rows count: "Newton", "L-BFGS", ... when every implicit run uses
    solvers of one kind (fallbacks included), "solver" when they mix (a solver column then tells them apart)."""
    kinds = _iteration_kinds(rows)
    return kinds.pop() if len(kinds) == 1 else "solver"


def mixed_solvers(rows: list[SummaryRow]) -> bool:
    return len(_iteration_kinds(rows)) > 1


def any_safeguards(rows: list[SummaryRow]) -> bool:
    """Some run had a step where a solver safeguard fired: the safeguards column is shown."""
    return any(row.safeguard_steps for row in rows)


def any_not_converged(rows: list[SummaryRow]) -> bool:
    """Some run had a step that used up max_iterations (accepted or not): the not-converged column is shown."""
    return any(row.not_converged_steps for row in rows)


def steps_text(count: int, row: SummaryRow) -> str:
    """"12/200": steps of the run's steps taken; "" for none."""
    return f"{count}/{row.steps}" if count else ""


def energy_reference_text(rows: list[SummaryRow]) -> str:
    """"E_ref = E0 (initial energy) = 50 J" when the runs share it; otherwise what it is and its range."""
    names = sorted({row.energy_reference_name for row in rows})
    values = [row.energy_reference for row in rows if np.isfinite(row.energy_reference)]
    name = names[0] if len(names) == 1 else " or ".join(names)
    if not values:
        return f"E_ref = {name}"
    low, high = min(values), max(values)
    if math.isclose(low, high, rel_tol=1e-12):
        return f"E_ref = {name} = {low:.4g} J"
    return f"E_ref = {name}, {low:.4g} to {high:.4g} J (per run: E_ref column)"


def error_time_text(rows: list[SummaryRow]) -> str:
    """When the errors were measured: "t = 1.34 s" or "t = 1.25 to 1.35 s" (the step nearest record.error_time)."""
    times = [row.error_time for row in rows if np.isfinite(row.error) and np.isfinite(row.error_time)]
    if not times:
        return ""
    low, high = min(times), max(times)
    return f"t = {low:.4g} s" if math.isclose(low, high, rel_tol=1e-9) else f"t = {low:.4g} to {high:.4g} s"


def remainder_differs(rows: list[SummaryRow]) -> bool:
    """Some run's energy left or entered physically (damping, friction, prescribed work): its drift |E - E0| is not the
    integrator's remainder of the budget, and the two are shown apart."""
    return any(np.isfinite(row.max_rel_energy_remainder) and np.isfinite(row.max_rel_energy_drift)
               and not math.isclose(row.max_rel_energy_remainder, row.max_rel_energy_drift, rel_tol=1e-9, abs_tol=1e-300)
               for row in rows)


def any_dissipated(rows: list[SummaryRow]) -> bool:
    return any(np.isfinite(row.final_rel_dissipated_energy) and row.final_rel_dissipated_energy != 0 for row in rows)


def energy_reference_differs(rows: list[SummaryRow]) -> bool:
    values = [row.energy_reference for row in rows if np.isfinite(row.energy_reference)]
    return bool(values) and not math.isclose(min(values), max(values), rel_tol=1e-12)


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
    reason: str = ""  # why there is no slope (analysis.OrderFit.reason)
    error_time: str = ""  # when the errors were measured, e.g. "t = 1.34 s"

    @property
    def verdict(self) -> str:
        if self.exact:
            return "exact (errors at round-off)"
        if not np.isfinite(self.observed):
            return self.reason or "not enough asymptotic points"
        return "agrees" if abs(self.observed - self.declared) <= ORDER_TOLERANCE else "differs"


def error_runs(data: RunSet) -> list:
    """Runs that reached their end with a known error at their error time (exact, or against a reference)."""
    return [run for run in data.runs if not run.status.stopped and np.isfinite(run.error)]


def order_fits(data: RunSet) -> dict[tuple[str, str], tuple["analysis.OrderFit", list]]:
    """(group title, label) -> (observed order fit of the errors at the error time, runs sorted by dt). Step-controlled
    runs have none: against their mean step the error falls at the estimate's order, not the method's."""
    fits = {}
    usable = {id(run) for run in error_runs(data) if not math.isfinite(run.tolerance)}
    for title, runs in data.groups:
        for label in data.labels:
            mine = sorted((run for run in runs if run.label == label and id(run) in usable), key=lambda run: run.dt)
            if mine:
                fit = analysis.observed_order([run.dt for run in mine], [run.error for run in mine],
                                              scale=mine[0].length_scale)
                fits[(title, label)] = (fit, mine)
    return fits


def order_rows(data) -> list[OrderRow]:
    rows = []
    for (title, label), (fit, runs) in order_fits(data).items():
        method = runs[0].method
        declared = method.order_of_accuracy if method is not None else runs[0].order
        used = [run.dt for run, flag in zip(runs, fit.used) if flag]
        span = (f"{used[0]:.3g} s (1 dt)" if len(used) == 1 else
                f"{min(used):.3g} – {max(used):.3g} s ({len(used)} dts)" if used else "–")
        times = [run.error_time for run in runs]
        times = [time for time in times if np.isfinite(time)]
        when = ""
        if times:
            low, high = min(times), max(times)
            when = f"t = {low:.4g} s" if math.isclose(low, high, rel_tol=1e-9) else f"t = {low:.4g} to {high:.4g} s"
        rows.append(OrderRow(title, label, declared, fit.order, span, fit.exact, fit.reason, when))
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


def determinant_rows(data: RunSet) -> list[DeterminantRow]:
    """det of the probed one-step map for each (group, label, dt) of the runs with one degree of freedom
    (the mass on a spring), against the lectures' closed forms where the run is the undamped test equation."""
    candidates = []  # (group, run, formula, closed form), probed below: a map has 10^4 of them
    for title, runs in data.groups:
        seen = set()
        for run in runs:
            if run.stored.dof_count != 1 or (run.label, run.dt) in seen or run.method is None:
                continue
            seen.add((run.label, run.dt))
            formula, closed = "", math.nan
            if run.integrator in LECTURE_DETERMINANTS and run.frequency is not None:
                formula, form = LECTURE_DETERMINANTS[run.integrator]
                closed = form(run.hw ** 2)
            candidates.append((title, run, formula, closed))
    if len(candidates) > MAX_DETERMINANT_ROWS:  # the rows the lectures' closed forms check, only
        candidates = [candidate for candidate in candidates if np.isfinite(candidate[3])]
    rows = []
    for title, run, formula, closed in candidates:
        params = run.stored.system_params
        system = analysis.build_system(run.stored.system, params)
        rows.append(DeterminantRow(title, run.label, run.dt, float(params.get("stiffness", math.nan)),
                                   float(params.get("mass", math.nan)),
                                   analysis.determinant(run.method, run.dt, system), formula, closed))
    return rows
