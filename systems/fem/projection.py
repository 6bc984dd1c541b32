"""The SPD projection of an element's tangent A = d^2 psi / dF^2 from the analytic eigensystems of the isotropic
energies (Smith, de Goes & Kim 2019, "Analytic eigensystems for isotropic distortion energies"; docs/fem.md): the
eigenvalues from the singular values in closed form, the eigenvectors from the signed SVD (linalg.py), and only the
negative modes changed, as low-rank updates of the exact tangent."""

from __future__ import annotations

import math

import numba
import numpy as np

from ..compiled_cache import keep_fresh
from .linalg import (_closed_form_eigenvalues, _positive_definite_small, _signed_svd, _singular_values, _symmetric_eigen,
                     largest_magnitude, rank_one_update)
from .materials.dispatch import pair_eigenvalues, positive_semidefinite_everywhere, singular_hessian

# A + PSD_SHIFT max|lambda| I: eigenvalues above -PSD_SHIFT of the largest count as 0 (round-off: the rotation-invariant
# energies' tangent is singular at rest, where rigid rotations cost nothing), and leave the exact tangent as it is
PSD_SHIFT = 1e-12
# an element whose tangent's lowest eigenvalue, from the closed-form singular values, is above this fraction of the
# largest is PSD whatever their round-off: it skips the SVD (the singular values' error is far below this)
SCREEN_MARGIN = 1e-6
@numba.njit(cache=True)
def projection_scratch(d):
    """The arrays one element's projection works in, made once per chunk: U, V, S (d, d) of the SVD, sigma (d,), H
    and its eigenvectors (d, d), their eigenvalues (d,), the pairs' flip and twist eigenvalues (3, 2), the tangent's
    eigenvalues (d^2,) and one eigenvector (d^2,)."""
    return (np.empty((d, d)), np.empty((d, d)), np.empty((d, d)), np.empty(d), np.empty((d, d)), np.empty((d, d)),
            np.empty(d), np.empty((3, 2)), np.empty(d * d), np.empty(d * d))


@numba.njit(cache=True)
def _singular_terms(model, sigma, d, mu, lam, H, pairs):
    """psi as a function of the signed singular values: H = d^2 psi / d sigma^2 into H (d, d), and per pair (i, j),
    i < j in the order (0, 1), (0, 2), (1, 2), the tangent's two eigenvalues on the pair's "flip" (symmetric,
    (psi_i - psi_j) / (sigma_i - sigma_j)) and "twist" (antisymmetric, (psi_i + psi_j) / (sigma_i + sigma_j)) modes
    into pairs (pair, 2), each quotient written out per energy (its material's module) so that it has no cancellation
    at sigma_i = sigma_j (Smith, de Goes & Kim 2019, "Analytic eigensystems for isotropic distortion energies"). False
    for an element where the energy is undefined (neo-Hookean at J <= 0)."""
    J = 1.0
    for m in range(d):
        J *= sigma[m]
    if not singular_hessian(model, sigma, d, J, mu, lam, H):
        return False
    pair = 0
    for i in range(d):
        for j in range(i + 1, d):
            third = 1.0 if d == 2 else sigma[3 - i - j]
            si, sj = sigma[i], sigma[j]
            flip, twist = pair_eigenvalues(model, sigma, d, si, sj, third, J, mu, lam)
            pairs[pair, 0], pairs[pair, 1] = flip, twist
            pair += 1
    return True


@numba.njit(cache=True)
def project_tangent(model, F, d, mu, lam, A, mode, scratch):
    """The exact tangent A = d^2 psi / dF^2 at F made PSD in place, its negative eigenvalues clamped to 0 (mode 1) or
    mirrored (mode 2); True where it had any below -PSD_SHIFT of the largest, False where it was left as it is.
    From the analytic eigensystem of an isotropic energy: with F = U diag(sigma) V^T, d scaling modes U diag(z) V^T
    (z the eigenvectors of d^2 psi / d sigma^2) and per pair of singular values a flip and a twist mode,
    U (e_i e_j^T +- e_j e_i^T) V^T / sqrt 2 (``_singular_terms``). Only the negative modes' eigenvectors are formed,
    as a low-rank update A + (lambda' - lambda) q q^T of each. Mode 0 and the energies whose tangent is PSD at every F
    (linear elasticity's, constant, for every nu in (-1, 0.5)) never project."""
    if mode == 0 or positive_semidefinite_everywhere(model):
        return False
    U, V, S, sigma, H, Z, curvatures, pairs, values, vector = scratch
    # screening: the eigenvalues need the singular values alone, which the closed form gives at a fraction of the
    # SVD's cost; an element clearly PSD by them (the lowest above SCREEN_MARGIN of the largest) is left as it is
    _singular_values(F, d, S, sigma)
    if not _singular_terms(model, sigma, d, mu, lam, H, pairs):
        return False
    _closed_form_eigenvalues(H, d, curvatures)
    lowest, largest = curvatures[d - 1], max(abs(curvatures[0]), abs(curvatures[d - 1]))
    for pair in range(d * (d - 1) // 2):
        lowest = min(lowest, pairs[pair, 0], pairs[pair, 1])
        largest = max(largest, abs(pairs[pair, 0]), abs(pairs[pair, 1]))
    if lowest > SCREEN_MARGIN * largest:
        return False
    _signed_svd(F, d, U, sigma, V, S)
    _singular_terms(model, sigma, d, mu, lam, H, pairs)
    if _positive_definite_small(H, d):  # no scaling mode to project: no eigenvectors; the trace bounds the largest
        trace = 0.0
        for k in range(d):
            trace += H[k, k]
        for k in range(d):
            curvatures[k] = trace
    else:
        _symmetric_eigen(H, d, curvatures, Z)
    size = d * d
    for k in range(d):
        values[k] = curvatures[k]
    for pair in range(d * (d - 1) // 2):
        values[d + 2 * pair], values[d + 2 * pair + 1] = pairs[pair, 0], pairs[pair, 1]
    largest = largest_magnitude(values, size)
    changed = False
    for k in range(size):
        if values[k] >= -PSD_SHIFT * largest:
            continue
        changed = True
        # the mode's eigenvector, flattened as A is (F_ij -> i d + j)
        if k < d:
            for i in range(d):
                for j in range(d):
                    value = 0.0
                    for m in range(d):
                        value += Z[m, k] * U[i, m] * V[j, m]
                    vector[i * d + j] = value
        else:
            pair, sign = (k - d) // 2, (1.0 if (k - d) % 2 == 0 else -1.0)
            a, b = (0, 1) if pair == 0 else ((0, 2) if pair == 1 else (1, 2))
            for i in range(d):
                for j in range(d):
                    vector[i * d + j] = math.sqrt(0.5) * (U[i, a] * V[j, b] + sign * U[i, b] * V[j, a])
        rank_one_update(A, size, -values[k] if mode == 1 else -2.0 * values[k], vector)  # to 0, or to -lambda
    return changed


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
