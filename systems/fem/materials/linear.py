"""Linear elasticity: psi = mu eps:eps + lambda/2 tr(eps)^2, eps = (F + F^T)/2 - I, the small-strain energy
(docs/fem.md, "Energies"). Its tangent is constant and PSD for every nu in (-1, 0.5), so it is never projected; it is
not rotation invariant, so it is no shell's membrane (a shell's triangles turn out of their plane).

Each function is inlined into the dispatch (dispatch.py), which the element loops and the vertex sweeps call."""

from __future__ import annotations

import numba

from ...compiled_cache import keep_fresh


@numba.njit(cache=True, inline="always")
def energy_terms(F, d, mu, lam, P, A, want_tangent, work):
    """psi(F) (J/m^3); P = dpsi/dF into P, and with want_tangent A = d^2 psi / dF^2 added into A (both zeroed by the
    caller, energies.py)."""
    trace = 0.0
    for i in range(d):
        trace += F[i, i] - 1.0
    psi = 0.5 * lam * trace * trace
    for i in range(d):
        for j in range(d):
            strain = 0.5 * (F[i, j] + F[j, i]) - (1.0 if i == j else 0.0)
            psi += mu * strain * strain
            P[i, j] = 2.0 * mu * strain + (lam * trace if i == j else 0.0)
    if want_tangent:
        for i in range(d):
            for j in range(d):
                A[i * d + j, i * d + j] += mu
                A[i * d + j, j * d + i] += mu
                if i == j:
                    for k in range(d):
                        A[i * d + i, k * d + k] += lam
    return psi


@numba.njit(cache=True, inline="always")
def vertex_stiffness(F, n, d, squared, mu, lam, A, K, work):
    """K = n^T A n = mu |n|^2 I + (mu + lambda) n n^T, added into K (zeroed by the caller)."""
    for i in range(d):
        K[i, i] += mu * squared
        for k in range(d):
            K[i, k] += (mu + lam) * n[i] * n[k]


@numba.njit(cache=True, inline="always")
def vertex_energy_change(F, n, u, d, squared_n, squared_u, turned, mu, lam, moved, P, A, work):
    """psi(F + u n^T) - psi(F) without cancellation: eps' - eps = (u n^T + n u^T)/2, so the change is
    mu (2 u^T eps n + (|u|^2 |n|^2 + (u . n)^2)/2) + lambda/2 dtr (2 tr eps + dtr), dtr = u . n (``turned``)."""
    strain, trace = 0.0, 0.0
    for i in range(d):
        trace += F[i, i] - 1.0
        for j in range(d):
            strain += u[i] * (0.5 * (F[i, j] + F[j, i]) - (1.0 if i == j else 0.0)) * n[j]
    return (mu * (2.0 * strain + 0.5 * (squared_u * squared_n + turned * turned))
            + 0.5 * lam * turned * (2.0 * trace + turned))


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
