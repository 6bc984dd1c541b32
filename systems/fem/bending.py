"""The discrete-shell bending energy (Grinspun, Hirani, Desbrun & Schroeder 2003), compiled with numba (docs/fem.md).

Each interior edge (x0, x1) of a shell is a hinge between the triangles (x0, x1, x2) and (x1, x0, x3):

    E = k 3 |e_rest|^2 / (A_1 + A_2) (theta - theta_rest)^2,

k the bending stiffness (N m), A_1, A_2 the rest areas, and theta the signed angle between the normals
N_1 = e x w_1 and N_2 = w_2 x e (e = x1 - x0, w_a = x_{a+1} - x0), which point the same way when the hinge is flat
whatever the triangles' own winding: theta = atan2((N_1 x N_2) . e / |e|, N_1 . N_2).

The exact Hessian by the chain z = (e, w_1, w_2) (linear in x) -> y = (N_1, N_2, e) (bilinear in z) -> theta:
theta's first and second derivatives in y are those of atan2(s, c), with s = T / |e|, T = det[N_1, N_2, e] and
c = N_1 . N_2, whose own derivatives are products of the Levi-Civita symbol with y; then theta_zz =
Y^T theta_yy Y + sum_a theta_{N_1,a} d^2 N_1,a / dz^2 + sum_a theta_{N_2,a} d^2 N_2,a / dz^2, the last two with the
Levi-Civita symbol's entries as the only second derivatives of a cross product.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..compiled_cache import keep_fresh
from .linalg import project_dense

PSD_SHIFT = 1e-12
CHUNK = 256
# z = (e, w_1, w_2) from the hinge's vertices: z_block = sum_a ZMAP[block, a] x_a
ZMAP = np.array([[-1.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 1.0]])


@numba.njit(cache=True)
def _epsilon(i, j, k):
    return (i - j) * (j - k) * (k - i) / 2.0


@numba.njit(cache=True)
def _product(A, B, out, transpose_a):
    """out = A B, or A^T B with transpose_a (square 9 x 9 here)."""
    n = out.shape[0]
    for i in range(n):
        for j in range(n):
            value = 0.0
            for k in range(n):
                value += (A[k, i] if transpose_a else A[i, k]) * B[k, j]
            out[i, j] = value


@numba.njit(cache=True)
def _hinge_vectors(x, hinge, z):
    """z (3, 3): the rows e, w_1, w_2 of one hinge."""
    base = 3 * hinge[0]
    for block in range(3):
        other = 3 * hinge[block + 1]
        for i in range(3):
            z[block, i] = x[other + i] - x[base + i]


@numba.njit(cache=True)
def _angle(z):
    """theta of the hinge whose e, w_1, w_2 are the rows of z."""
    e, w1, w2 = z[0], z[1], z[2]
    n1 = (e[1] * w1[2] - e[2] * w1[1], e[2] * w1[0] - e[0] * w1[2], e[0] * w1[1] - e[1] * w1[0])
    n2 = (w2[1] * e[2] - w2[2] * e[1], w2[2] * e[0] - w2[0] * e[2], w2[0] * e[1] - w2[1] * e[0])
    cross = (n1[1] * n2[2] - n1[2] * n2[1], n1[2] * n2[0] - n1[0] * n2[2], n1[0] * n2[1] - n1[1] * n2[0])
    length = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    s = (cross[0] * e[0] + cross[1] * e[1] + cross[2] * e[2]) / length
    c = n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2]
    return math.atan2(s, c)


@numba.njit(cache=True)
def rest_angles(x, hinges):
    angles = np.empty(hinges.shape[0])
    z = np.empty((3, 3))
    for h in range(hinges.shape[0]):
        _hinge_vectors(x, hinges[h], z)
        angles[h] = _angle(z)
    return angles


@numba.njit(cache=True)
def _angle_derivatives(z, gradient, hessian, want_hessian, work):
    """theta, its gradient in z (9,) into gradient and with want_hessian its Hessian (9, 9) into hessian (work: the y
    derivatives, (4, 9, 9))."""
    y = work[0, 0]  # (9,): N_1, N_2, e
    e, w1, w2 = z[0], z[1], z[2]
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        y[i] = e[i1] * w1[i2] - e[i2] * w1[i1]
        y[3 + i] = w2[i1] * e[i2] - w2[i2] * e[i1]
        y[6 + i] = e[i]
    n1, n2 = y[0:3], y[3:6]
    length = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    T = 0.0
    for a in range(3):
        for b in range(3):
            for c in range(3):
                T += _epsilon(a, b, c) * n1[a] * n2[b] * e[c]
    s = T / length
    c_value = n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2]
    theta = math.atan2(s, c_value)
    r = s * s + c_value * c_value
    # first derivatives in y of T, |e|, s and c
    Ty, Ly, sy, cy = work[0, 1], work[0, 2], work[0, 3], work[0, 4]
    for i in range(9):
        Ty[i], Ly[i], cy[i] = 0.0, 0.0, 0.0
    for a in range(3):
        for b in range(3):
            for c in range(3):
                eps = _epsilon(a, b, c)
                if eps != 0.0:
                    Ty[a] += eps * n2[b] * e[c]
                    Ty[3 + b] += eps * n1[a] * e[c]
                    Ty[6 + c] += eps * n1[a] * n2[b]
    for i in range(3):
        Ly[6 + i] = e[i] / length
        cy[i], cy[3 + i] = n2[i], n1[i]
    for i in range(9):
        sy[i] = Ty[i] / length - T * Ly[i] / (length * length)
    thetay = work[0, 5]
    for i in range(9):
        thetay[i] = (c_value * sy[i] - s * cy[i]) / r
    # theta_z = Y^T theta_y, Y = dy/dz: dN_1/de = -[w_1]x, dN_1/dw_1 = [e]x, dN_2/dw_2 = -[e]x, dN_2/de = [w_2]x
    Y = work[1]
    Y[:, :] = 0.0
    for a in range(3):
        for b in range(3):
            for c in range(3):
                eps = _epsilon(a, b, c)
                if eps != 0.0:
                    # N_1,a = eps_abc e_b w1_c; N_2,a = eps_abc w2_b e_c
                    Y[a, b] += eps * w1[c]
                    Y[a, 3 + c] += eps * e[b]
                    Y[3 + a, 6 + b] += eps * e[c]
                    Y[3 + a, c] += eps * w2[b]
        Y[6 + a, a] = 1.0
    for j in range(9):
        value = 0.0
        for i in range(9):
            value += Y[i, j] * thetay[i]
        gradient[j] = value
    if not want_hessian:
        return theta
    # second derivatives in y: T_yy (Levi-Civita with y), |e|'s, then s_yy, c_yy and theta_yy
    syy, thetayy = work[2], work[3]
    syy[:, :] = 0.0
    for a in range(3):
        for b in range(3):
            for c in range(3):
                eps = _epsilon(a, b, c)
                if eps != 0.0:
                    syy[a, 3 + b] += eps * e[c] / length
                    syy[3 + b, a] += eps * e[c] / length
                    syy[a, 6 + c] += eps * n2[b] / length
                    syy[6 + c, a] += eps * n2[b] / length
                    syy[3 + b, 6 + c] += eps * n1[a] / length
                    syy[6 + c, 3 + b] += eps * n1[a] / length
    square = length * length
    for i in range(9):
        for j in range(9):
            syy[i, j] += -(Ty[i] * Ly[j] + Ly[i] * Ty[j]) / square + 2.0 * T * Ly[i] * Ly[j] / (square * length)
    for i in range(3):
        for j in range(3):
            Lee = ((1.0 if i == j else 0.0) - e[i] * e[j] / square) / length
            syy[6 + i, 6 + j] -= T * Lee / square
    for i in range(9):
        for j in range(9):
            cyy = 1.0 if (j == i + 3 and i < 3) or (i == j + 3 and j < 3) else 0.0
            numerator = c_value * sy[i] - s * cy[i]
            thetayy[i, j] = ((sy[i] * cy[j] - cy[i] * sy[j] + c_value * syy[i, j] - s * cyy) / r
                             - numerator * 2.0 * (s * sy[j] + c_value * cy[j]) / (r * r))
    # theta_zz = Y^T theta_yy Y + the cross products' second derivatives weighted by theta_N
    _product(thetayy, Y, syy, False)
    _product(Y, syy, hessian, True)
    for a in range(3):
        for b in range(3):
            for c in range(3):
                eps = _epsilon(a, b, c)
                if eps != 0.0:
                    hessian[b, 3 + c] += eps * thetay[a]  # d^2 N_1,a / de_b dw1_c
                    hessian[3 + c, b] += eps * thetay[a]
                    hessian[6 + b, c] += eps * thetay[3 + a]  # d^2 N_2,a / dw2_b de_c
                    hessian[c, 6 + b] += eps * thetay[3 + a]
    for i in range(9):  # symmetric to round-off; made exactly so
        for j in range(i + 1, 9):
            mean = 0.5 * (hessian[i, j] + hessian[j, i])
            hessian[i, j] = hessian[j, i] = mean
    return theta


@numba.njit(cache=True, parallel=True)
def hinge_energies(x, hinges, stiffness, rest_angle):
    """k_h (theta - theta_rest)^2 of every hinge (J); stiffness k_h = k 3 |e_rest|^2 / (A_1 + A_2) per hinge."""
    count = hinges.shape[0]
    energies = np.empty(count)
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        z = np.empty((3, 3))
        for h in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _hinge_vectors(x, hinges[h], z)
            change = _angle(z) - rest_angle[h]
            energies[h] = stiffness[h] * change * change
    return energies


@numba.njit(cache=True, parallel=True)
def hinge_forces(x, hinges, stiffness, rest_angle, forces):
    """forces[h, a] = dE_h/dx_a (N), (hinges, 4, 3)."""
    count = hinges.shape[0]
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        z, gradient, hessian, work = np.empty((3, 3)), np.empty(9), np.empty((1, 1)), np.empty((4, 9, 9))
        for h in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _hinge_vectors(x, hinges[h], z)
            theta = _angle_derivatives(z, gradient, hessian, False, work)
            scale = 2.0 * stiffness[h] * (theta - rest_angle[h])
            for a in range(4):
                for i in range(3):
                    value = 0.0
                    for block in range(3):
                        value += ZMAP[block, a] * gradient[3 * block + i]
                    forces[h, a, i] = scale * value


@numba.njit(cache=True, parallel=True)
def hinge_hessians(x, hinges, stiffness, rest_angle, projection, blocks):
    """blocks[h] = d^2 E_h / dx^2 (12 x 12, vertex-major) = Z^T M Z with M = 2 k_h (theta_z theta_z^T + (theta -
    theta_rest) theta_zz) the Hessian in z = (e, w_1, w_2) = Z x; M projected to PSD as asked (0 none, 1 clamp, 2 abs)
    by its eigensystem. Z maps the 12 coordinates onto all of z (its null space the translations), so Z^T M Z is
    PSD exactly when M is, and the 9 x 9 eigenproblem is half the 12 x 12 one's cost."""
    count = hinges.shape[0]
    for chunk in numba.prange((count + CHUNK - 1) // CHUNK):
        z, gradient, hessian, work = np.empty((3, 3)), np.empty(9), np.empty((9, 9)), np.empty((4, 9, 9))
        scratch, vectors, values = np.empty((9, 9)), np.empty((9, 9)), np.empty(18)
        for h in range(chunk * CHUNK, min(count, (chunk + 1) * CHUNK)):
            _hinge_vectors(x, hinges[h], z)
            theta = _angle_derivatives(z, gradient, hessian, True, work)
            scale, change = 2.0 * stiffness[h], theta - rest_angle[h]
            for i in range(9):
                for j in range(9):
                    hessian[i, j] = scale * (gradient[i] * gradient[j] + change * hessian[i, j])
            project_dense(hessian, 9, projection, PSD_SHIFT, scratch, values, vectors)
            # Z^T M Z: vertex 0 takes minus the sum of the three z blocks, vertex a > 0 the block a - 1
            block_matrix = blocks[h]
            for p in range(3):
                for q in range(3):
                    for i in range(3):
                        for j in range(3):
                            block_matrix[3 * (p + 1) + i, 3 * (q + 1) + j] = hessian[3 * p + i, 3 * q + j]
            for q in range(1, 4):
                for i in range(3):
                    for j in range(3):
                        value = 0.0
                        for p in range(3):
                            value += block_matrix[3 * (p + 1) + i, 3 * q + j]
                        block_matrix[i, 3 * q + j] = -value
                        block_matrix[3 * q + j, i] = -value
            for i in range(3):
                for j in range(3):
                    value = 0.0
                    for q in range(1, 4):
                        value += block_matrix[i, 3 * q + j]
                    block_matrix[i, j] = -value
            for i in range(3):  # summed in another order for (j, i): made exactly symmetric
                for j in range(i + 1, 3):
                    mean = 0.5 * (block_matrix[i, j] + block_matrix[j, i])
                    block_matrix[i, j] = block_matrix[j, i] = mean


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
