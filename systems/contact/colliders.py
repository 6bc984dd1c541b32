"""Contact colliders: the analytic signed distance fields (plane, sphere, box, capsule, torus) and the sampled one
(grid_sdf.py), in 2-D and 3-D, registered by their config names in COLLIDERS; the contract is sdf.py's Collider."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .grid_sdf import GridSDF, load_grid_sdf
from .sdf import (Collider, _ball_derivatives, _enter_ball, _outer, _perpendicular, _positive, _unit, _vector,
                  filter_eigenvalues)


@dataclass(frozen=True, eq=False)
class Plane(Collider):
    """A half-space: phi(p) = n . (p - point), outside where phi >= 0; grad phi = n, hess phi = 0 (smooth).

    normal: (d,) outward normal (normalised here, nonzero); point: (d,) m, a point on the boundary."""

    shape: ClassVar[str] = "plane"
    positions: ClassVar[tuple[str, ...]] = ("point",)
    normal: np.ndarray
    point: np.ndarray

    def _check(self) -> int:
        normal = _unit(self.normal, "normal")
        self._set(normal=normal, point=_vector(self.point, "point", normal.size))
        return normal.size

    def _distance(self, q):
        return (q - self.point) @ self.normal

    def _derivatives(self, q):
        k, d = q.shape
        return self._distance(q), np.tile(self.normal, (k, 1)), np.zeros((k, d, d))

    def distance_and_normal(self, points, offset=None):
        q = self._local(points, offset)
        return self._distance(q), np.broadcast_to(self.normal, q.shape)

    def scaled_hessian(self, points, scale, project_spd=False, offset=None):
        return np.zeros((len(points), self.dim, self.dim))  # a plane is flat

    def _time_of_impact(self, start, end, level):
        """Exact: phi is linear along the move, phi(tau) = phi0 + tau (phi1 - phi0) = level."""
        gap0, gap1 = self._distance(start) - level, self._distance(end) - level
        tau = np.full(len(start), np.inf)
        crossing = (gap0 > 0) & (gap1 <= 0)
        tau[crossing] = gap0[crossing] / (gap0[crossing] - gap1[crossing])
        tau[gap0 <= 0] = 0.0
        return tau


@dataclass(frozen=True, eq=False)
class Sphere(Collider):
    """A ball (a disc in 2-D): phi(p) = |p - c| - r, grad phi = n = (p - c)/|p - c|, hess phi = (I - n n^T)/|p - c|.

    center: (d,) m; radius: m (> 0). Kink at the centre: there grad phi = e_0 (the first axis) and hess phi = 0."""

    shape: ClassVar[str] = "sphere"
    positions: ClassVar[tuple[str, ...]] = ("center",)
    center: np.ndarray
    radius: float

    def _check(self) -> int:
        self._set(center=_vector(self.center, "center"), radius=_positive(self.radius, "radius"))
        return self.center.size

    def _distance(self, q):
        return np.linalg.norm(q - self.center, axis=1) - self.radius

    def _derivatives(self, q):
        return _ball_derivatives(q - self.center, self.radius, np.eye(q.shape[1])[0])

    # The penalty's force and Hessian with the operations the sphere contact always used (the cloth's recorded
    # results, tests/data/cloth_before_mass_spring.npz, depend on them bit for bit).
    def _radial(self, points, offset):
        relative = self._local(points, offset) - self.center
        distance = np.sqrt(np.einsum("ij,ij->i", relative, relative))
        return distance, relative / np.maximum(distance, 1e-300)[:, None]

    def distance_and_normal(self, points, offset=None):
        distance, normal = self._radial(points, offset)
        return distance - self.radius, normal

    def scaled_hessian(self, points, scale, project_spd=False, offset=None):
        """s (I - n n^T)/|p - c|: one eigenvalue s/|p - c|, filtered as asked, across the normal."""
        distance, normal = self._radial(points, offset)
        curvature = filter_eigenvalues(scale / distance, project_spd)[:, None, None]
        return curvature * (np.eye(self.dim) - normal[:, :, None] * normal[:, None, :])

    def _bounds(self):
        return self.center - self.radius, self.center + self.radius

    def _time_of_impact(self, start, end, level):
        """Exact: the smaller root of |start - c + tau (end - start)| = r + level."""
        return _enter_ball(start - self.center, end - start, self.radius + level)


@dataclass(frozen=True, eq=False)
class Box(Collider):
    """An axis-aligned box, exact SDF: with a = |p - c| - h (per axis), phi = |max(a, 0)| + min(max_i a_i, 0).

    Outside, phi is the distance to the nearest face, edge or corner: grad phi = s * max(a, 0) / phi (s = sign(p - c))
    and hess phi = (diag(a > 0) - grad grad^T) / phi, zero in face regions. Inside (and on the surface) phi = a_i of
    the nearest face i: grad phi = s_i e_i, hess phi = 0. center: (d,) m; half_extents: (d,) m (> 0).
    Kinks: on a tie between faces the lowest axis is taken; on a symmetry plane (p_i = c_i) s_i = +1."""

    shape: ClassVar[str] = "box"
    positions: ClassVar[tuple[str, ...]] = ("center",)
    center: np.ndarray
    half_extents: np.ndarray

    def _check(self) -> int:
        center = _vector(self.center, "center")
        half = _vector(self.half_extents, "half_extents", center.size)
        if not np.all(half > 0):
            raise ValueError(f"half_extents must be > 0, got {half.tolist()}")
        self._set(center=center, half_extents=half)
        return center.size

    def _distance(self, q):
        a = np.abs(q - self.center) - self.half_extents
        return np.linalg.norm(np.maximum(a, 0.0), axis=1) + np.minimum(a.max(axis=1), 0.0)

    def _derivatives(self, q):
        k, d = q.shape
        local = q - self.center
        sign = np.where(local >= 0, 1.0, -1.0)
        a = np.abs(local) - self.half_extents
        beyond = a > 0  # axes along which the point lies past a face
        past = np.where(beyond, a, 0.0)
        out = np.linalg.norm(past, axis=1)
        outside = out > 0
        safe = np.where(outside, out, 1.0)
        nearest = np.argmax(a, axis=1)  # inside: the face whose plane is closest
        grad = np.zeros((k, d))
        grad[np.arange(k), nearest] = sign[np.arange(k), nearest]
        grad = np.where(outside[:, None], sign * past / safe[:, None], grad)
        hess = (beyond[:, :, None] * np.eye(d) - _outer(grad)) / safe[:, None, None]
        hess[~outside] = 0.0
        return out + np.minimum(a.max(axis=1), 0.0), grad, hess

    def _bounds(self):
        return self.center - self.half_extents, self.center + self.half_extents


@dataclass(frozen=True, eq=False)
class Capsule(Collider):
    """The points within radius of the segment a-b: phi(p) = |p - x(t)| - r, x(t) = a + t (b - a) the closest point,
    t = clip((p - a).(b - a) / |b - a|^2, 0, 1).

    grad phi = n = (p - x)/|p - x|; hess phi = (P - n n^T)/|p - x| with P = I - e e^T (e = (b - a)/|b - a|) along
    the cylinder (0 < t < 1, where x slides with p) and P = I at the end spheres, also on the end planes t = 0, 1
    (there phi is C^1 and its Hessian jumps). On the segment: grad phi = a fixed unit normal to e, hess phi = 0.
    a, b: (d,) m, distinct; radius: m (> 0)."""

    shape: ClassVar[str] = "capsule"
    positions: ClassVar[tuple[str, ...]] = ("a", "b")
    a: np.ndarray
    b: np.ndarray
    radius: float

    def _check(self) -> int:
        a = _vector(self.a, "a")
        b = _vector(self.b, "b", a.size)
        if np.array_equal(a, b):
            raise ValueError(f"b must differ from a (a capsule of one point is a sphere), got {b.tolist()}")
        self._set(a=a, b=b, radius=_positive(self.radius, "radius"))
        return a.size

    def _derivatives(self, q):
        axis = self.b - self.a
        t = (q - self.a) @ axis / (axis @ axis)
        r = q - self.a - np.clip(t, 0.0, 1.0)[:, None] * axis  # from the closest point of the segment
        unit = axis / np.linalg.norm(axis)
        slides = ((t > 0) & (t < 1))[:, None, None]
        across = np.eye(q.shape[1]) - slides * np.outer(unit, unit)
        return _ball_derivatives(r, self.radius, _perpendicular(unit), across)

    def _bounds(self):
        return np.minimum(self.a, self.b) - self.radius, np.maximum(self.a, self.b) + self.radius

    def _time_of_impact(self, start, end, level):
        """Exact: the first entry into either end ball or through the finite cylinder's side, all of radius
        r + level (an entry through a flat end lies inside an end ball, which is entered no later)."""
        reach = self.radius + level
        axis = self.b - self.a
        unit = axis / np.linalg.norm(axis)
        step, m = end - start, start - self.a
        side = _enter_ball(m - np.outer(m @ unit, unit), step - np.outer(step @ unit, unit), reach)
        finite = np.isfinite(side)
        t = (m + np.where(finite, side, 0.0)[:, None] * step) @ axis / (axis @ axis)
        side[(t < 0) | (t > 1)] = np.inf  # the infinite cylinder is entered beyond the segment's ends
        return np.minimum.reduce([side, _enter_ball(m, step, reach), _enter_ball(start - self.b, step, reach)])


@dataclass(frozen=True, eq=False)
class Torus(Collider):
    """A torus (3-D only): phi(p) = sqrt((rho - R)^2 + z^2) - r with q = p - center, z = q.axis, rho = |q - z axis|.

    With e = (q - z axis)/rho and D = sqrt((rho - R)^2 + z^2): grad phi = n = ((rho - R) e + z axis)/D and
    hess phi = (e e^T + axis axis^T + (rho - R)/rho (I - axis axis^T - e e^T) - n n^T)/D. Kinks: on the axis
    (rho = 0) e is a fixed unit normal to the axis, and on the core circle (D = 0) n = e; hess phi = 0 on both.
    center: (3,) m; axis: (3,) (normalised, nonzero); major_radius R, minor_radius r: m (> 0)."""

    shape: ClassVar[str] = "torus"
    dims: ClassVar[tuple[int, ...]] = (3,)
    positions: ClassVar[tuple[str, ...]] = ("center",)
    center: np.ndarray
    axis: np.ndarray
    major_radius: float
    minor_radius: float

    def _check(self) -> int:
        center = _vector(self.center, "center")
        if center.size != 3:
            raise ValueError(f"center must have 3 components (a torus exists only in 3-D), got {center.size}")
        self._set(center=center, axis=_unit(self.axis, "axis", 3), major_radius=_positive(self.major_radius, "major_radius"),
                  minor_radius=_positive(self.minor_radius, "minor_radius"))
        return 3

    def _derivatives(self, q):
        local = q - self.center
        height = local @ self.axis
        radial = local - height[:, None] * self.axis
        rho = np.linalg.norm(radial, axis=1)
        radial = radial / np.where(rho == 0, 1.0, rho)[:, None]
        radial[rho == 0] = _perpendicular(self.axis)
        core = np.hypot(rho - self.major_radius, height)
        singular = (rho == 0) | (core == 0)
        safe = np.where(core == 0, 1.0, core)
        normal = ((rho - self.major_radius)[:, None] * radial + height[:, None] * self.axis) / safe[:, None]
        normal[core == 0] = radial[core == 0]
        radial_outer, axial = _outer(radial), np.outer(self.axis, self.axis)
        # e turns with q around the axis at rate 1/rho: the (rho - R)/rho term
        turn = ((rho - self.major_radius) / np.where(rho == 0, 1.0, rho))[:, None, None] * (np.eye(3) - axial - radial_outer)
        hess = (radial_outer + axial + turn - _outer(normal)) / safe[:, None, None]
        hess[singular] = 0.0
        return core - self.minor_radius, normal, hess

    def _bounds(self):
        # the core circle's extent along axis i is R sqrt(1 - axis_i^2)
        half = self.major_radius * np.sqrt(np.clip(1 - self.axis**2, 0.0, None)) + self.minor_radius
        return self.center - half, self.center + half


COLLIDERS: dict[str, type[Collider]] = {cls.shape: cls for cls in (Plane, Sphere, Box, Capsule, Torus, GridSDF)}


def build_collider(shape: str, dim: int, **arguments) -> Collider:
    """The collider ``shape`` (a COLLIDERS name) from its constructor arguments (a grid_sdf may give load_grid_sdf's
    ``path``, ``origin``, ``spacing`` instead), checked to be dim-dimensional; ValueError otherwise."""
    if shape not in COLLIDERS:
        raise ValueError(f"unknown collider shape {shape!r}; valid: {', '.join(sorted(COLLIDERS))}")
    cls = COLLIDERS[shape]
    if dim not in cls.dims:
        raise ValueError(f"dim: a {shape} exists only in {' or '.join(f'{d}-D' for d in cls.dims)}, got {dim}-D")
    load = load_grid_sdf if cls is GridSDF and "path" in arguments else cls  # a grid may come from a file
    try:
        collider = load(**arguments)
    except TypeError as error:  # an unknown or missing argument: Python's message names it
        raise ValueError(f"{shape}: {error}") from None
    if collider.dim != dim:
        raise ValueError(f"{shape}: its arguments are {collider.dim}-D but dim is {dim}")
    return collider
