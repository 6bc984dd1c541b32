"""simrun.integrators (folder integrators/): the time integrators, found by their config name.

``INTEGRATORS`` maps each config name (an entry of the config's ``integrators:`` list, or its ``type``)
to the method's class; its parameters validate into a frozen instance. A new method joins with an
``Integrator`` subclass (integrators/base.py has the contract: ``name``, ``order``, ``explicit``,
``summary``, parameters as fields with a default and a description, and ``step``; an explicit
Runge-Kutta method supplies only its ``ButcherTableau``) and an entry in INTEGRATORS below; the tests
in tests/test_integrators.py then step it, and ask for its closed-form spectral radius in CLOSED_FORMS.
A method outside simrun joins by its path or an entry point (integrators/plugins.py).
"""

from .base import IncrementalPotential, Integrator, State
from .segment import SegmentPotential
from .euler import BackwardEuler, ForwardEuler, SymplecticEuler
from .explicit import RK4, ButcherTableau, Dopri5, ExplicitMidpoint, ExplicitRungeKutta, Leapfrog
from .exponential import ExponentialRosenbrockEuler
from .implicit import (AverageVectorField, GeneralizedAlpha, ImplicitMidpoint, Newmark,
                       SemiImplicitBackwardEuler)
from .dirk import ESDIRK, SDIRK2, SDIRK3, TRBDF2
from .multistep import BDF, BDF2, BDF2MidpointMix
from .radau import RadauIIA
from .rosenbrock import Rosenbrock
from .xpbd import XPBD
from .imex import IMEX
from .peers import SolveIVP
from .recorded import Recorded
from .mujoco import MuJoCo
from .newton_engine import Newton

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
        XPBD,
        SDIRK2,
        SDIRK3,
        TRBDF2,
        ESDIRK,
        BDF,
        Rosenbrock,
        RadauIIA,
        Dopri5,
        IMEX,
    )
}

# peers: other codes' solvers run beside simrun's methods on the same system and tolerances (runner/execution/peers.py),
# and trajectories other codes computed, measured on the config's system (runner/execution/recorded.py); not methods
# simrun steps, so the analyses of the methods (amplification, damping, stability) leave them out
PEERS: dict[str, type[Integrator]] = {SolveIVP.name: SolveIVP, Recorded.name: Recorded}

# engines: other codes' integrators stepping simrun's systems translated into their own models, a step at a time (so
# their amplification matrices are probed as simrun's own methods' are); each needs its extra (pip install '.[engines]')
ENGINES: dict[str, type[Integrator]] = {MuJoCo.name: MuJoCo, Newton.name: Newton}

__all__ = ["ENGINES", "INTEGRATORS", "PEERS", "Integrator", "IncrementalPotential", "SegmentPotential", "State",
           "ButcherTableau", "ExplicitRungeKutta"]
