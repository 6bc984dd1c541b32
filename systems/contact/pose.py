"""A collider in contact: its shape (an SDF, sdf.py) with its penalty stiffness and its motion, a constant velocity
and a constant rotation; every query maps the points into the shape's t = 0 frame and the derivatives back."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..constraints import cross, rotate
from .sdf import Collider


@dataclass
class ColliderContact:
    """One analytic or sampled collider with its penalty stiffness (N/m; None for IPC) and its motion: the collider's
    own constant ``velocity`` (m/s), and ``spin`` = (center (d,) m, unit axis (3,), rate rad/s) or None, a rotation
    about an axis through ``center`` (which moves with the velocity; 2-D: about z). At time t a point p of space is
    the point q = R(t)^T (p - c - v t) + c of the t = 0 shape, R(t) the rotation by rate t: every query maps the
    points there and the derivatives back (grad phi -> R grad phi, Hess phi -> R Hess phi R^T)."""

    collider: Collider
    stiffness: float | None
    spin: tuple[np.ndarray, np.ndarray, float] | None = None

    @property
    def moves(self) -> bool:
        return bool(np.any(self.collider.velocity)) or self.spin is not None

    def _offset(self, time: float) -> np.ndarray | None:
        velocity = self.collider.velocity
        return None if not np.any(velocity) else velocity * time

    def _rotation(self, time: float) -> np.ndarray:
        center, axis, rate = self.spin
        return rotate(np.eye(center.size), axis, rate * time).T

    def _local(self, points: np.ndarray, time: float) -> np.ndarray:
        """The points in the t = 0 frame of a spinning collider (q = R^T (p - c - v t) + c)."""
        center = self.spin[0] + self.collider.velocity * time
        return (points - center) @ self._rotation(time) + self.spin[0]

    def signed_distance(self, points: np.ndarray, time: float) -> np.ndarray:
        if self.spin is None:
            return self.collider.signed_distance(points, self._offset(time))
        return self.collider.signed_distance(self._local(points, time))

    def derivatives(self, points: np.ndarray, time: float):
        if self.spin is None:
            return self.collider.derivatives(points, self._offset(time))
        phi, gradient, hessian = self.collider.derivatives(self._local(points, time))
        rotation = self._rotation(time)
        return phi, gradient @ rotation.T, np.einsum("ij,kjl,ml->kim", rotation, hessian, rotation)

    def distance_and_normal(self, points: np.ndarray, time: float):
        if self.spin is None:
            return self.collider.distance_and_normal(points, self._offset(time))
        phi, normal = self.collider.distance_and_normal(self._local(points, time))
        return phi, normal @ self._rotation(time).T

    def scaled_hessian(self, points: np.ndarray, scale: np.ndarray, project_spd, time: float) -> np.ndarray:
        if self.spin is None:
            return self.collider.scaled_hessian(points, scale, project_spd, self._offset(time))
        rotation = self._rotation(time)  # a congruence: the projection's eigenvalues are the same in either frame
        local = self.collider.scaled_hessian(self._local(points, time), scale, project_spd)
        return np.einsum("ij,kjl,ml->kim", rotation, local, rotation)

    def time_of_impact(self, start: np.ndarray, end: np.ndarray, time: float) -> np.ndarray:
        """Along straight moves with the collider held where it is at ``time``: still straight in its own frame."""
        if self.spin is None:
            return self.collider.time_of_impact(start, end, self._offset(time))
        return self.collider.time_of_impact(self._local(start, time), self._local(end, time))

    def bounding_box(self, time: float):
        box = self.collider.bounding_box(self._offset(time))
        if box is None or self.spin is None:
            return box
        # the box's corners turned about the (moved) centre: a box around the turned shape
        lower, upper = box
        corners = np.array(np.meshgrid(*zip(lower, upper), indexing="ij")).reshape(lower.size, -1).T
        center = self.spin[0] + self.collider.velocity * time
        turned = (corners - center) @ self._rotation(time).T + center
        return turned.min(axis=0), turned.max(axis=0)

    def velocity_at(self, points: np.ndarray, time: float) -> np.ndarray:
        """The collider's velocity (m/s) at the points (k, d) of space: v + omega x (p - c(t))."""
        velocity = np.broadcast_to(self.collider.velocity, points.shape)
        if self.spin is None:
            return velocity
        center, axis, rate = self.spin
        omega = rate * (axis if points.shape[1] == 3 else np.array([0.0, 0.0, axis[2]]))
        return velocity + cross(omega, points - (center + self.collider.velocity * time))

    def carry(self, points: np.ndarray, start: float, end: float) -> np.ndarray:
        """The points moved rigidly with the collider from its pose at ``start`` to its pose at ``end`` (s)."""
        if self.spin is None:
            return points + self.collider.velocity * (end - start)
        local = self._local(points, start)
        center = self.spin[0] + self.collider.velocity * end
        return (local - self.spin[0]) @ self._rotation(end).T + center

    @property
    def reach_speed(self) -> float:
        """A bound (m/s) on the speed of the collider's surface, for how far it can travel in a step: |v| + |rate| r,
        r the distance from the spin's centre to the farthest point of the shape's box (inf when it is unbounded)."""
        speed = float(np.linalg.norm(self.collider.velocity))
        if self.spin is None:
            return speed
        box = self.collider.bounding_box()
        if box is None:
            return math.inf
        corners = np.array(np.meshgrid(*zip(*box), indexing="ij")).reshape(box[0].size, -1).T
        return speed + abs(self.spin[2]) * float(np.max(np.linalg.norm(corners - self.spin[0], axis=1)))
