"""First-order minimisers of the incremental potential: gradient descent, L-BFGS, Jacobi-Chebyshev descent.

Each iteration costs a gradient and the line search's energy evaluations. Gradient descent and L-BFGS
(with its scalar initial Hessian) evaluate the (SPD-projected) Hessian once per solve, to scale their
first step, and solve no linear system (linear_iterations stays 0); L-BFGS with the rest-shape initial
Hessian instead back-substitutes with a factor of the constant rest-shape matrix once per iteration
(one linear iteration each; the factor is kept for the run). Jacobi-Chebyshev evaluates its diagonal
once per solve (refreshing it at restarts changed no iteration count in our cloth tests and cost a
Hessian each).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
from scipy.linalg.blas import daxpy, ddot

from .base import Advance, Iterate, NonlinearSolver, chebyshev_weight, one_blas_thread
from .dofs import FreeDofs
from .line_search import MAX_LINE_SEARCH, accept, has_value, line_search
from .projective import RestFactor, factorise_spd, refusal

# A curvature pair (s, dg) of L-BFGS is kept only when s^T dg > this times dg^T dg, so that the
# inverse-Hessian model stays positive definite and well scaled (Byrd, Lu, Nocedal & Zhu 1995, sec. 6).
CURVATURE_EPS = np.finfo(float).eps
INITIAL_HESSIANS = ("scalar", "rest", "scaled_rest", "step")


def cauchy_step(problem, current: Iterate) -> float:
    """g^T g / g^T H+ g: the minimiser along -g of the quadratic model with the SPD-projected Hessian.

    It gives the first step its length (units of y per unit of gradient); 1 where the model has no
    positive curvature along g."""
    gradient = current.gradient
    curvature = float(gradient @ (problem.hessian(current.y, project_spd=True) @ gradient))
    length = float(gradient @ gradient) / curvature if curvature > 0.0 else 1.0
    return length if np.isfinite(length) and length > 0.0 else 1.0


def _prepare_energy(problem, current: Iterate, rule: str) -> None:
    if rule != "none" and has_value(problem):
        current.energy = problem.value(current.y)


def _gradient_at(problem, free: FreeDofs, advance: Advance) -> np.ndarray:
    if advance.gradient is None:
        advance.gradient = free.zero_fixed(np.array(problem.gradient(advance.y), dtype=float))
    return advance.gradient


def _lagged_point(problem, start: np.ndarray) -> np.ndarray:
    """Where L-BFGS's ``step`` H_0 is taken: the inertial guess x_n + theta h v_n (the step's y* is nearer to it
    than to x_n, so the lagged Hessian is less stale), or the solve's start where the problem has no guesses."""
    guess = getattr(problem, "initial_guess", None)
    return problem.start_point(guess("inertial")) if guess is not None and getattr(problem, "step_start", None) else start


@dataclass
class _DescentState:
    free: FreeDofs
    step_length: float  # gradient descent: the trial step; L-BFGS: the scale of H_0 (scalar and scaled_rest)
    pairs: deque = field(default_factory=deque)
    scaled_by: tuple | None = None  # scaled_rest: the pair that gave step_length its value
    step_solve: object = None  # initial_hessian step: b -> H+(y_0)^-1 b on the free dofs, factorised for this solve


def _secant_pair(problem, state, current, advance) -> tuple[np.ndarray, np.ndarray, float]:
    """(s, dg, s^T dg) of an accepted step: the secant information of Barzilai-Borwein and L-BFGS."""
    step = advance.y - current.y
    change = _gradient_at(problem, state.free, advance) - current.gradient
    return step, change, float(step @ change)


class GradientDescent(NonlinearSolver):
    """Steepest descent p_k = -a_k g_k with the line search; a_0 the Cauchy step, then the
    Barzilai-Borwein length a_k = s^T s / s^T dg (s = y_k - y_{k-1}, dg = g_k - g_{k-1}) as the trial
    step that the line search may cut (Barzilai & Borwein, IMA J. Numer. Anal. 8, 1988). Linear
    convergence; the rate degrades with the condition number of the Hessian."""

    name = "gradient_descent"
    filters_steps = True  # every step through line_search

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 line_search: str = "backtracking", **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        self.line_search = line_search

    def _begin(self, problem, current, free):
        _prepare_energy(problem, current, self.line_search)
        return _DescentState(free, cauchy_step(problem, current))

    def _direction(self, problem, current, state):
        return -state.step_length * current.gradient, 0

    def _advance(self, problem, current, direction, state):
        advance = line_search(problem, state.free, current, direction, self.line_search)
        if advance.ok:
            step, change, curvature = _secant_pair(problem, state, current, advance)
            if curvature > 0.0:
                state.step_length = float(step @ step) / curvature
        return advance


class LBFGS(NonlinearSolver):
    """Limited-memory BFGS: p_k = -H_k g_k by the two-loop recursion over the last ``history`` pairs
    (s_i, dg_i), then the line search (Nocedal & Wright, "Numerical Optimization", alg. 7.4 and 7.5).
    Pairs with s^T dg <= eps dg^T dg are skipped, so H_k stays positive definite and p_k a descent direction.

    The initial inverse Hessian H_0 of the recursion (``initial_hessian``; ``step`` unless told otherwise): ``scalar``,
    H_0 = (s^T dg / dg^T dg) I from the newest pair (the Cauchy step before the first); ``rest``,
    H_0 = A^{-1} with A = M + s K_r (+ (s/b) D) the problem's ``rest_hessian()``, the matrix of projective
    dynamics' global step, factorised once per run (Liu, Bouaziz & Kavan, "Quasi-Newton methods for
    real-time simulation of hyperelastic materials", ACM TOG 36(3), 2017): the first direction is then
    projective dynamics' step -A^{-1} g, and every H_0 q one back-substitution (a linear iteration);
    ``scaled_rest``, H_0 = gamma A^{-1} with gamma = s^T dg / dg^T A^{-1} dg from the newest pair (the
    scaling of N&W eq. 7.20 with A^{-1} in place of I): one more back-substitution per new pair.
    A gives each spring its stiffness k_e across it as well as along it, while the Hessian of a cloth near
    its rest lengths has ~0 across (k_e (1 - l_e/L)): on cloth_hang's out-of-plane modes the eigenvalues
    of A^{-1} H spread over 3e-4..0.1, and gamma fits the model to them (~40 % fewer iterations there).
    Both need a system with a rest stiffness (``requires``; refused in one line otherwise). ``step``:
    H_0 = H+^{-1}, the abs-projected Hessian at the step's inertial guess (``_lagged_point``), factorised once
    per step (not per run): the quasi-Newton method with a lagged Hessian, whose BFGS pairs correct what
    changed within the step; it needs no rest stiffness and follows the cloth's rotation, which the rest
    shape cannot.
    """

    name = "lbfgs"
    filters_steps = True  # every step through line_search

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 line_search: str = "backtracking", history: int = 8, initial_hessian: str = "step", **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        if initial_hessian not in INITIAL_HESSIANS:
            raise ValueError(f"initial_hessian must be one of {', '.join(INITIAL_HESSIANS)}, got {initial_hessian!r}")
        self.line_search = line_search
        self.history = history
        self.initial_hessian = initial_hessian
        # what this solver needs of the system (solvers/projective.py: refusal), per instance: it depends on H_0
        uses_rest = initial_hessian in ("rest", "scaled_rest")  # see refusal
        self.requires: tuple[str, ...] = ("rest_stiffness",) if uses_rest else ()
        self.rest_factor = RestFactor() if uses_rest else None

    def refusal(self, system, problem_kind: str) -> str | None:
        if not self.requires:
            return None
        return refusal(f"lbfgs with initial_hessian {self.initial_hessian}", self.requires, system,
                       problem_kind == "incremental_potential")

    def _begin(self, problem, current, free):
        if self.initial_hessian == "step":
            _prepare_energy(problem, current, self.line_search)
            factor = factorise_spd(free.restrict_matrix(free.filter_matrix(problem.hessian(_lagged_point(problem, current.y), project_spd="abs"))))
            state = _DescentState(free, 1.0, deque(maxlen=self.history))
            state.step_solve = lambda rhs: free.extend(factor(free.restrict(rhs)))
            return state  # the first step is the projected Newton step: no Cauchy length
        if self.rest_factor is not None:
            self.rest_factor.prepare(problem, free, f"lbfgs with initial_hessian {self.initial_hessian}")
            _prepare_energy(problem, current, self.line_search)
            return _DescentState(free, 1.0, deque(maxlen=self.history))  # the first step is -A^{-1} g: no Cauchy length
        _prepare_energy(problem, current, self.line_search)
        return _DescentState(free, cauchy_step(problem, current), deque(maxlen=self.history))

    def _direction(self, problem, current, state):
        rest = self.rest_factor
        if not state.pairs:
            if state.step_solve is not None:
                return -state.step_solve(current.gradient), 1
            if rest is not None:
                return -rest.solve(state.free, current.gradient), 1
            return -state.step_length * current.gradient, 0
        solves = 0
        if self.initial_hessian == "scaled_rest" and state.scaled_by is not state.pairs[-1]:
            state.scaled_by = state.pairs[-1]
            s, dg, rho = state.scaled_by
            curvature = float(dg @ rest.solve(state.free, dg))  # dg^T A^{-1} dg > 0: A is positive definite
            solves += 1
            if curvature > 0.0:
                state.step_length = 1.0 / (rho * curvature)  # s^T dg / dg^T A^{-1} dg
        # BLAS ddot and daxpy (in place) rather than `s @ q` and `q -= alpha * dg`: at the cloth's sizes the
        # operators' dispatch and temporaries cost several times the arithmetic, and the recursion makes
        # 4 * history of them per iteration. On one BLAS thread: see ``one_blas_thread``.
        q = current.gradient.copy()
        alphas = []
        with one_blas_thread():
            for s, dg, rho in reversed(state.pairs):  # newest first; a loop over the memory, not the dofs
                alpha = rho * ddot(s, q)
                q = daxpy(dg, q, a=-alpha)
                alphas.append(alpha)
        if state.step_solve is not None:
            q = state.step_solve(q)
            solves += 1
        elif rest is not None:
            q = rest.solve(state.free, q)  # H_0 q = gamma A^{-1} q (gamma = 1 for rest)
            if state.step_length != 1.0:
                q *= state.step_length
            solves += 1
        else:
            s, dg, _ = state.pairs[-1]
            q *= float(s @ dg) / float(dg @ dg)
        with one_blas_thread():
            for (s, dg, rho), alpha in zip(state.pairs, reversed(alphas)):  # oldest first
                beta = rho * ddot(dg, q)
                q = daxpy(s, q, a=alpha - beta)
        return -q, solves

    def _advance(self, problem, current, direction, state):
        advance = line_search(problem, state.free, current, direction, self.line_search)
        if advance.ok:
            step, change, curvature = _secant_pair(problem, state, current, advance)
            if curvature > CURVATURE_EPS * float(change @ change) and np.isfinite(curvature):
                state.pairs.append((step, change, 1.0 / curvature))
        return advance


@dataclass
class _ChebyshevState:
    free: FreeDofs
    inverse_diagonal: np.ndarray
    relaxation: float
    previous: np.ndarray  # y_{k-1}
    position: int = 0  # iterates produced since the (re)start of the Chebyshev sequence
    weight: float = 1.0  # omega_k


class JacobiChebyshev(NonlinearSolver):
    """Jacobi-preconditioned descent with Chebyshev semi-iterative acceleration.

        y^_{k+1} = y_k - D^{-1} g(y_k)                      (a Jacobi step, D = diag of the projected Hessian)
        y_{k+1}  = omega_{k+1} (gamma (y^_{k+1} - y_k) + y_k - y_{k-1}) + y_{k-1}
        omega_1 = 1,  omega_2 = 2 / (2 - rho^2),  omega_{k+1} = 4 / (4 - rho^2 omega_k)

    rho (``chebyshev_rho``) estimates the spectral radius of the Jacobi iteration, gamma
    (``relaxation``) under-relaxes each Jacobi step. With a line search, an update that raises the
    energy (or misses Armijo's decrease) is rejected and the Chebyshev sequence restarts from y_k
    (omega = 1, a plain Jacobi step); when that step too raises the energy, gamma is halved until it
    does not, and keeps its new value for the rest of the solve. Every rejection counts as a line
    search step. D is evaluated once per solve (at the start point). Sources: H. Wang, "A Chebyshev semi-iterative
    approach for accelerating projective and position-based dynamics", ACM TOG 34(6), 2015, eq. 12;
    H. Wang & Y. Yang, "Descent methods for elastic body simulation on the GPU", ACM TOG 35(6),
    2016, sec. 4 (the energy check and restart; they check every few iterations, we every one).
    """

    name = "jacobi_chebyshev"

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50, linear_solver="direct",
                 line_search: str = "backtracking", chebyshev_rho: float = 0.99, relaxation: float = 0.9,
                 spd_projection: str = "clamp", **options):
        super().__init__(tolerance, max_iterations, linear_solver, **options)
        if not 0.0 <= chebyshev_rho < 1.0:
            raise ValueError(f"chebyshev_rho must be in [0, 1), got {chebyshev_rho}")
        if not 0.0 < relaxation <= 1.0:
            raise ValueError(f"relaxation must be in (0, 1], got {relaxation}")
        self.line_search = line_search
        self.rho = chebyshev_rho
        self.relaxation = relaxation
        self.spd_projection = spd_projection

    def _inverse_diagonal(self, problem, y, free: FreeDofs) -> np.ndarray:
        hessian = problem.hessian(y, project_spd=self.spd_projection != "none")
        diagonal = np.asarray(hessian.diagonal() if scipy.sparse.issparse(hessian) else np.diag(hessian), dtype=float)
        diagonal = np.abs(diagonal)
        floor = np.finfo(float).eps * float(np.max(diagonal, initial=0.0))
        inverse = 1.0 / np.maximum(diagonal, floor if floor > 0 else 1.0)
        inverse[free.fixed] = 0.0  # a scaling, not a vector: only the fixed entries go (the directions are filtered)
        return inverse

    def _begin(self, problem, current, free):
        _prepare_energy(problem, current, self.line_search)
        return _ChebyshevState(free, self._inverse_diagonal(problem, current.y, free), self.relaxation, current.y)

    def _direction(self, problem, current, state):
        return -state.inverse_diagonal * current.gradient, 0

    def _weight(self, position: int, previous_weight: float) -> float:
        return chebyshev_weight(position, previous_weight, self.rho)

    def _advance(self, problem, current, direction, state):
        state.position += 1
        state.weight = self._weight(state.position, state.weight)
        candidate = state.weight * (state.relaxation * direction + current.y - state.previous) + state.previous
        checked = self.line_search != "none" and current.energy is not None
        if not checked:
            state.previous = current.y
            return Advance(candidate)
        energy = problem.value(candidate)
        ok, gradient = accept(problem, state.free, current, self.line_search, candidate, energy)
        rejections = 0
        if not ok:  # restart the Chebyshev sequence: a plain Jacobi step with a fresh diagonal
            rejections = 1
            state.position, state.weight = 1, 1.0
            while True:
                candidate = current.y + state.relaxation * direction
                energy = problem.value(candidate)
                ok, gradient = accept(problem, state.free, current, self.line_search, candidate, energy)
                if ok:
                    break
                if rejections > MAX_LINE_SEARCH:
                    return Advance(current.y, line_search_steps=rejections, ok=False)
                state.relaxation *= 0.5
                rejections += 1
        state.previous = current.y
        return Advance(candidate, gradient, energy, rejections)

