"""IPC contact of a mass-spring model's surface with itself and with static obstacle meshes, through ipctk.

The barrier (Li et al., "Incremental Potential Contact", SIGGRAPH 2020), for stiffness 1, as ipctk 1.6.1
evaluates it: its clamped log barrier on squared distances in its physical units
(``BarrierPotential(dhat, 1, use_physical_barrier=True)``, checked against ``ipctk.ClampedLogBarrier``),

    B(x) = sum_{pairs k with d_k < dhat} b(d_k^2) / dhat^3,   b(s) = -(s - dhat^2)^2 ln(s / dhat^2)   (m),

over the pairs of collision-mesh elements within dhat (3-D: point-triangle and edge-edge, the latter
mollified when nearly parallel; 2-D: point-edge), d_k the distance between their closest features. The
caller multiplies by its barrier stiffness kappa (N, so kappa B is in J): the units of the colliders'
barrier in contact/model.py, so one kappa serves both. Friction is IPC's lagged smoothed
Coulomb friction (see ``MeshContact.friction_energy``). Every distance, CCD, barrier and friction
computation is ipctk's; this module builds the collision mesh, keeps the obstacles fixed and maps ipctk's
arrays (all collision-mesh vertices, obstacles last) to the model's dofs.

The collision mesh: the model's surface (3-D: its triangles and their edges; 2-D: the boundary edges of
its triangles, or the given edges when it has none) followed by the obstacles' vertices and elements.
Only model vertices on that surface take part; the others have zero barrier and friction derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import ipctk
import numpy as np
import scipy.sparse

# ipctk's TBB threads (process-wide). One: with two threads its parallel sums made the barrier energy,
# gradient and Hessian differ from call to call at the same x (14 distinct energies in 20 calls, 64x64
# cloth), and a sweep already runs one process per core, where two threads gain nothing measurable
# (docs/performance.md, "Choices on the step path").
IPCTK_THREADS = 1

# Broad phase for building contacts, CCD and intersection tests: ipctk's default LBVH, the fastest of ipctk's
# broad phases with one thread, for building the contacts and for a CCD step (docs/performance.md, "Choices on the
# step path").
BROAD_PHASE = ipctk.LBVH

# CCD (ipctk.TightInclusionCCD, provably conservative). min_distance 0: the barrier's own minimum
# distance (dmin) is 0, and Tight Inclusion already stops short of contact by
# min((1 - r) d0, 1e-4 m) (r = conservative rescaling, d0 = the pair's start distance), so the
# configuration at the returned fraction has a positive distance.
CCD_MIN_DISTANCE = 0.0
# Distance precision (m) to which Tight Inclusion resolves a pair's gap before it answers (ipctk caps it at
# half the pair's start distance); ipctk's default.
CCD_TOLERANCE = 1e-6
# Cap on Tight Inclusion's box refinements per pair; when reached it returns its lower bound of the time of
# impact, still conservative, only earlier. A cloth pushed through the plane, its diagonal edges parallel
# above the plane's diagonal edge, is its worst case, where ipctk's default 1e7 (and 1e5) cost a CCD call far more
# than the step; 1e4 bounds it (the fraction 0.19 instead of 0.20 there) and gave the same fractions as 1e6 on
# near-contact Newton-like steps (docs/performance.md, "Choices on the step path").
CCD_MAX_ITERATIONS = 10_000
# Fraction of the start distance a step may close (the 0.8 of ipctk and of IPC's line search).
CCD_CONSERVATIVE_RESCALING = 0.8

# An obstacle triangle is degenerate when twice its area is below this fraction of its longest edge
# squared (its height is rounding noise of its length): its normal, and so the point-triangle distance,
# is then undefined.
DEGENERATE_TRIANGLE_RATIO = 1e-10
# An obstacle edge (2-D) is degenerate when it is shorter than this fraction of its obstacle's bounding
# box diagonal: its direction, and so the point-edge distance, is then rounding noise.
DEGENERATE_EDGE_RATIO = 1e-12

# Hessian projections by config name (the systems' convention, systems/base.py): False is the raw Hessian
# and True means "clamp".
HESSIAN_PROJECTIONS = {"clamp": ipctk.PSDProjectionMethod.CLAMP, "abs": ipctk.PSDProjectionMethod.ABS}

ipctk.set_num_threads(IPCTK_THREADS)


def _projection(project) -> ipctk.PSDProjectionMethod:
    """ipctk's PSD projection for ``project``: False (none), True or "clamp" (negative eigenvalues of each
    contact's local Hessian set to 0), "abs" (their absolute values)."""
    if isinstance(project, (bool, np.bool_)) or project is None:
        return ipctk.PSDProjectionMethod.CLAMP if project else ipctk.PSDProjectionMethod.NONE
    if project in HESSIAN_PROJECTIONS:
        return HESSIAN_PROJECTIONS[project]
    raise ValueError(f"project: unknown Hessian projection {project!r}; valid: False, True, "
                     + ", ".join(repr(name) for name in HESSIAN_PROJECTIONS))


def _index_array(elements, columns: int, vertex_count: int, name: str) -> np.ndarray:
    """``elements`` as an (k, columns) int32 array of indices into ``vertex_count`` vertices; ValueError naming ``name``."""
    array = np.asarray(elements)
    if array.size == 0:
        return np.zeros((0, columns), dtype=np.int32)
    if array.ndim != 2 or array.shape[1] != columns:
        raise ValueError(f"{name}: expected shape (k, {columns}), got {array.shape}")
    if not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"{name}: indices must be integers, got dtype {array.dtype}")
    bad = (array < 0) | (array >= vertex_count)
    if bad.any():
        row = int(np.argwhere(bad)[0, 0])
        raise ValueError(f"{name}: element {row} {array[row].tolist()} has an index out of range for {vertex_count} vertices")
    return array.astype(np.int32)


def boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """The edges used by exactly one triangle, shape (b, 2), each in its triangle's orientation.

    triangles: (t, 3) vertex indices."""
    directed = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    undirected = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    return directed[counts[inverse.ravel()] == 1]


@dataclass(frozen=True, eq=False)
class FrictionLag:
    """IPC's lagged friction state, built at x_lag by ``MeshContact.lag_friction``: ipctk's tangential
    collisions (for each contact within dhat at x_lag: its closest-point coordinates, tangent basis T_c and
    normal force magnitude lambda_c = kappa |d b(d^2) / dd| / dhat^3 at x_lag, N for kappa in N), with the
    Coulomb coefficient mu."""

    collisions: ipctk.TangentialCollisions
    mesh: ipctk.CollisionMesh  # the collision mesh the lag belongs to
    x_lag: np.ndarray  # (n*d,) m
    kappa: float  # barrier stiffness the normal forces were computed with
    mu: float  # Coulomb coefficient (1)

    @property
    def count(self) -> int:
        """Number of lagged friction contacts."""
        return len(self.collisions)

    def normal_forces(self) -> np.ndarray:
        """lambda_c (N) of each lagged contact, shape (count,). A Python loop: for diagnostics and tests."""
        return np.array([collision.normal_force_magnitude for collision in self.collisions])


class MeshContact:
    """IPC barrier, CCD and lagged friction between a model's surface, itself and static obstacles.

    All methods take and return quantities on the model's dofs: x (n*d,) m, vertex-major
    (x.reshape(n, d)); gradients (n*d,), Hessians scipy.sparse.csr_matrix (n*d, n*d). The obstacles never
    move. The contacts built at the last x are kept, so the energy, gradient and Hessian at the same x
    cost one broad phase.

    Parameters
    ----------
    rest: (n, d) rest positions (m), d = 2 or 3; ipctk uses them for the edge-edge mollifier and for
        adjacency.
    triangles: (t, 3) vertex indices or None. 3-D: the surface. 2-D: their boundary edges are the surface.
    edges: (e, 2) vertex indices or None: the surface when there are no triangles (2-D boundary edges;
        3-D codimensional segments, obstacle contact only). Ignored when there are triangles.
    obstacles: sequence of (vertices (m, d) m, elements): triangles (k, 3) in 3-D, edges (k, 2) in 2-D.
    self_contact: whether the model's surface collides with itself (adjacent elements never do).
    dhat: the barrier's reach (m): pairs closer than dhat repel.
    """

    def __init__(self, rest: np.ndarray, triangles: np.ndarray | None = None, edges: np.ndarray | None = None,
                 obstacles: Sequence[tuple[np.ndarray, np.ndarray]] = (), self_contact: bool = False,
                 dhat: float = 1e-3):
        rest = np.asarray(rest, dtype=float)
        if rest.ndim != 2 or rest.shape[1] not in (2, 3) or rest.shape[0] == 0:
            raise ValueError(f"rest: expected shape (n, 2) or (n, 3), got {rest.shape}")
        if not np.all(np.isfinite(rest)):
            raise ValueError("rest: positions must be finite")
        if not (np.isfinite(dhat) and dhat > 0):
            raise ValueError(f"dhat: must be a positive distance (m), got {dhat}")
        n, d = rest.shape
        self.vertex_count, self.dim, self.dhat = n, d, float(dhat)
        self.dof_count = n * d
        self.self_contact = bool(self_contact)
        obstacles = list(obstacles)
        if not obstacles and not self.self_contact:
            raise ValueError("nothing to collide: no obstacles and self_contact is False")

        triangles = _index_array(triangles if triangles is not None else [], 3, n, "triangles")
        edges = _index_array(edges if edges is not None else [], 2, n, "edges")
        if len(triangles):
            faces = triangles if d == 3 else np.zeros((0, 3), dtype=np.int32)
            surface_edges = ipctk.edges(triangles) if d == 3 else boundary_edges(triangles)
        else:
            faces, surface_edges = np.zeros((0, 3), dtype=np.int32), edges
            if self.self_contact and d == 3:
                raise ValueError("self_contact: self-contact needs a model with triangles (a 3-D model's edges are its springs, not a surface)")
            if self.self_contact and not len(edges):
                raise ValueError("self_contact: self-contact needs a model with triangles or edges")

        # model vertices on the surface (all of them for a model without elements: points against obstacles)
        used = np.unique(np.concatenate([faces.ravel(), surface_edges.ravel()]))
        self.surface_vertices = used if len(used) else np.arange(n)
        self._identity = len(self.surface_vertices) == n  # surface vertex k is model vertex k
        local = np.full(n, -1, dtype=np.int64)
        local[self.surface_vertices] = np.arange(len(self.surface_vertices))
        surface_count = len(self.surface_vertices)
        self._surface_dofs = (self.surface_vertices[:, None] * d + np.arange(d)).ravel()

        blocks_v, blocks_e, blocks_f = [rest[self.surface_vertices]], [local[surface_edges]], [local[faces]]
        self._edge_owner = [np.full(len(surface_edges), -1)]  # -1: model, o: obstacle o
        self._face_owner = [np.full(len(faces), -1)]
        self.obstacle_offsets = []  # first collision-mesh vertex of each obstacle
        offset = surface_count
        for o, obstacle in enumerate(obstacles):
            try:
                vertices, elements = obstacle
            except (TypeError, ValueError):
                raise ValueError(f"obstacles[{o}]: expected a pair (vertices, elements)") from None
            vertices = np.asarray(vertices, dtype=float)
            if vertices.ndim != 2 or vertices.shape[1] != d or vertices.shape[0] == 0:
                raise ValueError(f"obstacles[{o}]: vertices must have shape (m, {d}) for a {d}-D model, got {vertices.shape}")
            if not np.all(np.isfinite(vertices)):
                raise ValueError(f"obstacles[{o}]: vertices must be finite")
            kind = "triangles" if d == 3 else "edges"
            elements = _index_array(elements, 3 if d == 3 else 2, len(vertices), f"obstacles[{o}] {kind}")
            if not len(elements):
                raise ValueError(f"obstacles[{o}]: no {kind}")
            self._check_obstacle_elements(o, vertices, elements)
            self.obstacle_offsets.append(offset)
            blocks_v.append(vertices)
            if d == 3:
                obstacle_edges = ipctk.edges(elements)
                blocks_f.append(elements + offset)
                self._face_owner.append(np.full(len(elements), o))
            else:
                obstacle_edges = elements
            blocks_e.append(obstacle_edges + offset)
            self._edge_owner.append(np.full(len(obstacle_edges), o))
            offset += len(vertices)

        self._rest_vertices = np.asfortranarray(np.vstack(blocks_v))
        self._edges = np.asfortranarray(np.vstack(blocks_e).astype(np.int32))
        self._faces = np.asfortranarray(np.vstack(blocks_f).astype(np.int32))
        self._edge_owner = np.concatenate(self._edge_owner)
        self._face_owner = np.concatenate(self._face_owner)
        self._surface_count = surface_count
        self._model_collision_dofs = surface_count * d  # ipctk's dofs of the model come first
        self.mesh = ipctk.CollisionMesh(self._rest_vertices, self._edges, self._faces)
        if self.self_contact:
            self.mesh.can_collide = ipctk.make_static_obstacle_filter(surface_count)  # only obstacle-obstacle pairs blocked
        else:
            patches = np.r_[np.zeros(surface_count), np.ones(offset - surface_count)].astype(np.int32)
            self.mesh.can_collide = ipctk.make_vertex_patches_filter(patches)  # model-model and obstacle-obstacle blocked
        self.bbox_diagonal = ipctk.world_bbox_diagonal_length(self._rest_vertices)
        self._barrier = self._barrier_potential(1.0)
        self._ccd = ipctk.TightInclusionCCD(CCD_TOLERANCE, CCD_MAX_ITERATIONS, CCD_CONSERVATIVE_RESCALING)
        self._cached_x = None
        self._cached = None

    def _barrier_potential(self, kappa: float) -> ipctk.BarrierPotential:
        """ipctk's barrier kappa b(d^2) / dhat^3 (its physical barrier; the module docstring)."""
        return ipctk.BarrierPotential(self.dhat, float(kappa), use_physical_barrier=True)

    @staticmethod
    def _check_obstacle_elements(o: int, vertices: np.ndarray, elements: np.ndarray) -> None:
        """ValueError naming obstacle ``o``'s first degenerate element (see the DEGENERATE_* constants)."""
        corners = vertices[elements]
        if elements.shape[1] == 3:
            e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
            e3 = corners[:, 2] - corners[:, 1]
            twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
            longest = np.max(np.linalg.norm(np.stack([e1, e2, e3], axis=1), axis=2), axis=1)
            bad = np.flatnonzero(twice_area <= DEGENERATE_TRIANGLE_RATIO * longest**2)
            if len(bad):
                k = int(bad[0])
                raise ValueError(f"obstacles[{o}] triangle {k} {elements[k].tolist()} is degenerate: area {0.5 * twice_area[k]:.3g} m^2 for a longest edge of {longest[k]:.3g} m")
        else:
            length = np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1)
            diagonal = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
            bad = np.flatnonzero(length <= DEGENERATE_EDGE_RATIO * diagonal)
            if len(bad):
                k = int(bad[0])
                raise ValueError(f"obstacles[{o}] edge {k} {elements[k].tolist()} has zero length ({length[k]:.3g} m)")

    # -- maps between the model's dofs and ipctk's collision-mesh vertices --------------------------------

    def _vertices(self, x: np.ndarray) -> np.ndarray:
        """Collision-mesh vertex positions (m) for model positions x (n*d,): the surface vertices of x, then the obstacles."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.dof_count,):
            raise ValueError(f"x: expected shape ({self.dof_count},), got {x.shape}")
        vertices = self._rest_vertices.copy(order="F")
        model = x.reshape(self.vertex_count, self.dim)
        vertices[: self._surface_count] = model if self._identity else model[self.surface_vertices]
        return vertices

    def _to_model_vector(self, g: np.ndarray) -> np.ndarray:
        """ipctk's vector over all collision-mesh dofs -> (n*d,) on the model's dofs (the obstacles' part dropped)."""
        if self._identity:
            return np.array(g[: self._model_collision_dofs])
        out = np.zeros(self.dof_count)
        out[self._surface_dofs] = g[: self._model_collision_dofs]
        return out

    def _to_model_matrix(self, h: scipy.sparse.spmatrix) -> scipy.sparse.csr_matrix:
        """ipctk's sparse matrix over all collision-mesh dofs -> csr (n*d, n*d) on the model's dofs."""
        m = self._model_collision_dofs
        block = h.tocsr()[:m, :m]
        if self._identity:
            return block
        block = block.tocoo()
        return scipy.sparse.csr_matrix((block.data, (self._surface_dofs[block.row], self._surface_dofs[block.col])),
                                       shape=(self.dof_count, self.dof_count))

    def _contacts(self, x: np.ndarray) -> tuple[np.ndarray, ipctk.NormalCollisions]:
        """(collision-mesh vertices, ipctk.NormalCollisions within dhat) at x; the last x's are reused."""
        if self._cached_x is not None and np.array_equal(x, self._cached_x):
            return self._cached
        vertices = self._vertices(x)
        collisions = ipctk.NormalCollisions()
        collisions.build(self.mesh, vertices, self.dhat, broad_phase=BROAD_PHASE())
        self._cached_x = np.array(x, dtype=float)
        self._cached = (vertices, collisions)
        return self._cached

    # -- barrier --------------------------------------------------------------------------------------------

    def barrier_energy(self, x: np.ndarray) -> float:
        """B(x) = sum_k b(d_k^2) / dhat^3, b(s) = -(s - dhat^2)^2 ln(s / dhat^2), over pairs within dhat (m).

        x: (n*d,) m. Infinite or NaN when a pair touches (d = 0); callers keep x intersection-free by CCD."""
        vertices, collisions = self._contacts(x)
        return float(self._barrier(collisions, self.mesh, vertices))

    def barrier_gradient(self, x: np.ndarray) -> np.ndarray:
        """dB/dx, shape (n*d,), dimensionless (N per unit kappa); zero at vertices off the surface."""
        vertices, collisions = self._contacts(x)
        return self._to_model_vector(self._barrier.gradient(collisions, self.mesh, vertices))

    def barrier_hessian(self, x: np.ndarray, project=False) -> scipy.sparse.csr_matrix:
        """d^2B/dx^2, csr (n*d, n*d), 1/m.

        project: False (exact), True or "clamp" (each contact's local Hessian with its negative eigenvalues
        set to 0, ipctk's CLAMP) or "abs" (their absolute values, ipctk's ABS)."""
        vertices, collisions = self._contacts(x)
        h = self._barrier.hessian(collisions, self.mesh, vertices, _projection(project))
        return self._to_model_matrix(h)

    def active_count(self, x: np.ndarray) -> int:
        """Number of pairs within dhat at x (ipctk's normal collisions)."""
        return len(self._contacts(x)[1])

    def minimum_distance(self, x: np.ndarray) -> float:
        """min_k d_k (m) over the pairs within dhat at x; inf when no pair is within dhat."""
        vertices, collisions = self._contacts(x)
        if len(collisions) == 0:
            return float("inf")
        # ipctk returns the squared distance
        return float(np.sqrt(collisions.compute_minimum_distance(self.mesh, vertices)))

    # -- continuous collision detection -----------------------------------------------------------------

    def collision_free_step(self, x_start: np.ndarray, x_end: np.ndarray) -> float:
        """The largest alpha in [0, 1] such that ipctk's CCD certifies x_start + t (x_end - x_start) free of
        collisions for t in [0, alpha] (linear trajectories; Tight Inclusion with CCD_* settings).

        x_start must be intersection-free with every pair at a positive distance (else the step is 0)."""
        vertices_start, vertices_end = self._vertices(x_start), self._vertices(x_end)
        return float(ipctk.compute_collision_free_stepsize(
            self.mesh, vertices_start, vertices_end, min_distance=CCD_MIN_DISTANCE,
            broad_phase=BROAD_PHASE(), narrow_phase_ccd=self._ccd))

    # -- diagnostics ------------------------------------------------------------------------------------

    def _vertex_name(self, v: int) -> str:
        if v < self._surface_count:
            return f"model vertex {int(self.surface_vertices[v])}"
        o = int(np.searchsorted(self.obstacle_offsets, v, side="right")) - 1
        return f"obstacle {o} vertex {v - self.obstacle_offsets[o]}"

    def _edge_name(self, e: int) -> str:
        a, b = (int(i) for i in self._edges[e])
        o = int(self._edge_owner[e])
        if o < 0:
            return f"model edge ({int(self.surface_vertices[a])}, {int(self.surface_vertices[b])})"
        first = int(np.flatnonzero(self._edge_owner == o)[0])
        element = f" {e - first}" if self.dim == 2 else ""  # 2-D obstacle edges are the given elements
        offset = self.obstacle_offsets[o]
        return f"obstacle {o} edge{element} ({a - offset}, {b - offset})"

    def _face_name(self, f: int) -> str:
        o = int(self._face_owner[f])
        if o < 0:
            return f"model triangle {f} {self.surface_vertices[self._faces[f]].tolist()}"
        first = int(np.flatnonzero(self._face_owner == o)[0])
        return f"obstacle {o} triangle {f - first} {(self._faces[f] - self.obstacle_offsets[o]).tolist()}"

    def _collision_name(self, collision) -> str:
        """'<element> and <element>' for an ipctk normal collision."""
        if isinstance(collision, ipctk.FaceVertexNormalCollision):
            return f"{self._vertex_name(collision.vertex_id)} and {self._face_name(collision.face_id)}"
        if isinstance(collision, ipctk.EdgeEdgeNormalCollision):
            return f"{self._edge_name(collision.edge0_id)} and {self._edge_name(collision.edge1_id)}"
        if isinstance(collision, ipctk.EdgeVertexNormalCollision):
            return f"{self._vertex_name(collision.vertex_id)} and {self._edge_name(collision.edge_id)}"
        if isinstance(collision, ipctk.VertexVertexNormalCollision):
            return f"{self._vertex_name(collision.vertex0_id)} and {self._vertex_name(collision.vertex1_id)}"
        return type(collision).__name__

    def intersection(self, x: np.ndarray) -> str | None:
        """None when ipctk.has_intersections finds none at x, else one line naming the first crossing pair:
        an edge through a triangle (3-D, ipctk.edge_triangle_intersection) or two crossing edges (2-D,
        ipctk.segment_segment_intersect)."""
        vertices = self._vertices(x)
        if not ipctk.has_intersections(self.mesh, vertices, broad_phase=BROAD_PHASE()):
            return None
        broad_phase = BROAD_PHASE()
        broad_phase.can_vertices_collide = self.mesh.can_collide
        broad_phase.build(vertices, self._edges, self._faces, 0.0)
        if self.dim == 3:
            for candidate in broad_phase.detect_edge_face_candidates():
                e, f = candidate.edge_id, candidate.face_id
                if set(self._edges[e].tolist()) & set(self._faces[f].tolist()):
                    continue  # an edge of the triangle or one sharing a corner with it
                a, b = vertices[self._edges[e]]
                hit, u, v, t = ipctk.edge_triangle_intersection(a, b, *vertices[self._faces[f]])
                if hit:
                    where = "" if np.isnan(t) else f" at {t:.3g} along the edge"
                    return f"intersection: {self._edge_name(e)} passes through {self._face_name(f)}{where} (distance 0)"
        else:
            for candidate in broad_phase.detect_edge_edge_candidates():
                e0, e1 = candidate.edge0_id, candidate.edge1_id
                if set(self._edges[e0].tolist()) & set(self._edges[e1].tolist()):
                    continue  # adjacent edges meet at their shared vertex
                if ipctk.segment_segment_intersect(*vertices[self._edges[e0]], *vertices[self._edges[e1]]):
                    return f"intersection: {self._edge_name(e0)} crosses {self._edge_name(e1)} (distance 0)"
        return "intersection: ipctk.has_intersections reports the surface crossing itself or an obstacle"

    def initial_check(self, x: np.ndarray) -> str | None:
        """None when x is a valid start for IPC, else one line: an intersection (``intersection``) or the pair
        at the smallest distance when it is <= 0 (the barrier is infinite there and ipctk's CCD returns a
        zero step, the test of ipctk.check_initial_distance with dmin = 0)."""
        found = self.intersection(x)
        if found is not None:
            return found
        vertices, collisions = self._contacts(x)
        if len(collisions) == 0 or collisions.compute_minimum_distance(self.mesh, vertices) > 0.0:
            return None
        # a start that fails: name the touching pair (a loop over the contacts, once)
        distances = [collisions[i].compute_distance(vertices, self._edges, self._faces) for i in range(len(collisions))]
        k = int(np.argmin(distances))
        return f"touching: {self._collision_name(collisions[k])} at distance {np.sqrt(max(distances[k], 0.0)):.3g} m"

    # -- barrier stiffness (IPC's adaptive kappa) -------------------------------------------------------

    def initial_barrier_stiffness(self, x: np.ndarray, energy_gradient: np.ndarray, average_mass: float) -> tuple[float, float]:
        """(kappa, max_kappa) (N) by ipctk.initial_barrier_stiffness (IPC, Li et al. 2020, supplement), which
        works with the barrier b itself (kappa_b = kappa / dhat^3):

            kappa_b = clamp(-g_b . g_E / |g_b|^2, kappa_min, 100 kappa_min),   g_b = dhat^3 g_B,
            kappa_min = 1e11 m_avg / (4 s0 b''(s0)),   s0 = (1e-8 L)^2,
            (kappa, max_kappa) = dhat^3 (kappa_b, 100 kappa_min)

        g_B = barrier_gradient(x); b'' = d^2 b / ds^2 on squared distances s (module docstring); L =
        ``bbox_diagonal``, the diagonal of the bounding box of the collision mesh at rest (model surface and
        obstacles, m). kappa balances the objective's gradient along g_B (kappa g_B = -g_E projected on g_B);
        kappa_min makes the barrier's stiffness at a distance of 1e-8 L match the mass (in IPC's units).

        x: (n*d,) m.
        energy_gradient: g_E, (n*d,), the gradient of the objective that kappa * barrier_energy is added to
            (ipctk's grad_energy: in IPC, the incremental potential without contact).
        average_mass: m_avg (kg), the mean vertex mass (ipctk's average_mass). ipctk's kappa_min assumes
            IPC's objective 1/2 |x - x_tilde|^2_M + h^2 Psi (kg m^2); for that objective divided by h^2 (J)
            pass m_avg / h^2."""
        energy_gradient = np.asarray(energy_gradient, dtype=float)
        if energy_gradient.shape != (self.dof_count,):
            raise ValueError(f"energy_gradient: expected shape ({self.dof_count},), got {energy_gradient.shape}")
        units = self.dhat**3  # b = dhat^3 B
        kappa, max_kappa = ipctk.initial_barrier_stiffness(
            self.bbox_diagonal, self._barrier.barrier, self.dhat, float(average_mass),
            energy_gradient, units * self.barrier_gradient(x))
        return float(kappa * units), float(max_kappa * units)

    def update_barrier_stiffness(self, previous_min_distance: float, min_distance: float, max_kappa: float, kappa: float) -> float:
        """kappa doubled (at most max_kappa) when the minimum distance shrank and both distances are below
        1e-9 L (ipctk.update_barrier_stiffness with its dhat_epsilon_scale 1e-9, L = ``bbox_diagonal``): the
        barrier is then losing against the other forces. Else kappa unchanged.

        previous_min_distance, min_distance: ``minimum_distance`` (m) at the previous and the current Newton
        iterate (inf without contact); squared here, as ipctk compares squared distances.
        max_kappa: the cap from ``initial_barrier_stiffness``; kappa: the current stiffness (any units: the
        update only doubles and caps)."""
        return float(ipctk.update_barrier_stiffness(
            float(previous_min_distance) ** 2, float(min_distance) ** 2, float(max_kappa), float(kappa), self.bbox_diagonal))

    # -- friction -------------------------------------------------------------------------------------------

    def lag_friction(self, x_lag: np.ndarray, kappa: float, mu: float) -> FrictionLag:
        """IPC's lagged friction state at x_lag: for each pair within dhat, its tangent basis T_c and closest
        points at x_lag and its normal force magnitude lambda_c = kappa |d b(d^2) / dd| / dhat^3 (N for kappa
        in N; for a vertex against a static triangle, kappa |barrier_gradient| at the vertex) from the
        barrier with stiffness kappa (ipctk.TangentialCollisions.build). mu: Coulomb coefficient (1; ipctk's
        static and kinetic coefficients both mu)."""
        if not (np.isfinite(mu) and mu >= 0):
            raise ValueError(f"mu: must be a non-negative friction coefficient, got {mu}")
        if not (np.isfinite(kappa) and kappa > 0):
            raise ValueError(f"kappa: must be a positive barrier stiffness, got {kappa}")
        vertices, collisions = self._contacts(x_lag)
        tangential = ipctk.TangentialCollisions()
        tangential.build(self.mesh, vertices, collisions, self._barrier_potential(kappa), float(mu))
        return FrictionLag(tangential, self.mesh, np.array(x_lag, dtype=float), float(kappa), float(mu))

    def _friction_input(self, lag: FrictionLag, w: np.ndarray, eps: float) -> tuple[ipctk.FrictionPotential, np.ndarray]:
        """ipctk's friction potential for eps and w on the collision mesh's vertices (obstacles: 0)."""
        if lag.mesh is not self.mesh:
            raise ValueError("lag: built by another MeshContact")
        if not (np.isfinite(eps) and eps > 0):
            raise ValueError(f"eps: must be a positive distance (m), got {eps}")
        w_vertices = self._vertices(w)
        w_vertices[self._surface_count:] = 0.0  # the obstacles do not move
        return ipctk.FrictionPotential(float(eps)), w_vertices

    def friction_energy(self, lag: FrictionLag, w: np.ndarray, eps: float) -> float:
        """D(w) = sum_c mu lambda_c f0(|u_c|; eps),  u_c = T_c^T G_c w  (J when lambda is in N and w in m).

        G_c w: the relative motion of contact c's closest points, at its barycentric coordinates lagged at
        x_lag (a vertex p against a triangle (a, b, c): w_p - (1 - b1 - b2) w_a - b1 w_b - b2 w_c; obstacle
        vertices have w = 0); T_c: its lagged tangent basis (d x (d-1)); lambda_c: its lagged normal force.
        f0(y) = -y^3/(3 eps^2) + y^2/eps + eps/3 for y < eps, else y (ipctk.smooth_friction_f0; Li et al.
        2020). This is ipctk's FrictionPotential(eps) evaluated on w (checked term by term in
        tests/test_mesh_contact.py). ipctk reads its argument as velocities with eps = eps_v (m/s); since
        f0(s y; s eps) = s f0(y; eps), passing the displacement-like w = y - a (m) with eps = eps_v * b (m)
        is IPC's friction in displacement form (Li et al. 2020: u = x - x^t, eps = eps_v h).

        w: (n*d,) m; eps: m."""
        potential, w_vertices = self._friction_input(lag, w, eps)
        return float(potential(lag.collisions, self.mesh, w_vertices))

    def friction_gradient(self, lag: FrictionLag, w: np.ndarray, eps: float) -> np.ndarray:
        """dD/dw = sum_c mu lambda_c f1(|u_c|)/|u_c| G_c^T T_c u_c, shape (n*d,), N; f1 = f0' (f1 = 1 for
        |u_c| >= eps: a force of magnitude mu lambda_c against the sliding)."""
        potential, w_vertices = self._friction_input(lag, w, eps)
        return self._to_model_vector(potential.gradient(lag.collisions, self.mesh, w_vertices))

    def friction_hessian(self, lag: FrictionLag, w: np.ndarray, eps: float, project=False) -> scipy.sparse.csr_matrix:
        """d^2D/dw^2, csr (n*d, n*d), N/m; ``project`` as in ``barrier_hessian``."""
        potential, w_vertices = self._friction_input(lag, w, eps)
        return self._to_model_matrix(potential.hessian(lag.collisions, self.mesh, w_vertices, _projection(project)))

    def friction_count(self, lag: FrictionLag) -> int:
        """Number of lagged friction contacts."""
        return lag.count
