"""A particle held on a circle by a central force: linear (f = -m w^2 x) or gravity (f = -GMm x/|x|^3)."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field

from .base import System, SystemParams
from .compliant import anchored_springs
from .forms import NotOffered, ProjectiveForm


class CircularMotionParams(SystemParams):
    """Config of `circular_motion`: starts at (radius, 0), velocity (0, radius w): the exact motion is the circle."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["circular_motion"] = "circular_motion"
    force: Literal["linear", "gravity"] = Field("linear", description="linear: f = -m w^2 x; gravity: f = -GMm x/|x|^3, GM = w^2 r^3")
    mass: float = Field(1.0, gt=0, allow_inf_nan=False, description="m (kg)")
    radius: float = Field(1.0, gt=0, allow_inf_nan=False, description="r (m)")
    angular_velocity: float = Field(1.0, gt=0, allow_inf_nan=False, description="w (rad/s)")
    dimension: Literal[2, 3] = Field(2, description="2-D plane, or 3-D space with the orbit in the x-y plane")

    @property
    def dof_count(self) -> int:
        return self.dimension


class CircularMotion(System):
    """Uniform circular motion x(t) = r (cos wt, sin wt), for both force laws (GM = w^2 r^3)."""

    planar = True  # x0 and v0 lie in the x-y plane and the force is central: the orbit stays there

    def __init__(self, params: CircularMotionParams):
        self.params = params
        self.dim = params.dimension
        self.dof_count = params.dimension
        m, r, w = params.mass, params.radius, params.angular_velocity
        self.mass = np.full(self.dof_count, m)
        self.x0 = np.zeros(self.dof_count)
        self.x0[0] = r
        self.v0 = np.zeros(self.dof_count)
        self.v0[1] = r * w
        self.linear = params.force == "linear"
        self.stiffness = m * w * w  # linear law: P = m w^2 |x|^2 / 2
        self.gm_m = w * w * r ** 3 * m  # gravity: P = -GMm / |x|
        self._linear_hessian = np.eye(self.dof_count) * self.stiffness

    @property
    def test_frequency(self) -> float | None:
        """w (rad/s) with the linear force (P = m w^2 |x|^2 / 2: uncoupled copies of q'' + w^2 q = 0); None with gravity."""
        return float(self.params.angular_velocity) if self.linear else None

    def potential_energy(self, x):
        if self.linear:
            return 0.5 * self.stiffness * float(x.dot(x))
        return -self.gm_m / math.sqrt(x.dot(x))

    # The step path: one array operation instead of the base class's force -> division chain.
    def acceleration(self, x, v):
        if self.linear:
            return (-self.stiffness / self.params.mass) * x
        return (-self.gm_m / (self.params.mass * math.sqrt(x.dot(x)) ** 3)) * x

    # The per-step path (energy check, samples, velocity update): the base class's formulas on scalars
    # (the same products and sums, to round-off), without the observables dictionary and without
    # numpy operations whose fixed cost dwarfs the arithmetic on two or three numbers.
    def total_energy(self, x, v):
        squared_radius = _squared_norm(x.tolist())
        potential = 0.5 * self.stiffness * squared_radius if self.linear else -self.gm_m / math.sqrt(squared_radius)
        return 0.5 * self.params.mass * _squared_norm(v.tolist()) + potential

    def write_observables(self, x, v, row):
        """energy, kinetic_energy, potential_energy, momentum (dim), angular_momentum (3), radius."""
        m = self.params.mass
        if self.dim == 2:
            (qx, qy), (vx, vy) = x.tolist(), v.tolist()
            px, py = m * vx, m * vy
            kinetic = 0.5 * (px * vx + py * vy)
            squared_radius = qx * qx + qy * qy
        else:
            (qx, qy, qz), (vx, vy, vz) = x.tolist(), v.tolist()
            px, py, pz = m * vx, m * vy, m * vz
            kinetic = 0.5 * (px * vx + py * vy + pz * vz)
            squared_radius = qx * qx + qy * qy + qz * qz
        radius = math.sqrt(squared_radius)
        potential = 0.5 * self.stiffness * squared_radius if self.linear else -self.gm_m / radius
        energy = kinetic + potential
        if self.dim == 2:
            row[:9] = (energy, kinetic, potential, px, py, 0.0, 0.0, qx * py - qy * px, radius)
        else:
            row[:10] = (energy, kinetic, potential, px, py, pz,
                        qy * pz - qz * py, qz * px - qx * pz, qx * py - qy * px, radius)
        return energy

    def kick(self, x, v, dt):
        """v + dt a(x) with a(x) = (factor) x: the factor once, then the components as scalars (a new
        array from two or three floats costs less than the two array operations on so few numbers)."""
        position, velocity = x.tolist(), v.tolist()
        if self.linear:
            factor = dt * (-self.stiffness / self.params.mass)
        else:
            factor = dt * (-self.gm_m / (self.params.mass * math.sqrt(_squared_norm(position)) ** 3))
        if self.dim == 2:
            return np.array((velocity[0] + factor * position[0], velocity[1] + factor * position[1]))
        return np.array((velocity[0] + factor * position[0], velocity[1] + factor * position[1],
                         velocity[2] + factor * position[2]))

    def gradient(self, x):
        if self.linear:
            return self.stiffness * x
        r = math.sqrt(x.dot(x))
        return self.gm_m * x / r ** 3

    def hessian(self, x, project_spd=False):
        if self.linear:
            return self._linear_hessian
        r = math.sqrt(x.dot(x))
        # d/dx (GMm x / r^3) = GMm (I / r^3 - 3 x x^T / r^5): one negative (radial) eigenvalue
        hessian = self.gm_m * (np.eye(self.dof_count) / r ** 3 - 3.0 * np.outer(x, x) / r ** 5)
        if project_spd:
            eigenvalues, eigenvectors = np.linalg.eigh(hessian)
            filtered = np.abs(eigenvalues) if project_spd == "abs" else np.maximum(eigenvalues, 0.0)
            hessian = (eigenvectors * filtered) @ eigenvectors.T
        return hessian

    damping_is_constant = True  # undamped

    @property
    def quadratic_potential(self) -> bool:
        return self.linear  # k/2 |x|^2, k > 0; the gravitational law is not quadratic

    def projective_form(self):
        # the linear law k/2 |x|^2 is a zero-length Hookean spring to the centre
        if not self.linear:
            return NotOffered("the gravitational law -GMm/|x| is not a Hookean spring")
        return ProjectiveForm(rest_stiffness=lambda: self._linear_hessian)

    def compliant_form(self):
        # the linear law m w^2 |x|^2 / 2 is the vector constraint C = x - 0 of compliance 1/(m w^2)
        if not self.linear:
            return NotOffered("the gravitational law -GMm/|x| is not a Hookean spring")
        return anchored_springs(self.stiffness, 0.0, self.dim)

    energy_reference_name = "|E0| (initial energy)"

    def energy_scale(self) -> float:
        """|E0| (J): the orbit's own energy, m w^2 r^2 for the linear law, -m w^2 r^2 / 2 for gravity (a bound orbit)."""
        return abs(self.total_energy(self.x0, self.v0))

    def exact_solution(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        r, w = self.params.radius, self.params.angular_velocity
        x = np.zeros((t.size, self.dof_count))
        v = np.zeros((t.size, self.dof_count))
        x[:, 0], x[:, 1] = r * np.cos(w * t), r * np.sin(w * t)
        v[:, 0], v[:, 1] = -r * w * np.sin(w * t), r * w * np.cos(w * t)
        return x, v

    def extra_observables(self, x, v):
        return {"radius": math.sqrt(x.dot(x))}


CircularMotionParams.system_class = CircularMotion


def _squared_norm(components: list[float]) -> float:
    """|c|^2 of a 2- or 3-component vector given as floats: cheaper than ndarray.dot on so few numbers."""
    return components[0] * components[0] + components[1] * components[1] + (
        components[2] * components[2] if len(components) == 3 else 0.0)
