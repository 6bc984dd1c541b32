"""Mechanical systems, found by their config name."""

from .base import System
from .circular_motion import CircularMotion, CircularMotionParams
from .cloth import Cloth, ClothParams
from .spring_mass import SpringMass, SpringMassParams

# config name -> parameter model; `params.build()` gives the system
SYSTEMS = {
    "spring_mass": SpringMassParams,
    "circular_motion": CircularMotionParams,
    "cloth": ClothParams,
}

__all__ = ["SYSTEMS", "System", "SpringMass", "SpringMassParams", "CircularMotion", "CircularMotionParams", "Cloth", "ClothParams"]
