"""Time integrators, found by their config name."""

from .base import IncrementalPotential, Integrator, SegmentPotential, State
from .euler import BackwardEuler, ForwardEuler, SymplecticEuler
from .explicit import RK4, ButcherTableau, ExplicitMidpoint, ExplicitRungeKutta, Leapfrog
from .exponential import ExponentialRosenbrockEuler
from .implicit import (AverageVectorField, GeneralizedAlpha, ImplicitMidpoint, Newmark,
                       SemiImplicitBackwardEuler)
from .multistep import BDF2, BDF2MidpointMix

# config name -> class: the one place where a new method is made known
INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls
    for cls in (
        ForwardEuler,
        SymplecticEuler,
        BackwardEuler,
        Leapfrog,
        ExplicitMidpoint,
        RK4,
        ImplicitMidpoint,
        Newmark,
        BDF2,
        GeneralizedAlpha,
        BDF2MidpointMix,
        SemiImplicitBackwardEuler,
        ExponentialRosenbrockEuler,
        AverageVectorField,
    )
}

__all__ = ["INTEGRATORS", "Integrator", "IncrementalPotential", "SegmentPotential", "State",
           "ButcherTableau", "ExplicitRungeKutta"]
