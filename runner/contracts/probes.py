"""Where and how the contract checks (``simrun.contracts.system``) measure a system: the generic state, the
probe directions, and measures of matrices (eigenvalue range, asymmetry, negativity) small or large.

Derivatives are compared at the generic state x = x0 + 0.05 L z (L = ``length_scale``, z ~ N(0, I), seeded),
where no symmetry of x0 hides a wrong sign or a missing term. Up to DENSE_LIMIT dofs along every unit vector,
with LAPACK's eigenvalues; above, along PROBE_COUNT seeded random directions, with Lanczos' extreme eigenvalues.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from simrun.systems.base import System

PERTURBATION = 0.05  # of the length scale: springs stay far from zero length, an orbit far from its centre
SEED = 20240607
DENSE_LIMIT = 400  # dof: above, derivatives are probed along random directions and eigenvalues found by Lanczos
PROBE_COUNT = 8


# -- the probes --------------------------------------------------------------------------------------------
def generic_state(system: System) -> np.ndarray:
    """x0 + 0.05 L z with a seeded z ~ N(0, I) (m): where the derivatives are compared."""
    z = np.random.default_rng(SEED).standard_normal(system.dof_count)
    return system.x0 + PERTURBATION * system.length_scale * z


def generic_velocity(system: System) -> np.ndarray:
    """v0 + z with a seeded z ~ N(0, I) (m/s), zero on the fixed dofs."""
    v = system.v0 + np.random.default_rng(SEED + 1).standard_normal(system.dof_count)
    v[system.fixed_dofs] = 0.0
    return v


def probes(system: System) -> np.ndarray:
    """Directions (columns) along which derivatives are compared: all unit vectors, or seeded random unit vectors."""
    n = system.dof_count
    if n <= DENSE_LIMIT:
        return np.eye(n)
    directions = np.random.default_rng(SEED + 2).standard_normal((n, PROBE_COUNT))
    return directions / np.linalg.norm(directions, axis=0)


def dense(matrix) -> np.ndarray:
    return matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix, dtype=float)


def max_abs(values) -> float:
    values = np.abs(np.asarray(values, dtype=float))
    return float(values.max()) if values.size else 0.0


def free_dofs(system: System) -> np.ndarray:
    return np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)


def held_dofs(system: System) -> np.ndarray:
    """The fixed dofs that never move: all of them but those of vertices on prescribed paths (which move with
    their path, not by a force)."""
    constraints = getattr(system, "constraints", None)
    moving = constraints.moving_dofs if constraints is not None else ()
    return np.setdiff1d(np.asarray(system.fixed_dofs, dtype=np.intp), moving).astype(np.intp)


def eigenvalue_range(matrix) -> tuple[float, float]:
    """(smallest eigenvalue, largest |eigenvalue|) of a symmetric matrix: LAPACK when small, Lanczos when large."""
    if matrix.shape[0] <= DENSE_LIMIT:
        eigenvalues = np.linalg.eigvalsh(dense(matrix))
        return (float(eigenvalues[0]), float(np.abs(eigenvalues).max())) if eigenvalues.size else (0.0, 0.0)
    operator = scipy.sparse.csr_matrix(matrix)
    largest = float(abs(scipy.sparse.linalg.eigsh(operator, k=1, which="LM", return_eigenvectors=False)[0]))
    # the smallest eigenvalue of A is the largest of the shifted -A + s I, s = |A|: a well separated end for Lanczos
    shifted = scipy.sparse.linalg.eigsh(largest * scipy.sparse.identity(matrix.shape[0]) - operator, k=1, which="LA",
                                        return_eigenvectors=False)[0]
    return largest - float(shifted), largest


def asymmetry(matrix) -> float:
    """max |A - A^T| / max |A| (0 for a zero matrix)."""
    matrix = scipy.sparse.csr_matrix(matrix)
    return max_abs((matrix - matrix.T).data) / max(max_abs(matrix.data), 1e-300)


def negativity(matrix) -> tuple[float, float]:
    """(-smallest eigenvalue / largest |eigenvalue| (<= 0 for PSD), smallest eigenvalue)."""
    smallest, largest = eigenvalue_range(matrix)
    return -smallest / max(largest, 1e-300), smallest


def restricted(matrix, dofs: np.ndarray):
    """The square block of ``matrix`` on the rows and columns ``dofs`` (sparse stays sparse)."""
    if scipy.sparse.issparse(matrix):
        return scipy.sparse.csr_matrix(matrix)[dofs][:, dofs]
    return np.asarray(matrix, dtype=float)[np.ix_(dofs, dofs)]


def relative_error(difference, reference) -> float:
    """max |difference| / max |reference| (the reference's scale floored at 1e-300)."""
    return max_abs(difference) / max(max_abs(reference), 1e-300)
