"""What a system offers a solver family beyond its energy: one form per family, None where not offered.

Every solver can step a system from P, dP/dx and d^2P/dx^2 (systems/base.py). The solvers of graphics practice want
more, each its own part, and ask the system for it:

- ``vertex_form()``: vertex block descent's per-vertex blocks and local energy changes (``VertexForm``). Every
  system offers the generic one, read off its whole gradient and Hessian; systems of elements offer a faster one
  that sums only the elements at each vertex.
- ``projective_form()``: the constant rest stiffness K_r of projective dynamics' global step and of L-BFGS's
  rest-shape Hessian, and whether projective dynamics minimises the system's incremental potential exactly
  (``ProjectiveForm``).
- ``compliant_form()``: the system's Hookean springs as XPBD's compliant constraints (systems/compliant.py
  ``CompliantSprings``).
- ``contact_form()``: what the runner, the problems and the line search ask of a contact block
  (systems/contact/hooks.py ``ContactForm``).

A system returns the form, or None where it offers none. It may return ``NotOffered(reason)`` instead of None, so
that the solver's one-line refusal says why: ``NotOffered`` is false, like None, so test a form with ``if form``,
never with ``is None``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from .patterns import colour_vertices, diagonal_blocks

# P sums terms of both signs: a difference of two values of P below this fraction of them is round-off
ENERGY_DIFFERENCE_ROUNDOFF = 1024 * np.finfo(float).eps


@dataclass(frozen=True)
class NotOffered:
    """A form a system does not offer, and why, in a few words (the end of a solver's one-line refusal)."""

    reason: str

    def __bool__(self) -> bool:
        return False


def refusal_reason(form, default: str) -> str:
    """Why ``form`` (a system's answer to a form method, false: None or ``NotOffered``) is not offered."""
    return form.reason if isinstance(form, NotOffered) else default


def kept_form(system, attribute: str, build: Callable):
    """``build(system)``, built once per system object and kept in its ``attribute``: a shallow copy of the system
    (``released``, an IMEX part) builds its own, since the form holds the system it was built for."""
    form = system.__dict__.get(attribute)
    if form is None or form.system is not system:
        form = system.__dict__[attribute] = build(system)
    return form


@dataclass(frozen=True)
class ProjectiveForm:
    """What projective dynamics (Liu et al. 2013, Bouaziz et al. 2014) and L-BFGS's rest-shape initial Hessian (Liu,
    Bouaziz & Kavan 2017) take from a system.

    ``rest_stiffness()``: K_r (N/m), a new constant symmetric positive semi-definite matrix per call, in the
    Hessian's pattern where the system has one; for springs sum_e kappa_e (L_e kron I_d) (kappa_e the spring's
    stiffness along itself at rest, L_e its graph Laplacian). ``inexact``: None when P is a sum of Hookean springs
    (or of projective dynamics' own element constraints) plus terms linear in x, so that projective dynamics
    minimises the incremental potential exactly; otherwise why not, in a few words (projective dynamics is then
    refused, L-BFGS still takes K_r)."""

    rest_stiffness: Callable[[], object]
    inexact: str | None = None


class VertexForm:
    """What vertex block descent (solvers/vbd.py) asks of a system, vertex by vertex: vertex i owns the dofs
    dim i .. dim i + dim - 1.

    This generic form is right for every system: it reads the blocks off the whole gradient and Hessian, at the
    cost of a whole evaluation per call. Systems of elements subclass it to sum only the elements at each vertex
    (mass_spring/blocks.py, fem/vertex.py)."""

    def __init__(self, system):
        self.system = system
        self._colouring: list[np.ndarray] | None = None

    def blocks(self, x: np.ndarray, vertices: np.ndarray, project_spd=False) -> tuple[np.ndarray, np.ndarray]:
        """Per-vertex blocks of P at x: (dP/dx_i, shape (k, dim), N; d^2P/dx_i^2, shape (k, dim, dim), N/m) for the
        k vertices i, ``project_spd`` as ``System.hessian``."""
        system = self.system
        vertices = np.asarray(vertices, dtype=np.intp)
        gradient = np.asarray(system.gradient(x), dtype=float).reshape(-1, system.dim)[vertices]
        return gradient, diagonal_blocks(system.hessian(x, project_spd=project_spd), vertices, system.dim)

    def energy_changes(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The change of P (J), shape (k,), when vertex i of ``vertices`` moves by steps[i] ((k, dim), m) and every
        other vertex stays at x: what vertex block descent's backtracking judges. Systems of elements form it
        without cancellation from the elements at the vertex; this form evaluates P once per vertex, and where
        P(x + s_i) - P(x) is below P's round-off it takes the second-order change g_i . s_i + s_i^T H_i s_i / 2
        instead (exact to O(|s_i|^3), far below that round-off)."""
        system, d = self.system, self.system.dim
        vertices = np.asarray(vertices, dtype=np.intp)
        energy = system.potential_energy(x)
        moved = np.array(x, dtype=float)
        changes, scales = np.empty(len(vertices)), np.empty(len(vertices))
        for index, (vertex, step) in enumerate(zip(vertices.tolist(), steps)):
            dofs = slice(d * vertex, d * vertex + d)
            moved[dofs] = x[dofs] + step
            moved_energy = system.potential_energy(moved)
            changes[index], scales[index] = moved_energy - energy, max(abs(moved_energy), abs(energy))
            moved[dofs] = x[dofs]
        unresolved = np.abs(changes) <= ENERGY_DIFFERENCE_ROUNDOFF * scales
        if unresolved.any():
            gradient, hessian = self.blocks(x, vertices[unresolved])
            step = steps[unresolved]
            changes[unresolved] = np.einsum("ki,ki->k", gradient, step) + 0.5 * np.einsum("ki,kij,kj->k", step, hessian, step)
        return changes

    def step_fractions(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray | None:
        """The largest fraction (k,) of each vertex's step (vertex i alone moving by steps[i]) that the system's step
        filter allows (finite elements keep their volumes, IPC stops short of the colliders), or None where every
        step may be taken whole."""
        return None

    def colouring(self) -> list[np.ndarray]:
        """Vertices in groups of which no two interact (vertex arrays, one per colour): a greedy colouring of the
        graph whose edges are the nonzero off-diagonal blocks of the Hessian's pattern and of D's at x0
        (``hessian_pattern`` where the system has one). Built once per form."""
        if self._colouring is None:
            system, d = self.system, self.system.dim
            matrices = [system.hessian_pattern if system.hessian_pattern is not None else system.hessian(system.x0)]
            damping = system.damping_matrix(system.x0)
            if damping is not None:
                matrices.append(damping)
            pairs = []
            for matrix in matrices:
                if scipy.sparse.issparse(matrix):
                    matrix = matrix.tocoo()
                    rows, cols = matrix.row, matrix.col
                else:
                    rows, cols = np.nonzero(np.asarray(matrix))
                pairs.append(np.stack([rows // d, cols // d], axis=1))
            self._colouring = colour_vertices(system.dof_count // d, np.concatenate(pairs))
        return self._colouring

    def sweep(self):
        """Vertex block descent's compiled colour sweep of the system's terms (mass_spring/blocks.py ``SpringSweep``),
        or None: the solver then sweeps with ``blocks`` and ``energy_changes``."""
        return None


def contact_needs_step_filter(system) -> bool:
    """Whether ``system`` has a contact whose every step must be cut short of a collision (IPC's barrier): the
    integrators that cannot cut theirs and the solvers without a filtered line search refuse it."""
    contact = system.contact_form()
    return bool(contact) and contact.needs_step_filter


def has_friction(system) -> bool:
    """Whether ``system`` has a contact with friction (a dissipative potential of each step's velocity map)."""
    contact = system.contact_form()
    return bool(contact) and contact.has_friction
