"""The membrane form of an energy written through the invariants of C = F^T F (F a triangle's 3 x 2 deformation
gradient, membrane.py): psi = f(I_1, J) with I_1 = tr C and J = sqrt(det C), the area ratio. A material whose membrane
is such an f (co-rotated, neo-Hookean, stable neo-Hookean) gives f and its derivatives (psi, f_1, f_J, f_11, f_1J,
f_JJ); what follows from them for every such f is here. With H = dJ/dF = F adj(C) / J and Q = F C^-1 F^T (the
projector onto the deformed triangle's plane):

    P = 2 f_1 F + f_J H,
    A_ijkl = 2 f_1 d_ik d_jl + 4 f_11 F_ij F_kl + 2 f_1J (F_ij H_kl + H_ij F_kl) + f_JJ H_ij H_kl
             + f_J [(H_ij H_kl - H_il H_kj) / J + (d_ik - Q_ik) adj(C)_lj / J],

the last bracket being J's own second derivative; A flattens F_ij (i < 3, j < 2) to 2 i + j. At one corner with shape
gradient n, where (H_ij H_kl - H_il H_kj) contracted with n n vanishes:

    P n = 2 f_1 w + f_J c,
    K = 2 f_1 |n|^2 I + 4 f_11 w w^T + 2 f_1J (w c^T + c w^T) + f_JJ c c^T + f_J (n^T adj(C) n / J) (I - Q),

with w = F n and c = H n. The energy's change when one corner moves follows from the exact changes of I_1 and J
(``invariant_changes``). Every function is inlined into the materials' own."""

from __future__ import annotations

import math

import numba

from ...compiled_cache import keep_fresh

# J below this is taken as this in the terms that divide by it: a triangle collapsed to a segment, where J is not
# differentiable (it is |.|-like across rank 1)
AREA_FLOOR = 1e-12


@numba.njit(cache=True, inline="always")
def area_ratio(C):
    """J = sqrt(det C) of C = F^T F (2 x 2), 0 where round-off leaves det C below 0."""
    determinant = C[0, 0] * C[1, 1] - C[0, 1] * C[1, 0]
    return math.sqrt(max(determinant, 0.0))


@numba.njit(cache=True, inline="always")
def stress_and_tangent(F, C, J, f1, fJ, f11, f1J, fJJ, P, A, want_tangent, work):
    """P into P (3, 2) and with want_tangent A into A (6, 6) from f's derivatives (the module docstring); work[1],
    work[2], work[3] hold adj(C), H and Q."""
    adjugate, H, Q = work[1], work[2], work[3]
    floor = max(J, AREA_FLOOR)
    adjugate[0, 0], adjugate[0, 1], adjugate[1, 0], adjugate[1, 1] = C[1, 1], -C[0, 1], -C[1, 0], C[0, 0]
    for i in range(3):
        for j in range(2):
            H[i, j] = (F[i, 0] * adjugate[0, j] + F[i, 1] * adjugate[1, j]) / floor
            P[i, j] = 2.0 * f1 * F[i, j] + fJ * H[i, j]
    if not want_tangent:
        return
    for i in range(3):
        for k in range(3):
            value = 0.0
            for m in range(2):
                for n in range(2):
                    value += F[i, m] * adjugate[m, n] * F[k, n]
            Q[i, k] = value / (floor * floor)
    for i in range(3):
        for j in range(2):
            for k in range(3):
                for l in range(2):
                    value = (4.0 * f11 * F[i, j] * F[k, l] + 2.0 * f1J * (F[i, j] * H[k, l] + H[i, j] * F[k, l])
                             + fJJ * H[i, j] * H[k, l])
                    curvature = (H[i, j] * H[k, l] - H[i, l] * H[k, j]) / floor
                    curvature += ((1.0 if i == k else 0.0) - Q[i, k]) * adjugate[l, j] / floor
                    value += fJ * curvature
                    if i == k and j == l:
                        value += 2.0 * f1
                    A[2 * i + j, 2 * k + l] = value


@numba.njit(cache=True, inline="always")
def vertex_area_ratio(C00, C01, C11):
    """J = sqrt(det C) of C = [[C00, C01], [C01, C11]], 0 where round-off leaves det C below 0."""
    return math.sqrt(max(C00 * C11 - C01 * C01, 0.0))


@numba.njit(cache=True, inline="always")
def vertex_terms(F, n0, n1, squared, C00, C01, C11, J, f1, fJ, f11, f1J, fJJ, stress, K):
    """P n into stress and K = n^T A n into K at the corner with shape gradient n = (n0, n1), |n|^2 = squared, from f's
    derivatives (the module docstring), with c = F adj(C) n / J and Q = F adj(C) F^T / J^2."""
    floor = max(J, AREA_FLOOR)
    adjoint0, adjoint1 = C11 * n0 - C01 * n1, -C01 * n0 + C00 * n1  # adj(C) n
    curvature = fJ * (n0 * adjoint0 + n1 * adjoint1) / floor
    for i in range(3):
        w_i = F[i, 0] * n0 + F[i, 1] * n1
        c_i = (F[i, 0] * adjoint0 + F[i, 1] * adjoint1) / floor
        stress[i] = 2.0 * f1 * w_i + fJ * c_i
        for k in range(i, 3):
            w_k = F[k, 0] * n0 + F[k, 1] * n1
            c_k = (F[k, 0] * adjoint0 + F[k, 1] * adjoint1) / floor
            plane = (C11 * F[i, 0] * F[k, 0] - C01 * (F[i, 0] * F[k, 1] + F[i, 1] * F[k, 0])
                     + C00 * F[i, 1] * F[k, 1]) / (floor * floor)  # Q_ik
            value = (4.0 * f11 * w_i * w_k + 2.0 * f1J * (w_i * c_k + c_i * w_k) + fJJ * c_i * c_k
                     - curvature * plane)
            if i == k:
                value += 2.0 * f1 * squared + curvature
            K[i, k] = K[k, i] = value


@numba.njit(cache=True, inline="always")
def invariant_changes(C00, C01, C11, D00, D01, D11):
    """(I_1, its change, J, J after the change, J's change) for C and its change dC (2 x 2, symmetric): tr dC, and J'
    - J = (det C' - det C) / (J' + J) with det C' - det C = tr(adj(C) dC) + det(dC), without cancellation."""
    invariant, invariant_change = C00 + C11, D00 + D11
    determinant = C00 * C11 - C01 * C01
    determinant_change = C11 * D00 + C00 * D11 - 2.0 * C01 * D01 + (D00 * D11 - D01 * D01)
    J = math.sqrt(max(determinant, 0.0))
    moved = math.sqrt(max(determinant + determinant_change, 0.0))
    if determinant >= 0.0 and determinant + determinant_change >= 0.0:
        J_change = determinant_change / (J + moved) if J + moved > 0.0 else 0.0
    else:
        J_change = moved - J
    return invariant, invariant_change, J, moved, J_change


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
