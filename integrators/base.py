"""The contract of a time integrator, and the incremental potential that most implicit ones share.

An integrator is a small frozen object: its parameters are pydantic fields (so they double as the
config schema) and its class declares ``name``, ``order``, ``explicit`` and a one-line ``summary``.
It supplies
- ``step(system, state, dt, solver) -> (State, SolveStats)``: one step of size dt (s);
- optionally ``start(system, state) -> State``: fill the method's carried quantities (``State.aux``,
  e.g. the acceleration of Newmark or the previous state of a multistep method) from (x0, v0).

Implicit methods that are the minimisation of an incremental potential (DESIGN.md) build an
``IncrementalPotential`` and hand it to the solver, which knows nothing about integrators.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.sparse
from pydantic import BaseModel, ConfigDict

from simrun.solvers import SolveStats
from simrun.systems import System


@dataclass(frozen=True, slots=True)
class State:
    """The changing state: time t (s), positions x (m), velocities v (m/s), and a method's carried arrays."""

    t: float
    x: np.ndarray
    v: np.ndarray
    aux: tuple[np.ndarray, ...] = ()


class Integrator(BaseModel):
    """Base of all integrators; see the module docstring for the contract."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: ClassVar[str]
    order: ClassVar[int]
    explicit: ClassVar[bool]
    summary: ClassVar[str]

    def start(self, system: System, state: State) -> State:
        return state

    @abstractmethod
    def step(self, system: System, state: State, dt: float, solver) -> tuple[State, SolveStats]:
        """Advance ``state`` by dt (s); implicit methods solve with ``solver``."""

    @property
    def label(self) -> str:
        """The name, with every parameter that differs from its default: ``generalized_alpha[rho_inf=0]``."""
        changed = [
            f"{key}={value:g}" if isinstance(value, float) else f"{key}={value}"
            for key, value in self.model_dump().items()
            if value != type(self).model_fields[key].default
        ]
        return f"{self.name}[{','.join(changed)}]" if changed else self.name


def add_diagonal(matrix, diagonal: np.ndarray):
    """matrix + diag(diagonal), for a dense array or a scipy sparse matrix."""
    if scipy.sparse.issparse(matrix):
        return matrix + scipy.sparse.diags(diagonal, format=matrix.format)
    result = np.array(matrix, dtype=float)
    result[np.diag_indices_from(result)] += diagonal
    return result


class IncrementalPotential:
    """E(y) = 1/2 (y - y~)^T M (y - y~) + s [P(y) + 1/(2 b) (y - a)^T D (y - a)],  s = c h^2.

    The minimiser solves M (y - y~) = s f(y, v(y)) with v(y) = (y - a)/b the method's velocity at
    the evaluation point y, so every incremental-potential method is described by its predictor
    y~, scale s, and velocity map (a, b). Damping f_d = -D v enters as a Rayleigh term, with D taken
    at the start of the step (exact for constant D).

    Parameters: system; y_tilde (m), shape (dof_count,); scale s = c h^2 (s^2);
    velocity_origin a (m) and velocity_divisor b (s); damping_at: positions at which D is taken.
    """

    def __init__(self, system: System, y_tilde: np.ndarray, scale: float,
                 velocity_origin: np.ndarray | None = None, velocity_divisor: float = 1.0,
                 damping_at: np.ndarray | None = None):
        self.system = system
        self.y_tilde = y_tilde
        self.scale = scale
        self.fixed_dofs = system.fixed_dofs
        damping = None if damping_at is None else system.damping_matrix(damping_at)
        self.damping = damping
        self.velocity_origin = velocity_origin
        self.damping_weight = scale / velocity_divisor
        # the residual M (y - y~) + ... cannot resolve differences below round-off of its largest term
        self.residual_floor = 64.0 * np.finfo(float).eps * float(np.max(np.abs(system.mass * y_tilde), initial=1e-300))

    def value(self, y: np.ndarray) -> float:
        offset = y - self.y_tilde
        energy = 0.5 * float(np.dot(self.system.mass * offset, offset)) + self.scale * self.system.potential_energy(y)
        if self.damping is not None:
            rate = y - self.velocity_origin
            energy += 0.5 * self.damping_weight * float(rate @ (self.damping @ rate))
        return energy

    def gradient(self, y: np.ndarray) -> np.ndarray:
        gradient = self.system.mass * (y - self.y_tilde) + self.scale * self.system.gradient(y)
        if self.damping is not None:
            gradient += self.damping_weight * (self.damping @ (y - self.velocity_origin))
        if self.fixed_dofs.size:
            gradient[self.fixed_dofs] = 0.0
        return gradient

    def hessian(self, y: np.ndarray):
        hessian = self.scale * self.system.hessian(y)
        if self.damping is not None:
            hessian = hessian + self.damping_weight * self.damping
        return add_diagonal(hessian, self.system.mass)
