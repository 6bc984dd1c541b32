"""The energy density of one element of a solid, whatever its material: psi(F), the stress P = dpsi/dF and the tangent
A = d^2 psi / dF^2 (flattened row-major, F_ij -> i d + j), Lame mu and lambda given. Each material's formulas are in
its module (materials/; docs/fem.md lists them), chosen by its code ``model`` (materials/dispatch.py):

- LINEAR:      mu eps:eps + lambda/2 tr(eps)^2, eps = (F + F^T)/2 - I
- COROTATED:   mu ||F - R||^2 + lambda/2 (J - 1)^2 (Stomakhin et al. 2012), R from the polar decomposition
- STVK:        mu E:E + lambda/2 tr(E)^2, E = (F^T F - I)/2
- NEO_HOOKEAN: mu/2 (tr(F^T F) - d) - mu ln J + lambda/2 (ln J)^2 (infinite for J <= 0)
- STABLE_NEO_HOOKEAN: mu/2 (I_C - d) + lambda/2 (J - alpha)^2 - mu/2 ln(I_C + 1), alpha = 1 + mu d / ((d + 1) lambda)
  (Smith, de Goes & Kim 2018), less its constant value at rest; mu and lambda already re-parametrised by the caller
  (materials' ``energy_parameters``)
"""

from __future__ import annotations

import numba

from ..compiled_cache import keep_fresh
from .materials.dispatch import COROTATED, LINEAR, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK, energy_terms

# the codes ``model`` takes, as the callers of ``material_terms`` name them
__all__ = ["COROTATED", "LINEAR", "NEO_HOOKEAN", "STABLE_NEO_HOOKEAN", "STVK", "WORK_SLOTS", "material_terms"]

# (d, d) scratch matrices of material_terms: cofactor or strain, stress, F F^T; the co-rotated SVD's U, V, R, S, sigma
WORK_SLOTS = 6


@numba.njit(cache=True)
def material_terms(model, F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P = dpsi/dF into P (d, d), and with want_tangent A = d^2 psi / dF^2 into A (d^2, d^2); work
    (WORK_SLOTS, d, d) is scratch (the cofactor, Green's strain and its stress, the SVD), so that an element
    allocates nothing."""
    for i in range(d):
        for j in range(d):
            P[i, j] = 0.0
    if want_tangent:
        for a in range(d * d):
            for b in range(d * d):
                A[a, b] = 0.0
    return energy_terms(model, F, d, mu, lam, P, A, want_tangent, work)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
