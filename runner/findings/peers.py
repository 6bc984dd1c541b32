"""simrun's methods against scipy's on scipy's own ground: at equal error, what each one costs.

For every setting of the swept keys (each system, in ``work_precision.yaml``) that has step-controlled runs of a
simrun integrator and of its peer among ``solve_ivp``'s methods (``SCIPY_PEERS``), over a sweep of
``step_control.tolerance``: each method's wall time, accepted steps, Jacobian evaluations and factorisations at the
errors that both reach, interpolated on its own work-precision curve (``simrun.analysis.equal_error``), and their
ratios. Runs that did not end ok (diverged, not converged, over a budget such as ``record.max_steps``) or have no known error are
left out, and the finding names them. Error ranges that do not meet give no number, and the finding says so; a
setting where no run has a known error gives one "not measured" line.
"""

from __future__ import annotations

import math

import numpy as np

from simrun.analysis.equal_error import EqualError, equal_error
from simrun.analysis.rows import error_time_text
from simrun.findings.base import WALL_TIME_NOISE, Finding, _and
from simrun.format.summary import Status

# simrun's integrator -> the solve_ivp method that is its peer: the same method family, so that the comparison is
# between two implementations of one method (Radau IIA of order 5 with its own error estimate, both)
SCIPY_PEERS = {"radau_iia": "Radau"}
# how the counts are named in the sentences: measure -> (singular, plural)
COUNT_NAMES = {"accepted_steps": ("step", "steps"), "jacobian_evaluations": ("Jacobian", "Jacobians"),
               "factorisations": ("factorisation", "factorisations")}
# the ratios a sentence states after the wall time's: the costs a work-precision comparison weighs
STATED_RATIOS = {"accepted_steps": "steps", "jacobian_evaluations": "Jacobians"}


def peer_findings(data) -> list[Finding]:
    """One finding per setting and pair of simrun's method and its scipy peer (module docstring)."""
    result = []
    for title, runs in data.groups:
        controlled = [run for run in runs if math.isfinite(run.tolerance)]
        for ours, method in SCIPY_PEERS.items():
            mine = _by_label(run for run in controlled if run.integrator == ours)
            theirs = _by_label(run for run in controlled if run.integrator == "solve_ivp"
                               and run.integrator_params.get("method") == method)
            for our_label, our_runs in mine.items():
                for their_label, their_runs in theirs.items():
                    names = (f"simrun's {our_label}", f"scipy's {method}" + (f" ({their_label})" if len(theirs) > 1 else ""))
                    result.append(_finding(data, title, runs[0], (our_label, our_runs), (their_label, their_runs), names))
    return result


def _by_label(runs) -> dict[str, list]:
    found: dict[str, list] = {}
    for run in runs:
        found.setdefault(run.label, []).append(run)
    return found


def _finding(data, title: str, member, ours: tuple[str, list], theirs: tuple[str, list], names: tuple[str, str]) -> Finding:
    where = _where(title, member)
    runs = ours[1] + theirs[1]
    evidence = {"group": title, "ours": ours[0], "theirs": theirs[0]}
    ended = [run for run in runs if run.status is Status.OK]
    if ended and not any(np.isfinite(run.error) for run in ended):  # runs that did not end ok are named below instead
        why = "no run has a known error (no exact solution, and no reference: simrun report --reference dop853)"
        return Finding(f"Not measured: {names[0]} against {names[1]} at equal error{where}, because {why}.",
                       "#figure-work_precision", {**evidence, "why": why}, "not measured")
    measured = [run for run in runs if run.error_from_reference]
    floor = data.reference.accuracy_of(run.run_id for run in measured) if data.reference is not None and measured else math.nan
    compared = equal_error(ours, theirs, floor)
    evidence.update(errors=compared.errors, overlap=compared.overlap, ranges=compared.ranges, floor=floor,
                    costs={label: {name: values.tolist() for name, values in costs.items()}
                           for label, costs in compared.costs.items()},
                    ratios={name: [compared.ratio(name, index) for index in range(len(compared.errors))]
                            for name in ("wall_time", *COUNT_NAMES)},
                    left_out={label: [(run.run_id, run.tolerance, why) for run, why in left]
                              for label, left in compared.left_out.items()})
    against = "a reference solution" if measured else "the exact solution"
    when = error_time_text(runs)
    head = f"At equal error{where}, {names[0]} against {names[1]} (error{f' at {when}' if when else ''} against {against}"
    if compared.errors:
        head += "; costs interpolated log-log against the error between each one's runs over step_control.tolerance)"
        body = "; ".join(_at_error(compared, index, names) for index in range(len(compared.errors)))
    else:
        head += ")"
        body = _apart(compared, names)
    return Finding(f"{head}: {body}{_left_out(compared, names)}.", "#figure-work_precision", evidence, "equal error")


def _where(title: str, member) -> str:
    """" on the spring" (a sweep of labelled systems), " at <settings>" (other swept keys), or " on the spring mass"
    (the system's type, when nothing is swept)."""
    swept = member.stored.swept
    if set(swept) == {"system"} and isinstance(swept["system"], str):
        return f" on the {swept['system']}"
    if title:
        return f" at {title}"
    return f" on the {member.stored.system.replace('_', ' ')}" if member.stored.system else ""


def _at_error(compared: EqualError, index: int, names: tuple[str, str]) -> str:
    """The first error: "at 1e-6 m simrun's radau_iia took 1.9 s (878 steps, 112 Jacobians) and scipy's Radau 4.7 s
    (...): radau_iia 2.5x faster, with 1.2x fewer steps and 1.5x fewer Jacobians"; the next ones without the names."""
    ours, theirs = (compared.costs[label] for label in compared.labels)
    at = f"at {_error_text(compared.errors[index])}"
    pace = _pace(compared.ratio("wall_time", index))
    if index == 0:
        text = (f"{at} {names[0]} took {_costs(ours, index)} and {names[1]} {_costs(theirs, index)}: "
                f"{compared.labels[0]} {pace}")
    else:
        text = f"{at}, {_costs(ours, index)} and {_costs(theirs, index)}: {pace}"
    fewer = [_fewer(compared.ratio(name, index), what) for name, what in STATED_RATIOS.items()]
    fewer = [item for item in fewer if item]
    return text + (f", with {_and(fewer)}" if fewer else "")


def _error_text(error: float) -> str:
    """"1e-6 m", "3.2e-7 m", "0.05 m"."""
    return f"{_compact(error)} m"


def _compact(value: float) -> str:
    """Two digits, in powers of ten below 0.01: "1e-6", "3.2e-7", "0.05"."""
    if 1e-2 <= value < 1e3:
        return f"{value:.2g}"
    mantissa, exponent = f"{value:.1e}".split("e")
    return f"{mantissa.removesuffix('.0')}e{int(exponent)}"


def _costs(costs: dict[str, np.ndarray], index: int) -> str:
    counts = []
    for name, (one, many) in COUNT_NAMES.items():
        if name in costs and np.isfinite(costs[name][index]):
            value = costs[name][index]
            counts.append(f"{value:,.0f} {one if round(value) == 1 else many}")
    return _seconds(costs["wall_time"][index]) + (f" ({', '.join(counts)})" if counts else "")


def _seconds(value: float) -> str:
    return f"{value:.2g} s" if value >= 1 else f"{1e3 * value:.2g} ms"


def _pace(ratio: float) -> str:
    """Theirs over ours in wall time as "2.5x faster", "1.3x slower", or "as fast (within 10 %)"."""
    if abs(math.log(ratio)) <= math.log1p(WALL_TIME_NOISE):
        return f"as fast (within {100 * WALL_TIME_NOISE:g} %: timing noise)"
    return f"{ratio:.2g}x faster" if ratio > 1 else f"{1 / ratio:.2g}x slower"


def _fewer(ratio: float, what: str) -> str:
    """Theirs over ours in a count as "1.2x fewer steps", "1.5x more Jacobians", "as many steps"; "" unknown."""
    if not np.isfinite(ratio) or ratio <= 0:
        return ""
    if math.isclose(ratio, 1.0, rel_tol=0.05):
        return f"as many {what}"
    return f"{ratio:.2g}x fewer {what}" if ratio > 1 else f"{1 / ratio:.2g}x more {what}"


def _apart(compared: EqualError, names: tuple[str, str]) -> str:
    """Why there is no number: the ranges do not meet (each stated), or they meet only below the reference's accuracy."""
    ranges = []
    for name, label in zip(names, compared.labels):
        span = compared.ranges[label]
        ranges.append(f"{name} {_error_text(span[0])[:-2]} to {_error_text(span[1])}" if span else f"{name} none (no run ended ok with a known error)")
    text = "no error that both reach, so no equal-error comparison (errors reached: " + "; ".join(ranges) + ")"
    if np.isfinite(compared.floor) and all(compared.ranges.values()):
        text += f"; above the reference's own accuracy of {_error_text(compared.floor)}, where errors measure the method"
    return text


def _left_out(compared: EqualError, names: tuple[str, str]) -> str:
    """"; left out: scipy's Radau at tol 1e-08 (over record.max_steps)": runs without a point, by method and why."""
    parts = []
    for name, label in zip(names, compared.labels):
        by_why: dict[str, list[float]] = {}
        for run, why in compared.left_out[label]:
            by_why.setdefault(why, []).append(run.tolerance)
        parts += [f"{name} at tol {', '.join(_compact(tolerance) for tolerance in sorted(tolerances))} ({why})"
                  for why, tolerances in by_why.items()]
    return f"; left out: {'; '.join(parts)}" if parts else ""


__all__ = ["SCIPY_PEERS", "peer_findings"]
