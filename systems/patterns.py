"""Sparse-matrix and graph helpers the systems and the integrators share: sums that keep a CSR pattern's stored
zeros, a matrix's vertex blocks, and the vertex colouring of vertex block descent."""

from __future__ import annotations

import numpy as np
import scipy.sparse


def add_keeping_pattern(matrix, *terms):
    """matrix + sum(terms) as a CSR matrix that keeps every stored entry of each, zeros included: scipy's sparse
    sum drops explicit zeros, and a pattern that loses them reorders worse (MMD on the 24 x 24 cloth: 3x the
    fill-in of the fixed pattern, 8x the factorisation time)."""
    parts = [scipy.sparse.coo_matrix(part) for part in (matrix, *terms)]
    return scipy.sparse.csr_matrix((np.concatenate([part.data for part in parts]),
                                    (np.concatenate([part.row for part in parts]), np.concatenate([part.col for part in parts]))),
                                   shape=matrix.shape)


def diagonal_blocks(matrix, vertices: np.ndarray, dim: int) -> np.ndarray:
    """The dim x dim diagonal blocks of a dense array or scipy sparse matrix at ``vertices``: shape (k, dim, dim)."""
    offsets = np.arange(dim)
    first = (dim * np.asarray(vertices, dtype=np.intp))[:, None, None]
    rows = np.broadcast_to(first + offsets[None, :, None], (len(vertices), dim, dim)).ravel()
    cols = np.broadcast_to(first + offsets[None, None, :], (len(vertices), dim, dim)).ravel()
    if scipy.sparse.issparse(matrix):
        values = np.asarray(matrix.tocsr()[rows, cols], dtype=float).ravel()
    else:
        values = np.asarray(matrix, dtype=float)[rows, cols]
    return values.reshape(len(vertices), dim, dim)


def colour_vertices(vertex_count: int, pairs: np.ndarray) -> list[np.ndarray]:
    """A greedy colouring of the graph on ``vertex_count`` vertices with edges ``pairs`` ((m, 2) vertex indices;
    pairs (i, i) are ignored): one sorted index array per colour, no two vertices of a colour joined by an edge.
    networkx's ``greedy_color`` with the largest-first order (Welsh & Powell 1967): at most max degree + 1 colours."""
    import networkx  # here, not at the top: the command line starts without it, and only VBD colours vertices

    pairs = np.sort(np.asarray(pairs, dtype=np.intp).reshape(-1, 2), axis=1)
    pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)
    graph = networkx.Graph()
    graph.add_nodes_from(range(vertex_count))
    graph.add_edges_from(pairs.tolist())
    colour_of = networkx.greedy_color(graph, strategy="largest_first")
    colours = np.array([colour_of[vertex] for vertex in range(vertex_count)], dtype=np.intp)
    return [np.flatnonzero(colours == colour) for colour in range(int(colours.max(initial=-1)) + 1)]
