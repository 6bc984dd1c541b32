"""The contract every mechanical system fulfils.

A system is static: it describes the mechanics (mass, potential, damping, constraints) and never
holds the changing state. Integrators and the runner pass positions ``x`` and velocities ``v``
(arrays of shape ``(dof_count,)``, SI units) into it.

Implementers supply
- ``dof_count``, ``dim`` (spatial dimension), ``mass`` (lumped diagonal mass, ``(dof_count,)``, kg),
  ``x0`` and ``v0``;
- ``potential_energy(x)`` (J), ``gradient(x)`` (dP/dx, N) and ``hessian(x, project_spd=False)``
  (d^2P/dx^2, N/m; a dense array for small systems, a scipy sparse matrix for large ones);
- optionally ``damping_matrix(x)`` (D in f_d = -D(x) v, N s/m; ``None`` when undamped),
  ``fixed_dofs`` (indices that never move), ``observables(x, v)`` and ``exact_solution(t)``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class System(ABC):
    """Base class of the systems: derived quantities written once, in terms of the primitives."""

    dof_count: int
    dim: int
    mass: np.ndarray
    x0: np.ndarray
    v0: np.ndarray
    fixed_dofs: np.ndarray = np.zeros(0, dtype=np.intp)
    # small systems keep x and v in every sample; large ones (cloth) keep them as `frames` instead
    records_state_per_sample: bool = True

    # -- primitives every system provides ------------------------------------------------------
    @abstractmethod
    def potential_energy(self, x: np.ndarray) -> float:
        """P(x) (J)."""

    @abstractmethod
    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dP/dx (N), shape (dof_count,)."""

    @abstractmethod
    def hessian(self, x: np.ndarray, project_spd: bool = False):
        """d^2P/dx^2 (N/m), (dof_count, dof_count); SPD-projected on request."""

    # -- optional parts with neutral defaults --------------------------------------------------
    def damping_matrix(self, x: np.ndarray):
        """D(x) in the damping force f_d = -D(x) v, or None for an undamped system."""
        return None

    def exact_solution(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Exact (x, v) at times t, shapes (len(t), dof_count), or None where none is known."""
        return None

    def extra_observables(self, x: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray | float]:
        """System-specific observables (e.g. the radius of circular motion)."""
        return {}

    # -- derived quantities ---------------------------------------------------------------------
    def kinetic_energy(self, v: np.ndarray) -> float:
        return 0.5 * float(np.dot(self.mass * v, v))

    def total_energy(self, x: np.ndarray, v: np.ndarray) -> float:
        return self.kinetic_energy(v) + self.potential_energy(x)

    def damping_force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        damping = self.damping_matrix(x)
        if damping is None:
            return None
        return -(damping @ v)

    def force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Total force -dP/dx + f_d(x, v) (N); zero on fixed degrees of freedom."""
        force = -self.gradient(x)
        damping = self.damping_force(x, v)
        if damping is not None:
            force = force + damping
        if self.fixed_dofs.size:
            force[self.fixed_dofs] = 0.0
        return force

    def acceleration(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """M^-1 f(x, v) (m/s^2)."""
        return self.force(x, v) / self.mass

    def momentum(self, v: np.ndarray) -> np.ndarray:
        """Linear momentum sum_i m_i v_i, shape (dim,)."""
        return (self.mass * v).reshape(-1, self.dim).sum(axis=0)

    def angular_momentum(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Angular momentum about the origin sum_i x_i x m_i v_i, shape (3,) (2-D systems: (0, 0, Lz))."""
        if self.dim == 1:
            return np.zeros(3)
        positions = x.reshape(-1, self.dim)
        momenta = (self.mass * v).reshape(-1, self.dim)
        if self.dim == 2:
            lz = np.sum(positions[:, 0] * momenta[:, 1] - positions[:, 1] * momenta[:, 0])
            return np.array([0.0, 0.0, lz])
        return np.cross(positions, momenta).sum(axis=0)

    def observables(self, x: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray | float]:
        """Every recorded observable at (x, v): energies (J), momenta and the system's own."""
        kinetic = self.kinetic_energy(v)
        potential = self.potential_energy(x)
        values: dict[str, np.ndarray | float] = {
            "energy": kinetic + potential,
            "kinetic_energy": kinetic,
            "potential_energy": potential,
            "momentum": self.momentum(v),
        }
        if self.dim >= 2:
            values["angular_momentum"] = self.angular_momentum(x, v)
        values.update(self.extra_observables(x, v))
        return values

    def energy_scale(self) -> float:
        """A characteristic energy (J) against which energy growth is judged: |KE0| + |PE0|, else 1."""
        scale = abs(self.kinetic_energy(self.v0)) + abs(self.potential_energy(self.x0))
        return scale if scale > 0.0 else 1.0
