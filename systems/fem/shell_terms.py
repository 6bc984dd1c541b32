"""A shell's terms at one vertex in closed form, for vertex block descent (shell_vbd_kernels.py, whose docstring derives
them): a membrane triangle's P n and n^T A n, a hinge's angle and its derivatives in one vertex, a hinge wing's
projected block, and the projection of a symmetric 3 x 3 block by its closed-form eigensystem. Each is inlined into
the sweep, but the projection's eigensystem, a call with scalars in and out."""

from __future__ import annotations

import math

import numba

from ..compiled_cache import keep_fresh
from ..vertex_kernels import filtered_eigenvalue
from .materials.dispatch import membrane_vertex_terms as material_membrane_vertex_terms
from .vbd_kernels import project_block


@numba.njit(cache=True, error_model="numpy", inline="always")
def _eigenvector(k00, k01, k02, k11, k12, k22, value):
    """(found, a unit eigenvector) of the symmetric 3 x 3 K for its eigenvalue ``value``: the longest cross product of
    two rows of K - value I (each is orthogonal to the rows, so along the null vector where the others span a plane).
    Not found where all three vanish to round-off (a repeated eigenvalue: no single vector)."""
    r00, r11, r22 = k00 - value, k11 - value, k22 - value
    best0, best1, best2, size = 0.0, 0.0, 0.0, -1.0
    for pair in range(3):
        if pair == 0:  # rows 0 x 1
            c0, c1, c2 = k01 * k12 - k02 * r11, k02 * k01 - r00 * k12, r00 * r11 - k01 * k01
        elif pair == 1:  # rows 0 x 2
            c0, c1, c2 = k01 * r22 - k02 * k12, k02 * k02 - r00 * r22, r00 * k12 - k01 * k02
        else:  # rows 1 x 2
            c0, c1, c2 = r11 * r22 - k12 * k12, k12 * k02 - k01 * r22, k01 * k12 - r11 * k02
        squared = c0 * c0 + c1 * c1 + c2 * c2
        if squared > size:
            best0, best1, best2, size = c0, c1, c2, squared
    rows = max(r00 * r00 + k01 * k01 + k02 * k02, k01 * k01 + r11 * r11 + k12 * k12, k02 * k02 + k12 * k12 + r22 * r22)
    if not size > 1e-20 * rows * rows:
        return False, 0.0, 0.0, 0.0
    length = math.sqrt(size)
    return True, best0 / length, best1 / length, best2 / length


@numba.njit(cache=True, error_model="numpy", inline="always")
def _polished(k00, k01, k02, k11, k12, k22, value):
    """Two Newton steps on det(K - value I) = 0 from ``value``: the trigonometric solution loses half the digits of
    every eigenvalue where two of them nearly coincide (acos near +-1), and a simple root's Newton steps restore them."""
    for _ in range(2):
        a00, a11, a22 = k00 - value, k11 - value, k22 - value
        minors = a11 * a22 - k12 * k12 + a00 * a22 - k02 * k02 + a00 * a11 - k01 * k01  # -d det / d value
        determinant = a00 * (a11 * a22 - k12 * k12) - k01 * (k01 * a22 - k12 * k02) + k02 * (k01 * k12 - a11 * k02)
        if minors == 0.0:
            break
        value += determinant / minors
    return value


@numba.njit(cache=True, error_model="numpy", inline="always")
def project_block_3(K, projection, copy, values, vectors):
    """fem/vbd_kernels.py's ``project_block`` of a symmetric 3 x 3 K in closed form (``_projected``); the Jacobi
    rotations where that gives up (K = l I)."""
    if projection == 0:
        return
    if K[0, 0] > 0.0:  # positive definite by its leading minors: nothing to do
        minor = K[0, 0] * K[1, 1] - K[0, 1] * K[1, 0]
        if minor > 0.0 and (K[0, 0] * (K[1, 1] * K[2, 2] - K[1, 2] * K[2, 1])
                            - K[0, 1] * (K[1, 0] * K[2, 2] - K[1, 2] * K[2, 0])
                            + K[0, 2] * (K[1, 0] * K[2, 1] - K[1, 1] * K[2, 0])) > 0.0:
            return
    done, k00, k01, k02, k11, k12, k22 = _projected(K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], K[2, 2], projection)
    if not done:
        project_block(K, 3, projection, copy, values, vectors)
        return
    K[0, 0], K[1, 1], K[2, 2] = k00, k11, k22
    K[0, 1] = K[1, 0] = k01
    K[0, 2] = K[2, 0] = k02
    K[1, 2] = K[2, 1] = k12


@numba.njit(cache=True, error_model="numpy")
def _projected(k00, k01, k02, k11, k12, k22, projection):
    """(done, the projected K's six entries) of a symmetric 3 x 3 K that is not positive definite, in closed form
    instead of Jacobi rotations (a hinge's block away from its rest angle is indefinite, and the rotations per hinge
    and vertex were half the sweep); scalars in and out, since a call that takes arrays costs numba their reference
    counts:

    1. the eigenvalues by the trigonometric solution of the characteristic cubic, good only roughly where two nearly
       coincide (acos near +-1 halves their digits);
    2. the one lying apart from the other two (the highest or the lowest), polished by Newton's steps on the cubic (a
       simple root), and its eigenvector from the cross products of K - l I's rows;
    3. the other two exactly from the 2 x 2 block of K across that vector, with their vectors.

    Eigenvalues above -1e-13 of the largest count as 0 (the round-off of a singular PSD block: a hinge at rest, a flat
    membrane across its plane), as membrane.py's PSD_SHIFT has it; otherwise K = sum f(l) v v^T. Not done where the
    vector of step 2 is not unique to round-off (K = l I)."""
    mean = (k00 + k11 + k22) / 3.0
    b00, b11, b22 = k00 - mean, k11 - mean, k22 - mean
    spread = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (k01 * k01 + k02 * k02 + k12 * k12)) / 6.0)
    if not spread > 0.0:
        return False, k00, k01, k02, k11, k12, k22
    determinant = (b00 * (b11 * b22 - k12 * k12) - k01 * (k01 * b22 - k12 * k02)
                   + k02 * (k01 * k12 - b11 * k02)) / (spread * spread * spread)
    angle = math.acos(min(max(0.5 * determinant, -1.0), 1.0)) / 3.0
    highest = mean + 2.0 * spread * math.cos(angle)
    lowest = mean + 2.0 * spread * math.cos(angle + 2.0 * math.pi / 3.0)
    middle = 3.0 * mean - highest - lowest
    apart = _polished(k00, k01, k02, k11, k12, k22, highest if highest - middle >= middle - lowest else lowest)
    found, v0, v1, v2 = _eigenvector(k00, k01, k02, k11, k12, k22, apart)
    if not found:
        return False, k00, k01, k02, k11, k12, k22
    # e, f: an orthonormal pair across v (e = v x the axis v leans on least)
    if abs(v0) <= abs(v1) and abs(v0) <= abs(v2):
        e0, e1, e2 = 0.0, v2, -v1
    elif abs(v1) <= abs(v2):
        e0, e1, e2 = -v2, 0.0, v0
    else:
        e0, e1, e2 = v1, -v0, 0.0
    length = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / length, e1 / length, e2 / length
    f0, f1, f2 = v1 * e2 - v2 * e1, v2 * e0 - v0 * e2, v0 * e1 - v1 * e0
    Ke0, Ke1, Ke2 = k00 * e0 + k01 * e1 + k02 * e2, k01 * e0 + k11 * e1 + k12 * e2, k02 * e0 + k12 * e1 + k22 * e2
    Kf0, Kf1, Kf2 = k00 * f0 + k01 * f1 + k02 * f2, k01 * f0 + k11 * f1 + k12 * f2, k02 * f0 + k12 * f1 + k22 * f2
    B00 = e0 * Ke0 + e1 * Ke1 + e2 * Ke2
    B11 = f0 * Kf0 + f1 * Kf1 + f2 * Kf2
    B01 = 0.5 * (e0 * Kf0 + e1 * Kf1 + e2 * Kf2 + f0 * Ke0 + f1 * Ke1 + f2 * Ke2)
    half, centre = 0.5 * (B00 - B11), 0.5 * (B00 + B11)
    radius = math.sqrt(half * half + B01 * B01)
    upper, lower = centre + radius, centre - radius
    floor = -1e-13 * max(abs(apart), abs(upper), abs(lower))
    if apart >= floor and lower >= floor:
        return True, k00, k01, k02, k11, k12, k22
    turn = 0.5 * math.atan2(B01, half)  # the 2 x 2 block's vector of ``upper`` is (cos, sin) in (e, f)
    c, s = math.cos(turn), math.sin(turn)
    u0, u1, u2 = c * e0 + s * f0, c * e1 + s * f1, c * e2 + s * f2
    w0, w1, w2 = -s * e0 + c * f0, -s * e1 + c * f1, -s * e2 + c * f2
    apart = filtered_eigenvalue(apart, projection)
    upper = filtered_eigenvalue(upper, projection)
    lower = filtered_eigenvalue(lower, projection)
    return (True, apart * v0 * v0 + upper * u0 * u0 + lower * w0 * w0, apart * v0 * v1 + upper * u0 * u1 + lower * w0 * w1,
            apart * v0 * v2 + upper * u0 * u2 + lower * w0 * w2, apart * v1 * v1 + upper * u1 * u1 + lower * w1 * w1,
            apart * v1 * v2 + upper * u1 * u2 + lower * w1 * w2, apart * v2 * v2 + upper * u2 * u2 + lower * w2 * w2)


@numba.njit(cache=True, error_model="numpy", inline="always")
def membrane_vertex_terms(model, F, n0, n1, mu, lam, stress, K):
    """P n (into stress) and K = n^T A n (into K) of a triangle's 3 x 2 F at its corner with shape gradient n, in closed
    form (each material's: St. Venant-Kirchhoff's as a solid's, the others' from f(I_1, J),
    materials/invariant_membrane.py)."""
    squared = n0 * n0 + n1 * n1
    C00 = F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0]
    C01 = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
    C11 = F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1]
    material_membrane_vertex_terms(model, F, n0, n1, squared, C00, C01, C11, mu, lam, stress, K)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _hinge_angle(y, hinges, q, corner, u0, u1, u2):
    """theta of hinge row q with its vertex ``corner`` moved by u (bending.py's ``_angle`` of z = (e, w_1, w_2), in
    scalars: the per-hinge calls with arrays cost numba their reference counts, a third of the sweep)."""
    base = 3 * hinges[q, 0]
    e0, e1, e2 = y[3 * hinges[q, 1]] - y[base], y[3 * hinges[q, 1] + 1] - y[base + 1], y[3 * hinges[q, 1] + 2] - y[base + 2]
    a0, a1, a2 = y[3 * hinges[q, 2]] - y[base], y[3 * hinges[q, 2] + 1] - y[base + 1], y[3 * hinges[q, 2] + 2] - y[base + 2]
    b0, b1, b2 = y[3 * hinges[q, 3]] - y[base], y[3 * hinges[q, 3] + 1] - y[base + 1], y[3 * hinges[q, 3] + 2] - y[base + 2]
    if corner == 0:  # x0 moves e, w_1 and w_2 by -u
        e0, e1, e2, a0, a1, a2, b0, b1, b2 = e0 - u0, e1 - u1, e2 - u2, a0 - u0, a1 - u1, a2 - u2, b0 - u0, b1 - u1, b2 - u2
    elif corner == 1:
        e0, e1, e2 = e0 + u0, e1 + u1, e2 + u2
    elif corner == 2:
        a0, a1, a2 = a0 + u0, a1 + u1, a2 + u2
    else:
        b0, b1, b2 = b0 + u0, b1 + u1, b2 + u2
    n0, n1, n2 = e1 * a2 - e2 * a1, e2 * a0 - e0 * a2, e0 * a1 - e1 * a0  # N_1 = e x w_1
    m0, m1, m2 = b1 * e2 - b2 * e1, b2 * e0 - b0 * e2, b0 * e1 - b1 * e0  # N_2 = w_2 x e
    c0, c1, c2 = n1 * m2 - n2 * m1, n2 * m0 - n0 * m2, n0 * m1 - n1 * m0
    length = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    return math.atan2((c0 * e0 + c1 * e1 + c2 * e2) / length, n0 * m0 + n1 * m1 + n2 * m2)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _hinge_points(y, hinges, q, points):
    """Rows b = 0..3 of ``points``: x_b - x0 of hinge row q's vertices (row 0 zero)."""
    base = 3 * hinges[q, 0]
    for b in range(4):
        other = 3 * hinges[q, b]
        for r in range(3):
            points[b, r] = y[other + r] - y[base + r]


@numba.njit(cache=True, error_model="numpy", inline="always")
def hinge_angle_block(y, hinges, q, corner, along, curvature, vectors):
    """theta's gradient (into along) and Hessian (into curvature) in the position of hinge q's vertex ``corner`` alone,
    in closed form (the module docstring's "Hinges", here in the form that needs no 9 x 9 product). theta = atan2(s, c)
    gives, for any s and c of the vertex's position p, with r = s^2 + c^2, g = c s_p - s c_p and h = s s_p + c c_p,

        theta_p = g / r,    theta_pp = (c s_pp - s c_pp) / r - (g h^T + h g^T) / r^2.

    A wing vertex (corner 2 or 3) moves one triangle's normal linearly and leaves the other and e: with e, the other
    normal N fixed, s = -|e| N . q and c = (N x e) . q (corner 2; corner 3: s = -|e| N_1 . q, c = (e x N_1) . q) are
    linear in q = x_corner - x0, so s_pp = c_pp = 0. Vertex 1 moves p = e with w_1, w_2 fixed, where
    N_1 x N_2 = -(p . m) p (m = w_1 x w_2) and N_1 . N_2 = (p . w_1)(p . w_2) - |p|^2 (w_1 . w_2):

        s = -|p| (p . m),   c = (p . w_1)(p . w_2) - |p|^2 (w_1 . w_2).

    Vertex 0 is vertex 1 of the same hinge seen from x1 (p = x0 - x1, w_a = x_(a+1) - x1), whose angle is -theta."""
    _hinge_points(y, hinges, q, vectors)  # rows 0-3: x_b - x0 (e = row 1, w_1 = row 2, w_2 = row 3)
    if corner >= 2:
        e0, e1, e2 = vectors[1, 0], vectors[1, 1], vectors[1, 2]
        length = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        if corner == 2:  # N = N_2 = w_2 x e fixed; s = -|e| N . q, c = (N x e) . q
            w0, w1, w2 = vectors[3, 0], vectors[3, 1], vectors[3, 2]
            n0, n1, n2 = w1 * e2 - w2 * e1, w2 * e0 - w0 * e2, w0 * e1 - w1 * e0
            b0, b1, b2 = n1 * e2 - n2 * e1, n2 * e0 - n0 * e2, n0 * e1 - n1 * e0
        else:  # N = N_1 = e x w_1 fixed; s = -|e| N . q, c = (e x N) . q
            w0, w1, w2 = vectors[2, 0], vectors[2, 1], vectors[2, 2]
            n0, n1, n2 = e1 * w2 - e2 * w1, e2 * w0 - e0 * w2, e0 * w1 - e1 * w0
            b0, b1, b2 = e1 * n2 - e2 * n1, e2 * n0 - e0 * n2, e0 * n1 - e1 * n0
        a0, a1, a2 = -length * n0, -length * n1, -length * n2
        q0, q1, q2 = vectors[corner, 0], vectors[corner, 1], vectors[corner, 2]
        s = a0 * q0 + a1 * q1 + a2 * q2
        c = b0 * q0 + b1 * q1 + b2 * q2
        r = s * s + c * c
        g0, g1, g2 = c * a0 - s * b0, c * a1 - s * b1, c * a2 - s * b2
        h0, h1, h2 = s * a0 + c * b0, s * a1 + c * b1, s * a2 + c * b2
        along[0], along[1], along[2] = g0 / r, g1 / r, g2 / r
        vectors[8, 0], vectors[8, 1], vectors[8, 2] = g0, g1, g2  # for ``_wing_block``
        vectors[9, 0], vectors[9, 1], vectors[9, 2] = h0, h1, h2
        vectors[4, 0] = r
        square = r * r
        curvature[0, 0] = -2.0 * g0 * h0 / square
        curvature[1, 1] = -2.0 * g1 * h1 / square
        curvature[2, 2] = -2.0 * g2 * h2 / square
        curvature[0, 1] = curvature[1, 0] = -(g0 * h1 + h0 * g1) / square
        curvature[0, 2] = curvature[2, 0] = -(g0 * h2 + h0 * g2) / square
        curvature[1, 2] = curvature[2, 1] = -(g1 * h2 + h1 * g2) / square
        return
    if corner == 1:
        sign = 1.0
        p0, p1, p2 = vectors[1, 0], vectors[1, 1], vectors[1, 2]
        u0, u1, u2 = vectors[2, 0], vectors[2, 1], vectors[2, 2]
        v0, v1, v2 = vectors[3, 0], vectors[3, 1], vectors[3, 2]
    else:  # seen from x1: p = x0 - x1 = -e, w_a - e, and the angle's sign turned
        sign = -1.0
        p0, p1, p2 = -vectors[1, 0], -vectors[1, 1], -vectors[1, 2]
        u0, u1, u2 = vectors[2, 0] + p0, vectors[2, 1] + p1, vectors[2, 2] + p2
        v0, v1, v2 = vectors[3, 0] + p0, vectors[3, 1] + p1, vectors[3, 2] + p2
    m0, m1, m2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    squared = p0 * p0 + p1 * p1 + p2 * p2
    length = math.sqrt(squared)
    along_m = p0 * m0 + p1 * m1 + p2 * m2
    along_u = p0 * u0 + p1 * u1 + p2 * u2
    along_v = p0 * v0 + p1 * v1 + p2 * v2
    wings = u0 * v0 + u1 * v1 + u2 * v2
    s = -length * along_m
    c = along_u * along_v - squared * wings
    r = s * s + c * c
    ratio = along_m / length
    # s_p = -(p . m) p / |p| - |p| m;  c_p = (p . w_2) w_1 + (p . w_1) w_2 - 2 (w_1 . w_2) p
    sp0, sp1, sp2 = -ratio * p0 - length * m0, -ratio * p1 - length * m1, -ratio * p2 - length * m2
    cp0 = along_v * u0 + along_u * v0 - 2.0 * wings * p0
    cp1 = along_v * u1 + along_u * v1 - 2.0 * wings * p1
    cp2 = along_v * u2 + along_u * v2 - 2.0 * wings * p2
    g0, g1, g2 = c * sp0 - s * cp0, c * sp1 - s * cp1, c * sp2 - s * cp2
    h0, h1, h2 = s * sp0 + c * cp0, s * sp1 + c * cp1, s * sp2 + c * cp2
    along[0], along[1], along[2] = sign * g0 / r, sign * g1 / r, sign * g2 / r
    vectors[4, 0], vectors[4, 1], vectors[4, 2] = p0, p1, p2
    vectors[5, 0], vectors[5, 1], vectors[5, 2] = m0, m1, m2
    vectors[6, 0], vectors[6, 1], vectors[6, 2] = u0, u1, u2
    vectors[7, 0], vectors[7, 1], vectors[7, 2] = v0, v1, v2
    vectors[8, 0], vectors[8, 1], vectors[8, 2] = g0, g1, g2
    vectors[9, 0], vectors[9, 1], vectors[9, 2] = h0, h1, h2
    square = r * r
    for i in range(3):
        for k in range(i, 3):
            identity = 1.0 if i == k else 0.0
            pi, pk = vectors[4, i], vectors[4, k]
            # s_pp = -(p m^T + m p^T) / |p| - (p . m) (I - p p^T / |p|^2) / |p|;  c_pp = w_1 w_2^T + w_2 w_1^T - 2 (w_1 . w_2) I
            s_pp = -(pi * vectors[5, k] + vectors[5, i] * pk) / length - ratio * (identity - pi * pk / squared)
            c_pp = vectors[6, i] * vectors[7, k] + vectors[7, i] * vectors[6, k] - 2.0 * wings * identity
            value = ((c * s_pp - s * c_pp) / r
                     - (vectors[8, i] * vectors[9, k] + vectors[9, i] * vectors[8, k]) / square)
            curvature[i, k] = curvature[k, i] = sign * value


@numba.njit(cache=True, error_model="numpy", inline="always")
def _wing_block(K, scale, change, projection, points):
    """A wing vertex's hinge block 2 k_h (theta_a theta_a^T + (theta - theta_rest) theta_aa), projected, in closed form.
    There theta_a = g / r and theta_aa = -(g h^T + h g^T) / r^2 (``hinge_angle_block``, which leaves g, h and r in
    points), with g . h = 0 and |g| = |h| (a . b = 0 and |a| = |b| for its s = a . q, c = b . q): across the unit
    vectors of g and h the block is [[A, B], [B, 0]], A = 2 k_h |g|^2 / r^2 >= 0, B = -2 k_h (theta - theta_rest)
    |g| |h| / r^2, with eigenvalues l+ = (A + sqrt(A^2 + 4 B^2)) / 2 >= 0 and l- = -B^2 / l+ <= 0 and l+'s vector
    (l+, B). So a hinge's wing block is indefinite wherever it is off its rest angle, and its projection takes two
    square roots instead of an eigensystem."""
    r = points[4, 0]
    g0, g1, g2 = points[8, 0], points[8, 1], points[8, 2]
    h0, h1, h2 = points[9, 0], points[9, 1], points[9, 2]
    along, across = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2), math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    A = scale * along * along / (r * r)
    B = -scale * change * along * across / (r * r)
    upper = 0.5 * (A + math.sqrt(A * A + 4.0 * B * B))
    if not upper > 0.0:  # g = 0: no block
        for i in range(3):
            for k in range(3):
                K[i, k] = 0.0
        return
    lower = filtered_eigenvalue(-B * B / upper, projection)
    length = math.sqrt(upper * upper + B * B)
    p, q = upper / length, B / length  # l+'s vector in (g / |g|, h / |h|); l-'s is (-q, p)
    u0, u1, u2 = p * g0 / along + q * h0 / across, p * g1 / along + q * h1 / across, p * g2 / along + q * h2 / across
    w0, w1, w2 = -q * g0 / along + p * h0 / across, -q * g1 / along + p * h1 / across, -q * g2 / along + p * h2 / across
    K[0, 0] = upper * u0 * u0 + lower * w0 * w0
    K[1, 1] = upper * u1 * u1 + lower * w1 * w1
    K[2, 2] = upper * u2 * u2 + lower * w2 * w2
    K[0, 1] = K[1, 0] = upper * u0 * u1 + lower * w0 * w1
    K[0, 2] = K[2, 0] = upper * u0 * u2 + lower * w0 * w2
    K[1, 2] = K[2, 1] = upper * u1 * u2 + lower * w1 * w2


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
