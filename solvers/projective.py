"""Projective dynamics with Chebyshev acceleration, and the rest-shape matrix it shares with L-BFGS.

Both solvers use the constant matrix A = M + s K_r (+ (s/b) D) of a problem's ``rest_hessian()``,
factorised once and reused for every iteration and every step while the problem's ``rest_key`` (and the
free degrees of freedom) stay the same: ``RestFactor``. Solvers that need something of the system say so
in ``requires`` (``projective``: the incremental potential of Hookean springs, ``rest_stiffness``: a
K_r at all); ``refusal`` gives the one-line reason why a system cannot be solved by them, for the config
layer to refuse a run before it starts and for the solvers to refuse a problem they are handed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, ClassVar

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from simrun.systems.forms import refusal_reason

from .base import Advance, NonlinearSolver, chebyshev_weight
from .dofs import FreeDofs
from .line_search import accept, has_value
from .linear import CholeskySolver, cholmod_module, sparse_lu

# The auto estimate of rho is capped here: the Chebyshev weights approach 2 / (1 + sqrt(1 - rho^2)) -> 2, and
# an estimate at or above 1 (an indefinite Hessian: compressed springs) would extrapolate without bound; at
# 0.99999 the accelerated contraction is ~ 1 - sqrt(2 (1 - rho)) = 0.9955 per iteration, which a 64x64
# cloth at dt = 0.02 s needs (its rho is 0.999986).
AUTO_RHO_MAX = 0.99999
# Relative accuracy asked of the Lanczos estimate: its Ritz value approaches the top eigenvalue from below, so a
# loose tolerance errs on the safe side (a rho below the true one converges, only more slowly).
AUTO_TOLERANCE = 1e-3
# Below this many free dofs the generalized eigenproblem is solved densely (LAPACK), exactly.
AUTO_DENSE_LIMIT = 200
CHEBYSHEV_RHO_AUTO = "auto"


# ------------------------------------------------------------------------------------------------
# What a solver needs of the system, and the one-line refusal
# ------------------------------------------------------------------------------------------------
def refusal(solver_name: str, requires: tuple[str, ...], system, projective: bool) -> str | None:
    """Why a solver that needs ``requires`` cannot solve the problems of ``system``, in one line, or None.

    ``projective``: is the integrator's problem an incremental potential (``IncrementalPotential.projective``;
    False for the methods that sample the force along the step, whose ``SegmentPotential`` is not the
    energy projective dynamics minimises). Requirements (the system's ``projective_form()``, systems/forms.py):
    ``projective`` (the problem is an incremental potential, and the system's projective form exact: its
    potential Hookean springs plus linear terms) and ``rest_stiffness`` (the system has a projective form: a K_r)."""
    if "projective" in requires and not projective:
        return _not_incremental(solver_name)
    if "projective" not in requires and "rest_stiffness" not in requires:
        return None
    form = _projective_form(system)
    if "projective" in requires and (not form or form.inexact):
        return _not_hookean(solver_name, form.inexact if form else _reason(system, form))
    if not form:
        return _no_rest_stiffness(solver_name, system, form)
    return None


def _no_rest_stiffness(solver_name: str, system, form) -> str:
    return f"{solver_name} needs the rest stiffness K_r of the system, and {type(system).__name__} ({_reason(system, form)}) has none"


def _not_incremental(solver_name: str) -> str:
    return (f"{solver_name} needs an incremental potential, and this integrator samples the force along the step "
            "(as average_vector_field and bdf2_midpoint_mix do)")


def _not_hookean(solver_name: str, reason: str) -> str:
    return f"{solver_name} minimises the incremental potential of Hookean springs only: {reason}"


def _projective_form(system):
    method = getattr(system, "projective_form", None)
    return method() if callable(method) else None


def _reason(system, form) -> str:
    return refusal_reason(form, f"{type(system).__name__} does not declare its potential as Hookean springs")


def solver_refusal(solver, system, projective: bool) -> str | None:
    """``refusal`` for a built solver (or a FallbackChain: its first solver that refuses), from its ``requires``."""
    for member in getattr(solver, "solvers", (solver,)):
        reason = refusal(_requirement_label(member), tuple(getattr(member, "requires", ())), system, projective)
        if reason is not None:
            return reason
    return None


def _requirement_label(solver) -> str:
    initial_hessian = getattr(solver, "initial_hessian", None)
    return f"{solver.name} with initial_hessian {initial_hessian}" if initial_hessian in ("rest", "scaled_rest") else solver.name


def problem_refusal(solver_name: str, requires: tuple[str, ...], problem) -> str | None:
    """``refusal`` for the problem a solver is handed, as far as the problem tells without building a matrix
    (the rest stiffness is judged when ``RestFactor.prepare`` asks for the problem's ``rest_hessian``)."""
    if "projective" not in requires:
        return None
    system = getattr(problem, "system", None)
    if system is None:
        return f"{solver_name} needs an integrator's incremental potential; this problem is not one"
    return refusal(solver_name, ("projective",), system, bool(getattr(problem, "projective", False)))


# ------------------------------------------------------------------------------------------------
# The rest-shape matrix, factorised once
# ------------------------------------------------------------------------------------------------
class RestFactor:
    """Solves A p = b on the free dofs for A = ``problem.rest_hessian()``, factorised once per (rest_key, free dofs).

    A is symmetric positive definite (M > 0, K_r and D positive semi-definite), so the factorisation is
    CHOLMOD's Cholesky where scikit-sparse is installed (``CholeskySolver``), otherwise SuperLU with
    diagonal pivots in symmetric mode (``direct``'s SPD options); dense matrices (the small systems) take
    LAPACK's Cholesky. Fixed dofs are dropped (the free block A_ff) and sliding vertices filtered as the
    Newton matrix is (S A S + (I - S), ``FreeDofs.filter_matrix``), so the solution is zero on fixed dofs
    and moves sliding vertices along their allowed directions only. One object lives as long as its
    solver, i.e. a run: the integrator hands a new problem every step, with the same ``rest_key``.
    """

    def __init__(self):
        self._key = None  # (rest_key, FreeDofs) of the factor held
        self._system = None  # the system of that key, kept alive: its id() is part of rest_key and must not be reused
        self._solve: Callable[[np.ndarray], np.ndarray] | None = None
        self.matrix = None  # A_ff, filtered: the matrix of the factor held

    def prepare(self, problem, free: FreeDofs, solver_name: str) -> None:
        """Factorise the problem's A unless the factor held is already its; ValueError (one line naming
        ``solver_name``) where the problem has no rest-shape matrix."""
        rest_hessian = getattr(problem, "rest_hessian", None)
        if rest_hessian is None:
            raise ValueError(f"{solver_name} needs a problem with a rest-shape matrix (an integrator's incremental potential); this one has none")
        key = (problem.rest_key, free)
        if self._solve is not None and key == self._key:
            return
        matrix = rest_hessian()
        if matrix is None:
            raise ValueError(_no_rest_stiffness(solver_name, problem.system, _projective_form(problem.system)))
        self._solve = None  # a failing factorisation leaves no stale factor behind
        self.matrix = free.restrict_matrix(free.filter_matrix(matrix))
        self._solve = factorise_spd(self.matrix)
        self._key, self._system = key, problem.system

    def solve(self, free: FreeDofs, rhs: np.ndarray) -> np.ndarray:
        """p with A_ff p_f = rhs_f (filtered), zero on the fixed dofs, with the factor of the last ``prepare``."""
        reduced = free.restrict(rhs)
        if reduced.size == 0:
            return np.zeros_like(rhs)
        return free.extend(self._solve(reduced))

    def iteration_radius(self, problem, y: np.ndarray, free: FreeDofs, relaxation: float) -> float:
        """rho = 1 - gamma lambda_min, the spectral radius of the linearised iteration y <- y - gamma A^{-1} grad E(y)
        at y, with lambda_min the smallest eigenvalue of H v = lambda A v (H the Hessian at y, both filtered to
        the free dofs as the solves are), in [0, AUTO_RHO_MAX]; A must be ``prepare``d for this problem.

        A - H is positive semi-definite for Hookean springs (each spring's A block k_e I exceeds its Hessian
        block by k_e (l_e / L_e) across it), so the eigenvalues lie in (0, 1] wherever H is definite and
        1 - gamma lambda_min is the largest modulus of 1 - gamma lambda. It is found as the top eigenvalue
        mu of (A - H) v = mu A v: densely (LAPACK) for up to AUTO_DENSE_LIMIT dofs, else by Lanczos (ARPACK,
        with A^{-1} through the factor held), whose Ritz value approaches mu from below, so the estimate never
        overshoots the true radius by more than round-off."""
        hessian = free.restrict_matrix(free.filter_matrix(problem.hessian(y)))
        difference = self.matrix - hessian
        size = difference.shape[0]
        if size == 0:
            return 0.0
        if not np.count_nonzero(difference.data if scipy.sparse.issparse(difference) else difference):
            top = 0.0  # H = A (a linear problem whose Hessian is the rest matrix): PD is exact in one step
        elif size <= AUTO_DENSE_LIMIT:
            dense = lambda m: m.toarray() if scipy.sparse.issparse(m) else np.asarray(m, dtype=float)
            top = scipy.linalg.eigh(dense(difference), dense(self.matrix), eigvals_only=True,
                                    subset_by_index=[size - 1, size - 1], check_finite=False)[0]
        else:
            inverse = scipy.sparse.linalg.LinearOperator(difference.shape, matvec=self._solve, dtype=float)
            start = np.random.default_rng(0).standard_normal(size)  # ARPACK's own start is random per call: not reproducible
            try:
                top = scipy.sparse.linalg.eigsh(difference, k=1, M=self.matrix, Minv=inverse, which="LA", v0=start,
                                                tol=AUTO_TOLERANCE, return_eigenvectors=False)[0]
            except scipy.sparse.linalg.ArpackNoConvergence as failure:  # the Ritz values it has are lower bounds too
                top = failure.eigenvalues[-1] if len(failure.eigenvalues) else 0.0
            except scipy.sparse.linalg.ArpackError:  # no estimate: rho = 1 - gamma, at worst plain PD's own rate
                top = 0.0
        radius = 1.0 - relaxation * (1.0 - float(top))
        return min(max(radius, 0.0), AUTO_RHO_MAX) if math.isfinite(radius) else 0.0


def factorise_spd(matrix) -> Callable[[np.ndarray], np.ndarray]:
    """The solve b -> A^{-1} b of a factorised symmetric positive definite matrix (dense or sparse).

    A matrix that turns out not to be definite takes the direct solver's paths (``sparse_lu``)."""
    if not scipy.sparse.issparse(matrix):
        dense = np.asarray(matrix, dtype=float)
        try:
            factor = scipy.linalg.cho_factor(dense, check_finite=False)
        except np.linalg.LinAlgError:
            lu = scipy.linalg.lu_factor(dense, check_finite=False)
            return lambda rhs: scipy.linalg.lu_solve(lu, rhs, check_finite=False)
        return lambda rhs: scipy.linalg.cho_solve(factor, rhs, check_finite=False)
    matrix = matrix.tocsc()
    if CholeskySolver.missing() is None:
        cholmod = cholmod_module()
        try:
            return cholmod.cholesky(matrix).solve_A
        except cholmod.CholmodNotPositiveDefiniteError:
            pass
    # the matrices here are symmetric: CSC read as A^T is A, so solving with trans="N" solves A p = b
    return sparse_lu(matrix, True)[0].solve


# ------------------------------------------------------------------------------------------------
# Projective dynamics
# ------------------------------------------------------------------------------------------------
@dataclass(slots=True)
class _ProjectiveState:
    free: FreeDofs
    rho: float  # the Chebyshev rho of this solve
    previous: np.ndarray  # y_{k-1}
    position: int  # place in the Chebyshev sequence: <= 1 plain iterations (the warm-up), then accelerated
    weight: float = 1.0  # omega_k


class ProjectiveDynamics(NonlinearSolver):
    """Projective dynamics (the local-global iteration) for Hookean springs, with Chebyshev acceleration.

    The incremental potential of Hookean springs (plus linear forces f and the step's damping matrix D, taken
    once per step at ``damping_at`` and so constant within it) is
        E(y) = 1/2 |y - y~|_M^2 + s [sum_e k_e/2 (|S_e y| - l_e)^2 - f^T y] + s/(2b) |y - a|_D^2,
    with S_e y = x_i - x_j the spring vector. Liu et al. ("Fast simulation of mass-spring systems", ACM
    TOG 32(6), 2013) write each spring term as min over |p_e| = l_e of k_e/2 |S_e y - p_e|^2 and alternate
    the local step p_e = l_e S_e y_k / |S_e y_k| (the projection onto the rest length) with the global step
        A y_{k+1} = M y~ + s sum_e k_e S_e^T p_e + s f + (s/b) D a,    A = M + s K_r + (s/b) D,
    K_r = sum_e k_e S_e^T S_e = sum_e k_e (L_e kron I_d) (Bouaziz et al., "Projective dynamics", ACM TOG
    33(4), 2014). Since grad E(y) = A y - M y~ - s sum_e k_e S_e^T p_e(y) - s f - (s/b) D a (the spring
    term's gradient is k_e S_e^T (S_e y - p_e(y))), the global step is exactly
        y_{k+1} = y_k - A^{-1} grad E(y_k),
    a descent method with the constant matrix A (Liu, Bouaziz & Kavan, "Quasi-Newton methods for real-time
    simulation of hyperelastic materials", ACM TOG 36(3), 2017, sec. 3), which is how it is computed here:
    A is the problem's ``rest_hessian()``, factorised once per run (``RestFactor``). Each local-global
    pair minimises the augmented energy over p, then over y, so E never increases along plain iterations
    (also under-relaxed ones, y_k + gamma (y^_{k+1} - y_k) with 0 < gamma <= 1: a convex combination).

    Chebyshev acceleration (H. Wang, "A Chebyshev semi-iterative approach for accelerating projective and
    position-based dynamics", ACM TOG 34(6), 2015, eq. 12 and sec. 4):
        y_{k+1} = omega_{k+1} (gamma (y^_{k+1} - y_k) + y_k - y_{k-1}) + y_{k-1},
        omega = 1 for the first ``chebyshev_warmup`` iterations (Wang's S), then 2 / (2 - rho^2), then
        omega_{k+1} = 4 / (4 - rho^2 omega_k);
    rho (``chebyshev_rho``) estimates the spectral radius of the PD iteration (0: plain PD), gamma
    (``relaxation``) under-relaxes each global step. ``chebyshev_rho: auto`` computes rho: PD is the descent
    iteration y <- y - gamma A^{-1} grad E, whose linearisation has the spectral radius 1 - gamma lambda_min
    (lambda_min the smallest eigenvalue of H v = lambda A v), found by Lanczos at the first solve's start and
    kept for the run (for each dt and set of free dofs: ``RestFactor.iteration_radius``). Wang 2015 tunes
    rho by hand per scene; on cloth_hang's first step the computed one (0.99895 at dt = 0.01 s, 0.99963 at
    0.02 s, Lanczos; LAPACK: 0.99912 and 0.99978) takes 29x and 43x fewer iterations than plain PD to 1e-4 of
    the first residual, rho = 0.99 7x. An accelerated update that raises the energy is rejected
    and the sequence restarts with a plain step from y_k (as ``JacobiChebyshev``; Wang & Yang, "Descent
    methods for elastic body simulation on the GPU", ACM TOG 35(6), 2016); each rejection counts as a
    line-search step. Each global solve (a back-substitution) counts as one linear iteration.

    Refused (ValueError, one line: ``refusal``): problems that are not an incremental potential
    (``problem.projective`` False), systems whose projective form is inexact (squared-length springs,
    penalty contact) and systems without one. Where D depends on x (spring damping) A changes
    from step to step, and ``rest_key`` says so: one factorisation per step instead of per run.
    """

    name = "projective_dynamics"
    takes_newton_step = False  # its iteration is not Newton's: semi_implicit_backward_euler refuses it
    requires: ClassVar[tuple[str, ...]] = ("projective",)

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 chebyshev_rho: float | str = 0.0, chebyshev_warmup: int = 10, relaxation: float = 1.0, **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        if chebyshev_rho != CHEBYSHEV_RHO_AUTO and not (isinstance(chebyshev_rho, (int, float)) and 0.0 <= chebyshev_rho < 1.0):
            raise ValueError(f"chebyshev_rho must be in [0, 1) or {CHEBYSHEV_RHO_AUTO!r}, got {chebyshev_rho!r}")
        if chebyshev_warmup < 1:
            raise ValueError(f"chebyshev_warmup must be >= 1 (the first iteration has no previous one), got {chebyshev_warmup}")
        if not 0.0 < relaxation <= 1.0:
            raise ValueError(f"relaxation must be in (0, 1], got {relaxation}")
        self.chebyshev_rho = chebyshev_rho
        self.chebyshev_warmup = chebyshev_warmup
        self.relaxation = relaxation
        self.rest_factor = RestFactor()
        self._auto = (None, 0.0)  # (key, rho) of the computed rho: per system, scale (dt) and free dofs

    def refusal(self, system, problem_kind: str) -> str | None:
        """Why projective dynamics cannot solve this system's steps (one line), or None; ``problem_kind``:
        the integrator's (``Integrator.problem_kind``: only an incremental potential is PD's form)."""
        return refusal(self.name, self.requires, system, problem_kind == "incremental_potential")

    def _begin(self, problem, current, free):
        reason = problem_refusal(self.name, self.requires, problem)
        if reason is not None:
            raise ValueError(reason)
        self.rest_factor.prepare(problem, free, self.name)
        return _ProjectiveState(free, self._rho(problem, current.y, free), current.y, 1 - self.chebyshev_warmup)

    def _rho(self, problem, y, free) -> float:
        if self.chebyshev_rho != CHEBYSHEV_RHO_AUTO:
            return float(self.chebyshev_rho)
        # not rest_key itself: with spring damping A changes every step, the radius hardly (one estimate per run)
        key = (problem.rest_key[:2], free)
        if key != self._auto[0]:
            self._auto = (key, self.rest_factor.iteration_radius(problem, y, free, self.relaxation))
        return self._auto[1]

    def _direction(self, problem, current, state):
        return -self.rest_factor.solve(state.free, current.gradient), 1

    def _advance(self, problem, current, direction, state):
        gamma = self.relaxation
        state.position += 1
        if state.position <= 1:  # the warm-up: plain (under-relaxed) global steps
            state.previous = current.y
            return Advance(current.y + gamma * direction)
        state.weight = chebyshev_weight(state.position, state.weight, state.rho)
        candidate = state.weight * (gamma * direction + current.y - state.previous) + state.previous
        if state.weight == 1.0 or not has_value(problem):  # rho = 0: plain PD; no energy: no check
            state.previous = current.y
            return Advance(candidate)
        if current.energy is None:
            current.energy = problem.value(current.y)
        energy = problem.value(candidate)
        ok, gradient = accept(problem, state.free, current, "backtracking", candidate, energy)
        state.previous = current.y
        if ok:
            return Advance(candidate, gradient, energy)
        # restart the Chebyshev sequence: a plain step, which never raises E
        state.position, state.weight = 1, 1.0
        return Advance(current.y + gamma * direction, line_search_steps=1)

