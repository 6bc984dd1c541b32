"""simrun's systems read as the scenes an engine can build (docs/engines.md): the shapes that an engine's own model
expresses exactly, each read from a system or refused with the reason, so that every engine's translation
(integrators/mujoco.py, integrators/newton_engine.py) starts from the same reading and says the same about what it
cannot hold.

- **Uncoupled springs** (``UncoupledSprings``): a potential sum_i k_i q_i^2 / 2 (constant diagonal Hessian, at rest at
  the origin) with constant diagonal damping and lumped masses: the spring, the spring bank of the predictions,
  circular motion under its linear force.
- **Springs between vertices** (``VertexSprings``): a mass-spring model or the cloth with Hookean springs
  k/2 (L - l0)^2, damped only along them (simrun's ``spring`` damping model, beta dL/dt), under one uniform gravity,
  with vertices pinned whole or free.
- **A tetrahedral solid** (``TetSolid``): an undamped 3-D finite-element solid of stable neo-Hookean tetrahedra
  (Smith, de Goes & Kim 2018; systems/fem/materials/stable_neo_hookean.py) with lumped masses, under one uniform
  gravity, with vertices pinned whole or free.
Anything else (contact, prescribed paths, sliding vertices, consistent masses, other damping models or spring laws,
nonlinear forces) is what the engines' translations refuse: no approximation stands in for the system.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from simrun.systems.forms import NotOffered


@dataclass(frozen=True)
class UncoupledSprings:
    """Dof i: mass m_i, spring k_i to the origin, damper d_i (force -d_i v_i)."""

    stiffness: np.ndarray
    damping: np.ndarray
    mass: np.ndarray


@dataclass(frozen=True)
class VertexSprings:
    """Vertices with their rest positions (count, 3: a 2-D system in the z = 0 plane), masses and pins, and springs
    between two vertices, or from a vertex to a fixed anchor point (``second`` ANCHORED, systems/compliant.py;
    ``anchor`` (springs, 3), read for those only)."""

    dim: int
    rest: np.ndarray
    mass: np.ndarray
    pinned: np.ndarray
    free_dofs: np.ndarray
    gravity: np.ndarray
    first: np.ndarray
    second: np.ndarray
    anchor: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray


@dataclass(frozen=True)
class TetSolid:
    """Vertices with their rest positions (count, 3), lumped masses and pins; tetrahedra (elements, 4) ordered so that
    each one's rest volume is positive, with their Lame parameters mu and lambda (Pa)."""

    rest: np.ndarray
    mass: np.ndarray
    pinned: np.ndarray
    free_dofs: np.ndarray
    gravity: np.ndarray
    elements: np.ndarray
    mu: np.ndarray
    lam: np.ndarray

    dim: int = 3


def dense_diagonal(matrix) -> np.ndarray | None:
    """The diagonal of a matrix that has nothing off it, else None."""
    if matrix is None:
        return None
    if scipy.sparse.issparse(matrix):
        matrix = scipy.sparse.coo_array(matrix)
        off = matrix.row != matrix.col
        if np.any(matrix.data[off] != 0.0):
            return None
        return np.asarray(matrix.diagonal(), dtype=float)
    matrix = np.atleast_2d(np.asarray(matrix, dtype=float))
    diagonal = np.diag(matrix).copy()
    return diagonal if np.array_equal(matrix, np.diag(diagonal)) else None


def unheld(system, engine: str, contact_model: str) -> str | None:
    """What of the system's masses, constraints and contact an engine's translation would not hold, or None."""
    if system.mass_correction is not None:
        return f"a consistent mass matrix ({engine}'s point masses are lumped): use mass: lumped"
    constraints = system.constraints
    if system.sliding is not None or (constraints is not None and constraints.moving_dofs.size):
        return f"prescribed paths or sliding vertices (no {engine} element follows them here)"
    if system.contact_form():
        return f"contact ({contact_model})"
    return None


def uncoupled_springs(system) -> UncoupledSprings | str:
    """The system as uncoupled springs, or the reason it is not."""
    if not system.quadratic_potential:
        return "its potential is not quadratic"
    n = system.dof_count
    stiffness = dense_diagonal(system.hessian(system.x0))
    if stiffness is None:
        return "its springs are coupled (the Hessian has terms off its diagonal)"
    if np.any(system.gradient(np.zeros(n)) != 0.0):
        return "its springs are not at rest at the origin (or a field such as gravity acts)"
    damping = np.zeros(n)
    if system.is_damped:
        damping = dense_diagonal(system.damping_matrix(system.x0)) if system.damping_is_constant else None
        if damping is None:
            return "its damping is not constant and diagonal"
    if np.asarray(system.fixed_dofs).size:
        return "it holds dofs fixed"
    mass = np.broadcast_to(np.asarray(system.mass, dtype=float), (n,)).copy()
    return UncoupledSprings(np.asarray(stiffness, dtype=float), np.asarray(damping, dtype=float), mass)


def springs_between_vertices(system) -> VertexSprings | str:
    """The system as springs between vertices, or the reason it is not."""
    form = system.compliant_form()
    if form is None:
        return "it has no springs between vertices"
    if isinstance(form, NotOffered):
        return form.reason
    if form.other_forces:
        return "it has forces besides its springs, their dampers and gravity (damping not along the springs, contact)"
    dim, count = form.dim, form.vertex_count
    if dim not in (2, 3):
        return f"its vertices have {dim} coordinates"
    gravity = np.zeros(3)
    if system.external_acceleration is not None:
        field = np.asarray(system.external_acceleration, dtype=float).reshape(count, dim)
        if not np.all(field == field[0]):
            return "its external field is not one uniform gravity"
        gravity[:dim] = field[0]
    mass = np.asarray(system.mass, dtype=float).reshape(count, dim)
    if not np.all(mass == mass[:, :1]):
        return "its vertices' masses differ between coordinates"
    pins = _pinned_whole(system, count, dim)
    if isinstance(pins, str):
        return pins
    rest = np.zeros((count, 3))
    rest[:, :dim] = np.asarray(system.x0, dtype=float).reshape(count, dim)
    second = np.asarray(form.second, dtype=np.intp)
    anchor = np.zeros((second.size, 3))
    anchor[:, :dim] = form.anchor
    return VertexSprings(dim=dim, rest=rest, mass=mass[:, 0].copy(), pinned=pins[0], free_dofs=pins[1],
                         gravity=gravity, first=np.asarray(form.first, dtype=np.intp), second=second, anchor=anchor,
                         rest_length=np.asarray(form.rest_length, dtype=float),
                         stiffness=np.broadcast_to(np.asarray(form.stiffness, dtype=float), second.shape).copy(),
                         damping=np.broadcast_to(np.asarray(form.damping, dtype=float), second.shape).copy())


def _pinned_whole(system, count: int, dim: int) -> tuple[np.ndarray, np.ndarray] | str:
    """(pinned vertices, free dofs), or the reason when some vertex is held in some directions only."""
    fixed = np.zeros(count * dim, dtype=bool)
    fixed[np.asarray(system.fixed_dofs, dtype=np.intp)] = True
    held = fixed.reshape(count, dim)
    if np.any(held.any(axis=1) & ~held.all(axis=1)):
        return "some vertices are held in some directions only"
    return held.all(axis=1), np.flatnonzero(~fixed)


def tetrahedral_solid(system) -> TetSolid | str:
    """The system as stable neo-Hookean tetrahedra, or the reason it is not."""
    from simrun.systems.fem.system import Fem

    if not isinstance(system, Fem):
        return "it is not a finite-element solid"
    if system.is_shell or system.dim != 3:
        return "it is not a 3-D solid of tetrahedra (shells and 2-D solids have no counterpart here)"
    if system.material != "stable_neo_hookean":
        return f"its material is {system.material}, not stable_neo_hookean"
    if system.damping_terms:
        return "its damping (" + ", ".join(term.model for term in system.damping_terms) + ") is another model"
    lam = np.broadcast_to(system.lam, (system.elements.shape[0],)).astype(float)
    if np.any(lam <= 0.0):
        return "a Lame lambda <= 0 (the rest-stable alpha = 1 + 3 mu / (4 lambda) divides by it)"
    pins = _pinned_whole(system, system.vertex_count, 3)
    if isinstance(pins, str):
        return pins
    elements = np.array(system.elements, dtype=np.intp)
    rest = np.asarray(system.rest, dtype=float)
    edges = rest[elements[:, 1:]] - rest[elements[:, :1]]
    negative = np.linalg.det(edges) < 0.0
    elements[negative, 2:] = elements[negative][:, [3, 2]]  # the same F: a tetrahedron's vertices relabelled
    return TetSolid(rest=rest.copy(), mass=np.asarray(system.vertex_masses, dtype=float).copy(), pinned=pins[0],
                    free_dofs=pins[1], gravity=np.asarray(system.gravity, dtype=float).copy(), elements=elements,
                    mu=np.broadcast_to(system.mu, lam.shape).astype(float), lam=lam)


# the readings, in the order an engine tries them
READINGS = (uncoupled_springs, springs_between_vertices, tetrahedral_solid)


def read_scene(system, engine: str, contact_model: str,
               readings=READINGS) -> UncoupledSprings | VertexSprings | TetSolid | str:
    """The first of ``readings`` that takes ``system``, or why none does (each one's reason, in one line)."""
    held = unheld(system, engine, contact_model)
    if held is not None:
        return f"{engine}'s translation cannot express {held}"
    reasons = []
    for reading in readings:
        result = reading(system)
        if not isinstance(result, str):
            return result
        reasons.append(f"not {reading.__name__.replace('_', ' ')}: {result}")
    return f"{engine}'s translation cannot express this system (" + "; ".join(reasons) + ")"
