"""Two step-controlled methods at equal error: each one's costs read off its own work-precision curve at the errors
that both reach.

A sweep of ``step_control.tolerance`` gives each method one (error, cost) point per run. Runs at equal tolerance
compare what two error estimates make of one number, not what the methods cost: at one tolerance a method may land
ten times more accurate than another. At equal error the comparison is the methods'. Each method's log(cost) is
interpolated piecewise-linearly against log(error): a method of fixed order p in its asymptotic range follows the
power law cost = a error^(-1/p), a straight line there, so the interpolation is exact on it and close near it. Costs
are read only inside the range of errors that both methods' runs span, never extrapolated.

The costs are the run's wall time, accepted steps, Jacobian evaluations and LU factorisations (attributes
``accepted_steps``, ``jacobian_evaluations``, ``factorisations``); a count that some run of a method lacks (files
from before it was counted) is not compared.
"""

from __future__ import annotations

import dataclasses
import re
import math

import numpy as np

from simrun.format.record import run_attribute
from simrun.format.summary import Status

# The costs compared at equal error: name -> the run's value (NaN where the run did not count it).
COST_MEASURES = {
    "wall_time": lambda run: run.wall_time,
    "accepted_steps": lambda run: float(run_attribute(run.stored.attrs, "accepted_steps")),
    "jacobian_evaluations": lambda run: float(run_attribute(run.stored.attrs, "jacobian_evaluations")),
    "factorisations": lambda run: float(run_attribute(run.stored.attrs, "factorisations")),
}
# At most this many errors per comparison (the loosest decade, the tightest, one between): a sentence, not a table.
MAX_COMPARISON_ERRORS = 3


# -- the interpolation, on plain arrays ---------------------------------------------------------------
def cost_at_error(errors, costs, at) -> np.ndarray:
    """One method's cost at the errors ``at``, interpolated piecewise-linearly in log(cost) against log(error)
    between its runs' points; NaN outside the range of ``errors`` (no extrapolation).

    errors: (runs,) m, the runs' errors; costs: (runs,) the runs' costs (wall time s, or a count); at: (k,) m.
    Points with a non-finite or non-positive error or a non-finite cost are dropped; runs of one error share the
    geometric mean of their costs. Costs with a zero among them (a method that evaluated no Jacobian) are
    interpolated linearly in the cost, still against log(error): zero has no logarithm."""
    errors, costs = np.asarray(errors, dtype=float), np.asarray(costs, dtype=float)
    at = np.atleast_1d(np.asarray(at, dtype=float))
    keep = np.isfinite(errors) & (errors > 0) & np.isfinite(costs) & (costs >= 0)
    errors, costs = errors[keep], costs[keep]
    result = np.full(at.shape, np.nan)
    if not errors.size:
        return result
    logarithmic = bool(np.all(costs > 0))
    values = np.log(costs) if logarithmic else costs
    log_errors, where = np.unique(np.log(errors), return_inverse=True)
    mean_values = np.bincount(where, weights=values) / np.bincount(where)  # runs of one error: one point
    inside = (at > 0) & np.isfinite(at)
    log_at = np.log(at, where=inside, out=np.full(at.shape, np.nan))
    # a relative slack of round-off at the ends: an end of the overlap is one run's error, exp(log(e)) may miss it
    slack = 1e-12 * max(1.0, float(np.max(np.abs(log_errors))))
    inside &= (log_at >= log_errors[0] - slack) & (log_at <= log_errors[-1] + slack)
    read = np.interp(np.clip(log_at[inside], log_errors[0], log_errors[-1]), log_errors, mean_values)
    result[inside] = np.exp(read) if logarithmic else read
    return result


def error_overlap(first, second) -> tuple[float, float] | None:
    """(smallest, largest) m: the errors that both sets of runs span (each from its smallest to its largest finite
    positive error); None when the ranges do not meet."""
    ranges = []
    for errors in (first, second):
        errors = np.asarray(errors, dtype=float)
        errors = errors[np.isfinite(errors) & (errors > 0)]
        if not errors.size:
            return None
        ranges.append((float(errors.min()), float(errors.max())))
    low, high = max(low for low, _ in ranges), min(high for _, high in ranges)
    return (low, high) if low <= high else None


def comparison_errors(low: float, high: float, most: int = MAX_COMPARISON_ERRORS) -> list[float]:
    """m, largest first: the decades 10^k inside [low, high], at most ``most`` of them (the loosest, the tightest and
    ones between); the geometric midpoint where no decade lies inside."""
    # the slack: a decade that is an end of the range (one run's error exactly) stays inside it
    decades = [10.0 ** k for k in range(math.floor(math.log10(high) + 1e-9), math.ceil(math.log10(low) - 1e-9) - 1, -1)]
    decades = [error for error in decades if low * (1 - 1e-12) <= error <= high * (1 + 1e-12)]
    if not decades:
        return [math.sqrt(low * high)]
    if len(decades) > most:
        picks = np.unique(np.round(np.linspace(0, len(decades) - 1, most)).astype(int))
        decades = [decades[index] for index in picks]
    return decades


# -- the runs of a file ----------------------------------------------------------------------------
def left_out_reason(run) -> str:
    """Why a run has no point on its method's curve ("" for a run that has one): it did not end ok, or its error (or
    wall time) is unknown, or its error is exactly zero (no logarithm)."""
    if run.status is Status.OK:
        if not np.isfinite(run.error):
            return "no known error"
        if run.error <= 0:
            return "error exactly 0: no point on a log axis"
        return "" if run.wall_time > 0 else "no wall time"
    budget = re.search(r"record\.(max_wall_time|max_steps|max_solver_iterations)", run.stored.message)
    if budget is not None:
        return f"over {budget.group(0)}"
    return str(run.status).replace("_", " ")


@dataclasses.dataclass(frozen=True)
class EqualError:
    """Two methods' costs at the errors both reach (``errors``, m, largest first; empty when their ranges do not
    meet). ``costs[label][measure]``: (len(errors),) values, one per error; a measure is there for a method only where
    every run of it counted it. ``ranges``: label -> (smallest, largest) error of its runs; ``left_out``: label ->
    [(run, why)]."""

    labels: tuple[str, str]
    errors: list[float]
    costs: dict[str, dict[str, np.ndarray]]
    ranges: dict[str, tuple[float, float] | None]
    left_out: dict[str, list[tuple[object, str]]]
    overlap: tuple[float, float] | None
    floor: float = math.nan  # m: the reference's own accuracy, below which no error was compared (NaN: none)

    def ratio(self, measure: str, index: int) -> float:
        """The second method's cost over the first's at ``errors[index]`` (> 1: the first is cheaper); NaN where
        either did not count it."""
        if any(measure not in self.costs[label] for label in self.labels):
            return math.nan
        first, second = (self.costs[label][measure][index] for label in self.labels)
        return float(second / first) if first > 0 else math.nan


def equal_error(first: tuple[str, list], second: tuple[str, list], floor: float = math.nan) -> EqualError:
    """The costs of two methods, each (label, its runs), at the errors both reach: every decade inside the overlap of
    their error ranges (``comparison_errors``), above ``floor`` (m: a reference's own accuracy; below it the errors
    measure the reference). Runs without a point (``left_out_reason``) are left out and listed."""
    used, left_out, ranges = {}, {}, {}
    for label, runs in (first, second):
        used[label] = [run for run in runs if not left_out_reason(run)]
        left_out[label] = [(run, left_out_reason(run)) for run in runs if left_out_reason(run)]
        errors = [run.error for run in used[label]]
        ranges[label] = (min(errors), max(errors)) if errors else None
    labels = (first[0], second[0])
    overlap = error_overlap(*([run.error for run in used[label]] for label in labels))
    if overlap is not None and np.isfinite(floor):
        overlap = (max(overlap[0], floor), overlap[1]) if floor <= overlap[1] else None
    errors = comparison_errors(*overlap) if overlap is not None else []
    costs = {}
    for label in labels:
        errors_of = [run.error for run in used[label]]
        costs[label] = {name: cost_at_error(errors_of, [cost(run) for run in used[label]], errors)
                        for name, cost in COST_MEASURES.items()
                        if used[label] and all(np.isfinite(cost(run)) for run in used[label])}
    return EqualError(labels, errors, costs, ranges, left_out, overlap, floor)


__all__ = ["COST_MEASURES", "EqualError", "comparison_errors", "cost_at_error", "equal_error", "error_overlap",
           "left_out_reason"]
