"""Which material's kernel runs: the only place the kernels tell materials apart. A material is a code (the int the
element loops and the sweeps take as ``model``); each operation below is one small compiled function whose chain of
``if model == ...`` picks that material's own function (its module in this package). numba compiles one function for
every code, so the choice is a branch on an int, not a call through a table.

Every function is inlined into its caller (``inline="always"``), so that the caller compiles to what it did when the
branches were written in it, but ``membrane_change``, a call of its own in the shell's sweep as before. Each chain
ends on a material without a test: the others return before, and a model that has no such operation never gets here
(its caller asks the capability functions first, or the registry refused it: materials/__init__.py).
"""

from __future__ import annotations

import numba

from ...compiled_cache import keep_fresh
from . import corotated, linear, neo_hookean, stable_neo_hookean, stvk

# the kernels' code of each material (MATERIALS in materials/__init__.py names them)
LINEAR, COROTATED, STVK, NEO_HOOKEAN, STABLE_NEO_HOOKEAN = range(5)


# -- what a material's kernels offer -----------------------------------------------------------------------------
@numba.njit(cache=True, inline="always")
def positive_semidefinite_everywhere(model):
    """Whether the tangent is PSD at every F, so that the SPD projection never changes it (projection.py skips it)."""
    return model == LINEAR


@numba.njit(cache=True, inline="always")
def vertex_terms_from_invariants(model):
    """Whether a solid vertex's terms are written through J and I_C (``invariant_coefficients``, ``invariant_change``:
    tet_terms.py, and the 3-D sweep in scalars); the others' through ``vertex_stiffness`` and
    ``vertex_energy_change``."""
    return model == NEO_HOOKEAN or model == STABLE_NEO_HOOKEAN


@numba.njit(cache=True, inline="always")
def vertex_stiffness_needs_tangent(model):
    """Whether ``vertex_stiffness`` contracts the exact tangent A, which the caller then computes first."""
    return model == COROTATED


# -- an element of a solid: psi, P, A and the SPD projection's eigensystem --------------------------------------------
@numba.njit(cache=True, inline="always")
def energy_terms(model, F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P = dpsi/dF into P (d, d), with want_tangent A = d^2 psi / dF^2 into A (d^2, d^2); P and A zeroed
    by the caller (energies.py ``material_terms``), work (WORK_SLOTS, d, d) scratch."""
    if model == LINEAR:
        return linear.energy_terms(F, d, mu, lam, P, A, want_tangent, work)
    if model == STVK:
        return stvk.energy_terms(F, d, mu, lam, P, A, want_tangent, work)
    if model == NEO_HOOKEAN:
        return neo_hookean.energy_terms(F, d, mu, lam, P, A, want_tangent, work)
    if model == COROTATED:
        return corotated.energy_terms(F, d, mu, lam, P, A, want_tangent, work)
    return stable_neo_hookean.energy_terms(F, d, mu, lam, P, A, want_tangent, work)


@numba.njit(cache=True, inline="always")
def singular_hessian(model, sigma, d, J, mu, lam, H):
    """psi as a function of the signed singular values sigma (J their product): d^2 psi / d sigma^2 into H (d, d);
    False where the energy is undefined (projection.py)."""
    if model == NEO_HOOKEAN:
        return neo_hookean.singular_hessian(sigma, d, J, mu, lam, H)
    if model == STABLE_NEO_HOOKEAN:
        return stable_neo_hookean.singular_hessian(sigma, d, J, mu, lam, H)
    if model == COROTATED:
        return corotated.singular_hessian(sigma, d, J, mu, lam, H)
    return stvk.singular_hessian(sigma, d, J, mu, lam, H)


@numba.njit(cache=True, inline="always")
def pair_eigenvalues(model, sigma, d, si, sj, third, J, mu, lam):
    """(flip, twist): the tangent's eigenvalues on the pair (si, sj)'s symmetric and antisymmetric modes,
    (psi_i - psi_j) / (si - sj) and (psi_i + psi_j) / (si + sj), each written out without cancellation at si = sj;
    third: the third singular value (1 in 2-D)."""
    if model == NEO_HOOKEAN:
        return neo_hookean.pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam)
    if model == STABLE_NEO_HOOKEAN:
        return stable_neo_hookean.pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam)
    if model == COROTATED:
        return corotated.pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam)
    return stvk.pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam)


# -- a shell's membrane triangle (3 x 2 F) -----------------------------------------------------------------------
@numba.njit(cache=True, inline="always")
def membrane_terms(model, F, C, I1, mu, lam, P, A, want_tangent, work):
    """psi of a 3 x 2 F (C = F^T F and I_1 = tr C given), P into P (3, 2), with want_tangent A into A (6, 6); work
    (4, 3, 3) scratch (membrane.py)."""
    if model == STVK:
        return stvk.membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work)
    if model == NEO_HOOKEAN:
        return neo_hookean.membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work)
    if model == COROTATED:
        return corotated.membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work)
    return stable_neo_hookean.membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work)


@numba.njit(cache=True, inline="always")
def membrane_vertex_terms(model, F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K):
    """P n into stress (3,) and K = n^T A n into K (3, 3) of a triangle's 3 x 2 F at its corner with shape gradient
    n = (n0, n1), |n|^2 = squared, C = F^T F's entries given (shell_terms.py)."""
    if model == STVK:
        return stvk.membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K)
    if model == NEO_HOOKEAN:
        return neo_hookean.membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K)
    if model == COROTATED:
        return corotated.membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K)
    return stable_neo_hookean.membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K)


@numba.njit(cache=True, error_model="numpy")
def membrane_change(model, C00, C01, C11, D00, D01, D11, mu, lam):
    """psi(C + dC) - psi(C) of a membrane triangle from C = F^T F and its change dC (2 x 2, symmetric), without
    cancellation (shell_vbd_kernels.py)."""
    if model == STVK:
        return stvk.membrane_change(C00, C01, C11, D00, D01, D11, mu, lam)
    if model == NEO_HOOKEAN:
        return neo_hookean.membrane_change(C00, C01, C11, D00, D01, D11, mu, lam)
    if model == COROTATED:
        return corotated.membrane_change(C00, C01, C11, D00, D01, D11, mu, lam)
    return stable_neo_hookean.membrane_change(C00, C01, C11, D00, D01, D11, mu, lam)


# -- a solid's vertex, for vertex block descent (vbd_kernels.py, tet_terms.py) ------------------------------------
@numba.njit(cache=True, inline="always")
def vertex_stiffness(model, F, n, d, squared, mu, lam, A, K, work):
    """K = n^T A n (d, d) added into K (zeroed by the caller) at F, n the vertex's shape gradient and |n|^2 = squared;
    A the exact tangent where ``vertex_stiffness_needs_tangent``."""
    if model == COROTATED:
        return corotated.vertex_stiffness(F, n, d, squared, mu, lam, A, K, work)
    if model == LINEAR:
        return linear.vertex_stiffness(F, n, d, squared, mu, lam, A, K, work)
    if model == STVK:
        return stvk.vertex_stiffness(F, n, d, squared, mu, lam, A, K, work)
    if model == NEO_HOOKEAN:
        return neo_hookean.vertex_stiffness(F, n, d, squared, mu, lam, A, K, work)
    return stable_neo_hookean.vertex_stiffness(F, n, d, squared, mu, lam, A, K, work)


@numba.njit(cache=True, inline="always")
def vertex_energy_change(model, F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work):
    """psi(F + u n^T) - psi(F) without cancellation, |n|^2, |u|^2 and u . n given, for the materials whose vertex
    terms are not written through the invariants (those take ``invariant_change``)."""
    if model == COROTATED:
        return corotated.vertex_energy_change(F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work)
    if model == LINEAR:
        return linear.vertex_energy_change(F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work)
    return stvk.vertex_energy_change(F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work)


@numba.njit(cache=True, inline="always")
def invariant_coefficients(model, J, invariant, mu, lam, alpha):
    """(shear, stretch, spread, volume_stress, kept) of P n = shear w + volume_stress c and K = shear |n|^2 I +
    stretch w w^T + spread c c^T (w = F n, c = cof(F) n) from J and I_C; kept: what ``invariant_change`` reads
    besides J; alpha: the element's rest volume term (MATERIALS' ``rest_volume_term``, 0 where it has none)."""
    if model == NEO_HOOKEAN:
        return neo_hookean.invariant_coefficients(J, invariant, mu, lam, alpha)
    return stable_neo_hookean.invariant_coefficients(J, invariant, mu, lam, alpha)


@numba.njit(cache=True, inline="always")
def invariant_change(model, J, kept, invariant_change, volume_change, mu, lam, alpha):
    """psi' - psi from the exact changes of I_C and J, kept as ``invariant_coefficients`` left it."""
    if model == NEO_HOOKEAN:
        return neo_hookean.invariant_change(J, kept, invariant_change, volume_change, mu, lam, alpha)
    return stable_neo_hookean.invariant_change(J, kept, invariant_change, volume_change, mu, lam, alpha)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
