"""The terms of a mass-spring potential, spring by spring: the springs' geometry at one x (``SpringGeometry``) and the
spring laws (``SPRING_LAWS``: energy, gradient factor and Hessian block of W_e(|x_i - x_j|)); the damping models are
systems/vertex/damping.py's (``DAMPING_MODELS``), which fem takes too. ``system`` in a law's methods is the MassSpring
whose springs it evaluates (its stiffness and rest lengths, per spring)."""

from __future__ import annotations

import numpy as np

from ..contact.sdf import filter_eigenvalues


class SpringGeometry:
    """All springs at one x: x_i - x_j (m), lengths L (m), stretches L - l0 (m), tensions k (L - l0) (N);
    the unit directions and the spring energy on first use (an explicit step needs neither).
    Shared by every evaluation at the same x: read it only."""

    __slots__ = ("x", "delta", "length", "stretch", "tension", "_direction", "_energy")

    def __init__(self, x: np.ndarray, delta: np.ndarray, length: np.ndarray, stretch: np.ndarray, tension: np.ndarray):
        self.x, self.delta, self.length, self.stretch, self.tension = x, delta, length, stretch, tension
        self._direction = None
        self._energy = None

    @property
    def direction(self) -> np.ndarray:
        """(x_i - x_j) / L, shape (springs, d)."""
        if self._direction is None:
            self._direction = self.delta / self.length[:, None]
        return self._direction


class HookeanLaw:
    """W = k/2 (L - l0)^2: force k (L - l0) along the spring; Hessian block (lectures)
    k [u u^T + (1 - l0/L)(I - u u^T)], whose transverse factor turns negative under compression."""

    name = "hookean"
    rest_factor = 1.0  # d^2 W / dL^2 at L = l0, in units of k

    @staticmethod
    def energy(system, geometry: SpringGeometry) -> float:
        return 0.5 * float(np.dot(geometry.tension, geometry.stretch))

    @staticmethod
    def energy_changes(system, length: np.ndarray, moved_length: np.ndarray, squared_change: np.ndarray) -> np.ndarray:
        """W(L') - W(L) per spring (J) without cancellation: k/2 (L' - L)(L' + L - 2 l0), L' - L = (L'^2 - L^2)/(L' + L),
        from the lengths (m) and ``squared_change`` L'^2 - L^2 (m^2), which the caller forms without cancellation."""
        return 0.5 * system.stiffness * squared_change / (moved_length + length) * (moved_length + length - 2.0 * system.rest_length)

    @staticmethod
    def gradient_factor(system, geometry: SpringGeometry) -> np.ndarray:
        """c_e with dW_e/dx_i = c_e (x_i - x_j): k (L - l0) / L."""
        return geometry.tension / geometry.length

    @staticmethod
    def unit_gradient_factor(system, geometry: SpringGeometry) -> np.ndarray:
        """c_e per unit stiffness, (L - l0) / L: W is linear in k (calibration's sensitivities)."""
        return geometry.stretch / geometry.length

    @staticmethod
    def blocks(system, geometry: SpringGeometry, project_spd: bool) -> np.ndarray:
        outer = geometry.direction[:, :, None] * geometry.direction[:, None, :]
        transverse = filter_eigenvalues(1.0 - system.rest_length / geometry.length, project_spd)
        return system.stiffness[:, None, None] * (outer + transverse[:, None, None] * (system.identity - outer))


class SquaredLengthLaw:
    """W = k l0^2/2 (L^2/l0^2 - 1)^2, the spring of the course code "Physics-Based Simulation"
    (its mass-spring demo): force 2k (s - 1)(x_i - x_j) with s = L^2/l0^2; Hessian block
    2k [(3 s - 1) u u^T + (s - 1)(I - u u^T)]. The SPD projection clamps both factors at 0."""

    name = "squared_length"
    rest_factor = 4.0  # d^2 W / dL^2 at L = l0: k l0^2/2 * 8 L^2 / l0^4 = 4 k

    @staticmethod
    def _ratio(system, geometry):
        return np.square(geometry.length) / system.rest_length_squared

    @staticmethod
    def energy(system, geometry) -> float:
        strain = SquaredLengthLaw._ratio(system, geometry) - 1.0
        return 0.5 * float(np.dot(system.stiffness * system.rest_length_squared, np.square(strain)))

    @staticmethod
    def energy_changes(system, length, moved_length, squared_change):
        """W(L') - W(L) per spring (J) without cancellation: k/2 (L'^2 - L^2)(s' + s - 2), s = L^2/l0^2."""
        ratios = (np.square(moved_length) + np.square(length)) / system.rest_length_squared
        return 0.5 * system.stiffness * squared_change * (ratios - 2.0)

    @staticmethod
    def gradient_factor(system, geometry) -> np.ndarray:
        return 2.0 * system.stiffness * (SquaredLengthLaw._ratio(system, geometry) - 1.0)

    @staticmethod
    def unit_gradient_factor(system, geometry) -> np.ndarray:
        return 2.0 * (SquaredLengthLaw._ratio(system, geometry) - 1.0)

    @staticmethod
    def blocks(system, geometry, project_spd):
        ratio = SquaredLengthLaw._ratio(system, geometry)
        along = filter_eigenvalues(3.0 * ratio - 1.0, project_spd)
        transverse = filter_eigenvalues(ratio - 1.0, project_spd)
        outer = geometry.direction[:, :, None] * geometry.direction[:, None, :]
        return (2.0 * system.stiffness)[:, None, None] * (along[:, None, None] * outer
                                                         + transverse[:, None, None] * (system.identity - outer))


SPRING_LAWS = {law.name: law for law in (HookeanLaw, SquaredLengthLaw)}
