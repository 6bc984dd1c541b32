"""The colliders' per-vertex terms, compiled, for vertex block descent's colour sweeps: the penalty and the
IPC barrier of the plane, sphere, box, capsule and torus (colliders.py) at one point, moving and spinning (pose.py), as
model.py's ``point_terms`` and ``point_energy_changes`` give them in numpy (the reference in the tests).

Each of these shapes has, where it is smooth, grad phi = n and hess phi = P / rho with P a projector and rho > 0 the
distance to the shape's core (the point, segment or box it is a rounding of): P = I - n n^T for the sphere,
(I - e e^T) - n n^T along the capsule's side (I - n n^T at its ends), diag(past) - n n^T outside the box (the axes
along which the point lies past a face), and 0 for the plane and inside the box; the torus has two such terms (its
``_torus``). So the curvature term s hess phi of a
potential f(phi) (s = f'(phi)) has the one eigenvalue s / rho on range(P), and its projection (clamp or mirror, as
``Collider.scaled_hessian`` takes it with eigh) is filter(s / rho) P. A spinning collider's point is mapped into its
t = 0 frame, q = M^T (p - c(t)) + c0, and its derivatives back (grad -> M grad, P -> M P M^T), as pose.py does.

``colliders_of`` packs a ContactModel's colliders, where they stand at the model's time, into the arrays the kernels
read (one tuple, the sweeps' ``colliders``); None where a collider has no compiled form here (a grid SDF).
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
from numba import prange

from ..compiled_cache import keep_fresh
from ..vertex_kernels import filtered_eigenvalue
from .model import CCD_MARGIN
from .sdf import TOI_MAX_ITERATIONS, TOI_TOLERANCE, _perpendicular

PLANE, SPHERE, BOX, CAPSULE, TORUS = 0, 1, 2, 3, 4
SHAPE_CODES = {"plane": PLANE, "sphere": SPHERE, "box": BOX, "capsule": CAPSULE, "torus": TORUS}
PENALTY, IPC = 0, 1
# per collider, the shape's numbers: plane (normal, point), sphere (center, radius), box (center, half_extents),
# capsule (a, b, radius, a fixed unit normal to b - a: its gradient on the segment), torus (center, axis, R, r, a fixed
# unit normal to the axis: e on the axis); the torus's 11 are the most
PARAMETER_SLOTS = 11
_CCD = (CCD_MARGIN, TOI_TOLERANCE, TOI_MAX_ITERATIONS)


def colliders_of(contact, dim: int) -> tuple | None:
    """(shapes (c,), parameters (c, 10), frames M (c, d, d), moved centres c(t) (c, d), rest centres c0 (c, d),
    stiffnesses (c,), method, kappa, dhat, and IPC's CCD: its margin, the tolerance and iteration cap of conservative
    advancement) of the contact model's colliders at its time; None where one has no compiled form (or the model has
    mesh contact, which couples vertices). No contact: the same tuple with c = 0. The CCD's numbers travel with the
    colliders, not as the kernels' globals: numba would keep those in its cache when model.py or sdf.py changed."""
    if contact is None:
        return empty_colliders(dim)
    if contact.mesh is not None:
        return None
    count = len(contact.colliders)
    shapes = np.zeros(count, dtype=np.int64)
    parameters = np.zeros((count, PARAMETER_SLOTS))
    frames = np.zeros((count, dim, dim))
    moved, rest = np.zeros((count, dim)), np.zeros((count, dim))
    stiffness = np.zeros(count)
    time = contact.time
    for number, placed in enumerate(contact.colliders):
        collider = placed.collider
        code = SHAPE_CODES.get(collider.shape)
        if code is None:
            return None
        shapes[number] = code
        if code == PLANE:
            values = [collider.normal, collider.point]
        elif code == SPHERE:
            values = [collider.center, [collider.radius]]
        elif code == BOX:
            values = [collider.center, collider.half_extents]
        elif code == TORUS:
            values = [collider.center, collider.axis, [collider.major_radius, collider.minor_radius],
                      _perpendicular(collider.axis)]
        else:
            values = [collider.a, collider.b, [collider.radius], _perpendicular((collider.b - collider.a)
                                                                                / np.linalg.norm(collider.b - collider.a))]
        packed = np.concatenate(values)
        parameters[number, :packed.size] = packed
        if placed.spin is None:  # q = p - v t: M = I, c0 = 0
            frames[number] = np.eye(dim)
            moved[number] = collider.velocity * time
        else:
            frames[number] = placed._rotation(time)
            moved[number] = placed.spin[0] + collider.velocity * time
            rest[number] = placed.spin[0]
        stiffness[number] = 0.0 if placed.stiffness is None else placed.stiffness
    method = IPC if contact.method == "ipc" else PENALTY
    kappa = 0.0 if contact.kappa is None else float(contact.kappa)  # None: a penalty, whose stiffnesses are per collider
    return (shapes, parameters, frames, moved, rest, stiffness, method, kappa, float(contact.dhat)) + _CCD


def placed(sweep, contact, dim: int):
    """A system's compiled sweep (a dataclass with a ``colliders`` field) with its contact's colliders where they stand
    now: the sweep itself without contact, None where a collider has no compiled form (the numpy sweep then takes
    them)."""
    if sweep is None or contact is None:
        return sweep
    colliders = colliders_of(contact, dim)
    return None if colliders is None else dataclasses.replace(sweep, colliders=colliders)


def empty_colliders(dim: int) -> tuple:
    return (np.zeros(0, dtype=np.int64), np.zeros((0, PARAMETER_SLOTS)), np.zeros((0, dim, dim)), np.zeros((0, dim)),
            np.zeros((0, dim)), np.zeros(0), PENALTY, 1.0, 1.0) + _CCD


@numba.njit(cache=True)
def point_scratch(d, colliders):
    """One thread's arrays: q, the local normal, P, the world normal, each collider's phi at the vertex, the vertex's
    position and its moved position, Q (the torus's second projector), and a move's start and step in a collider's
    frame (``impact_fraction``)."""
    return (np.empty(d), np.empty(d), np.empty((d, d)), np.empty(d), np.empty(max(colliders[0].size, 1)), np.empty(d),
            np.empty(d), np.empty((d, d)), np.empty(d), np.empty(d))


@numba.njit(cache=True, error_model="numpy")
def _shape(code, parameters, c, q, d, normal, P, Q, with_derivatives):
    """phi(q) of collider c in its t = 0 frame and, ``with_derivatives``, its normal (into normal), 1 / rho with P
    (into P; 0 where the shape is flat there) and the torus's second curvature with Q (0 for the other shapes)."""
    if code == PLANE:
        phi = 0.0
        for a in range(d):
            phi += (q[a] - parameters[c, d + a]) * parameters[c, a]
            normal[a] = parameters[c, a]
        return phi, 0.0, 0.0
    if code == TORUS:
        return _torus(parameters, c, q, normal, P, Q, with_derivatives)
    if code == BOX:
        out = 0.0
        largest = -math.inf
        nearest = 0
        for a in range(d):
            local = q[a] - parameters[c, a]
            gap = abs(local) - parameters[c, d + a]
            if gap > 0.0:
                out += gap * gap
            if gap > largest:  # the first of a tie, as argmax
                largest, nearest = gap, a
        out = math.sqrt(out)
        phi = out + min(largest, 0.0)
        if not with_derivatives:
            return phi, 0.0, 0.0
        if out > 0.0:
            for a in range(d):
                local = q[a] - parameters[c, a]
                gap = abs(local) - parameters[c, d + a]
                normal[a] = (1.0 if local >= 0.0 else -1.0) * max(gap, 0.0) / out
            for a in range(d):
                gap = abs(q[a] - parameters[c, a]) - parameters[c, d + a]
                for b in range(d):
                    P[a, b] = (1.0 if a == b and gap > 0.0 else 0.0) - normal[a] * normal[b]
            return phi, 1.0 / out, 0.0
        for a in range(d):
            normal[a] = 0.0
        normal[nearest] = 1.0 if q[nearest] - parameters[c, nearest] >= 0.0 else -1.0
        return phi, 0.0, 0.0
    # sphere and capsule: the offset r from the nearest core point, phi = |r| - radius
    slides = False
    axis_squared = 0.0
    if code == SPHERE:
        radius = parameters[c, d]
        for a in range(d):
            normal[a] = q[a] - parameters[c, a]
    else:
        radius = parameters[c, 2 * d]
        along = 0.0
        for a in range(d):
            axis = parameters[c, d + a] - parameters[c, a]
            along += (q[a] - parameters[c, a]) * axis
            axis_squared += axis * axis
        t = along / axis_squared
        slides = 0.0 < t < 1.0
        t = min(max(t, 0.0), 1.0)
        for a in range(d):
            normal[a] = q[a] - parameters[c, a] - t * (parameters[c, d + a] - parameters[c, a])
    rho = 0.0
    for a in range(d):
        rho += normal[a] * normal[a]
    rho = math.sqrt(rho)
    if not with_derivatives:
        return rho - radius, 0.0, 0.0
    if rho == 0.0:  # on the core: a fixed normal, no curvature
        for a in range(d):
            normal[a] = (1.0 if a == 0 else 0.0) if code == SPHERE else parameters[c, 2 * d + 1 + a]
        return rho - radius, 0.0, 0.0
    for a in range(d):
        normal[a] /= rho
    for a in range(d):
        for b in range(d):
            across = 1.0 if a == b else 0.0
            if slides:
                across -= ((parameters[c, d + a] - parameters[c, a]) * (parameters[c, d + b] - parameters[c, b])
                           / axis_squared)
            P[a, b] = across - normal[a] * normal[b]
    return rho - radius, 1.0 / rho, 0.0


@numba.njit(cache=True, error_model="numpy")
def _torus(parameters, c, q, normal, P, Q, with_derivatives):
    """The torus (3-D; colliders.py ``Torus``): with z = q.axis, e the unit radial direction at distance rho from the
    axis and D = |(rho - R, z)|, hess phi = (e e^T + a a^T + (rho - R)/rho b b^T - n n^T) / D (b = a x e), which is
    t t^T / D + (rho - R) / (rho D) b b^T with t = (z e - (rho - R) a) / D the tangent of the tube's circle: P = t t^T
    and Q = b b^T, curvatures 1 / D and (rho - R) / (rho D) (negative in the hole). On the axis e is a fixed normal to
    it, on the core circle n = e, and hess phi = 0 on both."""
    height = 0.0
    for a in range(3):
        height += (q[a] - parameters[c, a]) * parameters[c, 3 + a]
    rho = 0.0
    for a in range(3):
        normal[a] = q[a] - parameters[c, a] - height * parameters[c, 3 + a]  # the radial part, for now
        rho += normal[a] * normal[a]
    rho = math.sqrt(rho)
    major = parameters[c, 6]
    core = math.hypot(rho - major, height)
    phi = core - parameters[c, 7]
    if not with_derivatives:
        return phi, 0.0, 0.0
    e0, e1, e2 = parameters[c, 8], parameters[c, 9], parameters[c, 10]
    if rho != 0.0:
        e0, e1, e2 = normal[0] / rho, normal[1] / rho, normal[2] / rho
    if core == 0.0:
        normal[0], normal[1], normal[2] = e0, e1, e2
        return phi, 0.0, 0.0
    a0, a1, a2 = parameters[c, 3], parameters[c, 4], parameters[c, 5]
    out = rho - major
    normal[0], normal[1], normal[2] = (out * e0 + height * a0) / core, (out * e1 + height * a1) / core, (
        out * e2 + height * a2) / core
    if rho == 0.0:
        return phi, 0.0, 0.0
    t0, t1, t2 = (height * e0 - out * a0) / core, (height * e1 - out * a1) / core, (height * e2 - out * a2) / core
    b0, b1, b2 = a1 * e2 - a2 * e1, a2 * e0 - a0 * e2, a0 * e1 - a1 * e0
    P[0, 0], P[0, 1], P[0, 2] = t0 * t0, t0 * t1, t0 * t2
    P[1, 0], P[1, 1], P[1, 2] = t1 * t0, t1 * t1, t1 * t2
    P[2, 0], P[2, 1], P[2, 2] = t2 * t0, t2 * t1, t2 * t2
    Q[0, 0], Q[0, 1], Q[0, 2] = b0 * b0, b0 * b1, b0 * b2
    Q[1, 0], Q[1, 1], Q[1, 2] = b1 * b0, b1 * b1, b1 * b2
    Q[2, 0], Q[2, 1], Q[2, 2] = b2 * b0, b2 * b1, b2 * b2
    return phi, 1.0 / core, out / (rho * core)


@numba.njit(cache=True, error_model="numpy")
def _local(c, p, d, frames, moved, rest, q):
    """q = M^T (p - c(t)) + c0: the point in collider c's t = 0 frame."""
    for a in range(d):
        total = 0.0
        for b in range(d):
            total += frames[c, b, a] * (p[b] - moved[c, b])
        q[a] = total + rest[c, a]


@numba.njit(cache=True, error_model="numpy")
def signed_distance(c, p, d, colliders, q, normal, P, Q):
    shapes, parameters, frames, moved, rest = colliders[0], colliders[1], colliders[2], colliders[3], colliders[4]
    _local(c, p, d, frames, moved, rest, q)
    return _shape(shapes[c], parameters, c, q, d, normal, P, Q, False)[0]


@numba.njit(cache=True, error_model="numpy")
def barrier(phi, dhat):
    """(B, dB/dphi, d^2B/dphi^2) of the physical IPC barrier at 0 < phi < dhat (model.py ``barrier``)."""
    s = phi * phi
    s_hat = dhat * dhat
    r = s - s_hat
    log = math.log(s / s_hat)
    first = -2.0 * r * log - r * r / s
    second = -2.0 * log - 4.0 * r / s + (r / s) * (r / s)
    scale = 1.0 / (dhat * dhat * dhat)
    return scale * (-r * r * log), scale * 2.0 * phi * first, scale * (4.0 * s * second + 2.0 * first)


@numba.njit(cache=True, error_model="numpy")
def _barrier_value(phi, dhat):
    if phi <= 0.0:
        return math.inf
    if phi < dhat:
        return barrier(phi, dhat)[0]
    return 0.0


@numba.njit(cache=True, error_model="numpy", inline="always")
def add_point_terms(p, d, colliders, projection, g, H, scratch):
    """The colliders' dP/dp into g and d^2P/dp^2 (its curvature term filtered by ``projection``) into H, at point p;
    each collider's phi at p into scratch's distances (what ``point_change`` starts from). A point on or inside a
    collider under IPC gets no term from it (numpy's ``point_terms`` gives such a state infinite energy). Returns the
    clearance: the least phi less the reach (0 for the penalty, dhat for IPC). A move shorter than it changes no
    collider's potential (each phi is 1-Lipschitz: these are exact distances), so ``point_change`` is 0 there."""
    shapes, parameters, frames, moved, rest, stiffness, method, kappa, dhat = colliders[:9]
    reach = dhat if method == IPC else 0.0
    clearance = math.inf
    q, normal, P, world, distances, Q = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4], scratch[7]
    for c in range(shapes.size):
        _local(c, p, d, frames, moved, rest, q)
        phi, curvature, twist = _shape(shapes[c], parameters, c, q, d, normal, P, Q, True)
        distances[c] = phi
        clearance = min(clearance, phi - reach)
        if method == PENALTY:
            if not phi < 0.0:
                continue
            depth = -phi
            slope, bend = -stiffness[c] * depth, stiffness[c]  # k/2 phi^2: f' = k phi, f'' = k
        else:
            if not (0.0 < phi < dhat):
                continue
            _, first, second = barrier(phi, dhat)
            slope, bend = kappa * first, kappa * second
        for a in range(d):
            total = 0.0
            for b in range(d):
                total += frames[c, a, b] * normal[b]
            world[a] = total
        for a in range(d):
            g[a] += slope * world[a]
            for b in range(d):
                H[a, b] += bend * world[a] * world[b]
        _add_curvature(H, slope * curvature, projection, c, P, d, frames)
        _add_curvature(H, slope * twist, projection, c, Q, d, frames)  # the torus's second curvature (0 elsewhere)
    return clearance


@numba.njit(cache=True, error_model="numpy")
def _add_curvature(H, value, projection, c, P, d, frames):
    """H += filter(value) M P M^T: one curvature term in the world frame (nothing where the filtered value is 0)."""
    factor = filtered_eigenvalue(value, projection)
    if factor == 0.0:
        return
    for a in range(d):
        for b in range(d):
            total = 0.0
            for k in range(d):
                for m in range(d):
                    total += frames[c, a, k] * P[k, m] * frames[c, b, m]
            H[a, b] += factor * total


@numba.njit(cache=True, error_model="numpy")
def point_change(p, u, d, colliders, scratch):
    """The change of the colliders' potential when point p moves by u, from the distances ``add_point_terms`` left:
    the penalty's k/2 (d' - d)(d' + d) (depths d), the barrier's kappa (B(phi') - B(phi))."""
    shapes, stiffness, method, kappa, dhat = colliders[0], colliders[5], colliders[6], colliders[7], colliders[8]
    q, normal, P, distances, moved_point, Q = scratch[0], scratch[1], scratch[2], scratch[4], scratch[6], scratch[7]
    for a in range(d):
        moved_point[a] = p[a] + u[a]
    change = 0.0
    for c in range(shapes.size):
        after = signed_distance(c, moved_point, d, colliders, q, normal, P, Q)
        before = distances[c]
        if method == PENALTY:
            depth, moved_depth = max(-before, 0.0), max(-after, 0.0)
            change += 0.5 * stiffness[c] * (moved_depth - depth) * (moved_depth + depth)
        else:
            change += kappa * (_barrier_value(after, dhat) - _barrier_value(before, dhat))
    return change


@numba.njit(cache=True, error_model="numpy")
def _enter_ball(m, step, d, radius):
    """The first tau in [0, 1] with |m + tau step| = radius: 0 if |m| <= radius already, inf if never (sdf.py's
    ``_enter_ball``). |step|^2 tau^2 + 2 b tau + c = 0 (b = m . step, c = |m|^2 - radius^2 > 0) has a root in tau > 0
    only when b < 0; the smaller one is c / (-b + sqrt(b^2 - |step|^2 c)), free of cancellation."""
    along, offset, squared = 0.0, 0.0, 0.0
    for a in range(d):
        along += m[a] * step[a]
        offset += m[a] * m[a]
        squared += step[a] * step[a]
    offset -= radius * radius
    if offset <= 0.0:
        return 0.0
    discriminant = along * along - squared * offset
    if along >= 0.0 or discriminant < 0.0:
        return math.inf
    tau = offset / (math.sqrt(discriminant) - along)
    return tau if tau <= 1.0 else math.inf


@numba.njit(cache=True, error_model="numpy")
def _time_of_impact(c, d, colliders, start, step, length, q, normal, P, Q):
    """The first tau in [0, 1] at which start + tau step (collider c's t = 0 frame; |step| = length > 0) reaches
    phi = 0, inf where it does not: colliders.py's ``_time_of_impact`` at distance 0. Exact for the plane, the sphere
    and the capsule; conservative advancement for the box and the torus, as sdf.py's: tau never passes the first root,
    and stops once phi <= TOI_TOLERANCE |step| (the colliders' tolerance and cap, ``colliders_of``)."""
    shapes, parameters, toi_tolerance, max_iterations = colliders[0], colliders[1], colliders[10], colliders[11]
    code = shapes[c]
    if code == PLANE:  # phi is linear along the move
        gap = _shape(code, parameters, c, start, d, normal, P, Q, False)[0]
        if gap <= 0.0:
            return 0.0
        for a in range(d):
            q[a] = start[a] + step[a]
        end_gap = _shape(code, parameters, c, q, d, normal, P, Q, False)[0]
        return gap / (gap - end_gap) if end_gap <= 0.0 else math.inf
    if code == SPHERE:
        for a in range(d):
            q[a] = start[a] - parameters[c, a]
        return _enter_ball(q, step, d, parameters[c, d])
    if code == CAPSULE:
        # the first entry into either end ball or through the finite cylinder's side (an entry through a flat end
        # lies inside an end ball, which is entered no later)
        radius, squared_axis, m_along, step_along = parameters[c, 2 * d], 0.0, 0.0, 0.0
        for a in range(d):
            axis = parameters[c, d + a] - parameters[c, a]
            squared_axis += axis * axis
            m_along += (start[a] - parameters[c, a]) * axis
            step_along += step[a] * axis
        for a in range(d):  # the parts of m = start - a and of step across the axis
            axis = parameters[c, d + a] - parameters[c, a]
            q[a] = start[a] - parameters[c, a] - m_along / squared_axis * axis
            normal[a] = step[a] - step_along / squared_axis * axis
        side = _enter_ball(q, normal, d, radius)
        if math.isfinite(side):
            t = (m_along + side * step_along) / squared_axis
            if t < 0.0 or t > 1.0:  # the infinite cylinder is entered beyond the segment's ends
                side = math.inf
        for a in range(d):
            q[a] = start[a] - parameters[c, a]
        first = min(side, _enter_ball(q, step, d, radius))
        for a in range(d):
            q[a] = start[a] - parameters[c, d + a]
        return min(first, _enter_ball(q, step, d, radius))
    tolerance = toi_tolerance * length
    gap = _shape(code, parameters, c, start, d, normal, P, Q, False)[0]
    if gap <= tolerance:
        return 0.0
    tau = 0.0
    for _ in range(max_iterations):
        tau += gap / length  # phi is 1-Lipschitz: it cannot reach 0 before this
        if tau > 1.0:
            return math.inf
        for a in range(d):
            q[a] = start[a] + tau * step[a]
        gap = _shape(code, parameters, c, q, d, normal, P, Q, False)[0]
        if gap <= tolerance:
            return tau
    return tau  # the cap: still a lower bound of the first root


@numba.njit(cache=True, error_model="numpy")
def impact_fraction(p, u, d, colliders, scratch):
    """IPC's step filter for point p moving alone by u: the largest fraction of u that stops (1 - the colliders'
    CCD margin) of the way to the first collider it would reach (model.py ``max_step`` for one point); 1 where it
    reaches none. Reads each
    collider's phi at p from scratch's distances (``add_point_terms``): a collider farther than |u| is not reached."""
    frames, moved, rest, margin = colliders[2], colliders[3], colliders[4], colliders[9]
    q, normal, P, distances, Q, start, step = (scratch[0], scratch[1], scratch[2], scratch[4], scratch[7], scratch[8],
                                               scratch[9])
    squared = 0.0
    for a in range(d):
        squared += u[a] * u[a]
    length = math.sqrt(squared)
    fraction = 1.0
    if not length > 0.0:
        return fraction
    for c in range(colliders[0].size):
        if length < distances[c]:
            continue
        _local(c, p, d, frames, moved, rest, start)
        for a in range(d):
            total = 0.0
            for b in range(d):
                total += frames[c, b, a] * u[b]  # M^T u: the move in the collider's frame
            step[a] = total
        impact = _time_of_impact(c, d, colliders, start, step, length, q, normal, P, Q)
        if impact <= 1.0:
            fraction = min(fraction, (1.0 - margin) * impact)
    return fraction


# -- the same terms at given points, vectorised over them (what the tests compare with numpy's) ---------------------
@numba.njit(parallel=True, cache=True, error_model="numpy")
def point_blocks(positions, colliders, projection, gradient, hessian):
    """gradient[k], hessian[k] += the colliders' terms at positions[k] (k points, each on its own)."""
    d = positions.shape[1]
    for k in prange(positions.shape[0]):
        scratch = point_scratch(d, colliders)
        add_point_terms(positions[k], d, colliders, projection, gradient[k], hessian[k], scratch)


@numba.njit(parallel=True, cache=True, error_model="numpy")
def point_moves(positions, steps, colliders, changes, fractions):
    """changes[k] = the change of the colliders' potential when point k alone moves by steps[k]; fractions[k] = IPC's
    ``impact_fraction`` of that move."""
    d = positions.shape[1]
    for k in prange(positions.shape[0]):
        scratch = point_scratch(d, colliders)
        g, H = np.zeros(d), np.zeros((d, d))
        add_point_terms(positions[k], d, colliders, 0, g, H, scratch)
        changes[k] = point_change(positions[k], steps[k], d, colliders, scratch)
        fractions[k] = impact_fraction(positions[k], steps[k], d, colliders, scratch)


# -- at vertex i of a sweep's flat positions y ---------------------------------------------------------------------
@numba.njit(cache=True, error_model="numpy", inline="always")
def add_vertex_terms(i, y, d, colliders, projection, g, H, scratch):
    """``add_point_terms`` at y_i, which it keeps in scratch for ``vertex_change``; returns its clearance."""
    point = scratch[5]
    for a in range(d):
        point[a] = y[d * i + a]
    return add_point_terms(point, d, colliders, projection, g, H, scratch)


@numba.njit(cache=True, error_model="numpy")
def vertex_change(u, d, colliders, scratch):
    """``point_change`` of the vertex ``add_vertex_terms`` last saw, moved by u."""
    return point_change(scratch[5], u, d, colliders, scratch)


@numba.njit(cache=True, error_model="numpy")
def vertex_impact_fraction(u, d, colliders, scratch):
    """``impact_fraction`` of the vertex ``add_vertex_terms`` last saw, moved by u."""
    return impact_fraction(scratch[5], u, d, colliders, scratch)


@numba.njit(cache=True, error_model="numpy", inline="always")
def may_reach(u, d, colliders, clearance):
    """Whether the move u of the vertex ``add_vertex_terms`` last saw (its ``clearance``) can reach a collider under
    IPC, |u| >= the least phi = clearance + dhat: only such a step needs its time of impact (a call that takes the
    colliders' and the scratch's arrays, which costs numba their reference counts)."""
    return colliders[6] == IPC and not beyond_reach(u, d, clearance + colliders[8])


@numba.njit(cache=True, error_model="numpy", inline="always")
def beyond_reach(u, d, clearance):
    """|u| < clearance (``add_point_terms``): the move changes no collider's potential, exactly (0 in numpy's form too)."""
    squared = 0.0
    for a in range(d):
        squared += u[a] * u[a]
    return math.sqrt(squared) < clearance


keep_fresh(globals())  # the cached kernels above compiled from today's sources (compiled_cache.py)
