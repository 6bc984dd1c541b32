"""St. Venant-Kirchhoff: psi = mu E:E + lambda/2 tr(E)^2, E = (F^T F - I)/2 (docs/fem.md, "Energies"); a shell's
membrane takes the same psi of its 3 x 2 F, E = (C - I)/2 with C = F^T F (2 x 2).

Everything here is written in Green's strain E and its stress S = 2 mu E + lambda tr(E) I, so P = F S and
dP_ij/dF_kl = delta_ik S_lj + mu (F_il F_kj + (F F^T)_ik delta_lj) + lambda F_ij F_kl, for a solid and a membrane
alike. In the signed singular values, E = diag(sigma^2 - 1)/2. Each function is inlined into the dispatch
(dispatch.py)."""

from __future__ import annotations

import numba

from ...compiled_cache import keep_fresh


@numba.njit(cache=True, inline="always")
def energy_terms(F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3), P into P and with want_tangent A into A (every entry); work[0], work[1], work[2]: E, S, F F^T."""
    E = work[0]
    for i in range(d):
        for j in range(d):
            value = 0.0
            for p in range(d):
                value += F[p, i] * F[p, j]
            E[i, j] = 0.5 * (value - (1.0 if i == j else 0.0))
    trace = 0.0
    for i in range(d):
        trace += E[i, i]
    psi = 0.5 * lam * trace * trace
    S = work[1]
    for i in range(d):
        for j in range(d):
            psi += mu * E[i, j] * E[i, j]
            S[i, j] = 2.0 * mu * E[i, j] + (lam * trace if i == j else 0.0)
    for i in range(d):
        for j in range(d):
            value = 0.0
            for m in range(d):
                value += F[i, m] * S[m, j]
            P[i, j] = value
    if want_tangent:
        FFt = work[2]
        for i in range(d):
            for k in range(d):
                value = 0.0
                for m in range(d):
                    value += F[i, m] * F[k, m]
                FFt[i, k] = value
        # dP_ij/dF_kl = delta_ik S_lj + mu (F_il F_kj + (F F^T)_ik delta_lj) + lambda F_ij F_kl
        for i in range(d):
            for j in range(d):
                for k in range(d):
                    for l in range(d):
                        value = mu * F[i, l] * F[k, j] + lam * F[i, j] * F[k, l]
                        if i == k:
                            value += S[l, j]
                        if l == j:
                            value += mu * FFt[i, k]
                        A[i * d + j, k * d + l] = value
    return psi


@numba.njit(cache=True, inline="always")
def singular_hessian(sigma, d, J, mu, lam, H):
    """d^2 psi / d sigma^2 into H (d, d); defined everywhere (True)."""
    trace = 0.0
    for m in range(d):
        trace += 0.5 * (sigma[m] * sigma[m] - 1.0)
    for i in range(d):
        for j in range(d):
            if i == j:
                H[i, i] = (2.0 * mu * (sigma[i] * sigma[i] + 0.5 * (sigma[i] * sigma[i] - 1.0))
                           + lam * (sigma[i] * sigma[i] + trace))
            else:
                H[i, j] = lam * sigma[i] * sigma[j]
    return True


@numba.njit(cache=True, inline="always")
def pair_eigenvalues(sigma, d, si, sj, third, J, mu, lam):
    """(flip, twist) of the pair of singular values si, sj, their quotients divided out."""
    trace = 0.0
    for m in range(d):
        trace += 0.5 * (sigma[m] * sigma[m] - 1.0)
    flip = mu * (si * si + si * sj + sj * sj - 1.0) + lam * trace
    twist = mu * (si * si - si * sj + sj * sj - 1.0) + lam * trace
    return flip, twist


@numba.njit(cache=True, inline="always")
def membrane_terms(F, C, I1, mu, lam, P, A, want_tangent, work):
    """psi of a 3 x 2 F (C = F^T F given), P into P (3, 2) and with want_tangent A into A (6, 6); work[1] holds S,
    work[3] F F^T."""
    S, FFt = work[1], work[3]
    E00, E01, E11 = 0.5 * (C[0, 0] - 1.0), 0.5 * C[0, 1], 0.5 * (C[1, 1] - 1.0)
    trace = E00 + E11
    psi = mu * (E00 * E00 + 2.0 * E01 * E01 + E11 * E11) + 0.5 * lam * trace * trace
    S[0, 0], S[0, 1], S[1, 0], S[1, 1] = 2.0 * mu * E00 + lam * trace, 2.0 * mu * E01, 2.0 * mu * E01, 2.0 * mu * E11 + lam * trace
    for i in range(3):
        for j in range(2):
            P[i, j] = F[i, 0] * S[0, j] + F[i, 1] * S[1, j]
    if want_tangent:
        for i in range(3):
            for k in range(3):
                FFt[i, k] = F[i, 0] * F[k, 0] + F[i, 1] * F[k, 1]
        # as for a solid
        for i in range(3):
            for j in range(2):
                for k in range(3):
                    for l in range(2):
                        value = mu * F[i, l] * F[k, j] + lam * F[i, j] * F[k, l]
                        if i == k:
                            value += S[l, j]
                        if l == j:
                            value += mu * FFt[i, k]
                        A[2 * i + j, 2 * k + l] = value
    return psi


@numba.njit(cache=True, inline="always")
def membrane_vertex_terms(F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K):
    """P n into stress and K = n^T A n = (n^T S n) I + (mu + lambda) w w^T + mu |n|^2 F F^T (w = F n) into K, as a
    solid's, of a triangle's 3 x 2 F at its corner with shape gradient n = (n0, n1)."""
    E00, E01, E11 = 0.5 * (C00 - 1.0), 0.5 * C01, 0.5 * (C11 - 1.0)
    trace = E00 + E11
    Sn0 = (2.0 * mu * E00 + lam * trace) * n0 + 2.0 * mu * E01 * n1
    Sn1 = 2.0 * mu * E01 * n0 + (2.0 * mu * E11 + lam * trace) * n1
    along = n0 * Sn0 + n1 * Sn1
    for i in range(3):
        stress[i] = F[i, 0] * Sn0 + F[i, 1] * Sn1
    for i in range(3):
        w_i = F[i, 0] * n0 + F[i, 1] * n1
        for k in range(i, 3):
            w_k = F[k, 0] * n0 + F[k, 1] * n1
            value = (mu + lam) * w_i * w_k + mu * squared * (F[i, 0] * F[k, 0] + F[i, 1] * F[k, 1])
            if i == k:
                value += along
            K[i, k] = K[k, i] = value


@numba.njit(cache=True, inline="always")
def membrane_change(C00, C01, C11, D00, D01, D11, mu, lam):
    """psi(C + dC) - psi(C) without cancellation, from E's change dC / 2."""
    E00, E01, E11 = 0.5 * (C00 - 1.0), 0.5 * C01, 0.5 * (C11 - 1.0)
    d00, d01, d11 = 0.5 * D00, 0.5 * D01, 0.5 * D11
    product = E00 * d00 + 2.0 * E01 * d01 + E11 * d11
    squared = d00 * d00 + 2.0 * d01 * d01 + d11 * d11
    trace, trace_change = E00 + E11, d00 + d11
    return mu * (2.0 * product + squared) + 0.5 * lam * trace_change * (2.0 * trace + trace_change)


@numba.njit(cache=True, inline="always")
def vertex_stiffness(F, n, d, squared, mu, lam, A, K, work):
    """K = n^T A n = (n^T S n) I + (mu + lambda) w w^T + mu |n|^2 F F^T (w = F n), added into K (zeroed by the
    caller); work[0, 0] holds w, work[1] E."""
    w = work[0, 0]
    for i in range(d):
        total = 0.0
        for j in range(d):
            total += F[i, j] * n[j]
        w[i] = total
    E = work[1]
    trace = 0.0
    for i in range(d):
        for j in range(d):
            value = 0.0
            for p in range(d):
                value += F[p, i] * F[p, j]
            E[i, j] = 0.5 * (value - (1.0 if i == j else 0.0))
        trace += E[i, i]
    stress = 0.0  # n^T S n
    for i in range(d):
        for j in range(d):
            stress += n[i] * (2.0 * mu * E[i, j] + (lam * trace if i == j else 0.0)) * n[j]
    for i in range(d):
        K[i, i] += stress
        for k in range(d):
            gram = 0.0
            for m in range(d):
                gram += F[i, m] * F[k, m]
            K[i, k] += (mu + lam) * w[i] * w[k] + mu * squared * gram


@numba.njit(cache=True, inline="always")
def vertex_energy_change(F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work):
    """psi(F + u n^T) - psi(F) without cancellation, from the strain's change E' - E = (v n^T + n v^T + |u|^2 n n^T)/2
    with v = F^T u; work[0, 0], work[1], work[2] hold v, E and the change."""
    v, E, change = work[0, 0], work[1], work[2]
    for j in range(d):
        total = 0.0
        for m in range(d):
            total += F[m, j] * u[m]
        v[j] = total
    trace, trace_change, product, squared_change = 0.0, 0.0, 0.0, 0.0
    for i in range(d):
        for j in range(d):
            value = 0.0
            for p in range(d):
                value += F[p, i] * F[p, j]
            E[i, j] = 0.5 * (value - (1.0 if i == j else 0.0))
            change[i, j] = 0.5 * (v[i] * n[j] + n[i] * v[j] + squared_u * n[i] * n[j])
            product += E[i, j] * change[i, j]
            squared_change += change[i, j] * change[i, j]
        trace += E[i, i]
        trace_change += change[i, i]
    return mu * (2.0 * product + squared_change) + 0.5 * lam * trace_change * (2.0 * trace + trace_change)


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
