"""Dense linear algebra of one element's small matrices (2 x 2 and 3 x 3), compiled with numba and allocating nothing:
the determinant, the cofactor matrix J F^-T and its derivative (the volume terms of the energies), F^T F, closed-form
symmetric eigensystems and the rotation-variant SVD that the co-rotated energy and the analytic SPD projection
(projection.py) need. No LAPACK call: from numba it costs microseconds per matrix."""

from __future__ import annotations

import math

import numba

from ..compiled_cache import keep_fresh

# a column F v_a of the SVD shorter than this fraction of the largest singular value is F's null space: U's column is
# then chosen orthogonal to the others instead of normalising round-off
RANK_FLOOR = 1e-14
@numba.njit(cache=True)
def _determinant(F, d):
    if d == 2:
        return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))


@numba.njit(cache=True)
def _epsilon2(i, j):
    return 0.0 if i == j else (1.0 if i < j else -1.0)


@numba.njit(cache=True)
def _epsilon3(i, j, k):
    return (i - j) * (j - k) * (k - i) / 2.0


@numba.njit(cache=True)
def _cofactor(F, d, C):
    """C = det(F) F^-T, written without the inverse (defined for every F)."""
    if d == 2:
        C[0, 0], C[0, 1], C[1, 0], C[1, 1] = F[1, 1], -F[1, 0], -F[0, 1], F[0, 0]
        return
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            C[i, j] = F[i1, j1] * F[i2, j2] - F[i1, j2] * F[i2, j1]


@numba.njit(cache=True)
def _cofactor_derivative(F, d, i, j, k, l):
    """dC_ij / dF_kl: eps_ik eps_jl in 2-D; eps_ikm eps_jln F_mn in 3-D, whose only term is m, n the third indices of
    (i, k) and (j, l)."""
    if d == 2:
        return _epsilon2(i, k) * _epsilon2(j, l)
    if i == k or j == l:
        return 0.0
    m, n = 3 - i - k, 3 - j - l
    return _epsilon3(i, k, m) * _epsilon3(j, l, n) * F[m, n]


@numba.njit(cache=True)
def _others(sigma, d, i):
    """J / sigma_i, as the product of the other singular values (defined at sigma_i = 0)."""
    value = 1.0
    for m in range(d):
        if m != i:
            value *= sigma[m]
    return value


@numba.njit(cache=True)
def _plane_eigen(b00, b01, b11):
    """(high, low, c, s): the eigenvalues of the symmetric 2 x 2 matrix [[b00, b01], [b01, b11]], descending, and the
    unit eigenvector (c, s) of the high one ((-s, c) is the low one's), without cancellation in either."""
    mean, half = 0.5 * (b00 + b11), 0.5 * (b00 - b11)
    radius = math.hypot(half, b01)
    if radius == 0.0:
        return mean, mean, 1.0, 0.0
    if half >= 0.0:
        c, s = half + radius, b01
    else:
        c, s = b01, radius - half
    norm = math.hypot(c, s)
    return mean + radius, mean - radius, c / norm, s / norm


@numba.njit(cache=True)
def _symmetric_eigen(S, d, values, vectors):
    """S = vectors diag(values) vectors^T for a symmetric d x d matrix (d <= 3), values descending; S is overwritten.
    The eigenvalues in closed form (``_closed_form_eigenvalues``); in 3-D the eigenvector of the one farther from the
    others from the largest cross product of two rows of S - lambda I, then the other two from the exact 2 x 2
    problem in the plane normal to it (Eberly, "A robust eigensolver for 3 x 3 symmetric matrices", 2014). An
    eigenvector's error is round-off over the gap to the next eigenvalue, so V diag(values) V^T equals S to
    round-off of |S| even where eigenvalues nearly coincide."""
    if d == 2:
        values[0], values[1], c, s = _plane_eigen(S[0, 0], S[0, 1], S[1, 1])
        vectors[0, 0], vectors[1, 0], vectors[0, 1], vectors[1, 1] = c, s, -s, c
        return
    a00, a01, a02, a11, a12, a22 = S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2]
    _closed_form_eigenvalues(S, 3, values)
    first = 0 if values[0] - values[1] >= values[1] - values[2] else 2
    shift = values[first]
    r0x, r0y, r0z = a00 - shift, a01, a02
    r1x, r1y, r1z = a01, a11 - shift, a12
    r2x, r2y, r2z = a02, a12, a22 - shift
    best, vx, vy, vz = -1.0, 1.0, 0.0, 0.0
    for pair in range(3):
        if pair == 0:
            cx, cy, cz = r0y * r1z - r0z * r1y, r0z * r1x - r0x * r1z, r0x * r1y - r0y * r1x
        elif pair == 1:
            cx, cy, cz = r0y * r2z - r0z * r2y, r0z * r2x - r0x * r2z, r0x * r2y - r0y * r2x
        else:
            cx, cy, cz = r1y * r2z - r1z * r2y, r1z * r2x - r1x * r2z, r1x * r2y - r1y * r2x
        norm = cx * cx + cy * cy + cz * cz
        if norm > best:
            best, vx, vy, vz = norm, cx, cy, cz
    if not best > 0.0:  # S - lambda I of rank 1 or 0 (two or three equal eigenvalues): any axis will do to start
        vx, vy, vz = 1.0, 0.0, 0.0
        best = 1.0
        if first == 2:  # the double eigenvalue is the top one: the single one's vector is S's range direction
            rows = (r0x * r0x + r0y * r0y + r0z * r0z, r1x * r1x + r1y * r1y + r1z * r1z, r2x * r2x + r2y * r2y + r2z * r2z)
            pick = 0 if rows[0] >= rows[1] and rows[0] >= rows[2] else (1 if rows[1] >= rows[2] else 2)
            if rows[pick] > 0.0:
                vx, vy, vz = (r0x, r0y, r0z) if pick == 0 else ((r1x, r1y, r1z) if pick == 1 else (r2x, r2y, r2z))
                best = rows[pick]
    scale = 1.0 / math.sqrt(best)
    vx, vy, vz = vx * scale, vy * scale, vz * scale
    # an orthonormal basis (u, w) of the plane normal to v
    if abs(vx) > abs(vy):
        scale = 1.0 / math.sqrt(vx * vx + vz * vz)
        ux, uy, uz = -vz * scale, 0.0, vx * scale
    else:
        scale = 1.0 / math.sqrt(vy * vy + vz * vz)
        ux, uy, uz = 0.0, vz * scale, -vy * scale
    wx, wy, wz = vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux
    # S restricted to the plane: [u w]^T S [u w]
    sux, suy, suz = a00 * ux + a01 * uy + a02 * uz, a01 * ux + a11 * uy + a12 * uz, a02 * ux + a12 * uy + a22 * uz
    swx, swy, swz = a00 * wx + a01 * wy + a02 * wz, a01 * wx + a11 * wy + a12 * wz, a02 * wx + a12 * wy + a22 * wz
    b00 = ux * sux + uy * suy + uz * suz
    b01 = wx * sux + wy * suy + wz * suz
    b11 = wx * swx + wy * swy + wz * swz
    high, low, c, s = _plane_eigen(b00, b01, b11)
    vectors[0, first], vectors[1, first], vectors[2, first] = vx, vy, vz
    values[first] = vx * (a00 * vx + a01 * vy + a02 * vz) + vy * (a01 * vx + a11 * vy + a12 * vz) + vz * (a02 * vx + a12 * vy + a22 * vz)
    others = (1, 2) if first == 0 else (0, 1)
    for column in range(2):
        target = others[column]
        p, q = (c, s) if column == 0 else (-s, c)
        vectors[0, target], vectors[1, target], vectors[2, target] = p * ux + q * wx, p * uy + q * wy, p * uz + q * wz
        values[target] = high if column == 0 else low


@numba.njit(cache=True)
def _closed_form_eigenvalues(S, d, values):
    """The eigenvalues of the symmetric d x d (d <= 3) matrix S, descending, in closed form (the trigonometric
    solution of the characteristic cubic in 3-D), accurate to round-off of |S|; S is overwritten."""
    if d == 2:
        mean, half = 0.5 * (S[0, 0] + S[1, 1]), math.hypot(0.5 * (S[0, 0] - S[1, 1]), S[0, 1])
        values[0], values[1] = mean + half, mean - half
        return
    mean = (S[0, 0] + S[1, 1] + S[2, 2]) / 3.0
    off = S[0, 1] ** 2 + S[0, 2] ** 2 + S[1, 2] ** 2
    spread = math.sqrt(((S[0, 0] - mean) ** 2 + (S[1, 1] - mean) ** 2 + (S[2, 2] - mean) ** 2 + 2.0 * off) / 6.0)
    if spread == 0.0:
        values[0] = values[1] = values[2] = mean
        return
    for i in range(3):
        S[i, i] -= mean
    angle = math.acos(max(-1.0, min(1.0, _determinant(S, 3) / (2.0 * spread ** 3)))) / 3.0
    values[0] = mean + 2.0 * spread * math.cos(angle)
    values[2] = mean + 2.0 * spread * math.cos(angle + 2.0 * math.pi / 3.0)
    values[1] = 3.0 * mean - values[0] - values[2]


@numba.njit(cache=True)
def _gram(F, d, S):
    """S = F^T F (d, d)."""
    for i in range(d):
        for j in range(d):
            value = 0.0
            for m in range(d):
                value += F[m, i] * F[m, j]
            S[i, j] = value


@numba.njit(cache=True)
def _singular_values(F, d, S, sigma):
    """The signed singular values of F (descending, the last with the sign of det F) from the closed-form eigenvalues
    of F^T F: accurate to round-off of |F|^2 in sigma^2, which is what the projection's screening needs (the
    full SVD costs three times more). S (d, d) is scratch."""
    _gram(F, d, S)
    _closed_form_eigenvalues(S, d, sigma)
    for i in range(d):
        sigma[i] = math.sqrt(max(sigma[i], 0.0))
    if _determinant(F, d) < 0.0:
        sigma[d - 1] = -sigma[d - 1]


@numba.njit(cache=True)
def _positive_definite_small(H, d):
    """Whether the symmetric d x d (d <= 3) matrix H is positive definite, by its leading principal minors."""
    if not H[0, 0] > 0.0:
        return False
    minor = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
    if not minor > 0.0:
        return False
    return d == 2 or _determinant(H, 3) > 0.0


@numba.njit(cache=True)
def _signed_svd(F, d, U, sigma, V, S):
    """F = U diag(sigma) V^T with U and V rotations, sigma descending but for the last, which takes the sign of det F
    (the rotation-variant SVD of Irving et al. 2004). V and sigma^2 from the eigensystem of F^T F; U's columns
    F v_i / sigma_i, the last one the cross product of the others, so that U is a rotation even for a flat element.
    S (d, d) is scratch."""
    _gram(F, d, S)
    _symmetric_eigen(S, d, sigma, V)
    if _determinant(V, d) < 0.0:
        for i in range(d):
            V[i, d - 1] = -V[i, d - 1]
    floor = RANK_FLOOR * math.sqrt(max(sigma[0], 0.0))  # sigma holds sigma^2 here
    for a in range(d - 1):
        for i in range(d):
            value = 0.0
            for j in range(d):
                value += F[i, j] * V[j, a]
            U[i, a] = value
        for b in range(a):  # Gram-Schmidt against the columns before: round-off of F^T F's eigenvectors
            overlap = 0.0
            for i in range(d):
                overlap += U[i, a] * U[i, b]
            for i in range(d):
                U[i, a] -= overlap * U[i, b]
        norm = 0.0
        for i in range(d):
            norm += U[i, a] * U[i, a]
        norm = math.sqrt(norm)
        if norm > floor and norm > 0.0:
            for i in range(d):
                U[i, a] /= norm
        elif a == 0:  # F = 0: any direction
            for i in range(d):
                U[i, 0] = 1.0 if i == 0 else 0.0
        else:  # 3-D, F of rank 1: a unit vector orthogonal to the first column, from the axis least along it
            axis = 0
            for k in range(1, 3):
                if abs(U[k, 0]) < abs(U[axis, 0]):
                    axis = k
            U[0, 1] = (U[1, 0] if axis == 2 else 0.0) - (U[2, 0] if axis == 1 else 0.0)
            U[1, 1] = (U[2, 0] if axis == 0 else 0.0) - (U[0, 0] if axis == 2 else 0.0)
            U[2, 1] = (U[0, 0] if axis == 1 else 0.0) - (U[1, 0] if axis == 0 else 0.0)
            norm = math.sqrt(U[0, 1] ** 2 + U[1, 1] ** 2 + U[2, 1] ** 2)
            for i in range(3):
                U[i, 1] /= norm
    if d == 2:
        U[0, 1], U[1, 1] = -U[1, 0], U[0, 0]
    else:
        U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
        U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
        U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]
    for a in range(d):
        value = 0.0
        for i in range(d):
            for j in range(d):
                value += U[i, a] * F[i, j] * V[j, a]
        sigma[a] = value


@numba.njit(cache=True)
def _positive_definite_dense(M, n, shift, L):
    """Whether M + shift I (symmetric n x n) is positive definite, by a Cholesky factorisation into the scratch L."""
    for j in range(n):
        value = M[j, j] + shift
        for k in range(j):
            value -= L[j, k] * L[j, k]
        if not value > 0.0:
            return False
        L[j, j] = math.sqrt(value)
        for i in range(j + 1, n):
            value = M[i, j]
            for k in range(j):
                value -= L[i, k] * L[j, k]
            L[i, j] = value / L[j, j]
    return True


@numba.njit(cache=True)
def _tridiagonal_eigen(S, n, values, vectors, off):
    """S = vectors diag(values) vectors^T for a symmetric n x n matrix, S overwritten (off (n,) is scratch): Householder
    reduction to tridiagonal form, then implicit QR steps with Wilkinson's shift on the unreduced blocks, their Givens
    rotations accumulated (Golub & Van Loan, "Matrix computations", algorithms 8.3.1 and 8.3.3). Each eigenvalue is
    accurate to round-off of |S|; about a fifth of cyclic Jacobi's time at n = 12."""
    for i in range(n):
        for j in range(n):
            vectors[i, j] = 1.0 if i == j else 0.0
    # Householder: column k below the subdiagonal to zero, S <- P S P, vectors <- vectors P, P = I - 2 v v^T
    v = values  # scratch until the end
    for k in range(n - 2):
        norm = 0.0
        for i in range(k + 1, n):
            norm += S[i, k] * S[i, k]
        norm = math.sqrt(norm)
        if norm == 0.0:
            continue
        alpha = -norm if S[k + 1, k] >= 0.0 else norm
        for i in range(n):
            v[i] = 0.0
        v[k + 1] = S[k + 1, k] - alpha
        for i in range(k + 2, n):
            v[i] = S[i, k]
        length = 0.0
        for i in range(k + 1, n):
            length += v[i] * v[i]
        length = math.sqrt(length)
        if length == 0.0:
            continue
        for i in range(k + 1, n):
            v[i] /= length
        # p = S v, K = v^T p, q = p - K v; S <- S - 2 v q^T - 2 q v^T
        K = 0.0
        for i in range(k, n):
            value = 0.0
            for j in range(k + 1, n):
                value += S[i, j] * v[j]
            off[i] = value
            K += v[i] * value
        for i in range(k, n):
            off[i] -= K * v[i]
        for i in range(k, n):
            for j in range(k, n):
                S[i, j] -= 2.0 * (v[i] * off[j] + off[i] * v[j])
        for i in range(n):
            value = 0.0
            for j in range(k + 1, n):
                value += vectors[i, j] * v[j]
            for j in range(k + 1, n):
                vectors[i, j] -= 2.0 * value * v[j]
    d = values
    for i in range(n):
        d[i] = S[i, i]
        off[i] = S[i + 1, i] if i + 1 < n else 0.0
    # implicit symmetric QR on the tridiagonal (d, off), deflating from the bottom: an off-diagonal entry below
    # round-off of the whole matrix is 0
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(d[i]) + abs(off[i]))
    small = 2.3e-16 * scale
    high = n - 1
    for _ in range(30 * n):
        while high > 0 and abs(off[high - 1]) <= small:
            off[high - 1] = 0.0
            high -= 1
        if high == 0:
            break
        low = high - 1
        while low > 0 and abs(off[low - 1]) > small:
            low -= 1
        # Wilkinson's shift: the eigenvalue of the trailing 2 x 2 nearer d[high]
        half = 0.5 * (d[high - 1] - d[high])
        square = off[high - 1] * off[high - 1]
        root = math.sqrt(half * half + square)
        shift = d[high] - square / (half + (root if half >= 0.0 else -root)) if square > 0.0 else d[high]
        x, z = d[low] - shift, off[low]
        for k in range(low, high):
            radius = math.hypot(x, z)
            c, s = (1.0, 0.0) if radius == 0.0 else (x / radius, -z / radius)
            if k > low:
                off[k - 1] = radius
            # the rotation G(k, k + 1) applied on both sides of the 2 x 2 block and to its neighbours
            dk, dk1, ek = d[k], d[k + 1], off[k]
            d[k] = c * c * dk - 2.0 * c * s * ek + s * s * dk1
            d[k + 1] = s * s * dk + 2.0 * c * s * ek + c * c * dk1
            off[k] = c * s * (dk - dk1) + (c * c - s * s) * ek
            if k < high - 1:
                x, z = off[k], -s * off[k + 1]
                off[k + 1] = c * off[k + 1]
            for i in range(n):
                vk, vk1 = vectors[i, k], vectors[i, k + 1]
                vectors[i, k], vectors[i, k + 1] = c * vk - s * vk1, s * vk + c * vk1


@numba.njit(cache=True)
def largest_magnitude(values, n):
    largest = 0.0
    for k in range(n):
        largest = max(largest, abs(values[k]))
    return largest


@numba.njit(cache=True)
def rank_one_update(M, n, change, vector):
    """M += change vector vector^T (n x n, in place): one eigenvalue of a symmetric M moved by change, vector its unit
    eigenvector."""
    for i in range(n):
        scaled = change * vector[i]
        for j in range(n):
            M[i, j] += scaled * vector[j]


@numba.njit(cache=True)
def project_dense(M, n, mode, shift, scratch, values, vectors):
    """The symmetric n x n matrix M made PSD in place, its eigenvalues below -shift max|M_ii| clamped to 0 (mode 1) or
    mirrored (mode 2): a Cholesky test first, which leaves the PSD ones (most of them) untouched, then the
    tridiagonal QR eigensystem. True where M was changed. scratch, vectors (n, n) and values (2 n,) are the
    caller's."""
    if mode == 0:
        return False
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(M[i, i]))
    if scale == 0.0 or _positive_definite_dense(M, n, shift * scale, scratch):
        return False
    for i in range(n):
        for j in range(n):
            scratch[i, j] = M[i, j]
    _tridiagonal_eigen(scratch, n, values[:n], vectors, values[n:])
    largest = largest_magnitude(values, n)
    changed = False
    for k in range(n):
        if values[k] >= -shift * largest:
            continue
        changed = True
        rank_one_update(M, n, -values[k] if mode == 1 else -2.0 * values[k], vectors[:, k])
    return changed


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
