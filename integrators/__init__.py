"""Time integrators, found by their config name."""

from .base import IncrementalPotential, Integrator, State
from .euler import BackwardEuler, ForwardEuler, SymplecticEuler

# config name -> class: the one place where a new method is made known
INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls
    for cls in (
        ForwardEuler,
        SymplecticEuler,
        BackwardEuler,
    )
}

__all__ = ["INTEGRATORS", "Integrator", "IncrementalPotential", "State"]
