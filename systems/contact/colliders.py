"""Contact colliders: analytic and sampled signed distance fields (SDFs) phi, in 2-D and 3-D.

A collider gives phi(p) (m, negative inside) and its exact derivatives, which penalty and IPC barrier contact
differentiate through: P = k/2 min(phi, 0)^2 has hess P = k (grad phi grad phi^T + min(phi, 0) hess phi) inside.
It moves with a constant ``velocity`` (m/s): at time t it is the t = 0 shape translated by velocity * t, which
every query takes as ``offset`` (d,) (m). Queries work on k points at once: points (k, d) -> phi (k,),
grad phi (k, d), hess phi (k, d, d) (1/m); ``time_of_impact`` limits a step to the first contact.
Shapes are registered in COLLIDERS under their config name; ``build_collider`` builds any of them.
References: I. Quilez, "Distance functions" (iquilezles.org: box, capsule, torus); B. Mirtich, "Impulse-based
dynamic simulation of rigid body systems", PhD thesis, UC Berkeley, 1996 (conservative advancement).
"""

from __future__ import annotations

import itertools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar

import numpy as np

# Conservative advancement stops once phi - level <= TOI_TOLERANCE |end - start|: a millionth of the move is far
# below any contact gap, and the result is then within TOI_TOLERANCE / cos(theta) of the true tau (theta: angle
# between the move and the surface normal).
TOI_TOLERANCE = 1e-6
# Each iteration shrinks the gap by about (1 - cos(theta) / L) (L: Lipschitz bound), so 200 iterations reach
# TOI_TOLERANCE for cos(theta) >= 0.1 at L <= 1.5; a point still going then returns its tau so far (a lower bound).
TOI_MAX_ITERATIONS = 200


def filter_eigenvalues(values: np.ndarray, project_spd) -> np.ndarray:
    """Eigenvalues as a projection asks: as they are (False), clamped at 0 (True, "clamp") or mirrored ("abs")."""
    if not project_spd:
        return values
    return np.abs(values) if project_spd == "abs" else np.maximum(values, 0.0)


def _vector(value, name: str, dim: int | None = None) -> np.ndarray:
    """value as a finite float vector with dim components (2 or 3 when dim is None)."""
    array = np.asarray(value, dtype=float)
    sizes = (2, 3) if dim is None else (dim,)
    if array.ndim != 1 or array.size not in sizes:
        raise ValueError(f"{name} must have {' or '.join(map(str, sizes))} components, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array.tolist()}")
    return array


def _positive(value, name: str) -> float:
    """value as a finite float > 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = np.nan  # not a number: reported below, under the argument's name
    if not (number > 0 and np.isfinite(number)):
        raise ValueError(f"{name} must be > 0, got {value}")
    return number


def _unit(value, name: str, dim: int | None = None) -> np.ndarray:
    """value / |value|; a zero vector is refused."""
    vector = _vector(value, name, dim)
    length = np.linalg.norm(vector)
    if length == 0:
        raise ValueError(f"{name} must be nonzero, got {vector.tolist()}")
    return vector / length


def _perpendicular(unit: np.ndarray) -> np.ndarray:
    """A unit vector normal to unit: the coordinate axis least aligned with it, made orthogonal (a fixed choice)."""
    axis = np.eye(unit.size)[np.argmin(np.abs(unit))]
    across = axis - (axis @ unit) * unit
    return across / np.linalg.norm(across)


def _outer(a: np.ndarray) -> np.ndarray:
    """a a^T per row: (k, d) -> (k, d, d)."""
    return a[:, :, None] * a[:, None, :]


def _enter_ball(m: np.ndarray, step: np.ndarray, radius: float) -> np.ndarray:
    """First tau in [0, 1] with |m + tau step| = radius (0 if |m| <= radius already, inf if never), per row.

    |step|^2 tau^2 + 2 b tau + c = 0 with b = m.step, c = |m|^2 - radius^2 > 0 has a root in tau > 0 only when
    b < 0; the smaller one is c / (-b + sqrt(b^2 - |step|^2 c)), free of cancellation."""
    b = np.einsum("ij,ij->i", m, step)
    c = np.einsum("ij,ij->i", m, m) - radius**2
    discriminant = b * b - np.einsum("ij,ij->i", step, step) * c
    tau = np.full(len(m), np.inf)
    hit = (b < 0) & (discriminant >= 0) & (c > 0)
    tau[hit] = c[hit] / (np.sqrt(discriminant[hit]) - b[hit])
    tau[tau > 1] = np.inf
    tau[c <= 0] = 0.0
    return tau


@dataclass(frozen=True, eq=False)
class Collider(ABC):
    """A rigid shape with signed distance phi (m, negative inside), translated by offset = velocity * t.

    Implementers supply (the public methods check shapes and apply the offset; q is in the t = 0 frame):
    ``_check()`` validates and normalises the constructor's arguments (ValueError naming the argument) and
    returns d; ``_derivatives(q)`` -> phi (k,), grad (k, d), hess (k, d, d); optionally ``_distance(q)`` (phi
    alone, cheaper); ``_bounds()`` a box around {phi <= 0} or None; ``_time_of_impact`` when the root is closed
    form (the default is conservative advancement with the ``lipschitz`` bound of phi). ``positions`` names
    the arguments that move with the shape, ``dims`` the dimensions it exists in; ``exact`` says phi is a true
    Euclidean SDF (|grad phi| = 1).
    """

    shape: ClassVar[str]
    dims: ClassVar[tuple[int, ...]] = (2, 3)
    exact: ClassVar[bool] = True
    positions: ClassVar[tuple[str, ...]]
    dim: int = field(init=False)
    lipschitz: float = field(default=1.0, init=False, repr=False)  # a bound on |grad phi| everywhere: 1 for a true SDF
    velocity: np.ndarray | None = field(default=None, kw_only=True)

    def __post_init__(self):
        dim = self._check()
        velocity = np.zeros(dim) if self.velocity is None else _vector(self.velocity, "velocity", dim)
        self._set(dim=dim, velocity=velocity)

    def _set(self, **values):
        for name, value in values.items():  # the dataclass is frozen: only validation may normalise it
            object.__setattr__(self, name, value)

    def signed_distance(self, points: np.ndarray, offset: np.ndarray | None = None) -> np.ndarray:
        """phi(p): signed distance (k,) (m, negative inside) of points (k, d) (m) to the shape moved by offset (d,) (m)."""
        return self._distance(self._local(points, offset))

    def derivatives(self, points: np.ndarray, offset: np.ndarray | None = None):
        """(phi (k,) m, grad phi (k, d), hess phi (k, d, d) 1/m) at points (k, d) (m); kinks: see the shape's docstring."""
        return self._derivatives(self._local(points, offset))

    def time_of_impact(self, start: np.ndarray, end: np.ndarray, offset: np.ndarray | None = None,
                       distance: float = 0.0) -> np.ndarray:
        """First tau in [0, 1] with phi(start + tau (end - start)) = distance, per point: (k,), inf when none.

        start, end: (k, d) m, each point's straight move; offset: (d,) m, held during the move (for a collider
        moving over [t0, t1], pass start - velocity t0, end - velocity t1 and no offset: the move relative to it
        is straight too); distance: the level (m, >= 0, e.g. a barrier's d_hat). A point at or below the level at
        start gives 0. Plane, sphere and capsule solve for the exact root; the other shapes advance
        conservatively: tau never exceeds the first root, and phi(tau) - distance <= TOI_TOLERANCE |end - start|
        (a move that comes that close to the level without reaching it reports that approach)."""
        level = float(distance)
        if not (np.isfinite(level) and level >= 0):
            raise ValueError(f"distance must be >= 0, got {distance}")
        start, end = self._local(start, offset, "start"), self._local(end, offset, "end")
        if start.shape != end.shape:
            raise ValueError(f"start and end must have the same shape, got {start.shape} and {end.shape}")
        return self._time_of_impact(start, end, level)

    def distance_and_normal(self, points: np.ndarray, offset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(phi (k,) m, grad phi (k, d)) at points (k, d) (m): what a penalty's force needs, without the Hessian."""
        phi, gradient, _ = self.derivatives(points, offset)
        return phi, gradient

    def scaled_hessian(self, points: np.ndarray, scale: np.ndarray, project_spd=False,
                       offset: np.ndarray | None = None) -> np.ndarray:
        """s_i hess phi(p_i) (k, d, d) for the factors s (k,), its eigenvalues as they are (``project_spd`` False),
        clamped at 0 (True or "clamp") or mirrored ("abs"): the curvature term s hess phi of a contact potential
        f(phi) (s = f'(phi)), which turns negative where f' < 0 on a convex collider."""
        matrix = np.asarray(scale, dtype=float)[:, None, None] * self.derivatives(points, offset)[2]
        if not project_spd:
            return matrix
        values, vectors = np.linalg.eigh(matrix)
        values = filter_eigenvalues(values, project_spd)
        return np.einsum("kij,kj,klj->kil", vectors, values, vectors)

    def bounding_box(self, offset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """(lower (d,), upper (d,)) m: an axis-aligned box holding every point with phi <= 0; None if unbounded."""
        bounds = self._bounds()
        shift = self._offset(offset)
        return None if bounds is None else (bounds[0] + shift, bounds[1] + shift)

    def translated(self, offset: np.ndarray) -> Collider:
        """The same collider with its position arguments moved by offset (d,) (m)."""
        shift = self._offset(offset)
        return replace(self, **{name: getattr(self, name) + shift for name in self.positions})

    def _offset(self, offset) -> np.ndarray:
        return np.zeros(self.dim) if offset is None else _vector(offset, "offset", self.dim)

    def _local(self, points, offset, name: str = "points") -> np.ndarray:
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != self.dim:
            raise ValueError(f"{name} must have shape (k, {self.dim}), got {points.shape}")
        return points - self._offset(offset)

    @abstractmethod
    def _check(self) -> int:
        """Validate and normalise the constructor's arguments (ValueError naming the argument); return d."""

    @abstractmethod
    def _derivatives(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """phi (k,) m, grad phi (k, d), hess phi (k, d, d) 1/m at points q (k, d) m of the t = 0 frame."""

    def _bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        return None  # unbounded

    def _distance(self, q: np.ndarray) -> np.ndarray:
        return self._derivatives(q)[0]

    def _time_of_impact(self, start: np.ndarray, end: np.ndarray, level: float) -> np.ndarray:
        """Conservative advancement: phi changes by at most L |end - start| per unit tau, so
        tau <- tau + (phi(tau) - level) / (L |end - start|) never passes the first root; a point stops once
        phi(tau) - level <= TOI_TOLERANCE |end - start| (a hit) or tau > 1 (no hit)."""
        step = end - start
        length = np.linalg.norm(step, axis=1)
        tolerance = TOI_TOLERANCE * length
        gap = self._distance(start) - level
        tau = np.where(gap <= tolerance, 0.0, np.inf)
        active = np.flatnonzero((gap > tolerance) & (length > 0))  # a point that does not move stays above the level
        along, gap = np.zeros(active.size), gap[active]
        for _ in range(TOI_MAX_ITERATIONS):
            along = along + gap / (self.lipschitz * length[active])
            before_end = along <= 1  # the others keep inf: the level is not reached within the move
            active, along = active[before_end], along[before_end]
            gap = self._distance(start[active] + along[:, None] * step[active]) - level
            hit = gap <= tolerance[active]
            tau[active[hit]] = along[hit]
            active, along, gap = active[~hit], along[~hit], gap[~hit]
            if active.size == 0:
                break
        tau[active] = along  # the cap was reached: still a lower bound of the first root
        return tau


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


def _ball_derivatives(r: np.ndarray, radius: float, at_core: np.ndarray, across: np.ndarray | None = None):
    """phi = |r| - radius and its derivatives for offsets r (k, d) from the nearest core point; across (k, d, d)
    is dr/dq (identity when None). hess = (dr/dq - n n^T)/|r| since n is normal to the directions the core point
    slides along. On the core (r = 0) grad = at_core and hess = 0."""
    rho = np.linalg.norm(r, axis=1)
    core = rho == 0
    safe = np.where(core, 1.0, rho)
    normal = r / safe[:, None]
    normal[core] = at_core
    across = np.eye(r.shape[1]) if across is None else across
    hess = (across - _outer(normal)) / safe[:, None, None]
    hess[core] = 0.0
    return rho - radius, normal, hess


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


@dataclass(frozen=True, eq=False)
class GridSDF(Collider):
    """A sampled SDF: multilinear interpolation (bilinear in 2-D, trilinear in 3-D) of samples on a regular grid.

    values: (n_0, ..., n_{d-1}), sample j along axis i at origin[i] + j spacing[i] (m), n_i >= 2, finite;
    origin: (d,) m; spacing: (d,) or a scalar, m (> 0). Inside the grid box, phi = sum over the cell's 2^d corners of
    value * prod_i (w_i or 1 - w_i) (w the position in the cell); grad and hess are the interpolant's within the
    cell (pure second derivatives 0, mixed ones not). Outside: phi(p) = phi(clamp(p)) + |p - clamp(p)|, a lower
    bound of a true SDF there. Kinks: on a grid line the cell above is used (the last cell at the far face); on
    the box's surface, the inside formula. ``lipschitz`` = sqrt(L^2 + 1) bounds |grad phi| everywhere (L: the
    interpolant's largest |grad|; outside, |grad phi|^2 = |grad along the box|^2 + 1), for conservative advancement.
    """

    shape: ClassVar[str] = "grid_sdf"
    exact: ClassVar[bool] = False
    positions: ClassVar[tuple[str, ...]] = ("origin",)
    values: np.ndarray
    origin: np.ndarray
    spacing: np.ndarray | float

    def _check(self) -> int:
        values = np.asarray(self.values, dtype=float)
        d = values.ndim
        if d not in (2, 3):
            raise ValueError(f"values must be a 2-D or 3-D array, got {d} dimensions")
        for name, value in (("origin", self.origin), ("spacing", self.spacing)):
            if np.shape(value) != (d,) and not (name == "spacing" and np.ndim(value) == 0):
                raise ValueError(f"{name} has {np.size(value)} components but values has {d} dimensions")
        spacing = np.full(d, float(self.spacing)) if np.ndim(self.spacing) == 0 else np.asarray(self.spacing, dtype=float)
        if not np.all((spacing > 0) & np.isfinite(spacing)):
            raise ValueError(f"spacing must be > 0 and finite, got {spacing.tolist()}")
        if min(values.shape) < 2:
            raise ValueError(f"values must have at least 2 samples along every axis, got shape {values.shape}")
        if (bad := np.count_nonzero(~np.isfinite(values))) > 0:
            raise ValueError(f"values must be finite: {bad} of {values.size} samples are NaN or infinite")
        self._set(values=values, origin=_vector(self.origin, "origin", d), spacing=spacing,
                  lipschitz=_grid_lipschitz(values, spacing))
        return d

    def _upper(self) -> np.ndarray:
        return self.origin + (np.array(self.values.shape) - 1) * self.spacing

    def _locate(self, q):
        """The nearest point of the grid box (k, d), its cell (k, d) and its position w (k, d) in [0, 1]^d within it."""
        clamped = np.clip(q, self.origin, self._upper())
        u = (clamped - self.origin) / self.spacing  # grid coordinates
        cell = np.minimum(np.floor(u).astype(np.intp), np.array(self.values.shape) - 2)
        return clamped, cell, u - cell

    def _distance(self, q):
        clamped, cell, w = self._locate(q)
        phi = sum(self.values[tuple((cell + corner).T)] * np.where(np.array(corner) == 1, w, 1 - w).prod(axis=1)
                  for corner in itertools.product((0, 1), repeat=self.dim))
        return phi + np.linalg.norm(q - clamped, axis=1)

    def _derivatives(self, q):
        d = self.dim
        clamped, cell, w = self._locate(q)
        eye = np.eye(d, dtype=bool)
        both = eye[:, None, :] | eye[None, :, :]  # [j, l, i]: axis i is one of the two differentiated
        phi, grad, hess = 0.0, 0.0, 0.0
        for corner in itertools.product((0, 1), repeat=d):  # the 2^d corners of every point's cell at once
            corner = np.array(corner)
            sample = self.values[tuple((cell + corner).T)]
            factor = np.where(corner == 1, w, 1 - w)  # (k, d): each axis' linear weight
            slope = 2.0 * corner - 1  # d factor_i / d u_i
            phi = phi + sample * factor.prod(axis=1)
            grad = grad + (sample[:, None] * slope) * np.where(eye, 1.0, factor[:, None, :]).prod(axis=2)
            hess = hess + (sample[:, None, None] * np.outer(slope, slope)) * np.where(both, 1.0, factor[:, None, None, :]).prod(axis=3)
        hess[:, eye] = 0.0  # each factor is linear in its own u_i
        grad, hess = grad / self.spacing, hess / np.outer(self.spacing, self.spacing)
        # outside: the clamped axes no longer move the interpolant; the distance to the box adds its own terms
        r = q - clamped
        beyond = r != 0
        grad, hess = np.where(beyond, 0.0, grad), hess * (~beyond[:, :, None] & ~beyond[:, None, :])
        gap = np.linalg.norm(r, axis=1)
        outside = gap > 0
        if np.any(outside):
            _, n, curvature = _ball_derivatives(r[outside], 0.0, np.zeros(d), beyond[outside][:, :, None] * np.eye(d))
            grad[outside] += n
            hess[outside] += curvature
        return phi + gap, grad, hess

    def _bounds(self):
        # phi >= min(values) + distance to the grid box, so phi <= 0 lies within -min(values) of it
        margin = max(0.0, -float(self.values.min()))
        return self.origin - margin, self._upper() + margin


def _grid_lipschitz(values: np.ndarray, spacing: np.ndarray) -> float:
    """sqrt(L^2 + 1) with L = max |grad| of the multilinear interpolant. Component i of its gradient is the difference
    along a cell edge of axis i over spacing_i, interpolated over the other axes, so |grad| is convex along every
    coordinate line and largest at a cell corner, where component i is the difference along the edge through it."""
    d = values.ndim
    slopes = [np.diff(values, axis=i) / spacing[i] for i in range(d)]
    largest = 0.0
    for corner in itertools.product((0, 1), repeat=d):
        squared = sum(slopes[i][tuple(slice(None) if j == i else slice(corner[j], corner[j] + values.shape[j] - 1)
                                      for j in range(d))] ** 2 for i in range(d))
        largest = max(largest, float(squared.max()))
    return float(np.sqrt(largest + 1.0))


def load_grid_sdf(path, origin=None, spacing=None, *, velocity=None) -> GridSDF:
    """A GridSDF from a ``.npy`` file (the values only: origin and spacing must be given) or a ``.npz`` file (arrays
    ``values`` and, optionally, ``origin`` and ``spacing``, which given arguments override). origin: (d,) m;
    spacing: (d,) or scalar m; velocity: (d,) m/s. A bad file or grid is a one-line ValueError naming the problem."""
    path = Path(path)
    if path.suffix == ".npy":
        values = np.load(path, allow_pickle=False)
    elif path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            if "values" not in archive.files:
                raise ValueError(f"{path.name} has no array 'values' (it holds: {', '.join(archive.files) or 'nothing'})")
            values = archive["values"]
            origin = archive["origin"] if origin is None and "origin" in archive.files else origin
            spacing = archive["spacing"] if spacing is None and "spacing" in archive.files else spacing
    else:
        raise ValueError(f"path must end in .npy or .npz, got {path.name!r}")
    for name, value in (("origin", origin), ("spacing", spacing)):
        if value is None:
            raise ValueError(f"{name} must be given: {path.name} does not hold it")
    return GridSDF(values, origin, spacing, velocity=velocity)


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
