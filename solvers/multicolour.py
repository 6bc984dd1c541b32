"""Multicolour Gauss-Seidel, compiled: the rows of a sparse matrix coloured so that no two rows of one
colour are coupled (A_ij = 0 for i != j of one colour), and the forward substitution (D + L) z = r in colour order,
each colour's rows in parallel.

Ordered by colour, the matrix is P A P^T, and Gauss-Seidel on it is forward Gauss-Seidel in that order (Saad,
"Iterative Methods for Sparse Linear Systems", sec. 12.4): L holds the entries of earlier colours. A row depends
only on rows of earlier colours, so a colour's rows are independent: the result does not depend on the thread count.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse
from numba import prange

from ..systems.compiled_cache import keep_fresh


@numba.njit(cache=True)
def greedy_colours(indptr, indices, count):
    """colour[i] for each row: the smallest colour that no coupled earlier row has (rows in their natural order)."""
    colour = np.full(count, -1, dtype=np.int64)
    taken = np.full(count + 1, -1, dtype=np.int64)  # taken[c] == row: colour c is used by a neighbour of row
    for row in range(count):
        for q in range(indptr[row], indptr[row + 1]):
            column = indices[q]
            if column != row and colour[column] >= 0:
                taken[colour[column]] = row
        chosen = 0
        while taken[chosen] == row:
            chosen += 1
        colour[row] = chosen
    return colour


@numba.njit(parallel=True, cache=True)
def forward_substitution(indptr, indices, data, diagonal, starts, residual, out):
    """out = (D + L)^{-1} residual for a matrix ordered by colour (colour c's rows starts[c]:starts[c + 1], columns
    sorted): L is each row's prefix of columns below its colour's first row."""
    for c in range(starts.size - 1):
        first = starts[c]
        for row in prange(starts[c], starts[c + 1]):
            total = residual[row]
            for q in range(indptr[row], indptr[row + 1]):
                column = indices[q]
                if column >= first:
                    break
                total -= data[q] * out[column]
            out[row] = total / diagonal[row]


class Colouring:
    """The colouring of one sparsity pattern (CSR, sorted indices), and the pattern ordered by colour, P A P^T: its
    indptr and indices, and where each of its entries lies in A's data (``gather``), so that a matrix of this pattern
    is put in colour order by one gather of its values. The rows are laid out colour by colour: a sweep reads them
    in one run instead of scattered over the matrix."""

    def __init__(self, matrix):
        self.digest = self.digest_of(matrix)
        self.colour_of = greedy_colours(matrix.indptr, matrix.indices, matrix.shape[0])
        self.rows = np.argsort(self.colour_of, kind="stable")
        self.starts = np.searchsorted(self.colour_of[self.rows], np.arange(int(self.colour_of.max(initial=-1)) + 2))
        positions = scipy.sparse.csr_matrix((np.arange(matrix.nnz, dtype=float), matrix.indices, matrix.indptr),
                                            shape=matrix.shape)
        ordered = positions[self.rows][:, self.rows].tocsr()
        ordered.sort_indices()
        self.indptr, self.indices = ordered.indptr, ordered.indices
        self.gather = ordered.data.astype(np.int64)

    @staticmethod
    def digest_of(matrix) -> int:
        return hash((matrix.shape, matrix.indptr.tobytes(), matrix.indices.tobytes()))

    @classmethod
    def of(cls, matrix, kept: "Colouring | None") -> "Colouring":
        """``kept`` where it is this (CSR, sorted) matrix's pattern's colouring, else a new one: a solver's matrices
        keep one pattern from iteration to iteration and step to step."""
        return kept if kept is not None and kept.digest == cls.digest_of(matrix) else cls(matrix)

    @property
    def count(self) -> int:
        return self.starts.size - 1

    def ordered(self, matrix):
        """P A P^T of a matrix of this pattern (CSR)."""
        return scipy.sparse.csr_matrix((matrix.data[self.gather], self.indices, self.indptr), shape=matrix.shape)

    def forward(self, ordered, diagonal, residual, out):
        """out = (D + L)^{-1} residual of the ordered matrix (``forward_substitution``); returns out."""
        forward_substitution(ordered.indptr, ordered.indices, ordered.data, diagonal, self.starts,
                             np.ascontiguousarray(residual, dtype=float), out)
        return out


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
