"""What the engines' integrators do on the test spring (docs/engines.md), stated first where a file has them: each one's
energy change per period at h w = 0.1 and 1 and where it grows, from its probed amplification matrix (the predict path
of simrun's own methods), with the engine, version, precision and device that took its steps."""

from __future__ import annotations

from simrun.analysis import oscillator as analysis
from simrun.analysis.runs import RunSet

from .base import Finding, _per_period_list, energy_lost_per_period

# the h w at which an engine's integrator is stated: a resolved motion, and one a step per sixth of a period
ENGINE_HW = (0.1, 1.0)


def engine_findings(data: RunSet, predictions: dict) -> list[Finding]:
    """One sentence per engine integrator of the file that has a prediction (the test spring, or any file whose
    runs name one), in config order."""
    engines: dict[str, str] = {}
    for run in data.runs:
        engine = str(run.stored.attrs.get("engine", ""))
        if engine and run.label in predictions:
            engines.setdefault(run.label, engine)
    result = []
    for label, engine in engines.items():
        prediction = predictions[label]
        damping = [prediction.at(hw)[1] for hw in ENGINE_HW]
        lost = [energy_lost_per_period(value) for value in damping]
        growth = analysis.growth_phrase(prediction) or f"stable at every h w probed (to {prediction.hw[-1]:.3g})"
        result.append(Finding(
            f"{label} ({engine}) on the test spring, predicted from its probed amplification matrix: energy per period "
            f"{_per_period_list(list(ENGINE_HW), lost, damping)}; {growth}.", "#figure-artificial_damping",
            {"integrator": label, "engine": engine, "hw": list(ENGINE_HW), "damping_over_w": damping,
             "energy_lost_per_period": lost, "stability_limit": prediction.stability_limit}, "engines"))
    return result
