"""Shared helpers: build runs from a config mapping, as a user's YAML would."""

from __future__ import annotations

import pytest

from simrun.config import expand_runs, validate_experiment
from simrun.simulate import simulate


def make_runs(system: dict, integrators: list, dt: list[float], duration: float = 1.0, **extra):
    raw = {"name": "test", "system": system, "integrators": integrators, "duration": duration,
           "sweep": {"dt": dt}, **extra}
    return expand_runs(validate_experiment(raw))


def run_one(system: dict, integrator, dt: float, duration: float, **extra):
    (run,) = make_runs(system, [integrator], [dt], duration, **extra)
    return simulate(run)


@pytest.fixture
def run_simulation():
    return run_one
