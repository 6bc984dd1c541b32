"""The finite-element system: a hyperelastic solid of linear simplices in 2-D or 3-D, or a shell of triangles in 3-D
(docs/fem.md).

P(x) = sum_e V_e psi(F_e) + bending - sum_i m_i g . x_i + contact, with psi one of the kernels' energy densities (a
shell's V_e its triangle's rest area times the thickness, and F_e 3 x 2: membrane.py) and, for a shell, the
discrete-shell hinges (bending.py); damping
f_d = -(alpha M + beta K_rest) v - c v (Rayleigh, K_rest the elastic Hessian at the rest shape, and drag); vertex
constraints (pins, sliding, prescribed paths) as filters, as for mass_spring. The element loops are compiled
(kernels.py); the Hessian's CSR pattern and each element block's place in it are built once, so an evaluation
fills one data array. Its energy in named parts for IMEX splits (``energy_terms``, ``with_terms``): split.py.
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse

from ..base import System, vertex_energy_reference
from ..constraints import VertexConstraints
from ..contact.hooks import WithContact
from ..contact.model import ContactModel
from ..forms import NotOffered, ProjectiveForm, kept_form
from . import bending, kernels, membrane, split
from .materials import CODES, MATERIALS
from .mesh import SimplexMesh
from .vertex import FemVertexForm

# Every line search keeps each element above this fraction of its volume at the search's start, as the course code's
# init_step_size does: the neo-Hookean energy is infinite at J <= 0, and an element pushed through zero volume
# by a long Newton step has no way back for any energy.
KEPT_VOLUME = 0.1
PROJECTIONS = {False: 0, True: 1, "clamp": 1, "abs": 2}  # project_spd -> the kernels' mode


class Fem(WithContact, System):
    """A hyperelastic solid of triangles (2-D) or tetrahedra (3-D): see the module docstring.

    Parameters (as resolved from a mesh and a config by params.py): mesh: a validated SimplexMesh; material: a
    MATERIALS name; mu, lam: (elements,) the energy's parameters (Pa); youngs_modulus, poisson_ratio: (elements,)
    E (Pa) and nu as configured; masses: (n,) kg; gravity: (d,) m/s^2; x0, v0: (n, d); damping: rayleigh and drag
    terms; constraints: VertexConstraints; contact: a ContactModel or None; boundary: the boundary faces (f, d);
    surface_edges: (m, 2) the edges drawn in frames. A shell (mesh.is_shell) takes thickness (m), its element
    weights V_e = thickness x area, and optionally bending_stiffness k (N m) of the hinges (h, 4) of mesh.hinges().
    consistent_masses: (elements,) kg, for the consistent mass matrix (``mass_correction``); None: lumped.
    """

    records_state_per_sample = False  # positions go to `frames`
    requires_step_filter = True  # every line search keeps the elements' volumes (max_step)

    def __init__(self, *, mesh: SimplexMesh, material: str, mu: np.ndarray, lam: np.ndarray,
                 youngs_modulus: np.ndarray, poisson_ratio: np.ndarray, masses: np.ndarray, gravity: np.ndarray,
                 x0: np.ndarray, v0: np.ndarray, damping: tuple = (), constraints: VertexConstraints | None = None,
                 contact: ContactModel | None = None, boundary: np.ndarray | None = None,
                 surface_edges: np.ndarray | None = None, thickness: float | None = None,
                 hinges: np.ndarray | None = None, bending_stiffness: float = 0.0,
                 consistent_masses: np.ndarray | None = None):
        d = mesh.dim
        self.mesh = mesh
        self.dim = self.vertex_dim = d
        self.vertex_count = mesh.vertex_count
        self.dof_count = d * self.vertex_count
        self.rest = mesh.vertices
        self.elements = mesh.elements
        self.material = material
        self._model = CODES[material]
        self.mu, self.lam = np.ascontiguousarray(mu, dtype=float), np.ascontiguousarray(lam, dtype=float)
        self.youngs_modulus, self.poisson_ratio = youngs_modulus, poisson_ratio
        self.x0 = np.ascontiguousarray(x0, dtype=float).ravel()
        self.v0 = np.ascontiguousarray(v0, dtype=float).ravel().copy()
        self.vertex_masses = masses
        self.mass = np.repeat(masses, d)
        self.gravity = np.asarray(gravity, dtype=float)
        self._gravity_force = (masses[:, None] * self.gravity).ravel()
        self.damping_terms = tuple(damping)
        self.contact = contact
        self.is_shell = mesh.is_shell
        self.thickness = thickness
        boundary = mesh.boundary_faces() if boundary is None else boundary
        self.frame_triangles = (boundary if d == 3 and not self.is_shell else mesh.elements).astype(np.int32)
        self.frame_edges = (surface_edges if surface_edges is not None else mesh.edges()).astype(np.int32)
        self.shape_gradients = shape_gradients(mesh)
        # the elements' weights: rest volumes (a 2-D solid's areas; a shell's areas times its thickness)
        self.volumes = np.abs(mesh.rest_volumes()) * (thickness if self.is_shell else 1.0)
        # whether the elements' elastic energy is part of P: False only in an IMEX split's part without ``elastic``
        # (split.py), which keeps the mesh (its volume ratios and step bound) but none of its elements' forces
        self.includes_elements = True
        self._kernels = membrane if self.is_shell else kernels
        self.hinges = np.zeros((0, 4), dtype=np.intp) if hinges is None else np.ascontiguousarray(hinges, dtype=np.intp)
        self.bending_stiffness = float(bending_stiffness)
        self.hinge_stiffness, self.rest_angles = _hinge_constants(mesh, self.hinges, self.bending_stiffness)
        self.constraints = constraints
        if constraints is not None:
            self.fixed_dofs = constraints.fixed_dofs
            self.sliding = constraints.sliding
            constraints.filter(self.v0)
            if constraints.moving_dofs.size:
                self.v0[constraints.moving_dofs] = constraints.path(0.0)[1]
        self._moving = constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp)
        self.consistent_masses = consistent_masses
        self._build_pattern()
        self.mass_correction = None if consistent_masses is None else self._consistent_correction(consistent_masses)
        self._rest_stiffness = self._elastic_hessian_data(self.rest.ravel(), 1)
        self._constant_damping = self._assemble_constant_damping()

    # -- setup ----------------------------------------------------------------------------------
    def _build_pattern(self) -> None:
        """The CSR pattern of the element blocks (where the elastic energy or the consistent mass fills them), the hinge
        blocks and every vertex's own block (contact's, drag's diagonal: a part of an IMEX split may have no elements),
        and where each entry of each block goes in its data array."""
        d, n = self.dim, self.dof_count
        with_elements = self.includes_elements or self.consistent_masses is not None
        vertices = np.arange(self.vertex_count)[:, None]
        groups = [self.elements if with_elements else self.elements[:0], self.hinges, vertices]
        entries = []
        for group in groups:
            dofs = (d * group[:, :, None] + np.arange(d)).reshape(len(group), group.shape[1] * d)  # (elements, k)
            rows = np.broadcast_to(dofs[:, :, None], dofs.shape + (dofs.shape[1],)).ravel()
            cols = np.broadcast_to(dofs[:, None, :], dofs.shape + (dofs.shape[1],)).ravel()
            entries.append((rows, cols, dofs.shape))
        rows = np.concatenate([rows for rows, _, _ in entries])
        cols = np.concatenate([cols for _, cols, _ in entries])
        pattern = scipy.sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
        pattern.sum_duplicates()
        pattern.sort_indices()
        keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(pattern.indptr)) * n + pattern.indices
        self._positions, self._hinge_positions, _ = (
            np.searchsorted(keys, rows.astype(np.int64) * n + cols).reshape(shape[0], shape[1], shape[1])
            for rows, cols, shape in entries)
        self._nnz = pattern.nnz
        self.hessian_pattern = pattern
        self.diagonal_positions = np.searchsorted(keys, np.arange(n, dtype=np.int64) * (n + 1))
        vertex = (d * np.arange(self.vertex_count)[:, None] + np.arange(d)).astype(np.int64)
        self._vertex_positions = np.searchsorted(keys, (vertex[:, :, None] * n + vertex[:, None, :]).ravel()).reshape(
            self.vertex_count, d, d)

    def _consistent_correction(self, element_masses: np.ndarray):
        """M_consistent - M_lumped in the Hessian's pattern (CSR): per element of k vertices and mass m_e, the block
        (a, b) is m_e / (k (k + 1)) (1 + delta_ab) I less the lumped m_e / k I on the diagonal (rows sum to 0)."""
        k, d = self.elements.shape[1], self.dim
        local = (np.ones((k, k)) + np.eye(k)) / (k * (k + 1)) - np.eye(k) / k
        blocks = element_masses[:, None, None, None, None] * local[None, :, None, :, None] * np.eye(d)[None, None, :, None, :]
        data = np.zeros(self._nnz)
        kernels.scatter_blocks(np.ascontiguousarray(blocks.reshape(len(self.elements), k * d, k * d)), self._positions,
                               data)
        return self.pattern_matrix(data)

    def _prepare_paths(self) -> None:
        self.__dict__.pop("_consistent_solve", None)  # released vertices join the free dofs of M a = f

    @functools.cached_property
    def _consistent_solve(self):
        """(free dofs, M_ff's factorisation, M_fm): what M a = f needs with the pinned dofs' a = 0 and the prescribed
        ones' a on their paths."""
        import scipy.sparse.linalg

        matrix = (scipy.sparse.diags_array(self.mass) + self.mass_correction).tocsr()
        held = np.union1d(self.fixed_dofs, self._moving)
        free = np.setdiff1d(np.arange(self.dof_count), held)
        factor = scipy.sparse.linalg.splu(matrix[free][:, free].tocsc())
        return free, factor, matrix[free][:, self._moving]

    def _elastic_hessian_data(self, x: np.ndarray, projection: int) -> np.ndarray:
        """The elements' and hinges' Hessian blocks, projected as asked, scattered into the pattern's data."""
        data = np.zeros(self._nnz)
        if self.includes_elements:
            self._kernels.element_hessians(x, self.elements, self.shape_gradients, self.volumes, self.mu, self.lam,
                                           self._model, projection, self._blocks)
            kernels.scatter_blocks(self._blocks, self._positions, data)
        if len(self.hinges):
            blocks = np.empty((len(self.hinges), 12, 12))
            bending.hinge_hessians(x, self.hinges, self.hinge_stiffness, self.rest_angles, projection, blocks)
            kernels.scatter_blocks(blocks, self._hinge_positions, data)
        return data

    @functools.cached_property
    def _blocks(self) -> np.ndarray:
        """The element blocks' scratch (elements, k, k), made once: 55 MB for 48,000 tets, whose first touch cost more
        than the blocks themselves when it was made per call."""
        k = self.elements.shape[1] * self.dim
        return np.empty((len(self.elements), k, k))

    def _assemble_constant_damping(self) -> np.ndarray | None:
        """The pattern data of alpha M + beta K_rest (rayleigh) and c I (drag), or None without them."""
        data = None
        for term in self.damping_terms:
            part = np.zeros(self._nnz)
            if term.model == "rayleigh":
                part += term.beta * self._rest_stiffness
                part[self.diagonal_positions] += term.alpha * self.mass
            elif term.model == "drag":
                part[self.diagonal_positions] += term.coefficient
            data = part if data is None else data + part
        return data

    # -- energy, gradient, Hessian ---------------------------------------------------------------
    def elastic_energy(self, x: np.ndarray) -> float:
        """sum_e V_e psi(F_e) + bending (J); infinite where a neo-Hookean element is inverted."""
        if not self.includes_elements:
            return self.bending_energy(x)
        return (float(self._kernels.element_energies(x, self.elements, self.shape_gradients, self.volumes, self.mu,
                                                     self.lam, self._model).sum()) + self.bending_energy(x))

    def bending_energy(self, x: np.ndarray) -> float:
        """The hinges' energy (J): 0 without bending."""
        if not len(self.hinges):
            return 0.0
        return float(bending.hinge_energies(x, self.hinges, self.hinge_stiffness, self.rest_angles).sum())

    def gravity_energy(self, x: np.ndarray) -> float:
        return -float(np.dot(self._gravity_force, x))

    def potential_energy(self, x):
        return self.elastic_energy(x) + self.gravity_energy(x) + self.contact_energy(x)

    def _elastic_gradient(self, x: np.ndarray) -> np.ndarray:
        """dP/dx without contact (N), flat (n d,)."""
        gradient = (self._element_gradient(x, self.elements, self.shape_gradients, self.volumes, self.mu, self.lam)
                    if self.includes_elements else np.zeros(x.size))
        if len(self.hinges):
            forces = np.empty((len(self.hinges), 4, 3))
            bending.hinge_forces(x, self.hinges, self.hinge_stiffness, self.rest_angles, forces)
            kernels.scatter_forces(forces, self.hinges, gradient)
        gradient -= self._gravity_force
        return gradient

    def _element_gradient(self, x, elements, gradients, volumes, mu, lam) -> np.ndarray:
        """dPsi/dx of the given elements (N), flat (n d,)."""
        forces = np.empty((len(elements), elements.shape[1], self.dim))
        self._kernels.element_forces(x, elements, gradients, volumes, mu, lam, self._model, forces)
        gradient = np.zeros(x.size)
        kernels.scatter_forces(forces, elements, gradient)
        return gradient

    def gradient(self, x):
        gradient = self._elastic_gradient(x)
        if self.contact is not None:
            self.contact.add_gradient(gradient, x)
        return gradient

    def hessian_data(self, x: np.ndarray, project_spd=False) -> np.ndarray:
        """The Hessian's values in the fixed CSR pattern: the elements' blocks (each projected to SPD on request, as
        ``project_spd`` says: clamp or abs of its stress derivative's eigenvalues) and contact's vertex blocks."""
        data = self._elastic_hessian_data(x, PROJECTIONS[project_spd])
        if self.contact is not None:
            blocks = np.zeros((self.vertex_count, self.dim, self.dim))
            self.contact.add_vertex_hessian(blocks, x, project_spd)
            np.add.at(data, self._vertex_positions, blocks)
        return data

    def volume_ratios(self, x: np.ndarray) -> np.ndarray:
        """J = det F of every element (its volume over its rest volume; a shell's triangle's area over its rest area),
        (elements,)."""
        if self.is_shell:
            return membrane.area_ratios(x, self.elements, self.shape_gradients)
        return kernels.volume_ratios(x, self.elements, self.shape_gradients)

    def max_step(self, x: np.ndarray, direction: np.ndarray) -> float:
        """The fraction of the step x -> x + direction that keeps every element above KEPT_VOLUME of its volume at x,
        and that crosses no contact surface."""
        if self.is_shell:
            fraction = membrane.area_keeping_step(x, direction, self.elements, KEPT_VOLUME)
        else:
            fraction = kernels.inversion_free_step(x, direction, self.elements, KEPT_VOLUME)
        if self.contact is None or not self.contact.requires_step_filter:  # penalty contact: no surface to keep
            return fraction
        return min(fraction, self.contact.max_step(x, direction))

    # -- damping, and what projective dynamics and L-BFGS's rest-shape Hessian use ----------------------
    def damping_matrix(self, x):
        data = None if self._constant_damping is None else self._constant_damping.copy()
        blocks = None if self.contact is None else self.contact.damping_blocks(x)
        if blocks is not None:
            part = np.zeros(self._nnz)
            np.add.at(part, self._vertex_positions, blocks)
            data = part if data is None else data + part
        return None if data is None else self.pattern_matrix(data)

    @property
    def damping_is_constant(self) -> bool:
        return not (self.contact is not None and self.contact.is_damped)

    @functools.cached_property
    def _projective_stiffness(self) -> np.ndarray:
        """Projective dynamics' sum_e 2 mu_e V_e B_e^T B_e as the pattern's data."""
        g = self.shape_gradients
        weights = 2.0 * self.mu * self.volumes
        products = np.einsum("e,eai,ebi->eab", weights, g, g)  # 2 mu V (g_a . g_b)
        k, d = self.elements.shape[1], self.dim
        blocks = (products[:, :, None, :, None] * np.eye(d)[None, None, :, None, :]).reshape(len(g), k * d, k * d)
        data = np.zeros(self._nnz)
        kernels.scatter_blocks(np.ascontiguousarray(blocks), self._positions, data)
        return data

    def projective_form(self) -> ProjectiveForm:
        """K_r, the matrix of projective dynamics' global step and L-BFGS's initial Hessian: for the as-rigid-as-possible
        energy projective dynamics' own sum_e 2 mu_e V_e B_e^T B_e, B_e = dF_e/dx (Bouaziz et al. 2014), whose block
        (a, b) is 2 mu V (g_a . g_b) I; for every other energy the elastic Hessian at the rest shape, linear
        elasticity's stiffness matrix (which Rayleigh damping takes in every case).

        Exact for the as-rigid-as-possible energy, the co-rotated one with lambda = 0 (nu = 0): mu ||F - R||^2 =
        (w/2) dist(F, SO(d))^2 with w = 2 mu, projective dynamics' own element constraint, whose local step is the
        polar rotation. Its solver's step y - A^-1 grad E is then exactly its local-global step. Every other energy,
        a bending term or contact: the reason."""
        inexact = self._projective_inexact()

        def rest_stiffness():
            return self.pattern_matrix((self._rest_stiffness if inexact else self._projective_stiffness).copy())

        return ProjectiveForm(rest_stiffness=rest_stiffness, inexact=inexact)

    def _projective_inexact(self) -> str | None:
        rigid = MATERIALS[self.material].as_rigid_as_possible
        if not rigid or np.any(self.lam != 0.0):
            return ("projective dynamics' element constraint is the distance of F to the rotations: the co-rotated "
                    "energy with poisson_ratio 0 (as-rigid-as-possible), not "
                    + (f"{self.material}" if not rigid else "a volume term (poisson_ratio != 0)"))
        if len(self.hinges):
            return "the discrete-shell hinges are not of projective form"
        if not self.includes_elements:
            return "a part of an IMEX split without elastic has no element constraints"
        if self.contact is not None:
            return "contact is not an element constraint"
        return None

    def compliant_form(self) -> NotOffered:
        return NotOffered("finite elements are not springs: XPBD's element constraints are not built for them")

    # -- calibration: exact forward sensitivities (integrators/sensitivity.py) ---------------------------
    def parameter_derivative(self, changed: "Fem", change: float):
        """d(grad P)/dtheta and dD/dtheta for a config value theta that moves Young's moduli (``youngs_modulus``, a
        region's) or the damping coefficients (alpha, beta, drag), found by comparing ``changed`` (theta moved by
        ``change``) with this system; None for any other change. At a fixed nu every energy's mu and lambda are
        proportional to E (the stable neo-Hookean's re-parametrised ones too, whose alpha depends on their ratio
        alone), and its stress is linear in (mu, lambda): an element's gradient moves by its own gradient times
        dE_e/dtheta / E_e, and Rayleigh's beta K_rest by beta times K_rest's elements scaled the same way."""
        same = ("elements", "rest", "vertex_masses", "x0", "v0", "gravity", "fixed_dofs", "poisson_ratio", "volumes",
                "hinge_stiffness")
        # the sensitivities' equations take a diagonal M, and the whole system's elements
        if self.mass_correction is not None or not self.includes_elements:
            return None
        if (type(changed) is not type(self) or changed.material != self.material or self.contact is not None
                or changed.contact is not None or self.sliding is not None
                or any(not np.array_equal(getattr(self, name), getattr(changed, name)) for name in same)
                or [term.model for term in self.damping_terms] != [term.model for term in changed.damping_terms]):
            return None
        from ..base import ParameterDerivative

        rate = (changed.youngs_modulus - self.youngs_modulus) / change / self.youngs_modulus  # dE_e/dtheta / E_e
        moved = np.flatnonzero(rate)
        scaled = (self.elements[moved], self.shape_gradients[moved], self.volumes[moved], self.mu[moved] * rate[moved],
                  self.lam[moved] * rate[moved])
        terms = [((moved_term.coefficient - term.coefficient) / change, (moved_term.alpha - term.alpha) / change,
                  (moved_term.beta - term.beta) / change, term.beta, term.model)
                 for term, moved_term in zip(self.damping_terms, changed.damping_terms)]

        def gradient(x: np.ndarray) -> np.ndarray:
            if not moved.size:
                return np.zeros(self.dof_count)
            return self._element_gradient(x, *scaled)

        stiffness_rate = None
        if moved.size and any(term.model == "rayleigh" and term.beta for term in self.damping_terms):
            k = self.elements.shape[1] * self.dim
            blocks = np.empty((moved.size, k, k))
            self._kernels.element_hessians(self.rest.ravel(), *scaled, self._model, 1, blocks)
            stiffness_rate = np.zeros(self._nnz)
            kernels.scatter_blocks(blocks, self._positions[moved], stiffness_rate)
        if not any(any(term[:3]) for term in terms) and stiffness_rate is None:
            return ParameterDerivative(gradient=gradient)
        data = np.zeros(self._nnz)
        for coefficient_rate, alpha_rate, beta_rate, beta, model in terms:
            if model == "rayleigh":
                data += beta_rate * self._rest_stiffness
                data[self.diagonal_positions] += alpha_rate * self.mass
                if stiffness_rate is not None:
                    data += beta * stiffness_rate
            elif model == "drag":
                data[self.diagonal_positions] += coefficient_rate
        return ParameterDerivative(gradient=gradient, damping=lambda x: self.pattern_matrix(data.copy()))

    # -- named parts of the energy, for IMEX splits (integrators/imex.py) ------------------------
    @property
    def energy_terms(self) -> tuple[str, ...]:
        return split.energy_terms(self)

    def with_terms(self, names, complement=False):
        return split.with_terms(self, names, complement)

    # -- for vertex block descent: only the elements at each vertex (vertex.py, vbd_kernels.py) --------------
    def vertex_form(self) -> FemVertexForm:
        return kept_form(self, "_vertex_form", lambda system: FemVertexForm(system, KEPT_VOLUME))

    # -- vertices on prescribed paths -----------------------------------------------------------
    def acceleration(self, x, v):
        """M^-1 f, with the prescribed dofs' accelerations their paths'; a solve with a consistent M."""
        force = self.force(x, v)
        if self.mass_correction is None:
            acceleration = force / self.mass
            if self._moving.size:
                acceleration[self._moving] = self.constraints.accelerations_along(v)
            return acceleration
        free, factor, coupling = self._consistent_solve
        acceleration = np.zeros(self.dof_count)
        if self._moving.size:
            acceleration[self._moving] = self.constraints.accelerations_along(v)
        acceleration[free] = factor.solve(force[free] - coupling @ acceleration[self._moving])
        return acceleration

    @functools.cached_property
    def external_acceleration(self) -> np.ndarray:
        return np.tile(self.gravity, self.vertex_count)

    # -- observables ---------------------------------------------------------------------------
    def observables(self, x, v):
        elastic, gravity, contact = self.elastic_energy(x), self.gravity_energy(x), self.contact_energy(x)
        values = self._mechanical_observables(x, v, elastic + gravity + contact)
        ratios = self.volume_ratios(x)
        values.update(elastic_energy=elastic, gravity_energy=gravity, contact_energy=contact,
                      **(self._shell_parts(x, elastic) if self.is_shell else {}),
                      volume_ratio_min=float(ratios.min()), volume_ratio_max=float(ratios.max()))
        return values

    def _shell_parts(self, x: np.ndarray, elastic: float) -> dict[str, float]:
        """A shell's elastic energy in its two parts (J): membrane and bending (hinges)."""
        bending_part = self.bending_energy(x)
        return {"membrane_energy": elastic - bending_part, "bending_energy": bending_part}

    def potential_magnitude(self, x):
        """J: |elastic energy| + sum_i |g_i x_i| (as the base class has it), the gravity and contact terms, and the
        elements' own scale sum_e V_e d (mu_e + |lambda_e|): each psi is a sum of terms of size mu d (mu/2 tr(F^T F) and
        -mu d/2 in the neo-Hookean energy) that cancel near rest, so its round-off is eps mu d V however small psi is.
        Without it a line search near rest takes that round-off for an increase (backward Euler's square coming to
        rest: 50 iterations and 800 halvings a step)."""
        return (abs(self.elastic_energy(x)) + float(np.abs(self._elastic_gradient(x) * x).sum()) + self._cancelling
                + float(np.abs(self._gravity_force * x).sum()) + abs(self.contact_energy(x)))

    @functools.cached_property
    def _cancelling(self) -> float:
        if not self.includes_elements:
            return 0.0
        return float(self.mesh.element_dim * np.sum(self.volumes * (self.mu + np.abs(self.lam))))

    def _energy_reference(self) -> tuple[float, str]:
        """(E_ref, what it is): |KE0| + |elastic PE0| where that exceeds the floor, M |g| L (lifting the body by its
        largest extent), or without gravity the energy of a 1 % uniform stretch of the whole body."""
        elastic = self.elastic_energy(self.x0) + self.contact_energy(self.x0)
        return vertex_energy_reference(self, elastic, self.elastic_energy(1.01 * self.rest.ravel()), "elements")

    def energy_scale(self) -> float:
        return self._energy_reference()[0]

    @property
    def energy_reference_name(self) -> str:
        return self._energy_reference()[1]

    def frame(self, x: np.ndarray) -> np.ndarray:
        return x.reshape(-1, self.dim)


def shape_gradients(mesh: SimplexMesh) -> np.ndarray:
    """(elements, d + 1, d): the gradients g_a of the element's shape functions at rest (1/m), d its own dimension.
    D_m^-1's rows are g_1..g_d, and g_0 = -sum of them, so that F = sum_a x_a g_a^T. A shell's triangle has D_m in
    its rest plane's frame: t_1 along its first edge, t_2 = n x t_1."""
    d = mesh.element_dim
    edges = np.stack([mesh.vertices[mesh.elements[:, a]] - mesh.vertices[mesh.elements[:, 0]] for a in range(1, d + 1)],
                     axis=2)
    if mesh.is_shell:  # (t, 3, 2) -> the edges' coordinates in each triangle's frame (t, 2, 2)
        first = edges[:, :, 0] / np.linalg.norm(edges[:, :, 0], axis=1, keepdims=True)
        normal = np.cross(edges[:, :, 0], edges[:, :, 1])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        frame = np.stack([first, np.cross(normal, first)], axis=1)  # (t, 2, 3): rows t_1, t_2
        edges = frame @ edges
    inverse = np.linalg.inv(edges)
    return np.ascontiguousarray(np.concatenate([-inverse.sum(axis=1, keepdims=True), inverse], axis=1))


def _hinge_constants(mesh: SimplexMesh, hinges: np.ndarray, stiffness: float) -> tuple[np.ndarray, np.ndarray]:
    """(k_h, theta_rest) per hinge: k_h = k 3 |e_rest|^2 / (A_1 + A_2) (N m), Grinspun et al. 2003's |e| / h_e with h_e
    a third of the mean of the two triangles' heights over the edge, and the rest shape's dihedral angle (rad)."""
    if not len(hinges):
        return np.zeros(0), np.zeros(0)
    rest = mesh.vertices
    edge = rest[hinges[:, 1]] - rest[hinges[:, 0]]
    first = 0.5 * np.linalg.norm(np.cross(edge, rest[hinges[:, 2]] - rest[hinges[:, 0]]), axis=1)
    second = 0.5 * np.linalg.norm(np.cross(edge, rest[hinges[:, 3]] - rest[hinges[:, 0]]), axis=1)
    weights = stiffness * 3.0 * np.einsum("ij,ij->i", edge, edge) / (first + second)
    return weights, bending.rest_angles(np.ascontiguousarray(rest.ravel()), hinges)
