"""A Newton matrix factorised once and kept across iterations and steps (``solver.refactor: adaptive``).

Per iteration of a cloth step, Newton assembles the Hessian and factorises it; the factorisation is the cost
(docs/performance.md). Newton with a lagged matrix (the chord or "modified Newton" method, Kelley, "Iterative
Methods for Linear and Nonlinear Equations", SIAM 1995, ch. 5.4; Shamanskii's method) reuses the last
factorisation for as long as it still pays: each iteration then costs a gradient and two triangular solves, the
convergence is linear at the rate |I - A_lag^-1 H|, and the solver refactors at the current iterate when that rate
is worse than ``refactor_rate`` (the residual fell by less than that factor in an iteration), when the lagged
direction does not descend, or when the free dofs change. Successive steps of a run have nearly the same matrix
M + s K(x), so one factorisation serves many steps.

``preconditioned_solve`` uses the kept factorisation as the preconditioner of conjugate gradients on the current
matrix instead (``solver.refactor: preconditioner``, Newton-Krylov): Newton's directions to a relative residual,
refactorised when the preconditioned iteration needs too many steps.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from .dofs import FreeDofs
from .linear import FactorisationLog, sparse_lu


class LaggedFactor:
    """The factorisation of one Newton matrix restricted to its free dofs; ``solve(rhs)`` -> p with p = 0 on fixed
    dofs, as a linear solver's."""

    def __init__(self, matrix, free: FreeDofs, spd: bool, log: FactorisationLog | None = None):
        self.free = free
        reduced = free.restrict_matrix(free.filter_matrix(matrix))
        if scipy.sparse.issparse(reduced):
            reduced = reduced.tocsr()
            if not reduced.has_sorted_indices:
                reduced = reduced.sorted_indices()
            # CSR arrays read as CSC: the transpose, factored and solved with trans="T" (as the direct solver does)
            transposed = scipy.sparse.csc_matrix((reduced.data, reduced.indices, reduced.indptr), shape=reduced.shape)
            factor = sparse_lu(transposed, spd, log=log)[0]
            self._solve = lambda rhs: factor.solve(rhs, trans="T")
        else:
            lu = scipy.linalg.lu_factor(np.asarray(reduced, dtype=float), check_finite=False)
            self._solve = lambda rhs: scipy.linalg.lu_solve(lu, rhs, check_finite=False)

    def fits(self, free: FreeDofs) -> bool:
        """Is it the factorisation of a matrix on these free dofs?"""
        return free is self.free or (free.size == self.free.size and np.array_equal(free.fixed, self.free.fixed)
                                     and free.sliding is None and self.free.sliding is None)

    def preconditioned_solve(self, matrix, rhs: np.ndarray, tolerance: float, limit: int) -> tuple[np.ndarray | None, int]:
        """A p = rhs on the free dofs by conjugate gradients (scipy's cg) preconditioned with this factorisation, to
        |r| <= tolerance |rhs|; (p, iterations), or (None, iterations) when it needs more than ``limit``."""
        reduced = self.free.restrict(rhs)
        if reduced.size == 0:
            return np.zeros_like(rhs), 0
        operator = self.free.restrict_matrix(self.free.filter_matrix(matrix))
        count = [0]

        def counted(_):
            count[0] += 1

        preconditioner = scipy.sparse.linalg.LinearOperator(operator.shape, matvec=lambda vector: self._solve(
            np.ascontiguousarray(vector)), dtype=float)
        solution, info = scipy.sparse.linalg.cg(operator, reduced, rtol=tolerance, atol=0.0, maxiter=limit,
                                                M=preconditioner, callback=counted)
        if info != 0:
            return None, count[0]
        return self.free.extend(solution), count[0]

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        reduced = self.free.restrict(rhs)
        if reduced.size == 0:
            return np.zeros_like(rhs)
        return self.free.extend(self._solve(np.ascontiguousarray(reduced)))


__all__ = ["LaggedFactor"]
