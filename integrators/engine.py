"""What every engine's integrator is (integrators/mujoco.py, integrators/newton_engine.py): a method whose steps
another code takes, on a model translated from the system, built once per system and step size and kept while the
system lives. A subclass says how the engine is missing, what it refuses, and how its stepper is built; the stepping,
the model built before the timed steps, and the refusals every engine shares are here.
"""

from __future__ import annotations

import weakref
from abc import abstractmethod
from typing import ClassVar

from simrun.solvers import EXPLICIT_STEP

from .base import Integrator

# each system's steppers, by engine and options: built before a run's first step, kept while the system lives
_STEPPERS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


class EngineIntegrator(Integrator):
    """An engine's integrator: ``step`` hands the state to a stepper (the engine's model, data and solver for one
    system and dt), which steps it with the engine's own code and hands it back."""

    explicit: ClassVar[bool] = True  # simrun's solver is never called: the engine takes the whole step
    fixed_steps_only: ClassVar[bool] = True  # the engine's step size is a model option, with no error estimate
    family: ClassVar[str] = "engines"

    @classmethod
    @abstractmethod
    def missing(cls) -> str | None:
        """Why this engine cannot run here (its extra is not installed), or None."""

    @abstractmethod
    def engine_refusal(self, system) -> str | None:
        """Why the engine cannot take this system with these options (in one line), or None."""

    @abstractmethod
    def build_stepper(self, system, dt: float):
        """The engine's stepper for ``system`` at steps of dt: an object whose ``step(state)`` returns the next state."""

    def refusal(self, system) -> str | None:
        missing = self.missing()
        if missing is not None:
            return missing
        if getattr(system, "lane_count", None) is not None:
            return "is not stepped as lanes"
        return self.engine_refusal(system)

    def prepare(self, system, dt: float) -> None:
        self._stepper(system, dt)

    def step(self, system, state, dt, solver):
        return self._stepper(system, dt).step(state), EXPLICIT_STEP

    def _stepper(self, system, dt: float):
        """The system's stepper for steps of dt with these options: built once, kept with the system."""
        steppers = _STEPPERS.setdefault(system, {})
        key = (self.name, float(dt), tuple(sorted(self.model_dump().items())))
        stepper = steppers.get(key)
        if stepper is None:
            stepper = steppers[key] = self.build_stepper(system, float(dt))
        return stepper
