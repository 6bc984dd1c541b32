"""What a file says of its integrators: stability, artificial damping, accuracy and cost, observed orders, energy, and
what could not be measured (the topics of ``simrun.findings`` before contact, cost and the damping map)."""

from __future__ import annotations

import json
import math
from collections import Counter

import numpy as np

from simrun.analysis import oscillator as analysis
from simrun.analysis.rows import (DAMPING_TOLERANCE, ORDER_TOLERANCE, OrderRow, SummaryRow, energy_reference_text,
                                  error_runs)
from simrun.analysis.runs import explicit_prediction, test_equation_runs
from simrun.findings.base import (MAX_NAMED, WALL_TIME_NOISE, Finding, _and, _dts, _per_period_list, _who,
                                  across_settings, drift_text, energy_lost_per_period)
from simrun.format.summary import Status

DAMPING_BUDGET = 0.01  # the damping budget of the ranking: at most this fraction of the energy gained or lost per period
# Error budgets are decades of the length scale, from this fraction down to the smallest error that
# two methods reach; at most MAX_ERROR_BUDGETS of them are stated (the loosest, the tightest, one between).
LOOSEST_ERROR_BUDGET, MAX_ERROR_BUDGETS = 0.1, 3
MAX_DAMPING_POINTS = 6  # the damping per period is stated at the sweep's h w, at most this many (spread over the sweep)
BUDGET_BISECTION_STEPS = 40  # in log h w, for the largest h w within the damping budget: 2^-40 of a decade
SMALLEST_BUDGET_HW = 1e-8  # where the budget search looks below the predicted grid: within any budget at small h w


# -- a sweep over many settings ---------------------------------------------------------------------
def _many_settings(data) -> dict[str, dict]:
    """Each group title's swept values where the groups are more than a sentence names (a map: its findings are said
    across the settings, ``across_settings``), else {}."""
    if len(data.groups) <= MAX_NAMED:
        return {}
    return {title: json.loads(runs[0].group or "{}") for title, runs in data.groups}


# -- stability --------------------------------------------------------------------------------------
def stability_findings(data, rows, predictions, several) -> list[Finding]:
    drift = {row.run_id: row.max_rel_energy_drift for row in rows}
    per_label, all_bounded = [], []
    # a sweep over many settings (a map): each group's sentence in h w alone, so that groups alike share one sentence
    settings = _many_settings(data)
    frequencies = {run.frequency for _, runs in data.groups for run in runs if run.frequency}
    for title, runs in data.groups:
        for label in data.labels:
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            if not mine:
                continue
            reached = [run.dt for run in mine if not run.status.stopped]
            diverged = [run.dt for run in mine if run.status is Status.DIVERGED]
            failed = [run.dt for run in mine if run.status is Status.FAILED]
            frequency = next((run.frequency for run in mine if run.frequency), None)
            prediction = predictions.get(label) if frequency else None
            explicit_run = None if frequency else next((run for run in mine if run.explicit_frequency is not None
                                                        and run.method is not None), None)
            if explicit_run is not None:  # off the test equation: the limit of the forces taken explicitly
                frequency, prediction = explicit_run.explicit_frequency, explicit_prediction(explicit_run.method)
            evidence = {"integrator": label, "group": title, "bounded_dts": reached, "diverged_dts": diverged,
                        "failed_dts": failed, "largest_bounded_dt": max(reached, default=math.nan),
                        "smallest_diverged_dt": min(diverged, default=math.nan)}
            if not diverged and not failed and prediction is None:
                all_bounded.append((title, label, reached))
                continue
            parts = [_measured_stability(reached, diverged, failed)]
            if prediction is not None:
                limit = prediction.stability_limit
                evidence.update(predicted_limit_hw=limit, predicted_limit_dt=limit / frequency if frequency else math.inf,
                                frequency=frequency)
                if explicit_run is not None:
                    parts.append(_explicit_stability(limit, frequency, explicit_run))
                else:
                    parts.append(_predicted_stability(limit, frequency if len(frequencies) == 1 else None, prediction))
                beyond = [run for run in mine if not run.status.stopped and run.dt * frequency > limit * (1 + 1e-9)]
                if beyond:
                    growth = max(drift[run.run_id] for run in beyond)
                    parts.append(f"beyond the limit, the runs at dt = {_dts([run.dt for run in beyond])} grew "
                                 f"(max |E − E0| up to {drift_text(growth)}) without reaching the divergence bound")
                    evidence["beyond_limit_dts"] = [run.dt for run in beyond]
                below = [dt for dt in diverged if dt * frequency < limit * (1 - 1e-9)]
                if below:
                    parts.append(f"diverged below the predicted limit at dt = {_dts(below)}")
            anchor = "#stability" if prediction is not None and explicit_run is None else "#figure-stability_map"
            per_label.append((_who(title, label, several), "; ".join(parts), anchor, evidence))
    if settings:  # more settings than a sentence names: say it across them
        return _said_across(per_label, settings) + _all_bounded(all_bounded, per_label, several, settings)
    return _said_once(per_label) + _all_bounded(all_bounded, per_label, several, {})


def _all_bounded(all_bounded, per_label, several, settings) -> list[Finding]:
    """The runs without a prediction that all reached their end, in one sentence."""
    if not all_bounded:
        return []
    dts = sorted({dt for _, _, reached in all_bounded for dt in reached})
    labels = list(dict.fromkeys(_who(title, label, several) for title, label, _ in all_bounded))
    if not per_label:
        whom = "Every run"
    elif settings:
        whom = "Every run of " + across_settings([(label, title) for title, label, _ in all_bounded], settings)
    else:
        whom = f"Every run of {_and(labels)}"
    return [Finding(f"{whom} reached its end without diverging (measured; dt up to {max(dts):g} s).",
                    "#figure-stability_map", {"integrators": labels, "bounded_dts": dts, "diverged_dts": []}, "stability")]


def _said_across(items: list[tuple[str, str, str, dict]], settings: dict[str, dict]) -> list[Finding]:
    """(who, what, anchor, evidence) of a sweep over many settings as findings: one sentence for each thing said, its
    integrators and settings worded across the sweep (``across_settings``), the largest groups first."""
    alike: dict[tuple[str, str], list[dict]] = {}
    for _, what, anchor, evidence in items:
        alike.setdefault((what, anchor), []).append(evidence)
    result = []
    for (what, anchor), members in sorted(alike.items(), key=lambda item: -len(item[1])):
        who = across_settings([(item["integrator"], item["group"]) for item in members], settings)
        evidence = {"integrators": list(dict.fromkeys(item["integrator"] for item in members)),
                    "settings": len({item["group"] for item in members}), "each": members[:MAX_NAMED]}
        result.append(Finding(f"{who}: {what}.", anchor, evidence, "stability"))
    return result


def _said_once(items: list[tuple[str, str, str, dict]]) -> list[Finding]:
    """(who, what, anchor, evidence) as findings; integrators of which the same is said share one sentence
    (their evidence under "integrators", each one's under "each")."""
    alike: dict[tuple[str, str], list[tuple[str, dict]]] = {}
    for who, what, anchor, evidence in items:
        alike.setdefault((what, anchor), []).append((who, evidence))
    result = []
    for (what, anchor), members in alike.items():
        if len(members) == 1:
            who, evidence = members[0]
        else:
            who = _and([name for name, _ in members])
            evidence = {"integrators": [item["integrator"] for _, item in members],
                        "each": [item for _, item in members[:MAX_NAMED]]}  # the first ones, as the sentence names them
            if len(members) > MAX_NAMED:
                evidence["more"] = len(members) - MAX_NAMED
        result.append(Finding(f"{who}: {what}.", anchor, evidence, "stability"))
    return result


def _measured_stability(reached, diverged, failed) -> str:
    if not diverged and not failed:
        text = f"measured: reached the end without diverging at every dt run (up to {max(reached):g} s)"
    elif not reached:
        text = f"measured: stopped at every dt run (from {min(diverged + failed):g} s)"
        if diverged:
            text += f", diverged at dt = {_dts(diverged)}"
    elif diverged and max(reached) < min(diverged):
        text = (f"measured: reached the end without diverging up to dt = {max(reached):g} s, "
                f"diverged from dt = {min(diverged):g} s")
    else:
        text = f"measured: reached the end at dt = {_dts(reached)}"
        if diverged:
            text += f", diverged at dt = {_dts(diverged)}"
    if failed:
        text += f", failed at dt = {_dts(failed)}"
    return text


def _predicted_stability(limit: float, frequency: float | None, prediction) -> str:
    """The predicted limit in h w, and in dt where the sweep has one frequency (``frequency``; None: several)."""
    if limit == 0:
        from simrun.analysis.oscillator import growth_phrase

        phrase = growth_phrase(prediction)
        if phrase != "grows at every h":  # BDF3, BDF4: unstable as h -> 0, damped beyond
            return f"predicted: unstable at small steps ({phrase}: spectral radius ρ > 1 there)"
        return "predicted: unstable at every step size (spectral radius ρ > 1 at every h w)"
    if math.isinf(limit):
        return f"predicted: stable at every h w (ρ ≤ 1 up to h w = {prediction.hw[-1]:g})"
    in_dt = f" (dt = {limit / frequency:.4g} s at w = {frequency:.4g} rad/s)" if frequency else ""
    return f"predicted: stable up to h w = {limit:.4g}{in_dt}"


def _explicit_stability(limit: float, frequency: float, run) -> str:
    """The predicted limit of a method off the test equation: its explicit form's (h w)* over the frequency that
    bounds its step (the system's stiffest; IMEX Euler's of K_E − K_I), at the start shape."""
    imex = run.method.family == "imex"
    what = "of K_E − K_I (explicit minus implicit terms)" if imex else "of the system"
    if frequency == 0.0:
        return ("predicted: stable at every step (K_E − K_I has no positive eigenvalue: on every mode the implicit terms "
                "are the stiffer)")
    if limit == 0:
        return f"predicted: unstable at every step (its explicit form grows at every h w; stiffest w = {frequency:.4g} rad/s)"
    if math.isinf(limit):
        return "predicted: stable at every step"
    return (f"predicted: stable up to dt = {limit / frequency:.4g} s (h w = {limit:.4g} at the stiffest frequency {what}, "
            f"w = {frequency:.4g} rad/s, at the start shape)")


def largest_dt_findings(data, several) -> list[Finding]:
    """Who survives the largest dt of each group (measured: only the runs at that dt), when not all did."""
    result = []
    for title, runs in data.groups:
        largest = max(run.dt for run in runs)
        at = [run for run in runs if run.dt == largest]
        stopped = [run for run in at if run.status.stopped]
        if not stopped:
            continue
        bounded = [run.label for run in at if not run.status.stopped]
        diverged = [run.label for run in at if run.status is Status.DIVERGED]
        failed = [run.label for run in at if run.status is Status.FAILED]
        hws = {f"{run.hw:.3g}" for run in at if np.isfinite(run.hw)}
        where = f"dt = {largest:g} s" + (f" (h w = {hws.pop()})" if len(hws) == 1 else "")
        where += f" ({title})" if several and title else ""
        result.append(Finding(_largest_dt_sentence(where, bounded, diverged, failed), "#figure-stability_map",
                              {"group": title, "dt": largest, "bounded": bounded, "diverged": diverged, "failed": failed},
                              "stability"))
    settings = _many_settings(data)
    return _largest_dt_across(result, settings) if settings and result else result


def _largest_dt_sentence(where: str, bounded: list[str], diverged: list[str], failed: list[str]) -> str:
    """"At the largest dt, <where> only A reached the end without diverging; B diverged (measured)."""
    where = where if where.endswith(":") else where + ","
    sentence = (f"At the largest dt, {where} only {_and(bounded)} reached the end without diverging" if bounded
                else f"At the largest dt, {where} no method reached the end")
    if diverged:
        sentence += f"; {_and(diverged)} diverged"
    if failed:
        sentence += f"; {_and(failed)} failed"
    return sentence + " (measured)."


def _largest_dt_across(found: list[Finding], settings: dict[str, dict]) -> list[Finding]:
    """The largest-dt findings of a sweep over many settings: one per outcome (who reached the end, who diverged,
    who failed), with the settings it holds at, the most common first."""
    alike: dict[tuple, list[Finding]] = {}
    for finding in found:
        evidence = finding.evidence
        key = (evidence["dt"], tuple(evidence["bounded"]), tuple(evidence["diverged"]), tuple(evidence["failed"]))
        alike.setdefault(key, []).append(finding)
    result = []
    for (dt, bounded, diverged, failed), members in sorted(alike.items(), key=lambda item: -len(item[1])):
        where = across_settings([("", finding.evidence["group"]) for finding in members], settings).strip()
        sentence = _largest_dt_sentence(f"{dt:g} s, {where}:", list(bounded), list(diverged), list(failed))
        result.append(Finding(sentence, "#figure-stability_map",
                              {"dt": dt, "bounded": list(bounded), "diverged": list(diverged), "failed": list(failed),
                               "settings": len(members)}, "stability"))
    return result


# -- artificial damping -------------------------------------------------------------------------------
def damping_findings(data, predictions, several) -> list[Finding]:
    result = []
    groups = data.groups
    if _many_settings(data):  # the predicted damping depends on h w alone: one sentence per method, over the sweep's h w
        groups = [(f"over the h w of all {len(groups):,} settings", [run for _, runs in groups for run in runs])]
    for title, runs in groups:
        for label in data.labels:
            if label not in predictions:
                continue
            hws = sorted({run.hw for run in runs if run.label == label and np.isfinite(run.hw) and run.hw > 0})
            if not hws:
                continue
            if len(hws) > MAX_DAMPING_POINTS:
                hws = [hws[index] for index in np.unique(np.linspace(0, len(hws) - 1, MAX_DAMPING_POINTS - 1).round().astype(int))]
            damping = [predictions[label].at(hw)[1] for hw in hws]
            lost = [energy_lost_per_period(value) for value in damping]
            told = _per_period_list(hws, lost, damping)
            result.append(Finding(
                f"Artificial damping of {_who(title, label, several)} (predicted from the amplification matrix; the "
                f"energy change per period T = 2π/w of the test equation): {told}.", "#figure-artificial_damping",
                {"integrator": label, "group": title, "hw": hws, "damping_over_w": damping, "energy_lost_per_period": lost},
                "damping"))
    return result


def measured_damping_findings(rows: list[SummaryRow]) -> list[Finding]:
    on_test = [row for row in rows if np.isfinite(row.hw)]
    if not on_test:
        return []
    measured = [row for row in on_test if np.isfinite(row.measured_damping) and np.isfinite(row.predicted_damping)]
    resolved = [row for row in measured if row.measured_resolved]
    agree = [row for row in resolved if row.damping_agrees]
    differ = [row for row in resolved if not row.damping_agrees]
    unresolved = len(measured) - len(resolved)
    # (a run measured without a prediction is not among them: measured_only_findings states it)
    not_measured = sum(1 for row in on_test if not np.isfinite(row.measured_damping))
    if not any(np.isfinite(row.predicted_damping) for row in on_test):
        return []  # nothing predicted to agree with: measured_only_findings says what the runs measured
    if resolved:
        sentence = (f"Measured artificial damping (fitted to each run's energy decay) agrees with the prediction within "
                    f"{100 * DAMPING_TOLERANCE:g} % (where none is predicted: within {analysis.RESOLVED_ABSOLUTE_ERROR:g} w) "
                    f"in {len(agree)} of the {len(resolved)} runs that resolve it")
    else:
        sentence = "No run resolves its artificial damping (the energy decay of a run of a few steps is not fitted)"
    if differ:
        sentence += "; it differs in " + ", ".join(
            f"#{row.index} {row.integrator} ("
            + (f"{100 * row.damping_difference:+.1f} %" if row.damping_relative else f"d/w {row.measured_damping:.2g}, none predicted")
            + ")" for row in differ)
    notes = []
    if unresolved:
        notes.append(f"{unresolved} run{'s are' if unresolved != 1 else ' is'} too short to resolve it")
    if not_measured:
        notes.append(f"{not_measured} run{'s' if not_measured != 1 else ''} that stopped early (diverged or failed) or "
                     f"kept no energy {'are' if not_measured != 1 else 'is'} not fitted")
    sentence += (" (" + "; ".join(notes) + ")") if notes else ""
    return [Finding(sentence + ".", "#summary",
                    {"resolved": len(resolved), "agree": len(agree), "differ": [row.run_id for row in differ],
                     "unresolved": unresolved, "not_measured": not_measured}, "damping")]


def measured_only_findings(rows: list[SummaryRow]) -> list[Finding]:
    """What the runs that no amplification matrix predicts (recorded trajectories, peers) measured on the test equation:
    their artificial damping d/w (fitted to the energy decay) and period error (zero crossings), run by run."""
    rows = [row for row in rows if np.isfinite(row.hw) and not np.isfinite(row.predicted_damping)
            and (np.isfinite(row.measured_damping) or np.isfinite(row.period_error))]
    if not rows:
        return []
    rows = sorted(rows, key=lambda row: (row.integrator, row.hw))
    shown = rows[:MAX_DAMPING_POINTS]

    def told(row: SummaryRow) -> str:
        parts = []
        if np.isfinite(row.measured_damping):
            resolution = "" if row.measured_resolved else ", not resolved by the run"
            parts.append(f"d/w {row.measured_damping:.3g}{resolution}")
        if np.isfinite(row.period_error):
            parts.append(f"period error {row.period_error:+.3g}")
        return f"{row.integrator} at h w = {row.hw:.3g}: " + ", ".join(parts)

    more = f"; {len(rows) - len(shown)} more in the runs table" if len(rows) > len(shown) else ""
    return [Finding("Measured only (no amplification matrix predicts these runs): " + "; ".join(map(told, shown)) + more
                    + ".", "#figure-artificial_damping",
                    {"run_ids": [row.run_id for row in rows], "hw": [row.hw for row in rows],
                     "damping_over_w": [row.measured_damping for row in rows],
                     "period_error": [row.period_error for row in rows]}, "damping")]


def largest_hw_within(prediction, budget: float = DAMPING_BUDGET) -> float:
    """The largest h w up to which the method's predicted energy change per period stays within ``budget``
    (and rho <= 1 + its growth tolerance); inf when it does over the whole predicted range."""
    def within(hw: float) -> bool:
        rho, damping = prediction.at(hw)
        return rho <= 1 + prediction.growth_tolerance and abs(energy_lost_per_period(damping)) <= budget

    lost = -np.expm1(-2.0 * np.pi * prediction.damping)
    ok = (np.abs(lost) <= budget) & (prediction.rho <= 1 + prediction.growth_tolerance)
    if ok.all():
        return math.inf
    first = int(np.argmin(ok))
    if first:
        low, high = float(prediction.hw[first - 1]), float(prediction.hw[first])
    elif within(SMALLEST_BUDGET_HW):
        low, high = SMALLEST_BUDGET_HW, float(prediction.hw[0])
    else:
        return 0.0
    for _ in range(BUDGET_BISECTION_STEPS):
        middle = math.sqrt(low * high)
        low, high = (middle, high) if within(middle) else (low, middle)
    return low


def damping_budget_findings(data, predictions) -> list[Finding]:
    if not predictions:
        return []
    frequencies = sorted({run.frequency for run in test_equation_runs(data)})
    largest = {label: (largest_hw_within(prediction) if prediction.stability_limit > 0 else 0.0)
               for label, prediction in predictions.items()}
    parts = []
    for label in sorted(largest, key=lambda name: -largest[name]):
        value, prediction = largest[label], predictions[label]
        limit = prediction.stability_limit
        if limit == 0:
            parts.append(f"{label} at no h w from 0 (unstable at small steps)")
        elif math.isinf(value):
            parts.append(f"{label} at every h w up to {prediction.hw[-1]:g}")
        elif value == 0:
            parts.append(f"{label} at no h w")
        else:
            notes = [f"dt = {value / frequencies[0]:.2g} s"] if len(frequencies) == 1 else []
            if limit < math.inf and math.isclose(value, limit, rel_tol=1e-3):
                notes.append("its stability limit")
            parts.append(f"{label} up to h w = {value:.2g}" + (f" ({'; '.join(notes)})" if notes else ""))
    at = f" at w = {frequencies[0]:.4g} rad/s" if len(frequencies) == 1 else ""
    sentence = (f"Largest step within a damping budget of {100 * DAMPING_BUDGET:g} % of the energy gained or lost per "
                f"period (predicted{at}): " + "; ".join(parts) + ".")
    return [Finding(sentence, "#figure-artificial_damping", {"budget": DAMPING_BUDGET, "largest_hw": largest}, "damping")]


# -- accuracy and cost ------------------------------------------------------------------------------
def accuracy_findings(data, several) -> list[Finding]:
    result = []
    usable = set(map(id, error_runs(data)))
    for title, runs in data.groups:
        mine = [run for run in runs if id(run) in usable]
        if not mine:
            continue
        scale = max(run.length_scale for run in mine)
        errors = {id(run): (run.error, run.error_time, run.error_from_reference) for run in mine}
        # the tightest budget is the smallest error that two methods reach (one, in a file of one), above round-off:
        # a method exact on the problem (errors at round-off) would otherwise rank alone at 1e-14
        best = sorted(min(errors[id(run)][0] for run in mine if run.label == label)
                      for label in dict.fromkeys(run.label for run in mine))
        smallest = max(best[min(1, len(best) - 1)], analysis.ROUND_OFF_ERROR * scale)
        floor = data.reference.accuracy_of(run.run_id for run in mine) if data.reference is not None else math.nan
        if np.isfinite(floor):  # below the reference's own accuracy a budget would rank the reference's error, not the runs'
            smallest = max(smallest, floor)
        times = [time for _, time, _ in errors.values() if np.isfinite(time)]
        when = (f"t = {min(times):.4g} s" if math.isclose(min(times), max(times), rel_tol=1e-9)
                else f"t = {min(times):.4g} to {max(times):.4g} s") if times else "the end"
        against = "a reference solution" if any(reference for _, _, reference in errors.values()) else "the exact solution"
        budgets = []
        budget = LOOSEST_ERROR_BUDGET * scale
        while smallest <= budget:
            budgets.append(budget)
            budget /= 10
        if len(budgets) > MAX_ERROR_BUDGETS:
            budgets = [budgets[0], budgets[len(budgets) // 2], budgets[-1]]
        labels = list(dict.fromkeys(run.label for run in runs))
        for budget in budgets:
            cheapest = {}
            for run in mine:
                if errors[id(run)][0] <= budget and (run.label not in cheapest or run.wall_time < cheapest[run.label].wall_time):
                    cheapest[run.label] = run
            # an engine's wall time is another code's stepping: ranked apart, per engine, never against simrun's
            ranked = sorted(cheapest.values(), key=lambda run: run.wall_time)
            ranking = [run for run in ranked if not _engine(run)]
            engines: dict[str, list] = {}
            for run in ranked:
                if _engine(run):
                    engines.setdefault(_engine(run), []).append(run)
            missing = [label for label in labels if label not in cheapest]
            listed = "; ".join([_cheapest_first(ranking)] * bool(ranking) + [
                f"{engine}, timed apart: {_cheapest_first(members)}" for engine, members in engines.items()])
            sentence = (f"Error ≤ {budget:.1g} m ({100 * budget / scale:g} % of the length scale {scale:g} m) against {against} "
                        f"at {when}{f' ({title})' if several and title else ''}, cheapest first (measured wall time of "
                        f"the whole run; ≈: within {100 * WALL_TIME_NOISE:g} %): {listed}")
            if missing:
                sentence += f"; not reached at any {'tolerance' if any(math.isfinite(run.tolerance) for run in mine) else 'dt'} run by {_and(missing)}"
            result.append(Finding(sentence + ".", "#figure-work_precision",
                                  {"group": title, "budget": budget, "budget_fraction": budget / scale, "against": against,
                                   "ranking": [(run.label, run.wall_time, run.dt, errors[id(run)][0]) for run in ranking],
                                   "engines": {engine: [(run.label, run.wall_time, run.dt, errors[id(run)][0])
                                                        for run in members] for engine, members in engines.items()},
                                   "not_reached": missing}, "accuracy"))
    return _accuracy_across(result, len(data.groups)) if _many_settings(data) and result else result


def _engine(run) -> str:
    """The engine that stepped a run (its version, precision and device), or "" for simrun's own methods."""
    return str(run.stored.attrs.get("engine", ""))


def _cheapest_first(ranking: list) -> str:
    """Runs with their wall times in the order given; ≈ between two within the noise of a wall time (no rank)."""
    listed = ""
    for number, run in enumerate(ranking):
        if number:
            listed += " ≈ " if run.wall_time <= (1 + WALL_TIME_NOISE) * ranking[number - 1].wall_time else ", "
        setting = f"tol = {run.tolerance:g}" if math.isfinite(run.tolerance) else f"dt = {run.dt:g} s"
        listed += f"{run.label} {run.wall_time:.3g} s ({setting})"
    return listed


def _accuracy_across(found: list[Finding], settings: int) -> list[Finding]:
    """The accuracy rankings of a sweep over many settings, one sentence per error budget (a fraction of the length
    scale): how often each method was the cheapest within it, and how often no run of it reached it."""
    by_budget: dict[float, list[Finding]] = {}
    for finding in found:
        by_budget.setdefault(round(finding.evidence["budget_fraction"], 12), []).append(finding)
    result = []
    for fraction, members in sorted(by_budget.items(), reverse=True):
        first = Counter(finding.evidence["ranking"][0][0] for finding in members if finding.evidence["ranking"])
        missing = Counter(label for finding in members for label in finding.evidence["not_reached"])
        cheapest = ", ".join(f"{label} at {count:,}" for label, count in first.most_common())
        sentence = (f"Error ≤ {100 * fraction:g} % of the length scale against {members[0].evidence['against']}, at "
                    f"{len(members):,} of {settings:,} settings: the cheapest method within it (measured wall time of "
                    f"the whole run) was {cheapest or 'none'}")
        if missing:
            sentence += "; not reached at any dt run by " + ", ".join(f"{label} at {count:,}" for label, count in missing.most_common())
        result.append(Finding(sentence + ".", "#figure-work_precision",
                              {"budget_fraction": fraction, "cheapest": dict(first), "not_reached": dict(missing),
                               "settings": len(members)}, "accuracy"))
    return result


def order_findings(orders: list[OrderRow], several: bool) -> list[Finding]:
    fitted = [row for row in orders if np.isfinite(row.observed)]
    exact = [row for row in orders if row.exact]
    result = []
    if fitted:
        when = {row.error_time for row in fitted if row.error_time}
        items = []
        for row in fitted:
            verdict = "agrees" if abs(row.observed - row.declared) <= ORDER_TOLERANCE else "differs"
            items.append(f"{_who(row.group, row.integrator, several)} {row.observed:.2f} (declared {row.declared}, {verdict})")
        result.append(Finding(
            f"Observed order of convergence (measured: slope of the error at {_and(sorted(when)) if when else 'the end'} "
            f"against dt): " + "; ".join(items) + ".", "#orders",
            {"orders": {(row.group, row.integrator): row.observed for row in fitted},
             "declared": {(row.group, row.integrator): row.declared for row in fitted}}, "accuracy"))
    if exact:
        names = _and([_who(row.group, row.integrator, several) for row in exact])
        result.append(Finding(f"{names} {'is' if len(exact) == 1 else 'are'} exact on this problem (every error at "
                              "round-off).", "#orders", {"exact": [row.integrator for row in exact]}, "accuracy"))
    return result


# -- energy (systems without the test equation) ----------------------------------------------------
def _recorded_any(stored, key: str) -> bool:
    """Does the run record this energy term, and is it ever non-zero?"""
    if key not in stored:
        return False
    values = stored.series(key)
    return bool(np.any(values[np.isfinite(values)] != 0.0))


def energy_findings(data, rows, several) -> list[Finding]:
    by_id = {row.run_id: row for row in rows}
    result = []
    # from the data, not the parameters (a number, a list of damping models, a plug-in's own names)
    damped = any(_recorded_any(run.stored, "dissipated_energy") for run in data.runs)
    driven = any(_recorded_any(run.stored, "prescribed_work") for run in data.runs)
    rubbing = any(_recorded_any(run.stored, "friction_dissipated") for run in data.runs)
    for title, runs in data.groups:
        dts = sorted({run.dt for run in runs}, reverse=True)
        chosen = [dt for dt in dts if len({run.label for run in runs if run.dt == dt and not run.status.stopped}) >= 2]
        for dt in dict.fromkeys(chosen[:1] + chosen[-1:]):
            at = sorted((by_id[run.run_id] for run in runs if run.dt == dt and not run.status.stopped),
                        key=lambda row: row.max_rel_energy_drift)
            at = [row for row in at if np.isfinite(row.max_rel_energy_drift)]
            if len(at) < 2:
                continue
            listed = ", ".join(f"{row.integrator} {drift_text(row.max_rel_energy_drift)}" for row in at)
            sentence = (f"Largest energy change over the run at dt = {dt:g} s{f' ({title})' if several and title else ''} "
                        f"(measured, max |E − E0| / E_ref, {energy_reference_text(at)}"
                        + ("; it includes the physical damping's loss" if damped else "")
                        + ("; it includes friction's loss" if rubbing else "")
                        + ("; it includes the work of the prescribed vertices" if driven else "") + f"): {listed}.")
            result.append(Finding(sentence, "#figure-energy_drift_vs_dt",
                                  {"group": title, "dt": dt,
                                   "max_rel_energy_drift": {row.integrator: row.max_rel_energy_drift for row in at}},
                                  "energy"))
    return result


# -- what could not be measured ---------------------------------------------------------------------
def not_measured_findings(data, orders: list[OrderRow], several: bool) -> list[Finding]:
    result = []
    if not test_equation_runs(data):
        result.append(Finding(
            "Not measured: stability limits, artificial damping and h w, because no run is on the undamped test equation "
            "(a system that declares a test frequency w: the spring without damping, linear circular motion).",
            "#summary", {"missing": ["stability limits", "artificial damping"]}, "not measured"))
    if not error_runs(data):
        reached = [run for run in data.runs if not run.status.stopped]
        if not reached:
            why = "every run stopped (diverged or failed) before its end"
        elif any(np.isfinite(run.stored.error_time) or "error" not in run.stored.attrs for run in reached):
            why = ("the system has no exact solution and no reference solution was asked for "
                   + ("(with contact: simrun report --reference <run_id>, e.g. the smallest dt)"
                      if any(run.stored.attrs.get("max_active_contacts") is not None for run in reached)
                      else "(simrun report --reference dop853, or a run_id)"))
        else:
            why = "no run reached its error time"
        result.append(Finding(f"Not measured: errors, observed orders and the accuracy ranking, because {why}.",
                              "#summary", {"missing": ["errors", "orders"], "why": why}, "not measured"))
    unfitted: dict[str, list[OrderRow]] = {}
    for row in orders:
        if not np.isfinite(row.observed) and not row.exact:
            unfitted.setdefault(row.reason or "not enough asymptotic points", []).append(row)
    settings = _many_settings(data)
    for reason, missing in unfitted.items():
        labels = [_who(row.group, row.integrator, several) for row in missing]
        who = across_settings([(row.integrator, row.group) for row in missing], settings) if settings else _and(labels)
        result.append(Finding(f"Not measured: the observed order of {who}: {reason}.", "#orders",
                              {"integrators": labels, "reason": reason}, "not measured"))
    return result


__all__ = ["Finding", "drift_text", "energy_lost_per_period", "findings", "largest_hw_within", "per_period_text"]
