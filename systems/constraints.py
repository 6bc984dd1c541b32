"""Vertex constraints as filters: pinned vertices, vertices that slide in a plane or along a line, and
vertices that move on a prescribed path.

Every constraint is a linear filter S on the vertex's d components (Baraff & Witkin, "Large steps in
cloth simulation", 1998, sec. 5; the "modified inverse mass" (1/m)(I - p p^T) of the lectures):
- pinned: S_i = 0;
- sliding in a plane with unit normal n: S_i = I - n n^T;
- sliding along a line with unit direction u: S_i = u u^T;
- prescribed: S_i = 0, and the vertex's position and velocity are given functions of time, up to the
  path's ``until`` if it has one; from there the vertices are free (``VertexConstraints.released``).
Forces, search directions and velocities are passed through S, so the constrained components never
change through a force. Components that S removes along a coordinate axis (a pin, a plane normal
[0, 1, 0], a rail along [1, 0, 0]) are plain fixed degrees of freedom, which every solver already
drops exactly; only filters that are not aligned with the axes remain as 3x3 (2x2) blocks, held by
``SlidingFilter``, which solvers apply to vectors and to the Newton matrix (S A S + C (I - S)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse

from .compiled_cache import keep_fresh


@numba.njit(cache=True, error_model="numpy")
def filter_in_place(projector, vector, scratch, d):
    """vector = S vector in place, S (d, d) a vertex's filter; scratch: d entries (the compiled loops' form)."""
    for a in range(d):
        total = 0.0
        for b in range(d):
            total += projector[a, b] * vector[b]
        scratch[a] = total
    for a in range(d):
        vector[a] = scratch[a]


@dataclass(frozen=True, eq=False)
class SlidingFilter:
    """The filters S_i of the vertices whose allowed directions are not coordinate axes.

    vertices: (s,) vertex indices; projectors: (s, d, d) symmetric orthogonal projectors; size: dofs."""

    vertices: np.ndarray
    projectors: np.ndarray
    size: int

    @property
    def dim(self) -> int:
        return int(self.projectors.shape[1])

    def apply(self, vector: np.ndarray) -> np.ndarray:
        """vector with each filtered vertex's block replaced by S_i times it (in place; returns vector)."""
        blocks = vector.reshape(-1, self.dim)
        blocks[self.vertices] = np.einsum("sij,sj->si", self.projectors, blocks[self.vertices])
        return vector

    @property
    def block_entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, columns) of every entry of the filtered vertices' d x d blocks, and their dofs (cached)."""
        cached = self.__dict__.get("_block_entries")
        if cached is None:
            d = self.dim
            dofs = d * self.vertices[:, None] + np.arange(d)  # (s, d)
            cached = (np.repeat(dofs, d, axis=1).ravel(), np.tile(dofs, (1, d)).ravel(), dofs.ravel())
            object.__setattr__(self, "_block_entries", cached)
        return cached

    @property
    def matrix(self) -> scipy.sparse.csr_matrix:
        """S as a sparse (size x size) matrix: identity except the filtered blocks."""
        cached = self.__dict__.get("_matrix")
        if cached is None:
            rows, cols, dofs = self.block_entries
            identity = np.ones(self.size)
            identity[dofs] = 0.0
            keep = np.flatnonzero(identity)
            cached = scipy.sparse.csr_matrix(
                (np.concatenate([identity[keep], self.projectors.ravel()]),
                 (np.concatenate([keep, rows]), np.concatenate([keep, cols]))), shape=(self.size, self.size))
            cached.sum_duplicates()
            cached.sort_indices()
            object.__setattr__(self, "_matrix", cached)
        return cached

    def filter_matrix(self, matrix):
        """S A S + C (I - S): the Newton matrix on the allowed directions, and on the removed ones the
        identity scaled by each vertex's mean diagonal entry of A (C), so that the filtered matrix keeps
        A's scale: a unit identity beside a mass-sized A (M + h^2 K ~ 0.01 kg) wrecks the conditioning that
        Jacobi, Gauss-Seidel and CG depend on. Its solution p of (S A S + C (I - S)) p = S b has
        (I - S) p = 0 and S A S p = S b (Ascher & Boxerman 2003), whatever C > 0."""
        projector, d = self.matrix, self.dim
        rows, cols, dofs = self.block_entries
        diagonal = (matrix.diagonal() if scipy.sparse.issparse(matrix) else np.diag(np.asarray(matrix)))[dofs]
        scale = np.abs(diagonal.reshape(-1, d)).mean(axis=1)
        scale = np.where(scale > 0, scale, 1.0)
        complement = scale[:, None, None] * (np.eye(d) - self.projectors)
        removed = scipy.sparse.csr_matrix((complement.ravel(), (rows, cols)), shape=(self.size, self.size))
        if scipy.sparse.issparse(matrix):
            return (projector @ matrix.tocsr() @ projector + removed).tocsr()
        dense = projector.toarray()
        return dense @ np.asarray(matrix, dtype=float) @ dense + removed.toarray()


@dataclass(frozen=True, eq=False)
class PrescribedMotion:
    """Vertices that follow a path: a constant velocity, or a rotation about an axis at a constant rate.

    vertices: (k,) indices; start: (k, d) positions at t = 0 (m); velocity: (d,) m/s (or None);
    rotation: (center (d,), axis (3,) unit, rate rad/s) or None; until: the time (s) at which the vertices
    are let go, or None (held on the path for the whole run). The path is rigid: every vertex of the
    set moves with the same velocity or turns about the same axis."""

    vertices: np.ndarray
    start: np.ndarray
    velocity: np.ndarray | None = None
    rotation: tuple[np.ndarray, np.ndarray, float] | None = None
    until: float | None = None

    def positions(self, t: float) -> np.ndarray:
        """(k, d) positions at time t (s)."""
        if self.velocity is not None:
            return self.start + t * self.velocity
        center, axis, rate = self.rotation
        return center + rotate(self.start - center, axis, rate * t)

    def velocities(self, t: float) -> np.ndarray:
        """(k, d) velocities at time t (s)."""
        if self.velocity is not None:
            return np.broadcast_to(self.velocity, self.start.shape).copy()
        center, axis, rate = self.rotation
        offset = self.positions(t) - center
        return cross(rate * axis, offset)

    def accelerations_along(self, velocities: np.ndarray) -> np.ndarray:
        """(k, d) accelerations of the path as a function of the vertices' velocities: 0 for a constant
        velocity, omega x v for a rotation at a constant rate (the path is the solution of x'' = omega x x'),
        so that a method's stages move the vertices along the arc to the method's own order."""
        if self.velocity is not None:
            return np.zeros_like(velocities)
        _, axis, rate = self.rotation
        return cross(rate * axis, velocities)

    def accelerations(self, t: float) -> np.ndarray:
        """(k, d) accelerations at time t (s^-2 m): zero for a velocity, centripetal for a rotation."""
        if self.velocity is not None:
            return np.zeros_like(self.start)
        center, axis, rate = self.rotation
        return cross(rate * axis, self.velocities(t))


def cross(omega: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """omega x offset (rows) for 3-D offsets, or the in-plane part for 2-D ones (omega along z): the velocities of
    a rigid spin (the start spin of a model, a prescribed rotation)."""
    if offset.shape[1] == 2:
        return omega[2] * np.stack([-offset[:, 1], offset[:, 0]], axis=1)
    return np.cross(omega, offset)


def rotate(offset: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation of the rows of offset by angle (rad) about the unit axis (2-D: about +z or -z, the sign
    of axis[2]): a prescribed rotation's path, a model's start shape."""
    cos, sin = math.cos(angle), math.sin(angle)
    if offset.shape[1] == 2:
        sign = axis[2]
        return np.stack([cos * offset[:, 0] - sign * sin * offset[:, 1], sign * sin * offset[:, 0] + cos * offset[:, 1]], axis=1)
    return (cos * offset + sin * np.cross(axis, offset)
            + (1.0 - cos) * np.outer(offset @ axis, axis))


def filter_block(dim: int, normal: np.ndarray | None = None, direction: np.ndarray | None = None) -> np.ndarray:
    """S for sliding in the plane with this normal (I - n n^T) or along the line with this direction (u u^T)."""
    unit = _unit(normal if normal is not None else direction)
    outer = np.outer(unit, unit)
    return np.eye(dim) - outer if normal is not None else outer


def _unit(vector: np.ndarray) -> np.ndarray:
    """vector / |vector|, scaled by its largest component first, so that a tiny vector (1e-320) has a direction too."""
    scaled = vector / np.max(np.abs(vector))
    return scaled / np.linalg.norm(scaled)


class VertexConstraints:
    """Every vertex constraint of one system, as fixed dofs, sliding filters and prescribed paths.

    pinned: vertex indices; sliding: list of (vertex indices, S (d, d)); prescribed: PrescribedMotions.
    A vertex may carry one constraint only (the caller checks and names the config entries)."""

    def __init__(self, dim: int, vertex_count: int, pinned: np.ndarray, sliding: list[tuple[np.ndarray, np.ndarray]],
                 prescribed: list[PrescribedMotion]):
        self.dim = dim
        self.size = dim * vertex_count
        self.pinned = np.asarray(pinned, dtype=np.intp)
        self.prescribed = tuple(prescribed)
        self._sliding_entries = list(sliding)
        moving = [motion.vertices for motion in prescribed]
        self.moving_vertices = np.concatenate(moving).astype(np.intp) if moving else np.zeros(0, dtype=np.intp)
        self.moving_dofs = (dim * self.moving_vertices[:, None] + np.arange(dim)).ravel()
        fixed = [(dim * self.pinned[:, None] + np.arange(dim)).ravel(), self.moving_dofs]
        blocks_vertices, blocks = [], []
        for vertices, block in sliding:
            axis_aligned = np.array_equal(block, np.diag(np.diag(block))) and set(np.diag(block).tolist()) <= {0.0, 1.0}
            if axis_aligned:  # S is diagonal with 0s and 1s: plain fixed dofs, exact for every solver
                removed = np.flatnonzero(np.diag(block) == 0.0)
                fixed.append((dim * np.asarray(vertices)[:, None] + removed).ravel())
            else:
                blocks_vertices.append(np.asarray(vertices, dtype=np.intp))
                blocks.append(np.broadcast_to(block, (len(vertices), dim, dim)))
        self.fixed_dofs = np.unique(np.concatenate(fixed)).astype(np.intp)
        self.sliding = (SlidingFilter(np.concatenate(blocks_vertices), np.ascontiguousarray(np.concatenate(blocks)), self.size)
                        if blocks else None)

    @property
    def release_times(self) -> tuple[float, ...]:
        """The times (s) at which paths end and let their vertices go, ascending."""
        return tuple(sorted({motion.until for motion in self.prescribed if motion.until is not None}))

    def released(self, t: float) -> VertexConstraints:
        """These constraints without the paths that end by t (``until <= t``): their vertices are free from t on."""
        kept = [motion for motion in self.prescribed if motion.until is None or motion.until > t]
        return VertexConstraints(self.dim, self.size // self.dim, self.pinned, self._sliding_entries, kept)

    def filter(self, vector: np.ndarray) -> np.ndarray:
        """S vector, in place: fixed components zeroed, sliding blocks projected; returns vector."""
        vector[self.fixed_dofs] = 0.0
        if self.sliding is not None:
            self.sliding.apply(vector)
        return vector

    def path(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) of the moving dofs at time t, flat in the order of ``moving_dofs``."""
        positions = [motion.positions(t) for motion in self.prescribed]
        velocities = [motion.velocities(t) for motion in self.prescribed]
        return np.concatenate(positions).ravel(), np.concatenate(velocities).ravel()

    def accelerations_along(self, v: np.ndarray) -> np.ndarray:
        """The paths' accelerations at the moving dofs (flat, ``moving_dofs`` order) for the velocities v (all dofs)."""
        blocks = v.reshape(-1, self.dim)
        return np.concatenate([motion.accelerations_along(blocks[motion.vertices]) for motion in self.prescribed]).ravel()

    def path_accelerations(self, t: float) -> np.ndarray:
        return np.concatenate([motion.accelerations(t) for motion in self.prescribed]).ravel()


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
