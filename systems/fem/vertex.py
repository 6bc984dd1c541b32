"""A finite-element solid vertex by vertex, for vertex block descent (solvers/vbd.py): the elements around each vertex,
found once per system, and the compiled terms of vbd_kernels.py over them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class FemSweep:
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
    alpha: np.ndarray  # the stable neo-Hookean energy's rest volume term 1 + mu d / ((d + 1) lambda) (0 for the others)
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
        count, corners = elements.shape
        owner = elements.ravel()
        order = np.argsort(owner, kind="stable")  # each vertex's elements in element order
        element, corner = np.divmod(order, corners)
        turned = (corner[:, None] + np.arange(corners)) % corners  # the vertex's corner first, the others in turn
        indptr = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=system.vertex_count))]).astype(np.uint64)
        mu, lam, d = system.mu[element], system.lam[element], system.dim
        alpha = np.zeros_like(mu)
        if system.material == "stable_neo_hookean":
            with np.errstate(divide="ignore"):  # lambda = 0: alpha infinite, as the energy's own formula has it
                alpha = 1.0 + mu * d / ((d + 1.0) * lam)
        return cls(indptr, int(np.diff(indptr).max(initial=0)),
                   np.ascontiguousarray(elements[element[:, None], turned], dtype=np.uint64),
                   np.ascontiguousarray(system.shape_gradients[element[:, None], turned]),
                   system.volumes[element], mu, lam, alpha, system._model,
                   np.ascontiguousarray(system.vertex_masses[:, None] * system.gravity, dtype=float),
                   float(kept_volume), system.mu, system.lam, empty_colliders(system.dim))

    @property
    def _elements(self) -> tuple:
        return (self.indptr, self.max_degree, self.elements, self.shape_gradients, self.volumes, self.mu, self.lam,
                self.alpha, self.model)

    def sweep(self, y, vertices, constrained, projectors, potential, projection, determinant_floor, max_halvings,
              halvings) -> None:
        """One colour's steps in place in y (vbd_kernels.sweep_colour); ``potential``: the incremental potential's parts
        (solvers/vbd.py ``IncrementalParts``)."""
        from ..mass_spring.vbd_kernels import PROJECTION_CODES, unsigned
        from .vbd_kernels import sweep_colour

        sweep_colour(y, unsigned(vertices), constrained, projectors, potential.y_tilde, potential.mass, potential.scale,
                     *self._elements, self.gravity_force, self.kept_volume, potential.damping_indptr,
                     potential.damping_indices, potential.damping_data, potential.damping_weight,
                     potential.velocity_origin, self.colliders, PROJECTION_CODES[projection], determinant_floor,
                     max_halvings, halvings)

    def blocks(self, x: np.ndarray, vertices: np.ndarray, project_spd) -> tuple[np.ndarray, np.ndarray]:
        """(dP/dx_i (k, d), the projected sum of the elements' blocks (k, d, d)) of the elements and gravity."""
        from ..mass_spring.vbd_kernels import PROJECTION_CODES
        from .vbd_kernels import vertex_blocks

        vertices = np.ascontiguousarray(vertices, dtype=np.intp)
        d = self.shape_gradients.shape[2]
        gradient, hessian = np.empty((vertices.size, d)), np.empty((vertices.size, d, d))
        vertex_blocks(np.ascontiguousarray(x, dtype=float), vertices, *self._elements, PROJECTION_CODES[project_spd],
                      gradient, hessian)
        gradient -= self.gravity_force[vertices]
        return gradient, hessian

    def changes(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the change of the elements' energy and gravity's (k,) J, the kept fraction of each step (k,))."""
        from .vbd_kernels import vertex_changes

        vertices = np.ascontiguousarray(vertices, dtype=np.intp)
        steps = np.ascontiguousarray(steps, dtype=float)
        changes, fractions = np.empty(vertices.size), np.empty(vertices.size)
        vertex_changes(np.ascontiguousarray(x, dtype=float), vertices, steps, *self._elements, self.kept_volume,
                       changes, fractions)
        changes -= np.einsum("ij,ij->i", self.gravity_force[vertices], steps)
        return changes, fractions
