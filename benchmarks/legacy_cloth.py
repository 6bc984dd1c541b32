"""The cloth system as it was before it became a grid ``mass_spring`` (systems/cloth.py at commit
50b8fe0), kept unchanged here as the reference of ``benchmarks/mass_spring_paths.py``: the general
mass-spring path must cost no more than this specialised one. Not used by simrun itself.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from simrun.systems.base import System
from simrun.systems.cloth import ClothParams, grid_springs

_ONES3 = np.ones(3)  # sums the three components of each row in one matrix-vector product


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
        """(x_i - x_j) / L, shape (springs, 3)."""
        if self._direction is None:
            self._direction = self.delta / self.length[:, None]
        return self._direction

    @property
    def energy(self) -> float:
        """sum_springs k/2 (L - l0)^2 (J)."""
        if self._energy is None:
            self._energy = 0.5 * float(np.dot(self.tension, self.stretch))
        return self._energy


class LegacyCloth(System):
    """P(x) = sum_springs k/2 (|x_i - x_j| - l0)^2 - sum_i m_i g . x_i + contact penalties.

    Spring Hessian block (lectures): H_e = k [u u^T + (1 - l0/L)(I - u u^T)], u = (x_i - x_j)/L;
    the SPD projection clamps 1 - l0/L at 0 (the only eigenvalue that can turn negative, when the
    spring is compressed). Spring damping -k_d ((v_i - v_j) . u) u is f_d = -D(x) v with
    D = sum_e k_d u u^T in the same block pattern.
    """

    dim = 3
    records_state_per_sample = False  # positions go to `frames`, at their own cadence

    def __init__(self, params: ClothParams):
        self.params = params
        nx, ny = params.resolution
        self.shape = (nx, ny)
        self.vertex_count = nx * ny
        self.dof_count = 3 * self.vertex_count
        xs = np.linspace(0.0, params.size[0], nx)
        ys = np.linspace(0.0, params.size[1], ny)
        grid_x, grid_y = np.meshgrid(xs, ys)  # (ny, nx): vertex = row * nx + col
        rest = np.stack([grid_x.ravel(), grid_y.ravel(), np.full(self.vertex_count, params.height)], axis=1)
        self.x0 = rest.ravel()
        spin = np.cross(np.array(params.initial_spin), rest - rest.mean(axis=0))
        self.v0 = (spin + np.array(params.initial_velocity)).ravel()
        self.vertex_mass = params.mass / self.vertex_count
        self.mass = np.full(self.dof_count, self.vertex_mass)
        self.gravity = np.array(params.gravity, dtype=float)

        springs = grid_springs(nx, ny)
        stiffness = {"stretch": params.stretch_stiffness, "shear": params.shear_stiffness, "bend": params.bend_stiffness}
        kinds = [kind for kind in springs if stiffness[kind] > 0 or params.damping > 0]
        self.first = np.concatenate([springs[kind][0] for kind in kinds])
        self.second = np.concatenate([springs[kind][1] for kind in kinds])
        self.stiffness = np.concatenate([np.full(springs[kind][0].size, stiffness[kind]) for kind in kinds])
        self.rest_length = np.linalg.norm(rest[self.first] - rest[self.second], axis=1)
        self.spring_count = self.first.size

        self.pinned_vertices = self._pinned_vertices(params.pinned)
        self.fixed_dofs = (3 * self.pinned_vertices[:, None] + np.arange(3)).ravel()
        self.v0[self.fixed_dofs] = 0.0  # pinned vertices never move
        self._gravity_force = np.tile(self.vertex_mass * self.gravity, self.vertex_count)
        self._build_pattern()
        self._geometry: SpringGeometry | None = None  # of the last x the springs were evaluated at

    # -- setup ----------------------------------------------------------------------------------
    def _pinned_vertices(self, pinned) -> np.ndarray:
        nx, ny = self.shape
        index = np.arange(self.vertex_count).reshape(ny, nx)
        named = {
            "top_left": index[-1, :1], "top_right": index[-1, -1:], "bottom_left": index[0, :1],
            "bottom_right": index[0, -1:], "top": index[-1, :], "bottom": index[0, :],
            "left": index[:, 0], "right": index[:, -1],
        }
        chosen = [named[pin] if isinstance(pin, str) else np.array([pin]) for pin in pinned]
        return np.unique(np.concatenate(chosen)).astype(np.intp) if chosen else np.zeros(0, dtype=np.intp)

    def _build_pattern(self) -> None:
        """CSR pattern of all spring blocks (ii, jj, ij, ji) and vertex blocks, and the scatter map into it."""
        i, j = self.first, self.second
        offsets = np.arange(3)
        blocks = [(i, i), (j, j), (i, j), (j, i)]
        rows = [3 * a[:, None, None] + offsets[None, :, None] + 0 * offsets[None, None, :] for a, _ in blocks]
        cols = [3 * b[:, None, None] + 0 * offsets[None, :, None] + offsets[None, None, :] for _, b in blocks]
        vertices = np.arange(self.vertex_count)
        rows.append(3 * vertices[:, None, None] + offsets[None, :, None] + 0 * offsets[None, None, :])
        cols.append(3 * vertices[:, None, None] + 0 * offsets[None, :, None] + offsets[None, None, :])
        rows = np.concatenate([r.ravel() for r in rows])
        cols = np.concatenate([c.ravel() for c in cols])
        n = self.dof_count
        pattern = scipy.sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
        pattern.sum_duplicates()
        pattern.sort_indices()
        keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(pattern.indptr)) * n + pattern.indices
        self._scatter = np.searchsorted(keys, rows.astype(np.int64) * n + cols)
        self._spring_entries = 36 * self.spring_count
        self._indptr, self._indices = pattern.indptr, pattern.indices
        self._nnz = pattern.nnz
        self.hessian_pattern = pattern  # every Hessian and damping matrix shares its index arrays
        diagonal_keys = np.arange(n, dtype=np.int64) * (n + 1)
        self.diagonal_positions = np.searchsorted(keys, diagonal_keys)  # where M enters the data array
        # gradient scatter: the incidence matrix (+1 at vertex i, -1 at vertex j of each spring) times the
        # springs' forces, one sparse product for all three components, cheaper than the equivalent
        # np.bincount over 3 i + c and 3 j + c (docs/performance.md)
        self._first_dofs = (3 * i[:, None] + offsets).ravel()
        self._second_dofs = (3 * j[:, None] + offsets).ravel()
        springs = np.arange(self.spring_count)
        self._incidence = scipy.sparse.csr_matrix(
            (np.concatenate([np.ones(self.spring_count), -np.ones(self.spring_count)]),
             (np.concatenate([i, j]), np.concatenate([springs, springs]))),
            shape=(self.vertex_count, self.spring_count))

    def _matrix(self, data: np.ndarray) -> scipy.sparse.csr_matrix:
        return self.pattern_matrix(data)

    # -- geometry of all springs at once ---------------------------------------------------------
    def _springs(self, x: np.ndarray) -> SpringGeometry:
        """The springs' geometry at x. The last x's is kept, since a step evaluates the same x several
        times (the energy check and the samples at the end of a step, the force at the start of the next)."""
        geometry = self._geometry
        if geometry is not None and np.array_equal(geometry.x, x):  # an O(n) compare, far below the O(springs) geometry
            return geometry
        # a flat gather of the dofs 3 i + c: the same numbers as positions[self.first], cheaper than
        # that fancy index or np.take along axis 0 (docs/performance.md)
        delta = (np.take(x, self._first_dofs) - np.take(x, self._second_dofs)).reshape(-1, 3)
        # |delta|^2 as a matrix-vector product with (1, 1, 1), cheaper than einsum("ij,ij->i")
        length = np.sqrt(np.square(delta) @ _ONES3)
        stretch = length - self.rest_length
        geometry = SpringGeometry(x.copy(), delta, length, stretch, self.stiffness * stretch)
        self._geometry = geometry  # one assignment: a reader sees the old or the new geometry whole
        return geometry

    def _penetration(self, positions: np.ndarray):
        """Per contact: (penetration depth >= 0 per vertex, outward normal per vertex, stiffness)."""
        contacts = []
        ground = self.params.contact.ground
        if ground is not None:
            depth = np.maximum(ground.height - positions[:, 2], 0.0)
            normal = np.broadcast_to(np.array([0.0, 0.0, 1.0]), positions.shape)
            contacts.append((depth, normal, ground.stiffness, None))
        sphere = self.params.contact.sphere
        if sphere is not None:
            offset = positions - np.array(sphere.center)
            distance = np.sqrt(np.einsum("ij,ij->i", offset, offset))
            depth = np.maximum(sphere.radius - distance, 0.0)
            normal = offset / np.maximum(distance, 1e-300)[:, None]
            contacts.append((depth, normal, sphere.stiffness, distance))
        return contacts

    # -- energy, gradient, Hessian ---------------------------------------------------------------
    def spring_energy(self, x: np.ndarray) -> float:
        return self._springs(x).energy

    def gravity_energy(self, x: np.ndarray) -> float:
        return -float(np.dot(self._gravity_force, x))

    def contact_energy(self, x: np.ndarray) -> float:
        return sum(0.5 * stiffness * float(np.dot(depth, depth))
                   for depth, _, stiffness, _ in self._penetration(x.reshape(-1, 3)))

    def potential_energy(self, x):
        return self.spring_energy(x) + self.gravity_energy(x) + self.contact_energy(x)

    def gradient(self, x):
        geometry = self._springs(x)
        # dP/dx_i of each spring, k (L - l0) (x_i - x_j) / L: the one division on the springs' scalars;
        # the rows scaled through the transposed view, whose inner loop runs along the springs (cheaper
        # than broadcasting a (springs, 1) column over 3 components); the result is C-ordered
        spring_gradient = (geometry.delta.T * (geometry.tension / geometry.length)).T
        gradient = (self._incidence @ spring_gradient).ravel()
        gradient -= self._gravity_force
        for depth, normal, stiffness, _ in self._penetration(x.reshape(-1, 3)):
            gradient -= (stiffness * depth[:, None] * normal).ravel()
        return gradient

    def hessian(self, x, project_spd=False):
        return self._matrix(self.hessian_data(x, project_spd))

    def hessian_data(self, x: np.ndarray, project_spd: bool = False) -> np.ndarray:
        """The Hessian's values in the fixed CSR pattern (the data array of ``hessian``)."""
        geometry = self._springs(x)
        positions, direction = x.reshape(-1, 3), geometry.direction
        outer = direction[:, :, None] * direction[:, None, :]
        transverse = 1.0 - self.rest_length / geometry.length
        if project_spd:
            transverse = np.maximum(transverse, 0.0)
        eye = np.eye(3)
        block = self.stiffness[:, None, None] * (outer + transverse[:, None, None] * (eye - outer))
        vertex_block = np.zeros((self.vertex_count, 3, 3))
        for depth, normal, stiffness, distance in self._penetration(positions):
            touching = depth > 0
            if not touching.any():
                continue
            n = normal[touching]
            contact_outer = n[:, :, None] * n[:, None, :]
            if distance is None or project_spd:
                vertex_block[touching] += stiffness * contact_outer
            else:  # sphere: k n n^T - k (r - d)/d (I - n n^T); the second term is negative
                curvature = (depth[touching] / distance[touching])[:, None, None]
                vertex_block[touching] += stiffness * (contact_outer - curvature * (eye - contact_outer))
        values = np.concatenate([block.ravel(), block.ravel(), -block.ravel(), -block.ravel(), vertex_block.ravel()])
        return np.bincount(self._scatter, weights=values, minlength=self._nnz)

    def damping_matrix(self, x):
        if self.params.damping == 0.0:
            return None
        direction = self._springs(x).direction
        block = self.params.damping * direction[:, :, None] * direction[:, None, :]
        values = np.concatenate([block.ravel(), block.ravel(), -block.ravel(), -block.ravel(),
                                 np.zeros(9 * self.vertex_count)])
        return self._matrix(np.bincount(self._scatter, weights=values, minlength=self._nnz))

    def observables(self, x, v):
        """The base class's energies and momenta, then the parts of P: each part evaluated once."""
        spring, gravity, contact = self.spring_energy(x), self.gravity_energy(x), self.contact_energy(x)
        values = self._mechanical_observables(x, v, spring + gravity + contact)  # = potential_energy(x), bit for bit
        values.update(spring_energy=spring, gravity_energy=gravity, contact_energy=contact)
        return values

    energy_reference_name = "max(M |g| L, |KE0| + |PE0|)"

    def energy_scale(self) -> float:
        """Energy of lifting the cloth by its longest side, M |g| L, or |KE0| + |PE0| if larger (J): a cloth
        at rest has E0 = 0 and a nudge of 1e-8 m/s gives E0 ~ 1e-18 J, which no drift should be divided by."""
        lift = self.params.mass * float(np.linalg.norm(self.gravity)) * max(self.params.size)
        return max(super().energy_scale(), lift) if lift > 0 else super().energy_scale()

    @property
    def frame_shape(self) -> tuple[int, int]:
        """(ny, nx): a frame's vertices are row-major (vertex = row * nx + col), so it reshapes to (ny, nx, 3)."""
        nx, ny = self.shape
        return (ny, nx)

    def frame(self, x: np.ndarray) -> np.ndarray:
        """Vertex positions as (vertices, 3) (m)."""
        return x.reshape(-1, 3)





class LegacyClothParams(ClothParams):
    """ClothParams that build the legacy cloth (for Run objects of the benchmark)."""


LegacyClothParams.system_class = LegacyCloth
