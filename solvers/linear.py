"""Linear solvers for Newton directions: solve A p = b for a dense or sparse A with fixed degrees of freedom.

Every solver is a small object built with its tolerance and iteration limit, and
``solve(matrix, rhs, free, spd=False) -> (p, iterations)`` returns p with zeros on the fixed degrees of
freedom and the number of iterations it took (a direct factor-and-solve counts as one). All but
``mpcg`` solve the reduced system: the free rows and columns of A (restricted through the cached
``FreeDofs`` map, no index arrays rebuilt per call). ``mpcg`` works on the full system with Baraff
& Witkin's constraint filter instead. Iterative solvers start from p = 0 and stop when
|b - A p|_2 <= tolerance |b|_2 (scipy's ``rtol``) or after ``max_iterations``; a solver that did not
reach its tolerance returns its last iterate (an inexact Newton direction) and its count; one that
breaks down (mpcg on an indefinite matrix) or diverges (jacobi, gauss_seidel past DIVERGED_FACTOR)
raises ``numpy.linalg.LinAlgError``, which ends the nonlinear solve as not converged.
"""

from __future__ import annotations

import contextvars
import functools
import importlib
import math
import os
import warnings
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse
import scipy.sparse.linalg
import threadpoolctl

from .dofs import FreeDofs

# MMD on A^T + A suits the symmetric pattern of M + c h^2 K: it factors the cloth faster than scipy's
# default COLAMD ordering (docs/performance.md).
SPLU_ORDERING = "MMD_AT_PLUS_A"
# SPD matrices need no pivoting: diagonal pivots in symmetric mode factor the cloth's matrix faster
# (docs/performance.md).
SPLU_SPD_OPTIONS = dict(diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
# A diagonal pivot is kept while it is at least this fraction of its column's largest entry: threshold pivoting
# that leaves the symmetric ordering alone but where a pivot is (nearly) zero.
THRESHOLD_PIVOT = 0.1
# The paths of a sparse LU (SuperLU), in the order they are tried (docs/solvers.md, "Sparse direct solves"):
# diagonal pivots in the symmetric fill-reducing ordering; threshold pivoting in that ordering; COLAMD with partial
# pivoting, the last resort. Partial pivoting in the MMD ordering would destroy the ordering:
# a 2,930-vertex mesh in its file's vertex order fills 43 million entries of L + U against 2.5 million (180x the
# time). factorisation_path (per step) and factorisations (per run) say which path the factorisations took.
FACTORISATION_PATHS = ("symmetric", "threshold", "colamd")
SPLU_PATHS = (dict(permc_spec=SPLU_ORDERING, **SPLU_SPD_OPTIONS),
              dict(permc_spec=SPLU_ORDERING, diag_pivot_thresh=THRESHOLD_PIVOT, options=dict(SymmetricMode=True)),
              dict(permc_spec="COLAMD"))
# a factorisation of a matrix not known to be SPD (without pivoting, or with threshold pivoting; CHOLMOD's LDL^T)
# whose solution leaves a relative residual above this met a tiny pivot: the next path solves again
INDEFINITE_RESIDUAL = 1e-8


class FactorisationLog:
    """How a run's sparse factorisations went: a count per path of FACTORISATION_PATHS (``counts``), and the last
    path taken since ``take_step`` was asked (1 + its index; 0: no sparse factorisation); and the dense ones."""

    def __init__(self):
        self.counts = [0] * len(FACTORISATION_PATHS)
        self.dense = 0
        self._step = 0

    def record(self, path: int) -> None:
        self.counts[path] += 1
        self._step = max(self._step, path + 1)

    def record_dense(self) -> None:
        self.dense += 1

    @property
    def total(self) -> int:
        return sum(self.counts) + self.dense

    def take_step(self) -> int:
        """The furthest path any factorisation took since the last call (0: none), for factorisation_path."""
        step, self._step = self._step, 0
        return step

    def as_dict(self) -> dict[str, int]:
        return dict(zip(FACTORISATION_PATHS, self.counts))


# the log of the run being stepped, if it counts every factorisation (a step-controlled run's ``factorisations``):
# what factorisations outside a logging linear solver record into, the integrators' own (Radau IIA's blocks, a
# Rosenbrock step's matrix) and the dense ones. A context variable: each thread's runs count their own.
RUN_FACTORISATIONS: contextvars.ContextVar[FactorisationLog | None] = contextvars.ContextVar("run_factorisations",
                                                                                           default=None)


def record_dense_factorisation() -> None:
    """Count a dense factorisation in the run's log, if it keeps one."""
    log = RUN_FACTORISATIONS.get()
    if log is not None:
        log.record_dense()


def attach_factorisation_log(solver) -> FactorisationLog | None:
    """One FactorisationLog for the linear solvers of ``solver`` (a nonlinear solver or a fallback chain) that keep
    one (``direct``, ``cholesky``), set as their ``log``; None when none of them factors sparse matrices."""
    members = getattr(solver, "solvers", [solver])
    linear = [getattr(member, "linear_solver", None) for member in members]
    factoring = [one for one in linear if one is not None and hasattr(type(one), "log")]
    if not factoring:
        return None
    log = FactorisationLog()
    for one in factoring:
        one.log = log
    return log


def sparse_lu(transposed, spd: bool, rhs: np.ndarray | None = None, log: FactorisationLog | None = None):
    """A SuperLU factorisation of A, given A^T in CSC form (a CSR matrix's arrays read as CSC), by the first path of
    SPLU_PATHS that factors it: for an SPD matrix, the symmetric path whenever it has no zero pivot; for any other,
    the first path whose solution of ``rhs`` (or of A 1 without one) leaves a relative residual of at most
    INDEFINITE_RESIDUAL, COLAMD's partial pivoting whatever it leaves. Returns (factor: solve with trans="T", the
    solution of ``rhs`` or None); RuntimeError when every path meets an exactly singular matrix."""
    matrix = transposed.T  # A itself, as CSR: no copy
    if log is None:
        log = RUN_FACTORISATIONS.get()
    probe = rhs if rhs is not None else matrix @ np.ones(matrix.shape[0])
    last = len(SPLU_PATHS) - 1
    for path, options in enumerate(SPLU_PATHS):
        try:
            factor = scipy.sparse.linalg.splu(transposed, **options)
        except RuntimeError:  # a zero pivot (for an "SPD" matrix: not definite after all)
            if path == last:
                raise
            continue
        solution = factor.solve(probe, trans="T")
        if path == last or (spd and path == 0) or _residual_met(matrix, solution, probe):
            if log is not None:
                log.record(path)
            return factor, (solution if rhs is not None else None)
    raise AssertionError("unreachable: the last path returns or raises")


def _residual_met(matrix, solution: np.ndarray, rhs: np.ndarray) -> bool:
    residual = float(np.linalg.norm(rhs - matrix @ solution))
    return residual <= INDEFINITE_RESIDUAL * float(np.linalg.norm(rhs))  # False for NaN
FLOAT64 = np.dtype(np.float64)  # the one native float64 dtype object: `dtype is FLOAT64` is the cheapest test
EPSILON = float(np.finfo(float).eps)  # once: np.finfo is not free, and every dense solve compares rcond with it
# A stationary iteration whose residual grows past this factor times |b| diverges (spectral radius > 1).
DIVERGED_FACTOR = 1e8
# A stationary iteration's rate is measured over windows of this many iterations: it diverges when its residual grew
# over two windows in a row, and cannot converge when that rate would need more than HOPELESS_FACTOR times the
# iterations it has left (it would end far from its tolerance after running them all).
RATE_WINDOW = 10
HOPELESS_FACTOR = 4.0


def _diagonal(matrix) -> np.ndarray:
    diagonal = matrix.diagonal() if scipy.sparse.issparse(matrix) else np.diag(matrix)
    return np.asarray(diagonal, dtype=float)


def _safe_diagonal(matrix) -> np.ndarray:
    """diag(A), with 1 where the diagonal vanishes (no scaling is better than a division by zero)."""
    diagonal = _diagonal(matrix)
    return np.where(diagonal != 0.0, diagonal, 1.0)


def _inverse_diagonal(matrix) -> np.ndarray:
    return 1.0 / _safe_diagonal(matrix)


class LinearSolver(ABC):
    """Base of the linear solvers: ``solve(A, b, free, spd) -> (p, iterations)`` with p = 0 on fixed dofs.

    Parameters: tolerance (relative residual |b - A p|_2 / |b|_2, iterative solvers only);
    max_iterations (iterative solvers only).
    """

    name: ClassVar[str]
    iterative: ClassVar[bool] = True
    optional: ClassVar[bool] = False  # needs an optional package (see ``missing``)

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 1000):
        self.tolerance = tolerance
        self.max_iterations = max_iterations

    @classmethod
    def missing(cls) -> str | None:
        """Why this solver cannot run here (an optional package is not installed), or None."""
        return None

    wants_guess = False  # does ``solve`` use a guess of the solution (MPCG's filtered start)?

    @abstractmethod
    def solve(self, matrix, rhs: np.ndarray, free: FreeDofs, spd: bool = False) -> tuple[np.ndarray, int]:
        """p with A_ff p_f = b_f on the free dofs and p = 0 on the fixed ones; (p, iterations).

        Solvers whose ``wants_guess`` is True also take ``guess=``, an estimate of p."""

    def _target(self, rhs: np.ndarray) -> float:
        return self.tolerance * float(np.linalg.norm(rhs))


class ReducedSolver(LinearSolver):
    """Restrict to the free dofs, solve the reduced system with ``_solve``, extend with zeros."""

    def solve(self, matrix, rhs: np.ndarray, free: FreeDofs, spd: bool = False) -> tuple[np.ndarray, int]:
        if free.all_free and type(matrix) is np.ndarray and matrix.dtype is FLOAT64 and rhs.size:
            return self._solve(matrix, rhs, spd)  # restrict and extend would return these very arrays
        reduced_rhs = free.restrict(rhs)
        if reduced_rhs.size == 0:
            return np.zeros_like(rhs), 0
        solution, iterations = self._solve(free.restrict_matrix(free.filter_matrix(matrix)), reduced_rhs, spd)
        return free.extend(solution), iterations

    @abstractmethod
    def _solve(self, matrix, rhs: np.ndarray, spd: bool) -> tuple[np.ndarray, int]:
        """Solve the reduced (free-dof) system; (solution, iterations)."""

    def _stationary(self, matrix, rhs: np.ndarray, correction) -> tuple[np.ndarray, int]:
        """p_{k+1} = p_k + C (b - A p_k) from p_0 = 0 until |b - A p|_2 <= tolerance |b|_2; raises
        LinAlgError once the residual passes DIVERGED_FACTOR |b| (the iteration matrix's radius > 1)."""
        solution = np.zeros_like(rhs)
        residual = rhs.copy()
        target = self._target(rhs)
        limit = DIVERGED_FACTOR * float(np.linalg.norm(rhs))
        norms = np.empty(self.max_iterations + 1)
        iterations = 0
        while iterations < self.max_iterations:
            norm = norms[iterations] = float(np.linalg.norm(residual))
            if norm <= target:
                break
            if not norm <= limit:
                raise np.linalg.LinAlgError(f"{self.name}: the iteration diverges (spectral radius of its iteration matrix > 1)")
            if iterations >= 2 * RATE_WINDOW and iterations % RATE_WINDOW == 0:
                self._check_rate(norms[iterations - 2 * RATE_WINDOW:iterations + 1:RATE_WINDOW], target, iterations)
            solution += correction(residual)
            residual = rhs - matrix @ solution
            iterations += 1
        return solution, iterations

    def _check_rate(self, norms: np.ndarray, target: float, iterations: int) -> None:
        """Stop a stationary iteration that cannot reach ``target`` in its budget: its residual, once the fast
        components have decayed, changes by the spectral radius rho of its iteration matrix per iteration. ``norms``:
        the residual norms RATE_WINDOW and 2 RATE_WINDOW iterations ago, and now. Raises LinAlgError when it grew over
        both windows (rho >= 1: it diverges, if only slowly) or when even the slower window's rate would need more
        than HOPELESS_FACTOR times the iterations left."""
        before, middle, now = norms
        if not (now > 0.0 and middle > 0.0 and before > 0.0):
            return
        rate = max(now / middle, middle / before) ** (1.0 / RATE_WINDOW)
        if now >= middle >= before:
            raise np.linalg.LinAlgError(f"{self.name}: the iteration diverges (its residual grew by {rate:.4g} per "
                                        f"iteration over {2 * RATE_WINDOW} iterations: spectral radius >= 1)")
        left = self.max_iterations - iterations
        if rate < 1.0 and math.log(target / now) / math.log(rate) > HOPELESS_FACTOR * left:
            raise np.linalg.LinAlgError(f"{self.name}: cannot reach its tolerance in max_iterations {self.max_iterations}: "
                                        f"its residual falls by {rate:.6g} per iteration (spectral radius near 1)")


class DirectSolver(ReducedSolver):
    """Sparse LU (SuperLU in the symmetric MMD ordering, by the first path of SPLU_PATHS that factors the matrix
    accurately: ``sparse_lu``), or LAPACK for dense matrices (Cholesky for SPD ones, LU otherwise). Counts one
    iteration. ``log`` (a FactorisationLog, or None) counts the paths its sparse factorisations took."""

    name = "direct"
    iterative = False
    log: FactorisationLog | None = None

    def _solve(self, matrix, rhs, spd):
        if type(matrix) is not np.ndarray and scipy.sparse.issparse(matrix):  # the type test first: issparse is an ABC check
            if not matrix.has_sorted_indices:
                matrix = matrix.sorted_indices()  # a copy: the problem's matrix may share its index arrays
            # a CSR matrix's arrays read as CSC are its transpose: factor A^T, solve with its transpose
            transposed = scipy.sparse.csc_matrix((matrix.data, matrix.indices, matrix.indptr), shape=matrix.shape)
            return sparse_lu(transposed, spd, rhs, self.log)[1], 1
        return _dense_direct_solve(matrix, rhs, spd), 1


class CholeskySolver(ReducedSolver):
    """Sparse Cholesky through CHOLMOD (SuiteSparse, via scikit-sparse): symbolic analysis (fill-reducing
    ordering, supernodal structure) once per sparsity pattern, numeric refactorisation per solve.

    A run's Newton matrices share one pattern, so the analysis is done on the first and reused for
    the rest of the run (the solver object lives as long as its run). CHOLMOD picks a supernodal
    LL^T for large matrices and a simplicial LDL^T for small ones. A matrix that is not positive
    definite (plain Newton's raw Hessian of a buckled cloth) is solved by ``direct``'s paths (``sparse_lu``:
    the symmetric ordering first, pivoting only where it must) when LL^T fails or LDL^T leaves a residual above
    INDEFINITE_RESIDUAL; ``log`` counts those LU paths, not CHOLMOD's own factorisations; dense matrices (the small
    systems) take ``direct``'s LAPACK path. Counts one iteration. CHOLMOD takes the matrix as
    symmetric and reads one triangle: every Newton matrix here (the Hessian of an incremental or
    segment potential) is. Needs the optional extra ``cholmod`` (README, "Optional: the CHOLMOD
    solver").
    """

    name = "cholesky"
    iterative = False
    optional = True
    log: FactorisationLog | None = None

    @classmethod
    def missing(cls) -> str | None:
        try:
            cholmod_module()
        except ImportError as error:
            return str(error)
        return None

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 1000):
        super().__init__(tolerance, max_iterations)
        self._cholmod = cholmod_module()
        self._factor = None
        self._pattern = None  # (indptr, indices) the factor was analysed for

    def _solve(self, matrix, rhs, spd):
        if type(matrix) is np.ndarray or not scipy.sparse.issparse(matrix):
            return _dense_direct_solve(matrix, rhs, spd), 1
        if not matrix.has_sorted_indices:
            matrix = matrix.sorted_indices()
        # the CSR arrays read as CSC are A^T, which for the symmetric Newton matrices is A itself
        # (CHOLMOD reads one triangle of a matrix it takes as symmetric); no conversion
        transposed = scipy.sparse.csc_matrix((matrix.data, matrix.indices, matrix.indptr), shape=matrix.shape)
        factor = self._analysed_factor(transposed)
        try:
            factor.cholesky_inplace(transposed)
        except self._cholmod.CholmodNotPositiveDefiniteError:  # supernodal LL^T needs a definite matrix;
            return self._lu_solve(transposed, rhs), 1  # its analysis stays valid for the next matrix
        solution = factor.solve_A(rhs)
        if not spd:
            # small matrices get CHOLMOD's simplicial LDL^T, which factors indefinite matrices without
            # pivoting: accurate unless a pivot is (nearly) zero, which the residual tells
            residual = float(np.linalg.norm(rhs - matrix @ solution))
            if not residual <= INDEFINITE_RESIDUAL * float(np.linalg.norm(rhs)):
                return self._lu_solve(transposed, rhs), 1
        return solution, 1

    def _lu_solve(self, transposed, rhs):
        """A p = b by SuperLU for a matrix CHOLMOD could not factor accurately, from A^T in CSC form, with the
        direct solver's care: the symmetric ordering first, pivoting only where a pivot needs it (``sparse_lu``)."""
        return sparse_lu(transposed, False, rhs, self.log)[1]

    def _analysed_factor(self, matrix):
        pattern = self._pattern
        if pattern is None or not (_same_array(pattern[0], matrix.indptr) and _same_array(pattern[1], matrix.indices)):
            self._factor = self._cholmod.analyze(matrix)
            # copies: the caller may refill its index arrays with another pattern later
            self._pattern = (matrix.indptr.copy(), matrix.indices.copy())
        return self._factor


def _same_array(cached: np.ndarray, current: np.ndarray) -> bool:
    return cached.shape == current.shape and np.array_equal(cached, current)


@functools.cache
def cholmod_module():
    """scikit-sparse's CHOLMOD module; ImportError with the installation steps when it is missing.

    CHOLMOD brings its own BLAS (the system's OpenBLAS) beside numpy's bundled one. An OpenBLAS
    thread spins for a while after each parallel call, and numpy parallelises the dot products of
    the cloth's vectors (n > 10^4), so numpy's idle threads took the cores CHOLMOD's threads needed
    and slowed each refactorisation after an assembly. The BLAS libraries loaded before CHOLMOD
    (numpy's, scipy's) are therefore held at one thread; vector operations of this size are
    memory-bound and lose nothing by it. For the same reason CHOLMOD's OpenMP threads wait
    passively (sleep, not spin) unless the user chose a policy. The timings are in docs/performance.md."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # read once, when libgomp loads with CHOLMOD
    before = threadpoolctl.ThreadpoolController()
    try:
        module = importlib.import_module("sksparse.cholmod")
    except ImportError as error:
        raise ImportError(CHOLMOD_MISSING) from error
    before.select(user_api="blas").limit(limits=1)
    return module


CHOLMOD_MISSING = ("cholesky needs CHOLMOD through scikit-sparse, which is not installed: "
                   "`make install-cholmod` (Debian: apt-get install libsuitesparse-dev libopenblas0-pthread, "
                   "then pip install -e '.[cholmod]')")


def _dense_direct_solve(matrix, rhs: np.ndarray, spd: bool) -> np.ndarray:
    """A dense solve: LAPACK Cholesky for SPD matrices (LU when that fails), LU otherwise."""
    record_dense_factorisation()
    if matrix.shape[0] == 1:
        return rhs / matrix[0, 0]
    if matrix.dtype is FLOAT64 and rhs.dtype is FLOAT64 and rhs.ndim == 1:
        return _dense_solve(matrix, rhs, spd)
    if spd:
        try:
            return scipy.linalg.solve(matrix, rhs, assume_a="pos", check_finite=False)
        except np.linalg.LinAlgError:
            pass
    return scipy.linalg.solve(matrix, rhs, check_finite=False)


def _dense_solve(matrix: np.ndarray, rhs: np.ndarray, spd: bool) -> np.ndarray:
    """scipy.linalg.solve(matrix, rhs) (assume_a="pos" first when spd) through the LAPACK drivers it
    uses, called directly: on the 2x2 and 3x3 matrices of the small systems its argument checks cost
    far more than the solve (docs/performance.md). The same checks of the result, with |A|_1 from
    dlange("1") as scipy takes it:
    LinAlgError for a singular matrix, LinAlgWarning when the reciprocal condition number is below eps."""
    if spd:
        factor, solution, info = _dposv(matrix, rhs)
        if info == 0:
            rcond = _dpocon(factor, _dlange("1", matrix))[0]
            if not rcond >= EPSILON:  # `rcond < eps` would miss NaN
                _check_condition(rcond)
            return solution
        if info < 0:
            raise ValueError(f"LAPACK reported an illegal value in {-info}-th argument.")
    factor, _, solution, info = _dgesv(matrix, rhs)
    if info < 0:
        raise ValueError(f"LAPACK reported an illegal value in {-info}-th argument.")
    if info > 0:
        raise np.linalg.LinAlgError("Matrix is singular.")
    rcond = _dgecon(factor, _dlange("1", matrix))[0]
    if not rcond >= EPSILON:
        _check_condition(rcond)
    return solution


# the LAPACK wrappers bound once: attribute lookups are a visible share of a small system's 2x2 solve
_dposv, _dpocon, _dgesv, _dgecon, _dlange = (scipy.linalg.lapack.dposv, scipy.linalg.lapack.dpocon,
                                             scipy.linalg.lapack.dgesv, scipy.linalg.lapack.dgecon,
                                             scipy.linalg.lapack.dlange)


def _check_condition(rcond: float) -> None:
    """Called when rcond < eps or NaN: LinAlgError for a singular matrix, else scipy's LinAlgWarning."""
    if rcond == 0:
        raise np.linalg.LinAlgError("Matrix is singular.")
    if not rcond >= EPSILON:  # `rcond < eps` would miss NaN
        warnings.warn(f"Ill-conditioned matrix (rcond={rcond:.6g}): result may not be accurate.",
                      scipy.linalg.LinAlgWarning, stacklevel=4)


class ConjugateGradient(ReducedSolver):
    """Conjugate gradients (Hestenes & Stiefel 1952) through scipy.sparse.linalg.cg; SPD matrices.

    In exact arithmetic CG ends after at most k iterations on a matrix with k distinct eigenvalues."""

    name = "cg"

    def _preconditioner(self, matrix):
        return None

    def _solve(self, matrix, rhs, spd):
        count = 0

        def counted(_):
            nonlocal count
            count += 1

        solution, _ = scipy.sparse.linalg.cg(matrix, rhs, rtol=self.tolerance, atol=0.0, maxiter=self.max_iterations,
                                             M=self._preconditioner(matrix), callback=counted)
        return solution, count


class JacobiPCG(ConjugateGradient):
    """CG preconditioned with the diagonal of A (Jacobi preconditioner), through scipy.sparse.linalg.cg."""

    name = "pcg"

    def _preconditioner(self, matrix):
        inverse = _inverse_diagonal(matrix)
        return scipy.sparse.linalg.LinearOperator(matrix.shape, matvec=lambda r: inverse * r.ravel(), dtype=float)


class ModifiedPCG(LinearSolver):
    """The modified PCG of Baraff & Witkin ("Large steps in cloth simulation", SIGGRAPH 1998, sec. 5.3).

    CG with the Jacobi preconditioner on the full system, every search direction and residual passed
    through the constraint filter S: zero on fixed dofs (a pinned vertex, or a component removed along a
    coordinate axis) and the 3x3 (2x2) projector S_i = I - n n^T or u u^T of a vertex that slides in a
    plane or along a line in an oblique direction. Stops on the filtered residual,
    |S(b - A p)|_2 <= tolerance |S b|_2 (the 2-norm test of the other CG solvers, where Baraff & Witkin
    use the preconditioned norm).

    ``start``: ``zero`` starts from p_0 = z (the constrained components' values, here 0: a Newton
    direction never moves a constrained component), Baraff & Witkin's choice; ``filtered`` starts from
    p_0 = S g + (I - S) z with g the caller's guess (a Newton solver passes the step towards the
    method's inertial predictor, y~ - y, at the first iteration of a step), the start that Ascher &
    Boxerman ("On the modified conjugate gradient method in cloth simulation", The Visual Computer 19,
    2003) show keeps MPCG equivalent to PCG on the constrained subspace and report 25-50 % faster.
    """

    name = "mpcg"

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 1000, start: str = "zero"):
        super().__init__(tolerance, max_iterations)
        if start not in MPCG_STARTS:
            raise ValueError(f"mpcg start must be one of {', '.join(MPCG_STARTS)}, got {start!r}")
        self.start = start

    @property
    def wants_guess(self) -> bool:
        return self.start == "filtered"

    def solve(self, matrix, rhs, free, spd=False, guess=None):
        weights = None if free.all_free else free.filter_weights
        sliding = free.sliding

        def filtered(vector):
            vector = vector if weights is None else vector * weights
            return vector if sliding is None else sliding.apply(vector)

        inverse = _inverse_diagonal(matrix)
        residual = filtered(np.array(rhs, dtype=float))  # S b
        target = self._target(residual)
        if guess is not None and self.start == "filtered":
            solution = filtered(np.array(guess, dtype=float))  # S g + (I - S) z, z = 0
            residual = filtered(rhs - matrix @ solution)  # S (b - A p_0)
        else:
            solution = np.zeros_like(rhs, dtype=float)  # p_0 = z: satisfies the constraints exactly
        direction = filtered(inverse * residual)
        delta = float(residual @ direction)
        iterations = 0
        while float(np.linalg.norm(residual)) > target and iterations < self.max_iterations:
            product = filtered(matrix @ direction)
            curvature = float(direction @ product)
            if not curvature > 0.0:  # breakdown: A is not positive definite on the free subspace
                if iterations == 0:
                    raise np.linalg.LinAlgError("mpcg: the matrix is not positive definite on the free dofs")
                break
            alpha = delta / curvature
            solution += alpha * direction
            residual -= alpha * product
            iterations += 1
            preconditioned = inverse * residual
            delta_old, delta = delta, float(residual @ preconditioned)
            direction = filtered(preconditioned + (delta / delta_old) * direction)
        return solution, iterations


MPCG_STARTS = ("zero", "filtered")


class Jacobi(ReducedSolver):
    """The Jacobi iteration p_{k+1} = p_k + D^{-1} (b - A p_k), D = diag(A).

    Converges iff the spectral radius of I - D^{-1} A is below 1 (e.g. strictly diagonally dominant
    A), at that rate; raises LinAlgError when the residual grows past DIVERGED_FACTOR |b| (Saad,
    "Iterative Methods for Sparse Linear Systems", sec. 4.1)."""

    name = "jacobi"

    def _solve(self, matrix, rhs, spd):
        inverse = _inverse_diagonal(matrix)
        return self._stationary(matrix, rhs, lambda residual: inverse * residual)


class GaussSeidel(ReducedSolver):
    """Forward Gauss-Seidel p_{k+1} = p_k + (D + L)^{-1} (b - A p_k), L the strictly lower part of A.

    Converges for SPD and for strictly diagonally dominant A (Saad, sec. 4.1). Each sweep is one sparse triangular
    solve: the lower triangle factored once per linear solve by SuperLU in natural order without pivoting (its factors
    are the triangle itself), faster than spsolve_triangular's per-call copies (docs/performance.md); dense: LAPACK's."""

    name = "gauss_seidel"

    def _solve(self, matrix, rhs, spd):
        if scipy.sparse.issparse(matrix):
            lower = scipy.sparse.tril(matrix, format="csc")
            triangle = scipy.sparse.linalg.splu(lower, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                                                options=dict(SymmetricMode=True))
            sweep = triangle.solve
        else:
            lower = np.tril(matrix)

            def sweep(residual):
                return scipy.linalg.solve_triangular(lower, residual, lower=True, check_finite=False)

        return self._stationary(matrix, rhs, sweep)


class MulticolourGaussSeidel(ReducedSolver):
    """Gauss-Seidel over a colouring of the rows (multicolour.py): the forward sweep in colour order, each colour's rows
    in parallel, compiled; the colouring made once per sparsity pattern. It is forward Gauss-Seidel on P A P^T (P the
    colour order), so it converges where that does (SPD A, strictly diagonally dominant A)."""

    name = "multicolour_gauss_seidel"
    _colouring = None  # the last pattern's (multicolour.Colouring.of)

    def _solve(self, matrix, rhs, spd):
        from .multicolour import Colouring

        matrix = scipy.sparse.csr_matrix(matrix)
        matrix.sort_indices()
        colouring = self._colouring = Colouring.of(matrix, self._colouring)
        ordered, order, correction = colouring.ordered(matrix), colouring.rows, np.empty_like(rhs)
        diagonal = _safe_diagonal(ordered)
        solution, iterations = self._stationary(ordered, rhs[order], lambda r: colouring.forward(ordered, diagonal, r, correction))
        return solution[np.argsort(order)], iterations


# config name -> class; each is built with (tolerance, max_iterations)
LINEAR_SOLVERS: dict[str, type[LinearSolver]] = {
    cls.name: cls for cls in (DirectSolver, CholeskySolver, ConjugateGradient, JacobiPCG, ModifiedPCG, Jacobi,
                              GaussSeidel, MulticolourGaussSeidel)
}
