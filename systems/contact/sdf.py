"""The contract of a contact collider (a signed distance field phi, in 2-D and 3-D) and its shared helpers.

A collider gives phi(p) (m, negative inside) and its exact derivatives, which penalty and IPC barrier contact
differentiate through: P = k/2 min(phi, 0)^2 has hess P = k (grad phi grad phi^T + min(phi, 0) hess phi) inside.
It moves with a constant ``velocity`` (m/s): at time t it is the t = 0 shape translated by velocity * t, which
every query takes as ``offset`` (d,) (m). Queries work on k points at once: points (k, d) -> phi (k,),
grad phi (k, d), hess phi (k, d, d) (1/m); ``time_of_impact`` limits a step to the first contact.
The shapes are registered in colliders.py COLLIDERS under their config names; ``build_collider`` builds any of them.
References: I. Quilez, "Distance functions" (iquilezles.org: box, capsule, torus); B. Mirtich, "Impulse-based
dynamic simulation of rigid body systems", PhD thesis, UC Berkeley, 1996 (conservative advancement).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
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
