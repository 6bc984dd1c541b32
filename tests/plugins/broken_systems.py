"""Plug-ins that break the contract, for tests/test_plugins.py: each one is a mistake a user could make."""

import numpy as np
from pydantic import BaseModel

from pendulum_chain import Chain, ChainParams
from simrun.systems import SystemParams


class NotAParams(BaseModel):
    """A pydantic model, but not a SystemParams."""

    type: str = "broken_systems:NotAParams"


class WithoutSystemClass(SystemParams):
    """A SystemParams whose system_class was never set."""

    type: str = "broken_systems:WithoutSystemClass"

    @property
    def dof_count(self) -> int:
        return 1


class WrongGradientChain(Chain):
    """dP/dx 0.1 % too large: a typo in a constant."""

    def gradient(self, x):
        return 1.001 * super().gradient(x)


class WrongGradientParams(ChainParams):
    type: str = "broken_systems:WrongGradientParams"


WrongGradientParams.system_class = WrongGradientChain


class WrongHessianChain(Chain):
    """d2P/dx2 0.1 % too large, the gradient right."""

    def hessian(self, x, project_spd=False):
        return 1.001 * super().hessian(x, project_spd)


class WrongHessianParams(ChainParams):
    type: str = "broken_systems:WrongHessianParams"


WrongHessianParams.system_class = WrongHessianChain


class RoundOffReferenceChain(Chain):
    """E_ref = |KE0| + |PE0| with no floor: a chain released from horizontal has PE0 ~ 1e-17 J of round-off."""

    def energy_scale(self):
        return abs(self.kinetic_energy(self.v0)) + abs(self.potential_energy(self.x0))


class RoundOffReferenceParams(ChainParams):
    type: str = "broken_systems:RoundOffReferenceParams"
    angle: float = float(np.pi / 2)


RoundOffReferenceParams.system_class = RoundOffReferenceChain


class WithoutEnergyChain(Chain):
    """Forces only: the potential energy was never written (a port of a force-based code)."""

    def potential_energy(self, x):
        raise NotImplementedError("WithoutEnergyChain.potential_energy")


class WithoutEnergyParams(ChainParams):
    type: str = "broken_systems:WithoutEnergyParams"


WithoutEnergyParams.system_class = WithoutEnergyChain
