"""A finite-element solid or shell vertex by vertex, for vertex block descent (solvers/vbd.py): the elements (and a
shell's hinges) around each vertex, found once per system, and the compiled terms of vbd_kernels.py (solids) and
shell_vbd_kernels.py (shells) over them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..forms import VertexForm
from .materials import MATERIALS


class _CompiledTerms:
    """What the solid's and the shell's sweeps share: one colour's compiled sweep, and the same terms for given vertices
    (what the numpy sweep and contact take), through the kernel module ``_kernels()`` with the arguments ``_terms``."""

    def sweep(self, y, vertices, constrained, projectors, potential, projection, determinant_floor, max_halvings,
              halvings, gradient_norms) -> None:
        """One colour's steps in place in y (the kernels' ``sweep_colour``); ``potential``: the incremental potential's
        parts (solvers/vbd.py ``IncrementalParts``); per vertex, into halvings and gradient_norms: its backtracking
        rounds and the |g_i|_inf it met."""
        from ..vertex.kernel_arguments import PROJECTION_CODES, unsigned

        self._kernels().sweep_colour(
            y, unsigned(vertices), constrained, projectors, potential.y_tilde, potential.mass, potential.scale,
            *self._terms, self.gravity_force, self._kept, potential.damping_indptr, potential.damping_indices,
            potential.damping_data, potential.damping_weight, potential.velocity_origin, self.colliders,
            PROJECTION_CODES[projection], determinant_floor, max_halvings, halvings, gradient_norms)

    def blocks(self, x: np.ndarray, vertices: np.ndarray, project_spd) -> tuple[np.ndarray, np.ndarray]:
        """(dP/dx_i (k, d), the projected sum of the terms' blocks (k, d, d)) of the elastic terms and gravity."""
        from ..vertex.kernel_arguments import PROJECTION_CODES

        vertices = np.ascontiguousarray(vertices, dtype=np.intp)
        d = self.gravity_force.shape[1]
        gradient, hessian = np.empty((vertices.size, d)), np.empty((vertices.size, d, d))
        self._kernels().vertex_blocks(np.ascontiguousarray(x, dtype=float), vertices, *self._terms,
                                      PROJECTION_CODES[project_spd], gradient, hessian)
        gradient -= self.gravity_force[vertices]
        return gradient, hessian

    def changes(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the change of the elastic terms' energy and gravity's (k,) J, the kept fraction of each step (k,))."""
        vertices = np.ascontiguousarray(vertices, dtype=np.intp)
        steps = np.ascontiguousarray(steps, dtype=float)
        changes, fractions = np.empty(vertices.size), np.empty(vertices.size)
        self._kernels().vertex_changes(np.ascontiguousarray(x, dtype=float), vertices, steps, *self._terms, self._kept,
                                       changes, fractions)
        changes -= np.einsum("ij,ij->i", self.gravity_force[vertices], steps)
        return changes, fractions


@dataclass(frozen=True, eq=False)
class FemSweep(_CompiledTerms):
    """The elements at every vertex, one row per incidence: vertex i's are p in indptr[i]:indptr[i + 1] (in element
    order), each its element's corners and shape gradients with vertex i's first (elements (p, d + 1), all unsigned;
    shape_gradients (p, d + 1, d)), its volume, mu and lambda. A vertex's rows lie together, so a colour's sweep reads
    them in one run instead of from elements scattered over the mesh (twice as fast on the 10,000-tet box). The energy's
    code; gravity_force (n, d): m_i g (N); kept_volume: the fraction of its volume a step leaves each element (the step
    filter's)."""

    indptr: np.ndarray
    max_degree: int  # the most elements at one vertex
    elements: np.ndarray
    shape_gradients: np.ndarray
    volumes: np.ndarray
    mu: np.ndarray
    lam: np.ndarray
    alpha: np.ndarray  # the material's rest volume term (the stable neo-Hookean's 1 + mu d / ((d + 1) lambda)), or 0
    model: int
    gravity_force: np.ndarray
    kept_volume: float
    source_mu: np.ndarray  # the system's arrays these were taken from (a calibration's new system has new ones)
    source_lam: np.ndarray
    colliders: tuple  # where they stand for this solve (contact/point_kernels.py ``colliders_of``; none by default)

    @classmethod
    def of(cls, system, kept_volume: float) -> "FemSweep":
        from ..contact.point_kernels import empty_colliders

        elements = system.elements
        corners = elements.shape[1]
        indptr, element, corner = _incidences(elements, system.vertex_count)  # each vertex's elements in element order
        turned = (corner[:, None] + np.arange(corners)) % corners  # the vertex's corner first, the others in turn
        mu, lam, d = system.mu[element], system.lam[element], system.dim
        rest_volume_term = MATERIALS[system.material].rest_volume_term
        alpha = np.zeros_like(mu) if rest_volume_term is None else rest_volume_term(mu, lam, d)
        return cls(indptr, int(np.diff(indptr).max(initial=0)),
                   np.ascontiguousarray(elements[element[:, None], turned], dtype=np.uint64),
                   np.ascontiguousarray(system.shape_gradients[element[:, None], turned]),
                   system.volumes[element], mu, lam, alpha, system._model,
                   np.ascontiguousarray(system.vertex_masses[:, None] * system.gravity, dtype=float),
                   float(kept_volume), system.mu, system.lam, empty_colliders(system.dim))

    @property
    def _terms(self) -> tuple:
        return (self.indptr, self.max_degree, self.elements, self.shape_gradients, self.volumes, self.mu, self.lam,
                self.alpha, self.model)

    @property
    def _kept(self) -> float:
        return self.kept_volume

    @staticmethod
    def _kernels():
        from . import vbd_kernels

        return vbd_kernels


@dataclass(frozen=True, eq=False)
class ShellSweep(_CompiledTerms):
    """A shell's membrane triangles and discrete-shell hinges at every vertex (shell_vbd_kernels.py). The triangles as
    ``FemSweep``'s elements: vertex i's are p in indptr[i]:indptr[i + 1], each its triangle's corners turned so that
    vertex i comes first (a cyclic turn: the normal keeps its sign), their shape gradients (p, 3, 2), weights (rest
    area times thickness), mu and lambda. ``membrane`` 0 where the system leaves the triangles' energy out (an IMEX part
    with the hinges alone), whose rows still bound the step (its area filter is the whole's). The hinges: vertex i's are
    q in hinge_indptr[i]:hinge_indptr[i + 1], each the hinge's four vertices in its own order (the angle's sign is
    that order's), vertex i's corner in it (0-3), its stiffness k_h (N m) and rest angle (rad)."""

    indptr: np.ndarray
    max_degree: int
    elements: np.ndarray
    shape_gradients: np.ndarray
    weights: np.ndarray
    mu: np.ndarray
    lam: np.ndarray
    model: int
    membrane: int
    hinge_indptr: np.ndarray
    max_hinges: int
    hinges: np.ndarray
    corners: np.ndarray
    hinge_stiffness: np.ndarray
    rest_angles: np.ndarray
    gravity_force: np.ndarray
    kept_area: float
    source_mu: np.ndarray
    source_lam: np.ndarray
    colliders: tuple

    @classmethod
    def of(cls, system, kept_area: float) -> "ShellSweep":
        from ..contact.point_kernels import empty_colliders

        count = system.vertex_count
        indptr, element, corner = _incidences(system.elements, count)
        turned = (corner[:, None] + np.arange(3)) % 3
        hinge_indptr, hinge, hinge_corner = _incidences(system.hinges, count)
        return cls(indptr, int(np.diff(indptr).max(initial=0)),
                   np.ascontiguousarray(system.elements[element[:, None], turned], dtype=np.uint64),
                   np.ascontiguousarray(system.shape_gradients[element[:, None], turned]),
                   np.ascontiguousarray(system.volumes[element]), np.ascontiguousarray(system.mu[element]),
                   np.ascontiguousarray(system.lam[element]), system._model, int(system.includes_elements),
                   hinge_indptr, int(np.diff(hinge_indptr).max(initial=0)),
                   np.ascontiguousarray(system.hinges[hinge], dtype=np.uint64), hinge_corner.astype(np.int64),
                   np.ascontiguousarray(system.hinge_stiffness[hinge]), np.ascontiguousarray(system.rest_angles[hinge]),
                   np.ascontiguousarray(system.vertex_masses[:, None] * system.gravity, dtype=float),
                   float(kept_area), system.mu, system.lam, empty_colliders(3))

    @property
    def _terms(self) -> tuple:
        return (self.indptr, self.max_degree, self.elements, self.shape_gradients, self.weights, self.mu, self.lam,
                self.model, self.membrane, self.hinge_indptr, self.max_hinges, self.hinges, self.corners,
                self.hinge_stiffness, self.rest_angles)

    @property
    def _kept(self) -> float:
        return self.kept_area

    @staticmethod
    def _kernels():
        from . import shell_vbd_kernels

        return shell_vbd_kernels


def _incidences(groups: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr (n + 1,) uint64, group, corner): vertex i's incidences are rows indptr[i]:indptr[i + 1] of (group,
    corner), in group order; ``groups`` (m, c) the vertices of each element or hinge."""
    owner = groups.ravel()
    order = np.argsort(owner, kind="stable")
    group, corner = np.divmod(order, groups.shape[1])
    indptr = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=vertex_count))]).astype(np.uint64)
    return indptr, group, corner


class FemVertexForm(VertexForm):
    """A finite-element system's vertex form (systems/forms.py): each vertex's elements (``FemSweep`` of a solid,
    ``ShellSweep`` of a shell's triangles and hinges), gravity and the colliders; the generic form where the elements
    are not the system's (a solid's IMEX part without its elements). ``kept_volume``: the fraction of each element's
    volume that the step filter keeps."""

    def __init__(self, system, kept_volume: float):
        super().__init__(system)
        self.kept_volume = kept_volume
        self._sweep = None

    def element_sweep(self):
        """The elements at each vertex, or None where the generic blocks serve; taken again when the system's moduli
        are new arrays (a calibration's changed system)."""
        system = self.system
        if not (system.is_shell or system.includes_elements):
            return None
        sweep = self._sweep
        if sweep is None or sweep.source_mu is not system.mu or sweep.source_lam is not system.lam:
            sweep = self._sweep = (ShellSweep if system.is_shell else FemSweep).of(system, self.kept_volume)
        return sweep

    def blocks(self, x, vertices, project_spd=False):
        """The elements' blocks at each vertex, each element's projected on its own (vbd_kernels.py), gravity, and the
        colliders' blocks."""
        sweep = self.element_sweep()
        if sweep is None:
            return super().blocks(x, vertices, project_spd)
        gradient, hessian = sweep.blocks(x, vertices, project_spd)
        contact = self.system.contact
        if contact is not None:  # the colliders act on each vertex alone
            contact.point_terms(x.reshape(-1, self.system.dim)[vertices], gradient, hessian, project_spd)
        return gradient, hessian

    def energy_changes(self, x, vertices, steps):
        sweep = self.element_sweep()
        if sweep is None:
            return super().energy_changes(x, vertices, steps)
        changes, _ = sweep.changes(x, vertices, steps)
        contact = self.system.contact
        if contact is not None:
            changes += contact.point_energy_changes(x.reshape(-1, self.system.dim)[vertices], steps)
        return changes

    def step_fractions(self, x, vertices, steps):
        """The largest fraction of each vertex's step that keeps its elements above ``kept_volume`` of their volume
        (the step filter of ``max_step``, exact for one vertex: J is linear in its position) and stops short of the
        colliders under IPC (contact/hooks.py)."""
        contact = self.system.contact_form()
        colliders = None if contact is None else contact.point_step_fractions(x, vertices, steps)
        sweep = self.element_sweep()
        if sweep is None:
            return colliders
        kept = sweep.changes(x, vertices, steps)[1]
        return kept if colliders is None else np.minimum(kept, colliders)

    def sweep(self):
        """The elements and the colliders, where they stand now, for vertex block descent's compiled colour sweep;
        None where ``element_sweep`` is None or a collider has no compiled form (contact/point_kernels.py)."""
        from ..contact.point_kernels import placed

        return placed(self.element_sweep(), self.system.contact, self.system.dim)
