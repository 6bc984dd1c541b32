"""XPBD with small steps: a system's springs as compliant constraints, projected in substeps.

Macklin, Mueller & Chentanez, "XPBD: position-based simulation of compliant constrained dynamics", MIG 2016
(the compliant constraint update, eq. 18, and its damping, eq. 26); Macklin, Storey, Lu, Terdiman,
Chentanez, Jeschke & Mueller, "Small steps in physics simulation", SCA 2019 (many substeps of one iteration
each instead of many iterations in one step). The springs come from ``System.compliant_form()``
(systems/compliant.py); the constraint projection is Gauss-Seidel over groups of springs that share no
vertex, each group one compiled parallel pass (xpbd_kernels.py; vector constraints one vectorised update).
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import dataclass
from types import SimpleNamespace
from typing import ClassVar

import numpy as np
from pydantic import Field

from simrun.solvers import EXPLICIT_STEP
from simrun.systems.compliant import ANCHORED
from simrun.systems.forms import refusal_reason

from .base import Integrator, State, mass_refusal
from .xpbd_kernels import project_distance


class XPBD(Integrator):
    """Extended position-based dynamics in substeps; first order, stable at every h on the linear spring.

    Per substep of h_s = h / substeps, with the system's springs as constraints C_e (compliance 1/k_e, damper
    beta_e along the spring; systems/compliant.py) and W the inverse mass passed through each vertex's
    filter (0 on pinned dofs and on vertices on prescribed paths, S_i / m_i on sliding vertices):

        v  += h_s M^-1 f_other(x, v)      f_other = f - f_springs: gravity, and (explicitly) penalty contact and
                                          damping that is not along the springs (relative, drag, rayleigh)
        x_n = x,  x = x_n + h_s v,  lambda = 0
        `iterations` times, for each group of springs that share no vertex (Gauss-Seidel over the groups):
            Delta lambda = (-C - a lambda - g grad C (x - x_n)) / ((1 + g) grad C W grad C^T + a),
            a = 1 / (k h_s^2),  g = a b / h_s with b = h_s^2 beta          (MMC 2016, eqs. 18 and 26)
            lambda += Delta lambda,  x += W grad C^T Delta lambda
        v = (x - x_n) / h_s,  and the vertices on prescribed paths placed on their paths at the substep's end.

    Numerator and denominator are multiplied by k h_s^2 here, which gives the same Delta lambda and allows k = 0
    (a damper alone): Delta lambda = (-k h_s^2 C - lambda - beta h_s grad C (x - x_n)) / ((k h_s^2 + beta h_s)
    grad C W grad C^T + 1). A correction moves the two ends by m_i-weighted opposite amounts: linear momentum is
    conserved. On a zero-length spring C = x_i - x_j is linear, one iteration solves a substep's constraint
    exactly and the substep is backward Euler with h_s (damper included); on the test spring
    rho = (1 + (h w / substeps)^2)^(-substeps/2): artificial damping ~ h w / substeps at small steps. Explicit
    forces in f_other keep their explicit stability limits on h_s (stiff contact or rayleigh damping need
    enough substeps). Systems without a compliant form are refused, with its reason.
    """

    name: ClassVar[str] = "xpbd"
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True  # no nonlinear solve: the solver is never called
    # its work is the projections on numba's threads (xpbd_kernels.py), with no BLAS call that gains from threads: the
    # run holds BLAS at one thread (runner/execution/simulate.py, as for a solver with NonlinearSolver's attribute)
    needs_no_blas_threads: ClassVar[bool] = True
    summary: ClassVar[str] = "XPBD with substeps (small steps); on the spring each substep is backward Euler with h/substeps"

    substeps: int = Field(10, ge=1, le=10_000, description="substeps per step, each h/substeps long (small steps)")
    iterations: int = Field(1, ge=1, le=1_000, description="constraint projection sweeps per substep (small steps: 1)")

    def refusal(self, system):
        springs = system.compliant_form()
        if not springs:
            return f"xpbd needs the system's springs as compliant constraints: {_not_compliant(system, springs)}"
        return mass_refusal(self.name, system) or super().refusal(system)

    def step(self, system, state, dt, solver):
        projection = spring_projection(system)
        h = dt / self.substeps
        scaled = projection.scaled(h)
        moving = projection.moving_dofs
        x, v = state.x, state.v.copy()
        for substep in range(1, self.substeps + 1):
            acceleration = projection.acceleration(system, x, v)
            if acceleration is not None:
                v += h * acceleration
            # the prediction x_n + h_s v and its corrections are kept as the displacement from x_n: the velocity
            # (x - x_n) / h_s is then good to eps |v|, not to eps |x| / h_s (two nearby positions subtracted)
            displacement = h * v
            if moving.size:
                path_x, path_v = system.constraints.path(state.t + substep * h)
                displacement[moving] = path_x - x[moving]
            multipliers = [group.zero_multipliers() for group in projection.groups]
            for _ in range(self.iterations):
                for group, (stiffness_h2, damping_h), multiplier in zip(projection.groups, scaled, multipliers):
                    group.project(x, displacement, multiplier, stiffness_h2, damping_h)
            v = displacement / h
            x = x + displacement
            if moving.size:
                x[moving], v[moving] = path_x, path_v
        return State(state.t + dt, x, v), EXPLICIT_STEP


# ==================================================================================================
# The projection, prepared once per system
# ==================================================================================================
@dataclass(eq=False)
class SpringGroup:
    """Springs of one colour (no shared vertex) and one kind (distance or vector constraints), with what their
    update needs: ends, anchors, l0 (m), k (N/m), beta (N s/m), and the inverse masses of both ends per
    coordinate, (g, d), 1/kg (0 on pinned dofs, prescribed vertices and anchors). ``sliding``: per end, the
    rows whose vertex slides and their projectors S (rows, d, d), or None."""

    first: np.ndarray  # (g,) vertex i
    second: np.ndarray  # (f,) vertex j of the rows in free_rows
    free_rows: np.ndarray | None  # (f,) rows whose second end is a vertex; None: all of them
    anchor: np.ndarray  # (g, d) m, the second end of anchored rows
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    first_weight: np.ndarray  # (g, d) 1/kg
    second_weight: np.ndarray  # (g, d) 1/kg
    sliding: tuple  # (first, second): each None or (rows, projectors)
    vector: bool  # l0 = 0: C = x_i - x_j (d rows); else C = |x_i - x_j| - l0

    def zero_multipliers(self) -> np.ndarray:
        """lambda = 0 at the start of a substep: (g,) for distance constraints, (g, d) for vector constraints."""
        return np.zeros(self.first_weight.shape if self.vector else self.first.shape)

    def _second_ends(self, values: np.ndarray, anchor: np.ndarray | None) -> np.ndarray:
        """values (n, d) at the second ends, (g, d); in the rows of anchored springs ``anchor``, or 0 for None."""
        if self.free_rows is None:
            return values[self.second]
        ends = np.zeros_like(self.anchor) if anchor is None else anchor.copy()
        ends[self.free_rows] = values[self.second]
        return ends

    def project(self, start: np.ndarray, displacement: np.ndarray, multiplier: np.ndarray, stiffness_h2: np.ndarray,
                damping_h: np.ndarray) -> None:
        """One XPBD update of every constraint of the group at x = x_n + displacement, in place on the
        displacement (m) and the multipliers (N s^2). start: x_n of the substep (m), shape (n d,);
        stiffness_h2 = k h_s^2 (kg), damping_h = beta h_s (kg) per spring. Distance constraints in one compiled
        pass (xpbd_kernels.py), vector constraints (l0 = 0) vectorised here."""
        d = self.first_weight.shape[1]
        start, moves = start.reshape(-1, d), displacement.reshape(-1, d)
        damped = bool(damping_h.any())
        if not self.vector:
            compiled = self._compiled
            project_distance(start, moves, multiplier, self.first, compiled.second, self.anchor, self.rest_length,
                             stiffness_h2, damping_h, self.first_weight, self.second_weight, compiled.first_slides,
                             compiled.first_projectors, compiled.second_slides, compiled.second_projectors, damped)
            return
        # x_i - x_j as (x_i,n - x_j,n) + (relative displacement), the second the damper's grad C (x - x_n)
        moved = moves[self.first] - self._second_ends(moves, None)
        delta = (start[self.first] - self._second_ends(start, self.anchor)) + moved
        numerator = -stiffness_h2[:, None] * delta - multiplier
        if damped:
            numerator -= damping_h[:, None] * moved
        change, first_step, second_step = self._vector_update(numerator, stiffness_h2 + damping_h)
        multiplier += change
        moves[self.first] += first_step
        moves[self.second] -= second_step if self.free_rows is None else second_step[self.free_rows]

    @functools.cached_property
    def _compiled(self) -> SimpleNamespace:
        """The group in the compiled kernel's form: every row's second end (-1: anchored), and per end whether it
        slides and its projector (the identity where it does not)."""
        rows, d = self.first.size, self.first_weight.shape[1]
        second = np.full(rows, -1, dtype=np.intp)
        second[slice(None) if self.free_rows is None else self.free_rows] = self.second

        def filters(sliding):
            slides, projectors = np.zeros(rows, dtype=np.bool_), np.broadcast_to(np.eye(d), (rows, d, d)).copy()
            if sliding is not None:
                slides[sliding[0]], projectors[sliding[0]] = True, sliding[1]
            return slides, projectors

        (first_slides, first_projectors), (second_slides, second_projectors) = (filters(end) for end in self.sliding)
        return SimpleNamespace(second=second, first_slides=first_slides, first_projectors=first_projectors,
                               second_slides=second_slides, second_projectors=second_projectors)

    def _vector_update(self, numerator: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Delta lambda = ((k h^2 + beta h)(W_i + W_j) + I)^-1 numerator per spring, and the moves W_i Delta lambda,
        W_j Delta lambda, each (g, d). Per coordinate where W is diagonal; a d x d solve per spring where an end
        slides (W = S / m is a full block)."""
        if self.sliding[0] is None and self.sliding[1] is None:
            change = numerator / (scale[:, None] * (self.first_weight + self.second_weight) + 1.0)
            return change, self.first_weight * change, self.second_weight * change
        first_block = _weight_blocks(self.first_weight, self.sliding[0])
        second_block = _weight_blocks(self.second_weight, self.sliding[1])
        d = numerator.shape[1]
        matrix = scale[:, None, None] * (first_block + second_block) + np.eye(d)
        change = np.linalg.solve(matrix, numerator[:, :, None])[:, :, 0]
        return change, np.einsum("gij,gj->gi", first_block, change), np.einsum("gij,gj->gi", second_block, change)


def _filtered(vectors: np.ndarray, sliding) -> np.ndarray:
    """vectors with the rows of sliding ends passed through their projectors S (in place; returns vectors)."""
    if sliding is not None:
        rows, projectors = sliding
        vectors[rows] = np.einsum("sij,sj->si", projectors, vectors[rows])
    return vectors


def _weight_blocks(weights: np.ndarray, sliding) -> np.ndarray:
    """The ends' inverse-mass blocks W (g, d, d): diag(weights), and S / m at sliding ends."""
    blocks = weights[:, :, None] * np.eye(weights.shape[1])
    if sliding is not None:
        rows, projectors = sliding
        blocks[rows] = projectors @ blocks[rows]  # S diag(1/m) = S / m: a sliding vertex has no pinned dof
    return blocks


def _not_compliant(system, form) -> str:
    return refusal_reason(form, f"{type(system).__name__} does not declare its springs as compliant constraints")


class SpringProjection:
    """What XPBD needs of one system, prepared once: the spring groups (colours x kinds), the inverse masses
    with the vertex filters, the dofs on prescribed paths and the explicit acceleration of the other forces."""

    def __init__(self, system):
        springs = system.compliant_form()
        if not springs:
            raise ValueError(f"xpbd needs the system's springs as compliant constraints: {_not_compliant(system, springs)}")
        self.springs = springs
        d = springs.dim
        inverse_mass = 1.0 / np.asarray(system.mass, dtype=float)
        inverse_mass[system.fixed_dofs] = 0.0  # pinned dofs, and the vertices on prescribed paths (fixed_dofs too)
        vertex_weight = inverse_mass.reshape(-1, d)
        self.inverse_mass = inverse_mass
        constraints = system.constraints
        self.moving_dofs = (constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp))
        sliding = system.sliding
        slider = np.full(springs.vertex_count, -1, dtype=np.intp)  # vertex -> its row in sliding.projectors, or -1
        if sliding is not None:
            slider[sliding.vertices] = np.arange(sliding.vertices.size)
        self.groups: list[SpringGroup] = []
        for colour in springs.colours:
            for vector in (False, True):
                rows = colour[(springs.rest_length[colour] == 0.0) == vector]
                if rows.size:
                    self.groups.append(_group(springs, rows, vertex_weight, slider, sliding, vector))
        # without other forces the explicit part is the constant external field, filtered once here
        self.constant_acceleration = None
        if not springs.other_forces and system.external_acceleration is not None:
            self.constant_acceleration = self._filtered(system, np.array(system.external_acceleration, dtype=float))
        self._scaled = (None, None)

    @staticmethod
    def _filtered(system, acceleration: np.ndarray) -> np.ndarray:
        acceleration[system.fixed_dofs] = 0.0
        if system.sliding is not None:
            system.sliding.apply(acceleration)
        return acceleration

    def acceleration(self, system, x: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        """M^-1 f_other(x, v) (m/s^2) on the free directions, f_other = f - f_springs; None when it is zero."""
        if not self.springs.other_forces:
            return self.constant_acceleration
        force = system.force(x, v) - self.springs.force(x, v)
        return self._filtered(system, force * self.inverse_mass)

    def scaled(self, h: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """(k h^2, beta h) per group for the substep h (s); kept for the last h (a run's steps share it)."""
        last_h, scaled = self._scaled
        if last_h != h:
            scaled = [(group.stiffness * (h * h), group.damping * h) for group in self.groups]
            self._scaled = (h, scaled)
        return scaled


def _group(springs, rows: np.ndarray, vertex_weight: np.ndarray, slider: np.ndarray, sliding, vector: bool) -> SpringGroup:
    first, second = springs.first[rows], springs.second[rows]
    free = second != ANCHORED
    second_weight = np.zeros((rows.size, springs.dim))
    second_weight[free] = vertex_weight[second[free]]

    def sliding_rows(vertices: np.ndarray, present: np.ndarray):
        at = np.flatnonzero(present & (slider[np.where(present, vertices, 0)] >= 0))
        return None if at.size == 0 else (at, sliding.projectors[slider[vertices[at]]])

    return SpringGroup(
        first=first, second=second[free], free_rows=None if free.all() else np.flatnonzero(free),
        anchor=springs.anchor[rows], rest_length=springs.rest_length[rows], stiffness=springs.stiffness[rows],
        damping=springs.damping[rows], first_weight=vertex_weight[first].copy(), second_weight=second_weight,
        sliding=(sliding_rows(first, np.ones(rows.size, dtype=bool)), sliding_rows(second, free)), vector=vector)


# the prepared projection of each system, for as long as the system lives
_PROJECTIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def spring_projection(system) -> SpringProjection:
    """The system's ``SpringProjection``, built on first use (the colouring is the costly part)."""
    try:
        projection = _PROJECTIONS.get(system)
    except TypeError:  # a system that cannot be a weak key (unhashable, no weak references): prepared per step
        return SpringProjection(system)
    if projection is None:
        projection = _PROJECTIONS[system] = SpringProjection(system)
    return projection
