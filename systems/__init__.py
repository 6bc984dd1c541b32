"""simrun.systems (folder systems/): mechanical systems, found by their config name.

``SYSTEMS`` maps each config name (``system.type``) to its parameter model, a ``SystemParams``;
``params.build()`` gives the ``System`` and ``system.capabilities`` what it declares about itself.
A new system joins with a params model + a System subclass + an entry in SYSTEMS; the tests in
tests/test_systems.py then check it (derivatives, damping, pins, observables, capabilities) without
anyone writing a test.
"""

from .base import Capabilities, System, SystemParams
from .circular_motion import CircularMotion, CircularMotionParams
from .cloth import Cloth, ClothParams
from .fem.params import FemParams
from .fem.system import Fem
from .mass_spring.params import MassSpringParams
from .mass_spring.system import MassSpring
from .spring_mass import SpringMass, SpringMassParams

# config name -> parameter model; `params.build()` gives the system
SYSTEMS = {
    "spring_mass": SpringMassParams,
    "circular_motion": CircularMotionParams,
    "cloth": ClothParams,
    "mass_spring": MassSpringParams,
    "fem": FemParams,
}

__all__ = ["SYSTEMS", "Capabilities", "System", "SystemParams", "SpringMass", "SpringMassParams", "CircularMotion",
           "CircularMotionParams", "Cloth", "ClothParams", "MassSpring", "MassSpringParams", "Fem", "FemParams"]
