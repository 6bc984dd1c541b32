"""The mass-spring system: any model of point masses and springs in 2-D or 3-D.

P(x) = sum_springs W_e(|x_i - x_j|) - sum_i m_i g . x_i + contact (systems/contact/), with the spring law W_e
one of ``SPRING_LAWS``; damping forces f_d = -D(x) v from any sum of ``DAMPING_MODELS``; vertex
constraints (pins, sliding, prescribed paths) as filters (systems/constraints.py).

Every quantity is computed for all springs (or vertices) at once; the sparse Hessian's pattern is
built once per system, so an evaluation only refills the values of a fixed CSR matrix with one
``np.bincount`` over a precomputed scatter map. The hookean law's arithmetic is fixed (the same
operations in the same order as results recorded before, tests/data/cloth_before_mass_spring.npz), so a
grid model reproduces those results bit for bit on the same machine (elsewhere to BLAS's round-off).
"""

from __future__ import annotations

import functools
from types import SimpleNamespace

import numpy as np
import scipy.sparse

from ..base import System, vertex_energy_reference
from . import derivatives, kernels, split
from ..compliant import CompliantSprings
from ..constraints import VertexConstraints
from ..contact.hooks import WithContact
from ..contact.model import ContactModel
from ..forms import NotOffered, ProjectiveForm, kept_form
from ..vertex.damping import Damping
from .blocks import SpringVertexForm
from .laws import SPRING_LAWS, HookeanLaw, SpringGeometry


class MassSpring(WithContact, System):
    """Point masses joined by springs, in 2-D or 3-D: see the module docstring.

    Parameters (arrays as resolved from a model and a config; systems/mass_spring/params.py builds them):
    rest: (n, d) rest shape (m); x0, v0: (n, d) initial state; springs: (m, 2); stiffness: (m,) N/m;
    rest_length: (m,) m; masses: (n,) kg; gravity: (d,) m/s^2; law: a SPRING_LAWS name; damping: Damping
    terms; constraints: VertexConstraints; contact: a ContactModel or None; triangles: (t, 3) or None; grid_shape:
    (ny, nx) or None; spring_kinds: (m,) indices into kind_names (stretch, shear, bend, ...), the terms an IMEX split
    names (default: one kind, "spring").
    """

    records_state_per_sample = False  # positions go to `frames`, at their own cadence

    def __init__(self, *, rest: np.ndarray, x0: np.ndarray, v0: np.ndarray, springs: np.ndarray, stiffness: np.ndarray,
                 rest_length: np.ndarray, masses: np.ndarray, gravity: np.ndarray, law: str = "hookean",
                 damping: tuple[Damping, ...] = (), constraints: VertexConstraints | None = None,
                 contact: ContactModel | None = None, triangles: np.ndarray | None = None, grid_shape: tuple[int, int] | None = None,
                 spring_kinds: np.ndarray | None = None, kind_names: tuple[str, ...] = ("spring",)):
        dim = rest.shape[1]
        self.dim = self.vertex_dim = dim
        self.vertex_count = rest.shape[0]
        self.dof_count = dim * self.vertex_count
        self.rest = rest
        self.x0 = np.ascontiguousarray(x0, dtype=float).ravel()
        self.v0 = np.ascontiguousarray(v0, dtype=float).ravel().copy()
        self.vertex_masses = masses
        self.mass = np.repeat(masses, dim)
        self.gravity = np.asarray(gravity, dtype=float)
        self.law = SPRING_LAWS[law]
        self.first = np.ascontiguousarray(springs[:, 0], dtype=np.intp)
        self.second = np.ascontiguousarray(springs[:, 1], dtype=np.intp)
        self.stiffness = stiffness
        self.rest_length = rest_length
        self.rest_length_squared = np.square(rest_length)
        self.spring_count = self.first.size
        # each spring's kind (an index into kind_names): what an IMEX split names (split.py)
        self.spring_kinds = np.zeros(self.spring_count, dtype=np.intp) if spring_kinds is None else np.asarray(spring_kinds, dtype=np.intp)
        self.kind_names = tuple(kind_names)
        self.identity = np.eye(dim)
        self.damping_terms = tuple(damping)
        self.contact = contact
        self.frame_edges = np.stack([self.first, self.second], axis=1).astype(np.int32)
        self.frame_triangles = None if triangles is None else np.asarray(triangles, dtype=np.int32)
        self.grid_shape = grid_shape

        self.constraints = constraints
        if constraints is not None:
            self.fixed_dofs = constraints.fixed_dofs
            self.sliding = constraints.sliding
            constraints.filter(self.v0)  # no velocity along a removed direction
            if constraints.moving_dofs.size:
                self.v0[constraints.moving_dofs] = constraints.path(0.0)[1]
        self._gravity_force = (masses[:, None] * self.gravity).ravel()
        self._build_pattern()
        self._constant_damping = self._assemble_constant_damping()
        self._geometry: SpringGeometry | None = None  # of the last x the springs were evaluated at
        self._moving = constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp)
        self._prepare_paths()

    # -- setup ----------------------------------------------------------------------------------
    def _build_pattern(self) -> None:
        """CSR pattern of all spring blocks (ii, jj, ij, ji) and vertex blocks, and the scatter map into it."""
        i, j, d = self.first, self.second, self.dim
        offsets = np.arange(d)
        blocks = [(i, i), (j, j), (i, j), (j, i)]
        rows = [d * a[:, None, None] + offsets[None, :, None] + 0 * offsets[None, None, :] for a, _ in blocks]
        cols = [d * b[:, None, None] + 0 * offsets[None, :, None] + offsets[None, None, :] for _, b in blocks]
        vertices = np.arange(self.vertex_count)
        rows.append(d * vertices[:, None, None] + offsets[None, :, None] + 0 * offsets[None, None, :])
        cols.append(d * vertices[:, None, None] + 0 * offsets[None, :, None] + offsets[None, None, :])
        rows = np.concatenate([r.ravel() for r in rows])
        cols = np.concatenate([c.ravel() for c in cols])
        n = self.dof_count
        pattern = scipy.sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
        pattern.sum_duplicates()
        pattern.sort_indices()
        keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(pattern.indptr)) * n + pattern.indices
        self._scatter = np.searchsorted(keys, rows.astype(np.int64) * n + cols)
        self._nnz = pattern.nnz
        self.hessian_pattern = pattern  # every Hessian and damping matrix shares its index arrays
        diagonal_keys = np.arange(n, dtype=np.int64) * (n + 1)
        self.diagonal_positions = np.searchsorted(keys, diagonal_keys)  # where M enters the data array
        # the incidence matrix (+1 at vertex i, -1 at vertex j of each spring): its rows are the springs each vertex's
        # gradient gathers, in order (kernels.gather_spring_gradient); the prescribed vertices' forces and the
        # sensitivities take its sparse products
        self._first_dofs = (d * i[:, None] + offsets).ravel()
        self._second_dofs = (d * j[:, None] + offsets).ravel()
        springs = np.arange(self.spring_count)
        self._incidence = scipy.sparse.csr_matrix(
            (np.concatenate([np.ones(self.spring_count), -np.ones(self.spring_count)]),
             (np.concatenate([i, j]), np.concatenate([springs, springs]))),
            shape=(self.vertex_count, self.spring_count))
        self._ones = np.ones(d)  # sums the components of each row in one matrix-vector product

    def _scatter_blocks(self, spring_block: np.ndarray, vertex_block: np.ndarray | None = None) -> np.ndarray:
        """The pattern's data array of sum_e [B_e at (ii), (jj); -B_e at (ij), (ji)] + the vertex blocks."""
        flat = spring_block.ravel()
        vertex = np.zeros(self.dim * self.dim * self.vertex_count) if vertex_block is None else vertex_block.ravel()
        return np.bincount(self._scatter, weights=np.concatenate([flat, flat, -flat, -flat, vertex]), minlength=self._nnz)

    def _assemble_constant_damping(self) -> np.ndarray | None:
        """The pattern data of the damping terms that do not depend on x (relative, drag, rayleigh), or None."""
        data = None
        d = self.dim
        for term in self.damping_terms:
            if term.model == "relative":
                part = self._scatter_blocks(np.broadcast_to(term.coefficient * self.identity, (self.spring_count, d, d)))
            elif term.model == "drag":
                part = self._scatter_blocks(np.zeros((self.spring_count, d, d)),
                                            np.broadcast_to(term.coefficient * self.identity, (self.vertex_count, d, d)))
            elif term.model == "rayleigh":
                rest = self.rest.ravel()
                stiffness = self._spring_hessian_data(self._geometry_at(rest), project_spd=True)
                part = term.beta * stiffness
                part[self.diagonal_positions] += term.alpha * self.mass
            else:
                continue
            data = part if data is None else data + part
        return data

    # -- geometry of all springs at once ---------------------------------------------------------
    def _geometry_at(self, x: np.ndarray) -> SpringGeometry:
        # one compiled pass over the springs (kernels.spring_geometry): the numbers of the numpy form
        # delta = x[d i + c] - x[d j + c], L = sqrt(delta^2 . 1), bit for bit, in 60 % of its time
        m, d = self.spring_count, self.dim
        delta, length, stretch, tension = np.empty((m, d)), np.empty(m), np.empty(m), np.empty(m)
        kernels.spring_geometry(np.ascontiguousarray(x, dtype=float), self.first, self.second, self.stiffness,
                                self.rest_length, d, delta, length, stretch, tension)
        return SpringGeometry(x.copy(), delta, length, stretch, tension)

    def _springs(self, x: np.ndarray) -> SpringGeometry:
        """The springs' geometry at x. The last x's is kept, since a step evaluates the same x several
        times (the energy check and the samples at the end of a step, the force at the start of the next)."""
        geometry = self._geometry
        if geometry is not None and np.array_equal(geometry.x, x):  # an O(n) compare, far below the O(springs) geometry
            return geometry
        geometry = self._geometry_at(x)
        self._geometry = geometry  # one assignment: a reader sees the old or the new geometry whole
        return geometry

    # -- vertices on prescribed paths -----------------------------------------------------------
    def acceleration(self, x, v):
        """M^-1 f(x, v), and on the vertices of prescribed paths the paths' own acceleration (omega x v for a
        rotation): explicit methods then move them along the arc within a step, to their own order."""
        acceleration = self.force(x, v) / self.mass
        if self._moving.size:
            acceleration[self._moving] = self.constraints.accelerations_along(v)
        return acceleration

    def _prepare_paths(self) -> None:
        """What ``driven_force`` needs: the springs that touch a prescribed vertex and their scatter onto its dofs."""
        if not self._moving.size:
            self._driven = None
            return
        moving_vertices = self.constraints.moving_vertices
        springs = np.flatnonzero(np.isin(self.first, moving_vertices) | np.isin(self.second, moving_vertices))
        d, offsets = self.dim, np.arange(self.dim)
        self._driven = SimpleNamespace(
            springs=springs, incidence=self._incidence[moving_vertices][:, springs].tocsr(),
            first_dofs=(d * self.first[springs][:, None] + offsets).ravel(),
            second_dofs=(d * self.second[springs][:, None] + offsets).ravel(),
            stiffness=self.stiffness[springs], rest_length=self.rest_length[springs],
            rest_length_squared=self.rest_length_squared[springs], identity=self.identity,
            damping_rows=None if self._constant_damping is None else self.pattern_matrix(self._constant_damping)[self._moving])

    def driven_force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The force -dP/dx - D v on the dofs of the prescribed vertices (``constraints.moving_dofs`` order),
        unfiltered: what their drivers hold them against. Only the springs that touch them are evaluated."""
        part = self._driven
        delta = (np.take(x, part.first_dofs) - np.take(x, part.second_dofs)).reshape(-1, self.dim)
        length = np.sqrt(np.square(delta) @ self._ones)
        stretch = length - part.rest_length
        geometry = SpringGeometry(x, delta, length, stretch, part.stiffness * stretch)
        spring_force = -(delta.T * self.law.gradient_factor(part, geometry)).T
        for term in self.damping_terms:
            if term.model == "spring":  # -k_d ((v_i - v_j) . u) u on vertex i, the opposite on j
                direction = geometry.direction
                rate = (np.take(v, part.first_dofs) - np.take(v, part.second_dofs)).reshape(-1, self.dim)
                spring_force -= term.coefficient * np.einsum("ij,ij->i", rate, direction)[:, None] * direction
        force = (part.incidence @ spring_force).ravel() + self._gravity_force[self._moving]
        if self.contact is not None and not self.contact.couples_vertices:  # per vertex: the moving ones alone
            contact_gradient = np.zeros((self.constraints.moving_vertices.size, self.dim))
            self.contact.point_terms(x.reshape(-1, self.dim)[self.constraints.moving_vertices], contact_gradient)
            force -= contact_gradient.ravel()
        elif self.contact is not None:
            contact_gradient = np.zeros(x.size)
            self.contact.add_gradient(contact_gradient, x)
            force -= contact_gradient[self._moving]
        if part.damping_rows is not None:
            force -= part.damping_rows @ v
        return force

    # -- energy, gradient, Hessian ---------------------------------------------------------------
    def spring_energy(self, x: np.ndarray) -> float:
        geometry = self._springs(x)
        if geometry._energy is None:
            geometry._energy = self.law.energy(self, geometry)
        return geometry._energy

    def gravity_energy(self, x: np.ndarray) -> float:
        return -float(np.dot(self._gravity_force, x))

    def potential_energy(self, x):
        return self.spring_energy(x) + self.gravity_energy(x) + self.contact_energy(x)

    def potential_magnitude(self, x):
        """spring energy + sum_e |dW_e/dL| L_e + sum_i |m_i g . x_i| + contact energy: each spring's W is computed
        from a length with round-off eps L, so its error is eps |dW/dL| L; the gravity terms cancel in P, not
        in its round-off (System.potential_magnitude)."""
        geometry = self._springs(x)
        virial = float(np.abs(self.law.gradient_factor(self, geometry)) @ np.square(geometry.length))
        return self.spring_energy(x) + virial + float(np.abs(self._gravity_force * x).sum()) + abs(self.contact_energy(x))

    def gradient(self, x):
        geometry = self._springs(x)
        gradient = self._spring_gradient(geometry)
        gradient -= self._gravity_force
        if self.contact is not None:
            self.contact.add_gradient(gradient, x)
        return gradient

    def _spring_gradient(self, geometry: SpringGeometry) -> np.ndarray:
        """sum_e dW_e/dx (N): c_e (x_i - x_j) on vertex i and its opposite on j, gathered per vertex in a compiled
        pass over the incidence matrix's rows (kernels.gather_spring_gradient): scipy's product of the incidence
        matrix with the springs' c_e delta_e, bit for bit, without forming them."""
        incidence = self._incidence
        return kernels.gather_spring_gradient(incidence.indptr, incidence.indices, incidence.data, geometry.delta,
                                              self.law.gradient_factor(self, geometry), self.dim, np.empty(self.dof_count))

    def gradients(self, X: np.ndarray) -> np.ndarray:
        """dP/dx at every row of X (Radau IIA's stages): the springs in one compiled pass per row (kernels.py), the
        numbers of ``gradient`` row by row to round-off."""
        X = np.ascontiguousarray(X, dtype=float)
        gradients = kernels.spring_gradients(X, self.first, self.second, self.stiffness, self.rest_length,
                                             self.rest_length_squared, self.dim, kernels.LAW_CODES[self.law.name],
                                             np.empty_like(X))
        gradients -= self._gravity_force
        if self.contact is not None:
            for gradient, x in zip(gradients, X):
                self.contact.add_gradient(gradient, x)
        return gradients

    @functools.cached_property
    def _vertex_positions(self) -> np.ndarray:
        """(n, d, d): where each vertex block's entries sit in the pattern's data array (the scatter map's last part)."""
        d = self.dim
        return self._scatter[-self.vertex_count * d * d:].reshape(self.vertex_count, d, d)

    def _spring_hessian_data(self, geometry: SpringGeometry, project_spd: bool, vertex_block=None) -> np.ndarray:
        return self._scatter_blocks(self.law.blocks(self, geometry, project_spd), vertex_block)

    def hessian_data(self, x: np.ndarray, project_spd: bool = False) -> np.ndarray:
        """The Hessian's values in the fixed CSR pattern (the data array of ``hessian``)."""
        geometry = self._springs(x)
        vertex_block = np.zeros((self.vertex_count, self.dim, self.dim))
        if self.contact is not None:
            self.contact.add_vertex_hessian(vertex_block, x, project_spd)
        return self._spring_hessian_data(geometry, project_spd, vertex_block)

    # -- the solver families' forms (systems/forms.py) -------------------------------------------------
    def projective_form(self) -> ProjectiveForm:
        """K_r = sum_e kappa_e (L_e kron I_d), kappa_e the law's stiffness along the spring at rest, in the Hessian's
        pattern; exact for Hookean springs without contact (spring damping too: D(x) is taken once per step, so A is
        refactorised per step)."""
        inexact = None
        if self.law is not HookeanLaw:
            inexact = f"spring_law {self.law.name} is not Hookean"
        elif self.contact is not None:
            inexact = "contact is not a spring of fixed rest length"
        return ProjectiveForm(rest_stiffness=self._rest_stiffness, inexact=inexact)

    def _rest_stiffness(self):
        kappa = self.law.rest_factor * self.stiffness
        return self.pattern_matrix(self._scatter_blocks(kappa[:, None, None] * self.identity))

    @property
    def damping_is_constant(self) -> bool:
        return not any(term.model == "spring" for term in self.damping_terms) and not (
            self.contact is not None and self.contact.is_damped)  # contact damping acts where a vertex touches

    def compliant_form(self) -> CompliantSprings | NotOffered:
        """The springs as distance constraints |x_i - x_j| - l0 of compliance 1/k, with the ``spring`` damping
        model's coefficient as the damper along each (beta). The other damping models (relative, drag, rayleigh) and
        penalty contact are not springs of this kind: ``other_forces`` says they exist, and XPBD applies them
        explicitly, as f(x, v) minus the springs' force."""
        if self.law is not HookeanLaw:
            return NotOffered(f"spring_law {self.law.name} is not a Hookean spring (XPBD needs k/2 (L - l0)^2)")
        along = sum(term.coefficient for term in self.damping_terms if term.model == "spring")
        other = (any(term.model != "spring" for term in self.damping_terms)
                 or self.contact is not None)
        return CompliantSprings(first=self.first, second=self.second, anchor=np.zeros((self.spring_count, self.dim)),
                                rest_length=self.rest_length, stiffness=self.stiffness,
                                damping=np.full(self.spring_count, float(along)), vertex_count=self.vertex_count,
                                other_forces=bool(other))

    def vertex_form(self) -> SpringVertexForm:
        """Only the springs at each vertex (blocks.py), and the colliders."""
        return kept_form(self, "_vertex_form", SpringVertexForm)

    # -- contact: contact_form() is WithContact's (systems/contact/hooks.py); systems/contact/model.py does the work --
    @property
    def requires_step_filter(self) -> bool:
        return self.contact is not None and self.contact.requires_step_filter

    def max_step(self, x: np.ndarray, direction: np.ndarray) -> float:
        return 1.0 if self.contact is None else self.contact.max_step(x, direction)

    def _elastic_gradient(self, x: np.ndarray) -> np.ndarray:
        """dP/dx without contact (N): what IPC's stiffness estimate balances the barrier against."""
        geometry = self._springs(x)
        return self._spring_gradient(geometry) - self._gravity_force

    def parameter_derivative(self, changed, change):
        return derivatives.parameter_derivative(self, changed, change)

    @property
    def energy_terms(self) -> tuple[str, ...]:
        return split.energy_terms(self)

    def with_terms(self, names, complement=False):
        return split.with_terms(self, names, complement)

    def damping_derivative(self, x, dx, w):
        return derivatives.spring_damping_derivative(self, x, dx, w)

    @functools.cached_property
    def external_acceleration(self) -> np.ndarray:
        return np.tile(self.gravity, self.vertex_count)

    def damping_matrix(self, x):
        data = None
        for term in self.damping_terms:
            if term.model == "spring":
                direction = self._springs(x).direction
                part = self._scatter_blocks(term.coefficient * direction[:, :, None] * direction[:, None, :])
                data = part if data is None else data + part
        if self._constant_damping is not None:
            data = self._constant_damping.copy() if data is None else data + self._constant_damping
        contact = None if self.contact is None else self.contact.damping_blocks(x)
        if contact is not None:
            part = self._scatter_blocks(np.zeros((self.spring_count, self.dim, self.dim)), contact)
            data = part if data is None else data + part
        return None if data is None else self.pattern_matrix(data)

    def observables(self, x, v):
        """The base class's energies and momenta, then the parts of P: each part evaluated once."""
        spring, gravity, contact = self.spring_energy(x), self.gravity_energy(x), self.contact_energy(x)
        values = self._mechanical_observables(x, v, spring + gravity + contact)  # = potential_energy(x), bit for bit
        values.update(spring_energy=spring, gravity_energy=gravity, contact_energy=contact)
        return values

    def _energy_reference(self) -> tuple[float, str]:
        """(E_ref, what it is): the larger of |KE0| + |elastic PE0| (springs and contact: gravity's energy depends on
        where the origin is, which would make the reference of a translated model another) and a floor, the energy
        of lifting the model by its largest extent, M |g| L, or without gravity the spring energy of a 1 % stretch
        of every spring. A model at rest has E0 = 0, and a nudge of 1e-8 m/s gives E0 ~ 1e-18 J, which no drift
        should be divided by."""
        elastic = self.spring_energy(self.x0) + self.contact_energy(self.x0)
        strain = 0.5 * float(np.dot(self.stiffness, np.square(0.01 * self.rest_length)))
        return vertex_energy_reference(self, elastic, strain, "springs")

    def energy_scale(self) -> float:
        return self._energy_reference()[0]

    @property
    def energy_reference_name(self) -> str:
        return self._energy_reference()[1]

    @property
    def frame_shape(self) -> tuple[int, int] | None:
        """(ny, nx) for grid models: a frame's vertices are row-major, so it reshapes to (ny, nx, d)."""
        return self.grid_shape

    def frame(self, x: np.ndarray) -> np.ndarray:
        """Vertex positions as (vertices, d) (m)."""
        return x.reshape(-1, self.dim)
