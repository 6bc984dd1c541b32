"""Per-vertex blocks of the mass-spring potential, for vertex block descent (solvers/vbd.py).

Vertex block descent updates one colour of vertices at a time, each vertex i by a Newton step on P as a
function of x_i alone (Chen et al., "Vertex block descent", ACM TOG 43(4), 2024, sec. 3.2). What it needs
of P is, per vertex i,

    g_i = sum_{e at i} c_e (x_i - x_j) - m_i g + contact,      H_i = sum_{e at i} B_e + contact block,

with c_e the law's gradient factor and B_e its Hessian block (``SPRING_LAWS``; vertex i at either end of
spring e sees the same B_e), and the change of P when x_i alone moves, for the solver's backtracking. Only
the springs that touch the vertices are evaluated: their incidences are found once per vertex set and kept
(the solver asks for the same few sets, its colours, at every iteration of every step).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse

from ..forms import VertexForm
from ..patterns import colour_vertices
from .laws import SpringGeometry


# Vertex sets whose incidences are kept: a solver asks for its colours (a few dozen at most); a bound keeps a
# caller that asks for ever new sets from growing the memory without end.
MAX_KEPT_SETS = 256


@dataclass(frozen=True, eq=False)
class IncidentSprings:
    """The p (vertex, spring) incidences of a set of k vertices: a spring with both ends in the set counts twice.

    owner: (p,) the vertex's index in the set; other_dofs: (p, d) the dofs of the spring's other end;
    summing: adds the incidences of each vertex, (p, ...) -> (k, ...): ``np.add.reduceat`` over the incidences
    sorted by vertex (each vertex's run starts at ``starts``), or a (k, p) CSR of ones where some vertex has
    none (reduceat cannot give an empty sum); stiffness, rest_length,
    rest_length_squared: (p,) and identity (d, d), what the spring laws read; gravity_force: (k, d) m_i g (N)."""

    vertices: np.ndarray
    owner: np.ndarray
    other_dofs: np.ndarray
    summing: Callable[[np.ndarray], np.ndarray]
    stiffness: np.ndarray
    rest_length: np.ndarray
    rest_length_squared: np.ndarray
    identity: np.ndarray
    gravity_force: np.ndarray


class SpringVertexForm(VertexForm):
    """Gradient and Hessian blocks and local energies of a MassSpring, vertex by vertex (see the module docstring):
    its vertex form (systems/forms.py)."""

    def __init__(self, system):
        super().__init__(system)
        self._kept: dict[bytes, IncidentSprings] = {}
        self._sweep: SpringSweep | None = None

    def colouring(self) -> list[np.ndarray]:
        """A greedy colouring of the spring graph: the vertices of a colour share no spring (every term of P that
        couples two vertices, damping included, lies along a spring; contact and gravity act on one vertex)."""
        if self._colouring is None:
            system = self.system
            self._colouring = colour_vertices(system.vertex_count, np.stack([system.first, system.second], axis=1))
        return self._colouring

    def step_fractions(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray | None:
        """IPC's step filter for each vertex moving alone: contact/hooks.py ``ContactForm.point_step_fractions``."""
        contact = self.system.contact_form()
        return None if contact is None else contact.point_step_fractions(x, vertices, steps)

    def sweep(self):
        """The springs (``SpringSweep``) and the colliders, where they stand now, for vertex block descent's compiled
        colour sweep; None where a collider has no compiled form (contact/point_kernels.py ``placed``: the numpy
        blocks take them)."""
        from ..contact.point_kernels import placed

        system = self.system
        if self._sweep is None or self._sweep.stiffness is not system.stiffness:
            self._sweep = SpringSweep.of(system)
        return placed(self._sweep, system.contact, system.dim)

    def incident(self, vertices: np.ndarray) -> IncidentSprings:
        """The incidences of ``vertices`` (found once per set)."""
        vertices = np.ascontiguousarray(vertices, dtype=np.intp)
        key = vertices.tobytes()
        part = self._kept.get(key)
        if part is not None:
            return part
        system, d = self.system, self.system.dim
        local = np.full(system.vertex_count, -1, dtype=np.intp)
        local[vertices] = np.arange(vertices.size)
        at_first, at_second = np.flatnonzero(local[system.first] >= 0), np.flatnonzero(local[system.second] >= 0)
        springs = np.concatenate([at_first, at_second])
        owner = np.concatenate([local[system.first[at_first]], local[system.second[at_second]]])
        other = np.concatenate([system.second[at_first], system.first[at_second]])
        by_vertex = np.argsort(owner, kind="stable")  # each vertex's incidences together, in their old order
        springs, owner, other = springs[by_vertex], owner[by_vertex], other[by_vertex]
        counts = np.bincount(owner, minlength=vertices.size)
        if counts.size and counts.all():
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            summing = functools.partial(np.add.reduceat, indices=starts, axis=0)
        else:
            summing = scipy.sparse.csr_matrix((np.ones(springs.size), (owner, np.arange(springs.size))),
                                              shape=(vertices.size, springs.size)).__matmul__
        part = IncidentSprings(
            vertices=vertices, owner=owner, other_dofs=d * other[:, None] + np.arange(d), summing=summing,
            stiffness=system.stiffness[springs], rest_length=system.rest_length[springs],
            rest_length_squared=system.rest_length_squared[springs], identity=system.identity,
            gravity_force=system.vertex_masses[vertices][:, None] * system.gravity)
        if len(self._kept) >= MAX_KEPT_SETS:
            self._kept.clear()
        self._kept[key] = part
        return part

    @staticmethod
    def _geometry(part: IncidentSprings, x: np.ndarray, positions: np.ndarray) -> SpringGeometry:
        """The incident springs with their vertex at ``positions`` and the other end at x: x_i - x_j seen from
        the vertex (the laws' blocks and factors do not depend on the sign of x_i - x_j)."""
        delta = positions[part.owner] - x[part.other_dofs]
        length = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        stretch = length - part.rest_length
        return SpringGeometry(positions, delta, length, stretch, part.stiffness * stretch)

    def blocks(self, x: np.ndarray, vertices: np.ndarray, project_spd=False) -> tuple[np.ndarray, np.ndarray]:
        """(dP/dx_i (k, d) N, d^2P/dx_i^2 (k, d, d) N/m) at x, the same numbers as ``System.vertex_blocks`` to round-off."""
        system, d = self.system, self.system.dim
        part = self.incident(vertices)
        positions = x.reshape(-1, d)[part.vertices]
        geometry = self._geometry(part, x, positions)
        law = system.law
        gradient = part.summing(law.gradient_factor(part, geometry)[:, None] * geometry.delta)
        gradient -= part.gravity_force
        spring_blocks = law.blocks(part, geometry, project_spd).reshape(-1, d * d)
        hessian = part.summing(spring_blocks).reshape(-1, d, d)
        if system.contact is not None:  # the colliders act on each vertex alone
            system.contact.point_terms(positions, gradient, hessian, project_spd)
        return gradient, hessian

    def energy_changes(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The change of P (J), shape (k,), when vertex i moves by steps[i] ((k, d), m) and the others stay at x;
        the vertices must share no spring (one colour). Formed without cancellation, so that it resolves the
        changes of the last iterations, ~|g|^2/H, far below the round-off of P itself:
        sum_{e at i} [W_e(L') - W_e(L)] with L'^2 - L^2 = s . (2 (x_i - x_j) + s), - m_i g . s, and the contact's."""
        system, d = self.system, self.system.dim
        part = self.incident(vertices)
        positions = x.reshape(-1, d)[part.vertices]
        delta = positions[part.owner] - x[part.other_dofs]
        step = steps[part.owner]
        moved = delta + step
        squared_change = np.einsum("ij,ij->i", step, delta + delta + step)
        length = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        moved_length = np.sqrt(np.einsum("ij,ij->i", moved, moved))
        changes = part.summing(system.law.energy_changes(part, length, moved_length, squared_change))
        changes -= np.einsum("ij,ij->i", part.gravity_force, steps)
        if system.contact is not None:
            changes += system.contact.point_energy_changes(positions, steps)
        return changes


@dataclass(frozen=True, eq=False)
class SpringSweep:
    """The springs at every vertex for the compiled colour sweep (vbd_kernels.py): vertex i's incidences are
    indptr[i]:indptr[i + 1] of ``other`` (the spring's other end) and ``springs`` (its index), in the numpy form's
    order, all unsigned; the springs' constants; the law's code; gravity_force (n, d): m_i g (N); the colliders where
    they stand for this solve (contact/point_kernels.py ``colliders_of``; none by default)."""

    indptr: np.ndarray
    other: np.ndarray
    springs: np.ndarray
    max_degree: int  # the most springs at one vertex
    stiffness: np.ndarray
    rest_length: np.ndarray
    rest_length_squared: np.ndarray
    law: int
    gravity_force: np.ndarray
    colliders: tuple

    @classmethod
    def of(cls, system) -> "SpringSweep":
        from ..contact.point_kernels import empty_colliders

        from .kernels import LAW_CODES

        count = system.spring_count
        owner = np.concatenate([system.first, system.second])
        order = np.argsort(owner, kind="stable")  # each vertex's incidences as first end, then as second end
        # unsigned indices: numba skips the wraparound test of a negative index (a fifth of the sweep's time)
        indptr = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=system.vertex_count))]).astype(np.uint64)
        return cls(indptr, np.concatenate([system.second, system.first])[order].astype(np.uint64),
                   np.concatenate([np.arange(count), np.arange(count)])[order].astype(np.uint64),
                   int(np.diff(indptr).max(initial=0)),
                   np.ascontiguousarray(system.stiffness, dtype=float), np.ascontiguousarray(system.rest_length, dtype=float),
                   np.ascontiguousarray(system.rest_length_squared, dtype=float), LAW_CODES[system.law.name],
                   np.ascontiguousarray(system.vertex_masses[:, None] * system.gravity, dtype=float),
                   empty_colliders(system.dim))

    def sweep(self, y, vertices, constrained, projectors, potential, projection, determinant_floor, max_halvings,
              halvings, gradient_norms) -> None:
        """One colour's steps in place in y (vbd_kernels.sweep_colour); ``potential``: the incremental potential's
        parts (``IncrementalParts``); per vertex, into halvings and gradient_norms: its backtracking rounds and the
        |g_i|_inf it met."""
        from ..vertex.kernel_arguments import PROJECTION_CODES, unsigned
        from .vbd_kernels import sweep_colour

        sweep_colour(y, unsigned(vertices), constrained, projectors, potential.y_tilde, potential.mass, potential.scale,
                     self.indptr, self.other, self.springs, self.max_degree, self.stiffness, self.rest_length,
                     self.rest_length_squared, self.law, self.gravity_force, potential.damping_indptr, potential.damping_indices,
                     potential.damping_data, potential.damping_weight, potential.velocity_origin, self.colliders,
                     PROJECTION_CODES[projection], determinant_floor, max_halvings, halvings, gradient_norms)
