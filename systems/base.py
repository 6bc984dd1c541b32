"""The contract every mechanical system fulfils.

A system is static: it describes the mechanics (mass, potential, damping, constraints) and never
holds the changing state. Integrators and the runner pass positions ``x`` and velocities ``v``
(arrays of shape ``(dof_count,)``, SI units) into it.

Required, the whole of it:
- ``dof_count``, ``dim`` (spatial dimension), ``mass`` (lumped diagonal mass, ``(dof_count,)``, kg),
  ``x0`` and ``v0``;
- ``potential_energy(x)`` (J), ``gradient(x)`` (dP/dx, N) and ``hessian(x, project_spd=False)``
  (d^2P/dx^2, N/m; a dense array for small systems, a scipy sparse matrix for large ones).

Optional, each with a neutral default:
- damping: ``damping_matrix(x)`` (D in f_d = -D(x) v, N s/m; None when undamped), ``damping_is_constant``;
- constraints: ``fixed_dofs`` (indices that never move), ``sliding``, ``constraints`` (prescribed paths);
- the Hessian's pattern, for large sparse systems: ``hessian_pattern`` (a CSR matrix whose pattern holds every
  entry of the Hessian and of D, and the whole diagonal), ``diagonal_positions`` (where the diagonal sits in
  its data array) and ``hessian_data(x, project_spd)`` (the Hessian's values in that pattern): implicit methods
  then assemble M + s K + ... in one data array instead of adding sparse matrices;
- what it declares about itself (``capabilities``, stored with every run): ``test_frequency``,
  ``length_scale``, ``energy_scale()``, ``frame_shape`` and ``planar``; ``observables``' own terms
  (``extra_observables(x, v)``) and ``exact_solution(t)``;
- what some methods use: ``external_acceleration`` (gravity per dof), ``quadratic_potential``, the step filter
  (``requires_step_filter``, ``max_step``), IMEX's named terms (``energy_terms``, ``with_terms``), calibration's
  ``parameter_derivative`` and ``damping_derivative``;
- the forms of the solver families (systems/forms.py): ``vertex_form()`` (VBD; a generic one by default),
  ``projective_form()`` (projective dynamics, L-BFGS's rest Hessian), ``compliant_form()`` (XPBD) and
  ``contact_form()`` (a contact block);
- faster versions of derived quantities on a system's step path (``acceleration``, ``kick``, ``total_energy``,
  ``write_observables``), equal to the generic ones to round-off.

``hessian(x, project_spd)``: ``project_spd`` is False (the exact Hessian), True or ``"clamp"`` (the
system's own cheap SPD projection: negative eigenvalues of its blocks set to 0) or ``"abs"`` (the
same blocks with their eigenvalues mirrored, |lambda|: Chen et al., "Trust-region eigenvalue
filtering for projected Newton", SIGGRAPH Asia 2024). A system that knows one projection only may
answer every true value with it.

A system's config is a ``SystemParams`` model whose ``system_class`` is the System subclass it builds.
docs/systems.md is the guide; runner/contracts (``simrun check-system``) measures a system against this contract.
"""

from __future__ import annotations

import copy
import functools
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from collections.abc import Callable
from typing import ClassVar

import numpy as np
import scipy.sparse
from pydantic import BaseModel, ConfigDict

from .capabilities import Capabilities  # noqa: F401  (re-exported: what a system declares)
from .forms import NotOffered, ProjectiveForm, VertexForm, kept_form


# |KE0| + |PE0| below this fraction of the work of the initial forces over the length scale is round-off
ENERGY_ROUND_OFF = 1e-8


@dataclass(frozen=True)
class ParameterDerivative:
    """d/dtheta of a system's potential gradient and damping matrix along one parameter theta in which both are
    linear: ``gradient(x)`` (N per unit of theta, shape (dof_count,)) and ``damping(x)`` (a matrix as
    ``damping_matrix`` gives, or None when theta does not enter D)."""

    gradient: Callable[[np.ndarray], np.ndarray]
    damping: Callable[[np.ndarray], object] | None = None


def vertex_energy_reference(system, elastic: float, stretch_energy: float, parts: str) -> tuple[float, str]:
    """(E_ref, what it is) of a model of vertices (mass_spring, fem): |KE0| + |elastic PE0| (``elastic``: of ``parts``,
    without gravity, whose energy depends on where the origin is) where that exceeds a floor, the energy of lifting the
    model by its largest extent, M |g| L, or without gravity ``stretch_energy``, that of a 1 % strain. A model at rest
    has E0 = 0, and a nudge of 1e-8 m/s gives E0 ~ 1e-18 J, which no drift should be divided by."""
    initial = abs(system.kinetic_energy(system.v0)) + abs(elastic)
    extent = float(np.max(np.ptp(system.rest, axis=0)))
    lift = float(np.sum(system.vertex_masses)) * float(np.linalg.norm(system.gravity)) * extent
    floor, floor_name = (lift, "M |g| L") if lift > 0 else (stretch_energy, "1 % strain energy")
    if initial > floor:
        return initial, f"|KE0| + |PE0 of {parts} and contact| (> {floor_name})"
    return (floor, floor_name) if floor > 0 else (1.0, "1 J")


class System(ABC):
    """Base class of the systems: derived quantities written once, in terms of the primitives."""

    # -- required: the state's size, the mass, the initial state, and P with its derivatives -------------------
    dof_count: int
    dim: int
    mass: np.ndarray
    x0: np.ndarray
    v0: np.ndarray

    @abstractmethod
    def potential_energy(self, x: np.ndarray) -> float:
        """P(x) (J)."""

    @abstractmethod
    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dP/dx (N), shape (dof_count,)."""

    @abstractmethod
    def hessian(self, x: np.ndarray, project_spd: bool = False):
        """d^2P/dx^2 (N/m), (dof_count, dof_count); SPD-projected on request."""

    # -- optional: the mass matrix off its diagonal, and the constraints ------------------------------------
    # a consistent mass matrix's part off its lumped diagonal, M - diag(mass) (a CSR matrix in the Hessian's pattern,
    # whose data adds to a Hessian's entry for entry, and whose rows sum to 0), or None: M is the diagonal ``mass``.
    # Only methods that take M as a matrix step such a system (``mass_refusal``); ``mass`` stays the lumped diagonal,
    # what scales and safeguards read.
    mass_correction = None
    fixed_dofs: np.ndarray = np.zeros(0, dtype=np.intp)
    # the filters of vertices that slide along directions that are not coordinate axes (systems/constraints.py)
    sliding = None
    # vertices on a prescribed path (systems/constraints.py: VertexConstraints), or None
    constraints = None

    def released(self, t: float) -> System:
        """This system from time t (s) on, once prescribed paths have ended (their ``until``): a shallow copy whose
        constraints no longer hold the ended paths' vertices, which are free from here, with the velocity their
        path gave them. self is left as it was, and caches keyed by the system (XPBD's projection, the VBD
        blocks) start afresh for the copy. A system without such paths is returned as it is."""
        if self.constraints is None or not self.constraints.release_times:
            return self
        released = copy.copy(self)
        released.constraints = constraints = self.constraints.released(t)
        released.fixed_dofs, released.sliding = constraints.fixed_dofs, constraints.sliding
        released._moving = constraints.moving_dofs
        released._prepare_paths()
        return released

    def _prepare_paths(self) -> None:
        """What a system precomputes for its vertices on prescribed paths (the springs that drive them), after
        ``released`` changed them; nothing by default."""

    # -- optional: damping ---------------------------------------------------------------------------------
    def damping_matrix(self, x: np.ndarray):
        """D(x) in the damping force f_d = -D(x) v, or None for an undamped system."""
        return None

    @property
    def damping_is_constant(self) -> bool:
        """Is D(x) the same at every x (or is there no damping)?"""
        return not self.is_damped

    @functools.cached_property
    def is_damped(self) -> bool:
        """Does the system have physical damping? Decided once (at x0), so that undamped systems skip
        ``damping_matrix`` on every force and step; a system's damping model does not switch on and off with x."""
        return self.damping_matrix(self.x0) is not None

    # -- optional: the Hessian's fixed pattern, for large sparse systems ------------------------------
    hessian_pattern = None  # a scipy CSR matrix: the fixed pattern of hessian_data (see the module docstring)
    diagonal_positions: np.ndarray

    def hessian_data(self, x: np.ndarray, project_spd: bool = False) -> np.ndarray:
        """The Hessian's values in ``hessian_pattern`` (a new array), for systems that have one."""
        raise TypeError(f"{type(self).__name__} has no fixed Hessian pattern (its hessian_pattern is None)")

    def pattern_matrix(self, data: np.ndarray):
        """The CSR matrix with ``hessian_pattern``'s structure and these values (shares the index arrays)."""
        pattern = self.hessian_pattern
        return scipy.sparse.csr_matrix((data, pattern.indices, pattern.indptr), shape=pattern.shape)

    def in_hessian_pattern(self, matrix) -> bool:
        """Is ``matrix`` a CSR matrix in exactly ``hessian_pattern`` (so that data arrays can be added)?"""
        pattern = self.hessian_pattern
        return matrix.format == "csr" and _same(matrix.indptr, pattern.indptr) and _same(matrix.indices, pattern.indices)

    # -- what the solver families of graphics practice take: one form each (systems/forms.py) -----------------
    def vertex_form(self) -> VertexForm | None:
        """Vertex block descent's per-vertex blocks: the generic form, read off the whole gradient and Hessian."""
        return kept_form(self, "_vertex_form", VertexForm)

    def projective_form(self) -> ProjectiveForm | None:
        """Projective dynamics' rest stiffness K_r, and whether it minimises the incremental potential exactly."""
        return NotOffered(f"{type(self).__name__} does not declare its potential as Hookean springs")

    def compliant_form(self):
        """The Hookean springs and their dampers as XPBD's compliant constraints (systems/compliant.py)."""
        return NotOffered(f"{type(self).__name__} does not declare its springs as compliant constraints")

    def contact_form(self):
        """What the runner, the problems and the line search ask of a contact block (systems/contact/hooks.py)."""
        return None

    # -- optional: what some methods use (the line search's step filter, a quadratic P, gravity, P's round-off) ----
    # every step a line search takes is cut to the fraction ``max_step`` allows: IPC's collision-free one, or (finite
    # elements) the one that keeps every element's volume
    requires_step_filter: bool = False

    def max_step(self, x: np.ndarray, direction: np.ndarray) -> float:
        """The largest fraction in [0, 1] of the step x -> x + direction that the system allows (read where
        ``requires_step_filter``)."""
        return 1.0

    # P is quadratic in x with a constant positive definite Hessian (the spring, the linear central force): the
    # incremental potential is then a convex quadratic, one full Newton step solves it, and Newton skips its line search
    quadratic_potential: bool = False

    external_acceleration: np.ndarray | None = None  # (dof_count,) m/s^2 of the constant external field (gravity), or None

    def potential_magnitude(self, x: np.ndarray) -> float:
        """J: the scale of P(x)'s round-off over eps. A term W(x) is computed from differences of
        coordinates, each with an error of about eps |x|, so its error is about eps |dW/dx| |x|, which for
        a nearly relaxed spring (W ~ stretch^2) is far above eps W. The default is |P| + sum_i |g_i x_i|;
        a line search cannot judge changes of E below ENERGY_ROUNDOFF times this."""
        return abs(self.potential_energy(x)) + float(np.abs(self.gradient(x) * x).sum())

    # -- named parts of the energy, for IMEX splits (integrators/imex.py) -------------------------
    @property
    def energy_terms(self) -> tuple[str, ...]:
        """The names of the parts of P (and of the damping) that a split may put on one side. A system without parts
        of its own has one, ``potential``: all of P and f_d."""
        return ("potential",)

    def with_terms(self, names: tuple[str, ...], complement: bool = False) -> "System | None":
        """This system with only the named terms of ``energy_terms`` (``complement``: with every other term), for
        the parts of an IMEX split; None where that leaves no force at all. Here: all of it, or nothing."""
        return self if ("potential" in names) != complement else None

    # -- calibration: exact forward sensitivities (integrators/sensitivity.py) ---------------------------
    def parameter_derivative(self, changed: "System", change: float) -> "ParameterDerivative | None":
        """How a parameter enters this system, found from ``changed``: the same system with one config value moved
        by ``change``. Systems whose gradient and damping matrix are linear in coefficients that config values
        select (a spring's stiffness, a damper's coefficient) return d(grad P)/dtheta and dD/dtheta; None when the
        change moves anything else (masses, rest shape, initial state), which only finite differences can follow."""
        return None

    def damping_derivative(self, x: np.ndarray, dx: np.ndarray, w: np.ndarray) -> np.ndarray | None:
        """d/de D(x + e dx) w at e = 0 (N), ``dx`` and ``w`` of shape (dof_count,) or (dof_count, p); None where
        D does not depend on x (``damping_is_constant``). Systems whose D(x) moves with x override it; for those that
        do not, exact sensitivities are not offered (``integrators.sensitivity.exact_refusal``)."""
        return None

    # runs of this system may be stepped together as lanes of one array (systems/lanes.py): the class that takes their
    # built systems, or None (each run is stepped alone); read from the class's own body, never inherited (a subclass
    # changes the physics that the lane class repeats)
    lanes_class: ClassVar[type | None] = None

    # -- what the system declares about itself (neutral defaults; subclasses override the parts) -------
    vertex_dim: int = 3  # coordinates per vertex in a frame (systems that keep frames)
    frame_edges: np.ndarray | None = None  # (m, 2) vertex pairs drawn as lines in pictures (the springs)
    frame_triangles: np.ndarray | None = None  # (t, 3) vertex triples drawn as a shaded surface
    # small systems keep x and v in every sample; large ones (cloth) keep them as `frames` instead
    records_state_per_sample: bool = True

    def exact_solution(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Exact (x, v) at times t, shapes (len(t), dof_count), or None where none is known."""
        return None

    def extra_observables(self, x: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray | float]:
        """System-specific observables (e.g. the radius of circular motion)."""
        return {}

    @property
    def energy_reference_name(self) -> str:
        """What ``energy_scale()`` is, in a few words (axis labels, table notes)."""
        initial, work = self._initial_energy_and_work()
        if initial > ENERGY_ROUND_OFF * work:
            return "|KE0| + |PE0|"
        return "L sum|f0| (|KE0| + |PE0| is round-off)" if work > 0.0 else "1 J (KE0 = PE0 = 0)"

    def energy_scale(self) -> float:
        """A characteristic energy (J) against which energy growth is judged: |KE0| + |PE0|; where that is
        round-off of cancelling terms (at most ENERGY_ROUND_OFF of W0 = length_scale * sum |f(x0, v0)|: a
        chain released from horizontal at the height of its pivot has E0 = 0 by construction, computed as
        1e-30 J or 1e-16 J), W0, the work of the initial forces over the length scale; 1 J when both are 0."""
        initial, work = self._initial_energy_and_work()
        if initial > ENERGY_ROUND_OFF * work:
            return initial
        return work if work > 0.0 else 1.0

    def _initial_energy_and_work(self) -> tuple[float, float]:
        """(|KE0| + |PE0|, length_scale * sum |f(x0, v0)| over the free dofs) (J)."""
        initial = abs(self.kinetic_energy(self.v0)) + abs(self.potential_energy(self.x0))
        work = self.length_scale * float(np.abs(self.force(self.x0, self.v0)).sum())
        return initial, work if math.isfinite(work) else 0.0

    @property
    def test_frequency(self) -> float | None:
        """w (rad/s) when the system is the undamped test equation q'' + w^2 q = 0 (or uncoupled copies of
        it: hessian(x) = w^2 M at every x, no damping), else None: the damping and stability predictions hold on it."""
        return None

    @property
    def length_scale(self) -> float:
        """The scale of position errors (m): max_i |x0_i|, or 1 when that is 0 or not finite."""
        scale = float(np.max(np.abs(self.x0))) if self.x0.size else 0.0
        return scale if math.isfinite(scale) and scale > 0.0 else 1.0

    @property
    def frame_shape(self) -> tuple[int, ...] | None:
        """The vertex grid of one stored frame (a frame holds prod(frame_shape) vertices of ``vertex_dim``
        coordinates), or None when x and v are recorded in every sample instead or the vertices form no grid."""
        return None

    planar: bool = False  # one body whose motion stays in the x-y plane (its trajectory is drawn as an orbit)

    @functools.cached_property
    def capabilities(self) -> Capabilities:
        """What the runner stores about this system with every run, so that figures never test a type name."""
        frame_shape = self.frame_shape
        if frame_shape is not None:
            frame_shape = tuple(int(size) for size in frame_shape)
            if self.vertex_dim * math.prod(frame_shape) != self.dof_count:
                raise ValueError(f"{type(self).__name__}.frame_shape {frame_shape} holds {math.prod(frame_shape)} vertices, "
                                 f"but a frame holds dof_count / vertex_dim = {self.dof_count / self.vertex_dim:g}")
        test_frequency = self.test_frequency
        return Capabilities(
            test_frequency=None if test_frequency is None else float(test_frequency),
            length_scale=float(self.length_scale),
            energy_scale=float(self.energy_scale()),
            frame_shape=frame_shape,
            planar=bool(self.planar),
            dof_count=int(self.dof_count),
            energy_reference_name=self.energy_reference_name,
            vertex_dim=0 if self.records_state_per_sample else int(self.vertex_dim),
            oscillator=self.oscillator,
        )

    def modal_energy(self, energy: np.ndarray, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The oscillator's modal energy at recorded samples (J): energies (samples,), x and v (samples, dofs); the
        energy itself by default (exact for the undamped test equation, which keeps it)."""
        return energy

    @property
    def oscillator(self) -> tuple[float, float] | None:
        """(w0 rad/s, zeta) when the system is a linear oscillator q'' + 2 zeta w0 q' + w0^2 q = 0 (or uncoupled copies of
        one), damped or not: the test equation (test_frequency, 0) by default, else None."""
        frequency = self.test_frequency
        return None if frequency is None else (float(frequency), 0.0)

    # -- derived quantities ---------------------------------------------------------------------
    def mass_times(self, vector: np.ndarray) -> np.ndarray:
        """M vector, M the whole mass matrix (kg x the vector's unit): the diagonal, plus a consistent mass's rest."""
        product = self.mass * vector
        if self.mass_correction is not None:
            product += self.mass_correction @ vector
        return product

    def kinetic_energy(self, v: np.ndarray) -> float:
        return 0.5 * float(self.mass_times(v).dot(v))  # ndarray.dot: cheapest on the 1- to 3-element vectors of the small systems

    def total_energy(self, x: np.ndarray, v: np.ndarray) -> float:
        return self.kinetic_energy(v) + self.potential_energy(x)

    def damping_force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        damping = self.damping_matrix(x)
        if damping is None:
            return None
        return -(damping @ v)

    def force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Total force -dP/dx + f_d(x, v) (N); zero on fixed degrees of freedom."""
        force = -self.gradient(x)
        if self.is_damped:
            damping = self.damping_force(x, v)
            if damping is not None:
                force = force + damping
        if self.fixed_dofs.size:
            force[self.fixed_dofs] = 0.0
        if self.sliding is not None:
            self.sliding.apply(force)
        return force

    def forces(self, X: np.ndarray, V: np.ndarray) -> np.ndarray:
        """f at every row (x_k, v_k) of X and V, shape (rows, dof_count) (N): the stages of an implicit Runge-Kutta
        step evaluated together. ``force`` per row for a system with a force of its own; else ``gradients``, which a
        system whose gradient vectorises over states overrides, with ``force``'s damping, fixed dofs and filters."""
        if type(self).force is not System.force:
            return np.stack([self.force(x, v) for x, v in zip(X, V)])
        forces = -self.gradients(X)
        if self.is_damped:
            for force, x, v in zip(forces, X, V):
                damping = self.damping_force(x, v)
                if damping is not None:
                    force += damping
        if self.fixed_dofs.size:
            forces[:, self.fixed_dofs] = 0.0
        if self.sliding is not None:
            for force in forces:
                self.sliding.apply(force)
        return forces

    def gradients(self, X: np.ndarray) -> np.ndarray:
        """dP/dx at every row of X, shape (rows, dof_count): one ``gradient`` per row."""
        return np.stack([self.gradient(x) for x in X])

    def acceleration(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """M^-1 f(x, v) (m/s^2)."""
        return self.force(x, v) / self.mass

    def kick(self, x: np.ndarray, v: np.ndarray, dt: float) -> np.ndarray:
        """v + dt M^-1 f(x, v) (m/s): the velocity after the force at (x, v) acted for dt (s).

        The velocity update of the explicit Euler methods; small systems override it with scalar
        arithmetic, one array instead of three."""
        return v + dt * self.acceleration(x, v)

    def momentum(self, v: np.ndarray) -> np.ndarray:
        """Linear momentum sum_i m_i v_i, shape (dim,)."""
        return self._momentum(self.mass_times(v))

    def _momentum(self, momenta: np.ndarray) -> np.ndarray:
        """sum_i p_i from the per-dof momenta m * v, shape (dim,); a single particle needs no sum."""
        if momenta.size == self.dim:
            return momenta
        # one strided sum per component: cheaper on the cloth than reshape(-1, dim).sum(axis=0) (docs/performance.md)
        return np.array([momenta[component::self.dim].sum() for component in range(self.dim)])

    def angular_momentum(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Angular momentum about the origin sum_i x_i x m_i v_i, shape (3,) (2-D systems: (0, 0, Lz))."""
        return self._angular_momentum(x, self.mass_times(v))

    def _angular_momentum(self, x: np.ndarray, momenta: np.ndarray) -> np.ndarray:
        if self.dim == 1:
            return np.zeros(3)
        if self.dof_count == self.dim:  # one particle: the cross product on scalars, no array temporaries
            if self.dim == 2:
                return np.array([0.0, 0.0, x[0] * momenta[1] - x[1] * momenta[0]])
            (qx, qy, qz), (px, py, pz) = x.tolist(), momenta.tolist()
            return np.array([qy * pz - qz * py, qz * px - qx * pz, qx * py - qy * px])
        # sum_i x_i x p_i from the dim x dim matrix G = sum_i x_i p_i^T (one BLAS product instead of
        # six strided products and three sums): L_x = G_yz - G_zy, L_y = G_zx - G_xz, L_z = G_xy - G_yx
        moments = x.reshape(-1, self.dim).T @ momenta.reshape(-1, self.dim)
        if self.dim == 2:
            return np.array([0.0, 0.0, moments[0, 1] - moments[1, 0]])
        return np.array([moments[1, 2] - moments[2, 1], moments[2, 0] - moments[0, 2], moments[0, 1] - moments[1, 0]])

    def observables(self, x: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray | float]:
        """Every recorded observable at (x, v): energies (J), momenta and the system's own.

        The keys and shapes are the same at every (x, v) (``observable_layout``)."""
        values = self._mechanical_observables(x, v, self.potential_energy(x))
        values.update(self.extra_observables(x, v))
        return values

    def _mechanical_observables(self, x: np.ndarray, v: np.ndarray, potential: float) -> dict[str, np.ndarray | float]:
        """Energies and momenta at (x, v), given the potential energy P(x) (J)."""
        momenta = self.mass_times(v)  # shared by the kinetic energy and both momenta
        kinetic = 0.5 * float(momenta.dot(v))  # = kinetic_energy(v), bit for bit
        values: dict[str, np.ndarray | float] = {
            "energy": kinetic + potential,
            "kinetic_energy": kinetic,
            "potential_energy": potential,
            "momentum": self._momentum(momenta),
        }
        if self.dim >= 2:
            values["angular_momentum"] = self._angular_momentum(x, momenta)
        return values

    @functools.cached_property
    def observable_layout(self) -> tuple[tuple[str, tuple[int, ...]], ...]:
        """(name, shape) of every observable, in the order of ``observables``: the columns of a recorded row."""
        return tuple((key, np.shape(value)) for key, value in self.observables(self.x0, self.v0).items())

    @functools.cached_property
    def observable_width(self) -> int:
        """Numbers in one row of observables: the sum of the sizes in ``observable_layout``."""
        return sum(math.prod(shape) for _, shape in self.observable_layout)

    def write_observables(self, x: np.ndarray, v: np.ndarray, row: np.ndarray) -> float:
        """Write ``observables(x, v)`` into row[:observable_width] (each flattened, in layout order) and
        return the total energy (J): the recorder's per-sample call. Small systems override it with
        scalar arithmetic that builds no dictionary; an override writes the same numbers (to round-off)."""
        values = self.observables(x, v)
        for (columns, flatten), value in zip(self._observable_columns, values.values()):
            row[columns] = np.ravel(value) if flatten else value
        return values["energy"]

    @functools.cached_property
    def _observable_columns(self) -> list[tuple[slice, bool]]:
        """Per observable: its columns in a row, and whether it must be flattened (more than one axis)."""
        columns, start = [], 0
        for _, shape in self.observable_layout:
            size = math.prod(shape)
            columns.append((slice(start, start + size), len(shape) > 1))
            start += size
        return columns


class SystemParams(BaseModel):
    """Base of the systems' config models: validated parameters that build their system.

    A subclass declares its fields (with a ``type: Literal["<config name>"]`` tag), a ``dof_count``
    property, and, once its System subclass exists, ``system_class`` (``MyParams.system_class = My``).
    Code that needs a class-level fact asks ``params.system_class`` (e.g. ``records_state_per_sample``)
    instead of building the system or comparing a type name.
    """

    model_config = ConfigDict(extra="forbid")
    system_class: ClassVar[type[System]]

    def build(self) -> System:
        """The system these parameters describe."""
        return self.system_class(self)

    def input_files(self) -> dict[str, str]:
        """The files the system reads (config field -> sha256 of the file): part of the config's hash, so that
        a changed model file is a changed experiment. None by default."""
        return {}


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal index arrays: the same memory (views of one array, no compare needed) or equal entries."""
    if a.shape != b.shape:
        return False
    if a.ctypes.data == b.ctypes.data and a.strides == b.strides and a.dtype == b.dtype:
        return True
    return bool(np.array_equal(a, b))
