"""Free degrees of freedom: index arrays built once per fixed_dofs, restriction maps once per sparsity pattern."""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse


class FreeDofs:
    """The free degrees of freedom of an n-vector, and restriction of vectors and matrices to them.

    Index arrays are built once (``free_dofs`` caches one object per (n, fixed_dofs)); the map from a
    CSR matrix's entries to those of its restriction is built once per sparsity pattern and reused
    while the pattern stays the same (the cloth refills one fixed pattern every step).
    """

    def __init__(self, size: int, fixed: np.ndarray, sliding=None):
        self.size = size
        # filters of vertices that slide along directions that are not coordinate axes (a SlidingFilter of
        # systems/constraints.py, or None): applied to every vector after the fixed dofs are zeroed, and
        # to the Newton matrix as S A S + (I - S) before it is restricted
        self.sliding = sliding
        self.fixed = np.unique(np.asarray(fixed, dtype=np.intp))
        self.mask = np.ones(size, dtype=bool)
        self.mask[self.fixed] = False
        self.index = np.flatnonzero(self.mask)
        self.count = self.index.size
        self.all_free = self.fixed.size == 0 and sliding is None
        self.filter_weights = self.mask.astype(float)  # S of Baraff & Witkin: 1 on free, 0 on fixed dofs
        self._dense_index = np.ix_(self.index, self.index)
        self._pattern = None  # (indptr, indices, kept entries, reduced indptr, reduced indices)

    def zero_fixed(self, vector: np.ndarray) -> np.ndarray:
        """S vector (in place): the fixed entries set to zero and the sliding vertices' blocks projected."""
        if not self.all_free:
            vector[self.fixed] = 0.0
            if self.sliding is not None:
                self.sliding.apply(vector)
        return vector

    def filter_matrix(self, matrix):
        """S A S + (I - S) where vertices slide along oblique directions (A itself otherwise): its solution
        on the free dofs moves the sliding vertices only along their allowed directions."""
        return matrix if self.sliding is None else self.sliding.filter_matrix(matrix)

    def restrict(self, vector: np.ndarray) -> np.ndarray:
        return vector if self.fixed.size == 0 else vector[self.index]

    def extend(self, reduced: np.ndarray) -> np.ndarray:
        """A full vector with ``reduced`` on the free entries and zeros on the fixed ones."""
        if self.fixed.size == 0:
            return reduced
        full = np.zeros(self.size, dtype=reduced.dtype)
        full[self.index] = reduced
        return full

    def restrict_matrix(self, matrix):
        """The free rows and columns of a dense array or a scipy sparse matrix (CSR for sparse ones)."""
        if not scipy.sparse.issparse(matrix):
            matrix = np.asarray(matrix, dtype=float)
            return matrix if self.fixed.size == 0 else matrix[self._dense_index]
        matrix = matrix.tocsr()
        if self.fixed.size == 0:
            return matrix
        _, _, kept, reduced_indptr, reduced_indices = self._pattern_of(matrix)
        return scipy.sparse.csr_matrix((matrix.data[kept], reduced_indices, reduced_indptr),
                                       shape=(self.count, self.count))

    def _pattern_of(self, matrix):
        pattern = self._pattern
        if (pattern is not None and np.array_equal(pattern[0], matrix.indptr)
                and np.array_equal(pattern[1], matrix.indices)):  # O(nnz) compares: far cheaper than a rebuild
            return pattern
        rows = np.repeat(np.arange(self.size), np.diff(matrix.indptr))
        kept = np.flatnonzero(self.mask[rows] & self.mask[matrix.indices])
        new_index = np.cumsum(self.mask) - 1  # old index -> index among the free dofs
        counts = np.bincount(new_index[rows[kept]], minlength=self.count)
        reduced_indptr = np.concatenate([[0], np.cumsum(counts)]).astype(matrix.indptr.dtype)
        reduced_indices = new_index[matrix.indices[kept]].astype(matrix.indices.dtype)
        # copies: a caller may refill or reuse its index arrays for another pattern
        pattern = (matrix.indptr.copy(), matrix.indices.copy(), kept, reduced_indptr, reduced_indices)
        self._pattern = pattern  # one assignment: a concurrent reader sees the old or the new map whole
        return pattern


@functools.lru_cache(maxsize=16)
def _free_dofs_cached(size: int, fixed_bytes: bytes, sliding) -> FreeDofs:
    return FreeDofs(size, np.frombuffer(fixed_bytes, dtype=np.intp), sliding)


def free_dofs(size: int, fixed_dofs, sliding=None) -> FreeDofs:
    """The (cached) FreeDofs of an n-vector with these fixed degrees of freedom and sliding filters
    (a SlidingFilter is hashed by identity: one per system)."""
    fixed = np.ascontiguousarray(np.asarray(fixed_dofs if fixed_dofs is not None else [], dtype=np.intp))
    return _free_dofs_cached(size, fixed.tobytes(), sliding)
