"""What the engines' integrators do on the test spring (docs/engines.md), stated first where a file has them: for each
engine, each of its integrators' energy change per period at h w = 0.1 and 1 and where it grows, from the probed
amplification matrix (the predict path of simrun's own methods), with the engine's version, precision and device."""

from __future__ import annotations

from simrun.analysis import oscillator as analysis
from simrun.analysis.runs import RunSet

from .base import Finding, _per_period_list, energy_lost_per_period

# the h w at which an engine's integrator is stated: a resolved motion, and one of a step per sixth of a period
ENGINE_HW = (0.1, 1.0)


def engine_findings(data: RunSet, predictions: dict) -> list[Finding]:
    """One sentence per engine of the file (its ``engine`` attribute), naming each of its integrators that has a
    prediction, in config order."""
    engines: dict[str, list[str]] = {}
    for run in data.runs:
        engine = str(run.stored.attrs.get("engine", ""))
        if engine and run.label in predictions and run.label not in engines.get(engine, []):
            engines.setdefault(engine, []).append(run.label)
    result = []
    for engine, labels in engines.items():
        parts, evidence = [], {}
        for label in labels:
            prediction = predictions[label]
            damping = [prediction.at(hw)[1] for hw in ENGINE_HW]
            lost = [energy_lost_per_period(value) for value in damping]
            growth = analysis.growth_phrase(prediction) or f"stable at every h w probed (to {prediction.hw[-1]:.3g})"
            parts.append(f"{label}: {_per_period_list(list(ENGINE_HW), lost, damping)}, {growth}")
            evidence[label] = {"hw": list(ENGINE_HW), "damping_over_w": damping, "energy_lost_per_period": lost,
                               "stability_limit": prediction.stability_limit}
        result.append(Finding(
            f"{engine}, its integrators on the test spring (energy per period, predicted from each one's probed "
            f"amplification matrix): " + "; ".join(parts) + ".", "#figure-artificial_damping",
            {"engine": engine, "integrators": evidence}, "engines"))
    return result
