"""Vertex block descent: Gauss-Seidel over colours of vertices, one d x d Newton step per vertex.

A. H. Chen, Z. Liu, Y. Yang and C. Yuksel, "Vertex block descent", ACM TOG 43(4), SIGGRAPH 2024. The
incremental potential E(y) is minimised over one vertex at a time, all others held: vertex i takes the
Newton step of E as a function of y_i alone,

    u_i = -H_i^{-1} g_i,   g_i = dE/dy_i,   H_i = d^2E/dy_i^2 = M_i + s d^2P/dy_i^2 + (s/b) D_ii   (sec. 3.2),

and is skipped where |det H_i| is too small to solve with (sec. 3.2; we measure det H_i against
|H_i|_F^d, so that the test needs no units). Vertices that share no term of E (one colour of a graph
colouring, sec. 3.9) are independent: their steps are taken together as one vectorised update, each colour
at the iterate that the colours before it left (Gauss-Seidel). One iteration is one sweep over the colours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.sparse

from simrun.systems.forms import contact_needs_step_filter

from .base import Advance, NonlinearSolver, chebyshev_weight
from .dofs import FreeDofs
from .line_search import collision_free

VBD_SPD_PROJECTIONS = ("clamp", "abs")
# The problems that offer vertex_blocks (``refusal``'s problem_kind): the integrators' IncrementalPotential.
VERTEX_PROBLEMS = ("incremental_potential",)
# Halvings of a vertex's step before it stays where it is for this sweep: 2^-20 ~ 1e-6 of a Newton step
# that still raises E means the step is useless at this iterate (a non-convex vertex), not too long.
MAX_HALVINGS = 20
# Colour plans kept per solver object: one per (system, constraints) it has solved; a run has one.
MAX_KEPT_PLANS = 8


@dataclass(frozen=True, eq=False)
class ColourPlan:
    """One colour's vertices that can move, and the filters of those that move in a subspace only.

    vertices: (k,) indices; filtered: (f,) positions in ``vertices`` of the vertices with some dofs fixed or a
    sliding filter; projectors: (f, d, d) their filters S_i (systems/constraints.py)."""

    vertices: np.ndarray
    filtered: np.ndarray
    projectors: np.ndarray
    constrained: np.ndarray  # (k,) bool: vertex k has a filter, all_projectors[k] (the compiled sweep's form)
    all_projectors: np.ndarray  # (k, d, d)


@dataclass(frozen=True)
class IncrementalParts:
    """E = 1/2 |y - y~|_M^2 + s P(y) + w [damping: (D (y - a)) and D_ii] as the compiled sweep reads it: D in CSR
    arrays (empty with w = 0 where the problem is undamped)."""

    y_tilde: np.ndarray
    mass: np.ndarray
    scale: float
    damping_indptr: np.ndarray
    damping_indices: np.ndarray
    damping_data: np.ndarray
    damping_weight: float
    velocity_origin: np.ndarray

    @classmethod
    def of(cls, problem) -> "IncrementalParts":
        y_tilde = np.ascontiguousarray(problem.y_tilde, dtype=float)
        if problem.damping is None:
            empty = np.zeros(1, dtype=np.intp)
            return cls(y_tilde, problem.system.mass, float(problem.scale), empty, empty, np.zeros(1), 0.0, y_tilde)
        damping = scipy.sparse.csr_matrix(problem.damping)
        return cls(y_tilde, problem.system.mass, float(problem.scale), damping.indptr.astype(np.intp),
                   damping.indices.astype(np.intp), np.ascontiguousarray(damping.data, dtype=float),
                   float(problem.damping_weight), np.ascontiguousarray(problem.velocity_origin, dtype=float))


def colour_plans(colouring: list[np.ndarray], free: FreeDofs, dim: int) -> list[ColourPlan]:
    """The colours without their pinned vertices (every dof fixed), each with the filters of its constrained vertices."""
    free_components = free.mask.reshape(-1, dim)
    projectors = np.zeros((free_components.shape[0], dim, dim))
    diagonal = np.arange(dim)
    projectors[:, diagonal, diagonal] = free_components  # fixed dofs: S_i = diag(free components)
    constrained = ~free_components.all(axis=1)
    if free.sliding is not None:  # a vertex takes one constraint: a sliding vertex has no fixed dof
        projectors[free.sliding.vertices] = free.sliding.projectors
        constrained[free.sliding.vertices] = True
    movable = free_components.any(axis=1)
    plans = []
    for colour in colouring:
        vertices = colour[movable[colour]]
        if vertices.size:
            filtered = np.flatnonzero(constrained[vertices])
            plans.append(ColourPlan(vertices, filtered, projectors[vertices[filtered]], constrained[vertices].copy(),
                                    np.ascontiguousarray(projectors[vertices])))
    return plans


@dataclass
class _SweepState:
    plans: list[ColourPlan]
    previous: np.ndarray  # y_{k-1}, for the Chebyshev update
    compiled: tuple | None = None  # (the system's compiled sweep, the problem's IncrementalParts), or None: numpy
    swept: np.ndarray | None = None  # the sweep's result from y_k
    halvings: int = 0  # backtracking rounds of the last sweep
    residual: float = math.inf  # the last sweep's residual: the largest |g_i|_inf (filtered) where vertex i met it
    position: int = 0  # iterates since the (re)start of the Chebyshev sequence
    weight: float = 1.0


def _crosses_no_collider(problem, y: np.ndarray, moved: np.ndarray) -> bool:
    """Whether the move y -> moved, every vertex at once along its straight line, reaches no collider under IPC (the
    sweep's own moves are cut vertex by vertex; the Chebyshev extrapolation is not); True without IPC. (A finite-
    element system's step filter also bounds its volumes, which the extrapolation's energy check already guards.)"""
    system = getattr(problem, "system", None)
    if system is None or not contact_needs_step_filter(system):
        return True
    return collision_free(problem, y, moved - y) >= 1.0


class VertexBlockDescent(NonlinearSolver):
    """Vertex block descent (see the module docstring) with per-vertex backtracking and optional Chebyshev acceleration.

    Energy descent. Each vertex's step is cut in halves until the change of E it causes alone, dE_i (the
    problem's ``vertex_energy_changes``, formed without cancellation), is <= 0, or dropped after MAX_HALVINGS.
    Vertices of one colour share no term of E, so E(y + sum_i u_i) - E(y) = sum_i dE_i(u_i) exactly: each colour,
    and so each sweep, never raises E. The steps are Newton steps of SPD blocks (``spd_projection``: the
    system's blocks with negative eigenvalues clamped at 0 or mirrored, plus M_i), hence descent directions,
    and the full step is taken wherever E_i's quadratic model is good. Where the system has a step filter (finite
    elements keep a tenth of their volume; IPC's colliders, which a step stops CCD_MARGIN short of), each vertex's
    step is first cut to it (``vertex_step_fractions``).

    Constraints. A vertex with fixed dofs or a sliding filter S_i takes the exact constrained step: the
    minimiser of the local quadratic model over y_i + range(S_i), the solution of
    (S_i H_i S_i + c (I - S_i)) u = -S_i g_i (c > 0: H_i's mean diagonal entry, which keeps the block's
    scale); pinned vertices are left out of the colours.

    Acceleration (``chebyshev_rho`` > 0; sec. 3.8 of the paper, after H. Wang, "A Chebyshev semi-iterative
    approach for accelerating projective and position-based dynamics", ACM TOG 34(6), 2015): from the sweep's
    result y^ of y_k, y_{k+1} = omega_{k+1} (y^ - y_{k-1}) + y_{k-1}. Where that raises E above E(y_k) it is
    rejected (one line search step) and the sequence restarts from y^ (Wang's restart on an energy increase),
    so the energy still never increases; it costs one evaluation of E per sweep. Under IPC it is rejected too
    where the move y_k -> y_{k+1}, every vertex at once, would reach a collider (``collision_free``): so every
    iterate's path, as a line search's, crosses no surface.

    Parameters: spd_projection ``clamp`` | ``abs``; chebyshev_rho in [0, 1), 0 for none; determinant_floor:
    vertex i is skipped in a sweep where |det H_i| <= determinant_floor |H_i|_F^d. With M_i in every block an
    SPD H_i has det H_i >= det M_i > 0, so the floor only catches blocks singular to working precision.

    Convergence. The sweep reports its residual as it met the vertices: the largest |g_i|_inf (filtered) where vertex
    i took its step (``Advance.residual_estimate``). The loop evaluates the full gradient only where that meets the
    threshold, and at the end of the solve: on the 12,288-tet beam a full gradient cost half a sweep, on the 64 x 64
    cloth a fifth. The full gradient alone decides convergence; it may find it one sweep after a full gradient per
    sweep would have. Counts: every sweep is one iteration; linear_iterations stays 0 (the d x d solves are direct);
    line_search_steps counts backtracking rounds (one vectorised halving of a colour's rejected steps) and Chebyshev
    rejections.
    """

    name = "vbd"
    takes_newton_step = False  # its iteration is not Newton's: semi_implicit_backward_euler refuses it
    needs_no_blas_threads = True  # compiled sweeps on numba's threads, and no factorisation
    filters_steps = True  # IPC: each vertex's step stops short of the colliders; so does the Chebyshev extrapolation
    requires: ClassVar[tuple[str, ...]] = ("vertex_blocks",)

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 spd_projection: str = "clamp", chebyshev_rho: float = 0.0, determinant_floor: float = 1e-20, **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        if spd_projection not in VBD_SPD_PROJECTIONS:
            raise ValueError(f"spd_projection must be one of {', '.join(VBD_SPD_PROJECTIONS)}, got {spd_projection!r}")
        if not 0.0 <= chebyshev_rho < 1.0:
            raise ValueError(f"chebyshev_rho must be in [0, 1), got {chebyshev_rho}")
        if not 0.0 <= determinant_floor < 1.0:
            raise ValueError(f"determinant_floor must be in [0, 1), got {determinant_floor}")
        self.spd_projection = spd_projection
        self.rho = chebyshev_rho
        self.determinant_floor = determinant_floor
        self._kept_plans: list[tuple] = []  # (colouring, free, plans): the objects held, so their ids stay theirs

    @staticmethod
    def refusal(system, problem_kind: str) -> str | None:
        """Why vbd cannot solve a ``problem_kind`` problem of ``system``, in one line; None when it can.

        ``problem_kind``: ``incremental_potential`` (integrators/base.py IncrementalPotential, which offers vertex
        blocks) or ``segment_potential`` (SegmentPotential: forces sampled along the step, no vertex blocks).
        The system needs vertices: ``dim`` coordinates each, dividing ``dof_count``."""
        if problem_kind not in VERTEX_PROBLEMS:
            return (f"vbd minimises an incremental potential vertex by vertex, and a {problem_kind} has no vertex blocks "
                    "(average_vector_field, bdf2_midpoint_mix sample the force along the step): use backward_euler, "
                    "implicit_midpoint, bdf2, newmark or generalized_alpha")
        dim = getattr(system, "dim", None)
        if not isinstance(dim, (int, np.integer)) or dim < 1 or system.dof_count % dim:
            return f"vbd updates one vertex at a time, and {type(system).__name__} has no vertices (dim {dim!r}, {system.dof_count} dofs)"
        contact = system.contact_form()
        if contact and (contact.has_friction or contact.coupling_hessian(system.x0) is not None):
            return ("vbd's vertex blocks hold the springs and the colliders, not friction or mesh contact (which couple "
                    "vertices through ipctk): use newton, projected_newton or lbfgs")
        if system.mass_correction is not None:
            return ("vbd's vertex blocks take each vertex's own mass, and a consistent mass matrix couples the vertices: "
                    "use mass: lumped, or newton, projected_newton or lbfgs")
        return None

    # -- the iteration ------------------------------------------------------------------------
    def _begin(self, problem, current, free):
        if self.rho > 0.0:
            current.energy = problem.value(current.y)
        sweep = problem.system.vertex_form().sweep() if hasattr(problem, "y_tilde") else None
        compiled = None if sweep is None else (sweep, IncrementalParts.of(problem))
        return _SweepState(self._plans(problem, free, current.y.size), current.y, compiled)

    def _plans(self, problem, free: FreeDofs, size: int) -> list[ColourPlan]:
        colouring = problem.vertex_colouring()
        for kept_colouring, kept_free, plans in self._kept_plans:
            if kept_colouring is colouring and kept_free is free:
                return plans
        vertex_count = sum(colour.size for colour in colouring)
        plans = colour_plans(colouring, free, size // vertex_count)
        if len(self._kept_plans) >= MAX_KEPT_PLANS:
            self._kept_plans.pop(0)
        self._kept_plans.append((colouring, free, plans))
        return plans

    def _direction(self, problem, current, state):
        if state.compiled is not None:
            state.swept, state.halvings, state.residual = self._compiled_sweep(current.y, state.plans, *state.compiled)
        else:
            state.swept, state.halvings, state.residual = self._sweep(problem, current.y, state.plans)
        return state.swept - current.y, 0

    def _advance(self, problem, current, direction, state):
        if self.rho == 0.0:
            return Advance(state.swept, line_search_steps=state.halvings, residual_estimate=state.residual)
        state.position += 1
        state.weight = chebyshev_weight(state.position, state.weight, self.rho)
        rejections = 0
        candidate, energy = state.swept, None
        if state.position >= 2:
            accelerated = state.weight * (state.swept - state.previous) + state.previous
            accelerated_energy = problem.value(accelerated)
            if accelerated_energy <= current.energy and _crosses_no_collider(problem, current.y, accelerated):
                candidate, energy = accelerated, accelerated_energy
            else:  # Wang's restart: the plain sweep, and the sequence starts again from it
                rejections, state.position, state.weight = 1, 1, 1.0
        if energy is None:
            energy = problem.value(candidate)
        state.previous = current.y
        return Advance(candidate, energy=energy, line_search_steps=state.halvings + rejections,
                       residual_estimate=state.residual)

    # -- one sweep -----------------------------------------------------------------------------
    def _sweep(self, problem, y: np.ndarray, plans: list[ColourPlan]) -> tuple[np.ndarray, int, float]:
        """One Gauss-Seidel sweep from y over the colours: (the new iterate, the backtracking rounds it took, its
        residual: the largest |g_i|_inf, filtered, of E where vertex i met it)."""
        swept = y.copy()  # a new iterate: the solve keeps its iterates by reference
        positions_of = None
        halvings = 0
        residual = 0.0
        for plan in plans:
            vertices = plan.vertices
            gradient, hessian = problem.vertex_blocks(swept, vertices, self.spd_projection)
            if positions_of is None:
                positions_of = swept.reshape(-1, gradient.shape[1])
            met = np.array(gradient)
            if plan.filtered.size:
                met[plan.filtered] = np.einsum("fij,fj->fi", plan.projectors, met[plan.filtered])
            largest = float(np.max(np.abs(met), initial=0.0))
            if not largest <= residual:  # a NaN too: Python's max would drop it
                residual = largest
            steps = self._newton_steps(gradient, hessian, plan)
            fractions = problem.vertex_step_fractions(swept, vertices, steps)
            if fractions is not None:
                steps *= np.minimum(fractions, 1.0)[:, None]
            changes = problem.vertex_energy_changes(swept, vertices, steps)
            rejected = np.flatnonzero(~(changes <= 0.0))  # NaN too
            rounds = 0
            while rejected.size and rounds < MAX_HALVINGS:
                steps[rejected] *= 0.5
                changes = problem.vertex_energy_changes(swept, vertices, steps)
                rejected = np.flatnonzero(~(changes <= 0.0))
                rounds += 1
            steps[rejected] = 0.0
            positions_of[vertices] += steps
            halvings += rounds
        return swept, halvings, residual if math.isfinite(residual) else math.inf

    def _compiled_sweep(self, y: np.ndarray, plans: list[ColourPlan], sweep, parts) -> tuple[np.ndarray, int, float]:
        """The same sweep by the system's compiled kernel (the system's vertex form's ``sweep``): each colour's vertices in parallel,
        the same numbers as ``_sweep`` to round-off. A colour's backtracking rounds are its vertices' most."""
        swept = np.array(y, dtype=float)  # a new iterate: the solve keeps its iterates by reference
        halvings = 0
        residual = 0.0
        rounds = np.zeros(max(plan.vertices.size for plan in plans) if plans else 0, dtype=np.int64)
        gradient_norms = np.zeros(rounds.size)
        for plan in plans:
            count = plan.vertices.size
            sweep.sweep(swept, plan.vertices, plan.constrained, plan.all_projectors, parts, self.spd_projection,
                        self.determinant_floor, MAX_HALVINGS, rounds[:count], gradient_norms[:count])
            halvings += int(rounds[:count].max())
            residual = max(residual, float(gradient_norms[:count].max()))
        return swept, halvings, residual

    def _newton_steps(self, gradient: np.ndarray, hessian: np.ndarray, plan: ColourPlan) -> np.ndarray:
        """u_i = -H_i^{-1} g_i for the colour's vertices, (k, d); constrained vertices on their subspaces, and
        u_i = 0 where H_i is singular to working precision (gradient and hessian are the caller's: changed here)."""
        k, d = gradient.shape
        if plan.filtered.size:
            filtered, projectors = plan.filtered, plan.projectors
            block = hessian[filtered]
            scale = np.abs(np.einsum("fii->fi", block)).mean(axis=1)
            scale = np.where(scale > 0.0, scale, 1.0)
            hessian[filtered] = projectors @ block @ projectors + scale[:, None, None] * (np.eye(d) - projectors)
            gradient[filtered] = np.einsum("fij,fj->fi", projectors, gradient[filtered])
        determinant = np.linalg.det(hessian)
        size = np.sqrt(np.einsum("kij,kij->k", hessian, hessian))
        solvable = (np.abs(determinant) > self.determinant_floor * size ** d) & np.isfinite(determinant)
        solvable &= np.isfinite(gradient).all(axis=1)
        if not solvable.all():
            hessian[~solvable] = np.eye(d)
            gradient[~solvable] = 0.0
        steps = -np.linalg.solve(hessian, gradient[:, :, None])[:, :, 0]
        if plan.filtered.size:  # exact in theory; the filter removes the round-off across the subspace
            steps[plan.filtered] = np.einsum("fij,fj->fi", plan.projectors, steps[plan.filtered])
        return steps
