"""What a method costs against a converged solve: the findings of sweeps of solver.type.

At a dt that several methods share (per setting of the swept keys that are not a method's, such as
system.resolution), every run that reached its end is set beside the baseline, the fastest run of an
implicit integrator whose every step converged (a Newton solve when there is one). Compared are the
implicit runs with any solver and the explicit ones (XPBD, symplectic Euler, ...): each one's wall time
per 1/60 s frame, its real-time factor, its error (or, without errors, its energy change), and its
distance max |x - x_ref| from the baseline's positions at the error time (dataset ``error_positions``).
The distance tells a method's own departure from what a converged implicit step at this dt gives.

One finding leads (what is measured, the baseline, and how much faster the fastest method is), then one
short finding per method, fastest first, so that the report lists them one per line.
"""

from __future__ import annotations

import json
import math

import numpy as np

from simrun.analysis.rows import SummaryRow, energy_reference_text, error_time_text
from simrun.analysis.runs import solver_text
from simrun.analysis.units import real_time_text
from simrun.experiment.sweep import LINEAR_SOLVER_KEYS
from simrun.findings.base import WALL_TIME_NOISE, Finding, _and, drift_text
from simrun.format.summary import FRAME_TIME, Status

# The baseline is a converged solve of one of these when there is one (what a real-time method is asked to
# match); any solver that converged every step gives the same positions within its tolerance.
BASELINE_SOLVERS = ("newton", "projected_newton")


def solver_cost(data, rows: list[SummaryRow]) -> list[Finding]:
    """Where the sweep varies solver.type: at the largest and the smallest dt that two methods, one of them implicit,
    share (per setting of the swept keys but the solver's), every method beside the baseline (module docstring).

    A method is an explicit integrator, or an implicit one with its solver: the solver's type (with fallbacks)
    and its other swept keys but the linear solver's. Of the runs that differ only in those (solver.linear_solver,
    ...), the fastest of those that converged best stands for the method, named with them."""
    if len({run.stored.params["solver.type"] for run in data.runs if "solver.type" in run.stored.params}) < 2:
        return []
    by_id = {row.run_id: row for row in rows}
    problems: dict[str, list] = {}
    for run in data.runs:
        setting = {key: value for key, value in run.stored.swept.items() if not key.startswith("solver.")}
        problems.setdefault(json.dumps(setting, sort_keys=True, default=str), []).append(run)
    several = len(problems) > 1
    comparisons = []
    for setting, runs in problems.items():
        shared = sorted((dt for dt in {run.dt for run in runs} if sum(run.dt == dt for run in runs) >= 2
                         and any(run.dt == dt and not run.explicit for run in runs)), reverse=True)
        for dt in dict.fromkeys(shared[:1] + shared[-1:]):
            mine = [run for run in runs if run.dt == dt]
            comparisons.append((json.loads(setting), dt, [by_id[run.run_id] for run in mine], {run.run_id: run for run in mine}))
    result = []
    for setting, dt, at, runs in comparisons:
        result += _methods_at(setting if several else {}, dt, at, runs, len(comparisons) > 1)
    return result


def _method_name(run, one_label: bool) -> tuple[str, list[str]]:
    """(the method as the findings name it, the linear-solver settings of its run): an explicit run's label; an
    implicit run's solver, e.g. "vbd (max_iterations = 5)", after its label unless every implicit run shares one."""
    if run.explicit:
        return run.label, []
    params = run.stored.params
    others = [f"{key.removeprefix('solver.')} = {params[key]}" for key in params
              if key.startswith("solver.") and key != "solver.type" and key not in LINEAR_SOLVER_KEYS]
    linear = [str(params[key]) for key in params if key in LINEAR_SOLVER_KEYS]
    name = (solver_text(run.stored.solver) or str(params.get("solver.type", ""))) + (f" ({', '.join(others)})" if others else "")
    return (name if one_label else f"{run.label} with {name}"), linear


def _trust(row: SummaryRow) -> int:
    """0: every step converged, 1: ok with accepted steps, 2: not converged."""
    return 0 if row.status == Status.OK and not row.not_converged_steps else 1 if row.status == Status.OK else 2


def _methods_at(setting: dict, dt: float, at: list[SummaryRow], runs: dict, prefixed: bool) -> list[Finding]:
    """The findings at one dt (and setting): none when fewer than two methods ran to their end. ``prefixed``: the
    file compares at several dts or settings, so that each method's finding says where."""
    implicit_labels = {runs[row.run_id].label for row in at if not runs[row.run_id].explicit}
    one_label = len(implicit_labels) == 1
    variants: dict[str, list[SummaryRow]] = {}
    stopped: dict[str, list[str]] = {}
    for row in at:
        name, _ = _method_name(runs[row.run_id], one_label)
        if Status(row.status).stopped or not np.isfinite(row.wall_time_per_frame):
            stopped.setdefault(str(row.status), []).append(name)
        else:
            variants.setdefault(name, []).append(row)
    if len(variants) < 2:
        return []
    chosen = {name: min(members, key=lambda row: (_trust(row), row.wall_time_per_frame)) for name, members in variants.items()}
    order = sorted(chosen, key=lambda name: chosen[name].wall_time_per_frame)
    by_error = all(np.isfinite(row.error) for row in chosen.values())
    measure = {name: (row.error if by_error else row.max_rel_energy_drift) for name, row in chosen.items()}
    converged = [name for name in order if not runs[chosen[name].run_id].explicit and _trust(chosen[name]) == 0]
    preferred = [name for name in converged if runs[chosen[name].run_id].stored.solver.get("type") in BASELINE_SOLVERS]
    baseline = (preferred or converged or [None])[0]
    reference = runs[chosen[baseline].run_id] if baseline else None
    deviation = {name: _deviation(runs[chosen[name].run_id], reference) if reference else math.nan for name in order}
    scale = reference.length_scale if reference else math.nan

    def numbers(name: str) -> str:
        row = chosen[name]
        told = measure[name]
        text = (f"{1e3 * row.wall_time_per_frame:.3g} ms per frame ({real_time_text(row.real_time_factor)} real time), "
                + (f"error {told:.2g} m" if by_error else f"max drift {drift_text(told)}"))
        if name != baseline and np.isfinite(deviation[name]):
            text += f", {deviation[name]:.2g} m ({100 * deviation[name] / scale:.2g} % of the length scale) from {baseline}"
        return text

    def notes(name: str) -> str:
        row, told = chosen[name], []
        if len(variants[name]) > 1:
            _, linear = _method_name(runs[row.run_id], one_label)
            told.append(f"with {', '.join(linear)}, the fastest of {len(variants[name])}"
                        + (" that converged" if _trust(row) == 0 and any(_trust(other) for other in variants[name]) else ""))
        if row.not_converged_steps:
            budget = runs[row.run_id].stored.solver.get("time_budget")
            limit = f"its time budget of {1e3 * budget:.3g} ms" if budget else "max_iterations"
            told.append(f"{row.not_converged_steps}/{row.steps} steps at {limit}"
                        + (", accepted" if row.status == Status.OK else ""))
        return "".join(f"; {note}" for note in told)

    where = f"dt = {dt:g} s" + "".join(f", {key} = {value}" for key, value in setting.items())
    against = "a reference" if any(row.error_from_reference for row in chosen.values()) else "the exact solution"
    what = (f"the error at {error_time_text(list(chosen.values()))} against {against}" if by_error else
            f"the energy change max |E − E0| / E_ref, {energy_reference_text(list(chosen.values()))}")
    fastest = order[0]
    if reference is not None:
        when = reference.stored.error_time
        what += (f", the distance max |x − x_ref| from the positions of {baseline} at "
                 f"{f't = {when:.4g} s' if np.isfinite(when) else 'the error time'}")
        head = (f"Cost at {where} against {baseline}, the fastest {'Newton' if preferred else 'implicit'} run whose "
                "every step converged")
        lead = f"{baseline} takes {numbers(baseline)}{notes(baseline)}"
        if fastest != baseline:
            speed = chosen[baseline].wall_time_per_frame / chosen[fastest].wall_time_per_frame
            pace = f"as fast (within {100 * WALL_TIME_NOISE:g} %)" if speed <= 1 + WALL_TIME_NOISE else f"{speed:.2g}x faster"
            lead += f"; the fastest, {fastest}, is {pace}"
            if np.isfinite(deviation[fastest]):
                lead += f", at {deviation[fastest]:.2g} m ({100 * deviation[fastest] / scale:.2g} % of the length scale {scale:g} m)"
    else:
        head = f"Cost at {where}: no implicit run converged at every step: no distance from a converged solve"
        lead = f"the fastest is {fastest}"
    for status, names in stopped.items():
        lead += f"; {_and(names)} {status.replace('_', ' ')}"
    solved = (f"; a solver's name stands for {next(iter(implicit_labels))} solved by it"
              if one_label and any(not runs[row.run_id].explicit for row in chosen.values()) else "")
    evidence = {"setting": setting, "dt": dt, "measure": "error" if by_error else "max_rel_energy_drift",
                "methods": {name: {"run_id": chosen[name].run_id, "integrator": chosen[name].integrator,
                                   "explicit": runs[chosen[name].run_id].explicit,
                                   "wall_time_per_frame": chosen[name].wall_time_per_frame,
                                   "real_time_factor": chosen[name].real_time_factor, "measure": measure[name],
                                   "deviation": deviation[name]} for name in order},
                "fastest": fastest, "baseline": baseline, "stopped": stopped}
    if reference is not None and fastest != baseline:
        evidence["speedup"] = chosen[baseline].wall_time_per_frame / chosen[fastest].wall_time_per_frame
    result = [Finding(f"{head} (measured: wall time per frame of 1/{1 / FRAME_TIME:g} s, the real-time factor, {what}"
                      f"{solved}): {lead}.", "#summary", evidence, "cost")]
    prefix = f"At {where}, " if prefixed else ""
    for name in order:
        if name == baseline:
            continue
        result.append(Finding(f"{prefix}{name}: {numbers(name)}{notes(name)}.", "#summary",
                              {"setting": setting, "dt": dt, "method": name, "baseline": baseline, **evidence["methods"][name]},
                              "cost"))
    return result


def _deviation(run, baseline) -> float:
    """m: max |x - x_baseline| over the dofs at the error time (dataset ``error_positions``); NaN without it."""
    mine, theirs = run.stored.get("error_positions"), baseline.stored.get("error_positions")
    if mine is None or theirs is None or np.shape(mine) != np.shape(theirs):
        return math.nan
    return float(np.max(np.abs(np.asarray(mine, dtype=float) - np.asarray(theirs, dtype=float)), initial=0.0))


__all__ = ["BASELINE_SOLVERS", "solver_cost"]
