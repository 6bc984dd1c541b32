"""Theory checks of the contact colliders (systems/contact/colliders.py).

Derivatives against central differences, the eikonal equation |grad phi| = 1 and closest-point projection of the
exact SDFs, known distances, the lecture's sampled disc, exactness of multilinear interpolation on affine fields,
times of impact against closed-form and bisected roots, and the errors for bad input.
"""

from __future__ import annotations

import re
from dataclasses import fields

import numpy as np
import pytest

from simrun.systems.contact.colliders import (COLLIDERS, Box, Capsule, GridSDF, Plane, Sphere, Torus, build_collider,
                                              load_grid_sdf)
from simrun.systems.contact.sdf import TOI_TOLERANCE

# Central differences: truncation STEP^2 |phi'''| <= 1e-10 * 1/KINK_MARGIN^2 and round-off eps / STEP ~ 1e-11
STEP = 1e-5
# Sampled points keep this distance (m) from every kink of their shape, so STEP never straddles one
KINK_MARGIN = 0.05
# The shapes whose time of impact is a closed-form root: equal to the true one to round-off
CLOSED_FORM = {"plane", "sphere", "capsule"}

# The lecture's SDF table: a disc of radius 4 centred at (6, 6) sampled at the centres (i + 0.5, j + 0.5) of a
# 12 x 12 grid of unit cells, printed to one decimal; LECTURE_TABLE[i][j] is the sample at x = i + 0.5, y = j + 0.5.
LECTURE_TABLE = [
    [3.8, 3.1, 2.5, 2.0, 1.7, 1.5, 1.5, 1.7, 2.0, 2.5, 3.1, 3.8],
    [3.1, 2.4, 1.7, 1.1, 0.7, 0.5, 0.5, 0.7, 1.1, 1.7, 2.4, 3.1],
    [2.5, 1.7, 0.9, 0.3, -0.2, -0.5, -0.5, -0.2, 0.3, 0.9, 1.7, 2.5],
    [2.0, 1.1, 0.3, -0.5, -1.1, -1.5, -1.5, -1.1, -0.5, 0.3, 1.1, 2.0],
    [1.7, 0.7, -0.2, -1.1, -1.9, -2.4, -2.4, -1.9, -1.1, -0.2, 0.7, 1.7],
    [1.5, 0.5, -0.5, -1.5, -2.4, -3.3, -3.3, -2.4, -1.5, -0.5, 0.5, 1.5],
    [1.5, 0.5, -0.5, -1.5, -2.4, -3.3, -3.3, -2.4, -1.5, -0.5, 0.5, 1.5],
    [1.7, 0.7, -0.2, -1.1, -1.9, -2.4, -2.4, -1.9, -1.1, -0.2, 0.7, 1.7],
    [2.0, 1.1, 0.3, -0.5, -1.1, -1.5, -1.5, -1.1, -0.5, 0.3, 1.1, 2.0],
    [2.5, 1.7, 0.9, 0.3, -0.2, -0.5, -0.5, -0.2, 0.3, 0.9, 1.7, 2.5],
    [3.1, 2.4, 1.7, 1.1, 0.7, 0.5, 0.5, 0.7, 1.1, 1.7, 2.4, 3.1],
    [3.8, 3.1, 2.5, 2.0, 1.7, 1.5, 1.5, 1.7, 2.0, 2.5, 3.1, 3.8],
]


def _nodes(shape, origin, spacing) -> np.ndarray:
    """Positions (*shape, d) of the samples of a grid: sample j along axis i at origin[i] + j spacing[i]."""
    index = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1)
    return np.asarray(origin) + index * np.asarray(spacing)


# One example per shape and dimension, with the distance of points to the shape's kinks (where phi is not C^2).
def _plane(dim):
    return Plane(np.array([1.0, -2.0, 0.5])[:dim], np.array([0.3, -0.2, 0.1])[:dim]), lambda p: np.full(len(p), np.inf)


def _sphere(dim):
    sphere = Sphere(np.array([0.4, -0.3, 0.2])[:dim], 1.3)
    return sphere, lambda p: np.linalg.norm(p - sphere.center, axis=1)


def _box(dim):
    box = Box(np.array([0.2, -0.1, 0.3])[:dim], np.array([1.2, 0.7, 0.9])[:dim])

    def kinks(p):  # outside: the planes |p_i - c_i| = h_i between regions; inside also ties and symmetry planes
        local = p - box.center
        a = np.abs(local) - box.half_extents
        top = np.sort(a, axis=1)
        inner = np.minimum(top[:, -1] - top[:, -2], np.abs(local).min(axis=1))
        return np.minimum(np.abs(a).min(axis=1), np.where(np.all(a <= 0, axis=1), inner, np.inf))
    return box, kinks


def _capsule(dim):
    capsule = Capsule(np.array([-0.8, 0.1, -0.2])[:dim], np.array([0.9, 0.6, 0.4])[:dim], 0.6)

    def kinks(p):  # the segment itself and the planes through its ends normal to it
        axis = capsule.b - capsule.a
        t = (p - capsule.a) @ axis / (axis @ axis)
        core = np.linalg.norm(p - capsule.a - np.clip(t, 0, 1)[:, None] * axis, axis=1)
        return np.minimum.reduce([core, np.abs(t) * np.linalg.norm(axis), np.abs(1 - t) * np.linalg.norm(axis)])
    return capsule, kinks


def _torus(dim):
    torus = Torus(np.array([0.1, -0.2, 0.3]), np.array([0.3, 0.4, 1.0]), 1.4, 0.6)

    def kinks(p):  # the axis and the core circle
        local = p - torus.center
        height = local @ torus.axis
        rho = np.linalg.norm(local - height[:, None] * torus.axis, axis=1)
        return np.minimum(rho, np.hypot(rho - torus.major_radius, height))
    return torus, kinks


def _grid_sdf(dim):
    """A ball of radius 1.5 sampled on an uneven grid (axis i has its own count and spacing)."""
    shape, origin, spacing = (9, 11, 8)[:dim], np.array([-2.0, -2.1, -1.9])[:dim], np.array([0.5, 0.4, 0.55])[:dim]
    grid = GridSDF(np.linalg.norm(_nodes(shape, origin, spacing) - 0.3, axis=-1) - 1.5, origin, spacing)

    def kinks(p):  # the cell faces (and the grid box's faces among them)
        u = (p - grid.origin) / grid.spacing
        return (np.abs(u - np.round(u)) * grid.spacing).min(axis=1)
    return grid, kinks


EXAMPLES = {"plane": _plane, "sphere": _sphere, "box": _box, "capsule": _capsule, "torus": _torus, "grid_sdf": _grid_sdf}
CASES = [pytest.param(shape, dim, id=f"{shape}-{dim}d") for shape in sorted(COLLIDERS) for dim in COLLIDERS[shape].dims]
EXACT_CASES = [case for case in CASES if COLLIDERS[case.values[0]].exact]


def _points(collider, count: int, seed: int) -> np.ndarray:
    """count random points (count, d) in the collider's bounding box grown by 1 m (a 3 m cube for a plane)."""
    rng = np.random.default_rng(seed)
    box = collider.bounding_box() or (np.full(collider.dim, -1.5), np.full(collider.dim, 1.5))
    return rng.uniform(box[0] - 1.0, box[1] + 1.0, size=(count, collider.dim))


def _smooth_points(shape, dim, count=300, seed=1):
    collider, kinks = EXAMPLES[shape](dim)
    points = _points(collider, count, seed)
    return collider, points[kinks(points) > KINK_MARGIN]


def test_every_shape_has_an_example():
    assert set(EXAMPLES) == set(COLLIDERS)


@pytest.mark.parametrize("shape, dim", CASES)
def test_gradient_and_hessian_match_finite_differences(shape, dim):
    """grad phi against central differences of phi, hess phi against central differences of grad phi."""
    collider, points = _smooth_points(shape, dim)
    assert len(points) > 100
    phi, grad, hess = collider.derivatives(points)
    np.testing.assert_array_equal(phi, collider.signed_distance(points))
    for j, e in enumerate(np.eye(dim) * STEP):
        slope = (collider.signed_distance(points + e) - collider.signed_distance(points - e)) / (2 * STEP)
        np.testing.assert_allclose(grad[:, j], slope, atol=1e-6)
        curvature = (collider.derivatives(points + e)[1] - collider.derivatives(points - e)[1]) / (2 * STEP)
        np.testing.assert_allclose(hess[:, :, j], curvature, atol=1e-5)
    np.testing.assert_allclose(hess, np.swapaxes(hess, 1, 2), atol=1e-12)


@pytest.mark.parametrize("shape, dim", EXACT_CASES)
def test_exact_sdfs_are_eikonal_and_project_onto_the_surface(shape, dim):
    """|grad phi| = 1 everywhere (at kinks too, by the chosen side), and p - phi(p) grad phi(p) lies on phi = 0."""
    collider, kinks = EXAMPLES[shape](dim)
    points = _points(collider, 300, seed=2)
    phi, grad, _ = collider.derivatives(points)
    np.testing.assert_allclose(np.linalg.norm(grad, axis=1), 1.0, atol=1e-12)
    smooth = kinks(points) > KINK_MARGIN
    projected = points[smooth] - phi[smooth, None] * grad[smooth]
    np.testing.assert_allclose(collider.signed_distance(projected), 0.0, atol=1e-12)


@pytest.mark.parametrize("shape, dim", CASES)
def test_bounding_box_holds_the_inside(shape, dim):
    collider, _ = EXAMPLES[shape](dim)
    points = _points(collider, 2000, seed=3)
    inside = points[collider.signed_distance(points) <= 0]
    box = collider.bounding_box()
    if box is None:
        assert shape == "plane"
        return
    assert len(inside) > 0
    assert np.all((inside >= box[0]) & (inside <= box[1]))


@pytest.mark.parametrize("collider, point, expected", [
    (Plane([0, 0, 1], [0, 0, 2]), [5, -3, 2], 0.0),
    (Plane([0, 0, 1], [0, 0, 2]), [0, 0, 0], -2.0),
    (Plane([3, 4], [0, 0]), [3, 4], 5.0),  # the normal is normalised
    (Sphere([1, 2, 3], 2), [1, 2, 3], -2.0),
    (Sphere([1, 2, 3], 2), [3, 2, 3], 0.0),
    (Sphere([1, 2, 3], 2), [1, 2, 7], 2.0),
    (Sphere([1, 2], 0.5), [4, 6], 4.5),
    (Box([0, 0], [1, 2]), [0, 0], -1.0),
    (Box([0, 0], [1, 2]), [3, 0], 2.0),
    (Box([0, 0], [1, 2]), [2, 4], np.sqrt(5)),  # corner region: distance to the corner (1, 2)
    (Box([0, 0], [1, 2]), [1, 0.5], 0.0),
    (Box([0, 0, 0], [1, 1, 1]), [2, 3, 4], np.sqrt(14)),
    (Box([0, 0, 0], [1, 2, 3]), [0.5, 0, 0], -0.5),
    (Capsule([0, 0, 0], [2, 0, 0], 0.5), [1, 0, 0], -0.5),
    (Capsule([0, 0, 0], [2, 0, 0], 0.5), [1, 1, 0], 0.5),
    (Capsule([0, 0, 0], [2, 0, 0], 0.5), [3, 0, 0], 0.5),
    (Capsule([0, 0, 0], [2, 0, 0], 0.5), [-1, 0, 0], 0.5),
    (Capsule([0, 0], [2, 0], 0.5), [1, 0.5], 0.0),
    (Capsule([0, 0], [2, 0], 0.5), [5, 4], 4.5),
    (Torus([0, 0, 0], [0, 0, 2], 2, 0.5), [2, 0, 0], -0.5),
    (Torus([0, 0, 0], [0, 0, 2], 2, 0.5), [0, 0, 0], 1.5),
    (Torus([0, 0, 0], [0, 0, 2], 2, 0.5), [2.5, 0, 0], 0.0),
    (Torus([0, 0, 0], [0, 0, 2], 2, 0.5), [0, 3, 0], 0.5),
    (Torus([0, 0, 0], [0, 0, 2], 2, 0.5), [0, -2, 1], 0.5),
    (Torus([1, 1, 1], [1, 0, 0], 2, 0.5), [1, 1, 3], -0.5),  # the axis along x: the core circle passes (1, 1, 3)
])
def test_known_distances(collider, point, expected):
    assert collider.signed_distance(np.array([point], dtype=float))[0] == pytest.approx(expected, abs=1e-12)


def at(*point) -> np.ndarray:
    """One point as a (1, d) array."""
    return np.array([point], dtype=float)


def test_kink_conventions():
    """Where phi is not smooth one side is taken, as documented: a unit gradient (so |grad phi| = 1 still) and, at
    cone points, a zero Hessian."""
    _, grad, hess = Sphere([1, 2, 3], 2).derivatives(at(1, 2, 3))  # the centre: the first axis
    np.testing.assert_array_equal(grad, [[1, 0, 0]])
    np.testing.assert_array_equal(hess, 0)
    _, grad, hess = Capsule([0, 0, 0], [2, 1, 0], 0.5).derivatives(at(1, 0.5, 0))  # on the segment: normal to it
    assert np.linalg.norm(grad) == pytest.approx(1) and grad[0] @ [2, 1, 0] == pytest.approx(0, abs=1e-15)
    np.testing.assert_array_equal(hess, 0)
    torus = Torus([0, 0, 0], [0, 0, 1], 2, 0.5)
    _, grad, hess = torus.derivatives(at(0, 0, 1))  # on the axis: the fixed radial direction (here x)
    np.testing.assert_allclose(grad, [[-2 / np.sqrt(5), 0, 1 / np.sqrt(5)]], atol=1e-15)
    np.testing.assert_array_equal(hess, 0)
    _, grad, hess = torus.derivatives(at(0, 2, 0))  # on the core circle: radially outward
    np.testing.assert_allclose(grad, [[0, 1, 0]], atol=1e-15)
    np.testing.assert_array_equal(hess, 0)
    _, grad, hess = Box([0, 0], [1, 1]).derivatives(at(0, 0))  # a tie: the lowest axis; a symmetry plane: +
    np.testing.assert_array_equal(grad, [[1, 0]])
    _, grad, _ = Box([0, 0], [1, 1]).derivatives(at(-0.5, -0.5))
    np.testing.assert_array_equal(grad, [[-1, 0]])


def test_a_moving_sphere_is_queried_at_its_offset():
    """A unit sphere moving at (1, 0, 0) m/s from the origin is centred at (2, 0, 0) at t = 2 s."""
    sphere = Sphere([0, 0, 0], 1, velocity=[1, 0, 0])
    offset = sphere.velocity * 2.0
    assert sphere.signed_distance(np.array([[2.0, 0, 0], [4.0, 0, 0]]), offset) == pytest.approx([-1.0, 1.0])
    np.testing.assert_allclose(sphere.bounding_box(offset), [[1, -1, -1], [3, 1, 1]])


def test_lecture_table_from_an_npz_grid(tmp_path):
    """The disc sampled at the cell centres, written to a file and loaded, reproduces the printed table; along a grid
    line the interpolant lies between the neighbouring samples, and inside a cell between the cell's extremes."""
    centres = _nodes((12, 12), (0.5, 0.5), (1.0, 1.0))
    samples = np.linalg.norm(centres - 6.0, axis=-1) - 4.0
    np.savez(tmp_path / "disc.npz", values=samples, origin=np.array([0.5, 0.5]), spacing=np.array(1.0))
    grid = load_grid_sdf(tmp_path / "disc.npz")
    at_centres = grid.signed_distance(centres.reshape(-1, 2)).reshape(12, 12)
    assert np.all(np.abs(at_centres - np.array(LECTURE_TABLE)) <= 0.05 + 1e-12)

    rng = np.random.default_rng(4)
    i, j, s = rng.integers(0, 11, 200), rng.integers(0, 12, 200), rng.uniform(0, 1, 200)
    between = grid.signed_distance(np.stack([i + 0.5 + s, j + 0.5], axis=1))  # from centre (i, j) to (i + 1, j)
    assert np.all(between >= np.minimum(samples[i, j], samples[i + 1, j]) - 1e-12)
    assert np.all(between <= np.maximum(samples[i, j], samples[i + 1, j]) + 1e-12)
    np.testing.assert_allclose(between, (1 - s) * samples[i, j] + s * samples[i + 1, j], atol=1e-12)

    i, j = rng.integers(0, 11, 200), rng.integers(0, 11, 200)
    inside = grid.signed_distance(np.stack([i, j], axis=1) + 0.5 + rng.uniform(0, 1, (200, 2)))
    corners = np.stack([samples[i, j], samples[i + 1, j], samples[i, j + 1], samples[i + 1, j + 1]])
    assert np.all((inside >= corners.min(axis=0) - 1e-12) & (inside <= corners.max(axis=0) + 1e-12))


@pytest.mark.parametrize("dim", [2, 3])
def test_multilinear_interpolation_is_exact_on_affine_fields(dim):
    """phi = g . p + c sampled on a grid is reproduced inside it, with gradient g and Hessian 0."""
    rng = np.random.default_rng(5)
    shape, origin, spacing = (5, 4, 6)[:dim], rng.normal(size=dim), rng.uniform(0.3, 1.5, dim)
    g, c = rng.normal(size=dim), 0.7
    grid = GridSDF(_nodes(shape, origin, spacing) @ g + c, origin, spacing)
    points = rng.uniform(origin, origin + (np.array(shape) - 1) * spacing, size=(200, dim))
    phi, grad, hess = grid.derivatives(points)
    np.testing.assert_allclose(phi, points @ g + c, atol=1e-12)
    np.testing.assert_allclose(grad, np.broadcast_to(g, grad.shape), atol=1e-12)
    np.testing.assert_allclose(hess, 0.0, atol=1e-12)


def test_grid_outside_adds_the_distance_to_the_box_and_respects_its_lipschitz_bound():
    grid, _ = _grid_sdf(2)
    upper = grid.origin + (np.array(grid.values.shape) - 1) * grid.spacing
    point = np.array([[upper[0] + 3.0, grid.origin[1] - 4.0]])  # beyond the corner (upper x, lower y)
    assert grid.signed_distance(point)[0] == pytest.approx(grid.values[-1, 0] + 5.0, abs=1e-12)
    rng = np.random.default_rng(6)
    p, q = _points(grid, 2000, seed=7), _points(grid, 2000, seed=8) * 0.1 + rng.normal(size=(2000, 2))
    change = np.abs(grid.signed_distance(p) - grid.signed_distance(q))
    assert np.all(change <= grid.lipschitz * np.linalg.norm(p - q, axis=1) * (1 + 1e-12))


def test_grid_bounding_box_reaches_past_the_grid_where_its_values_are_negative():
    """Outside, phi = phi(clamp(p)) + |p - clamp(p)| stays <= 0 up to -min(values) beyond the grid box."""
    grid = GridSDF(np.full((2, 3), -1.0), [0.0, 0.0], 1.0)
    lower, upper = grid.bounding_box()
    np.testing.assert_allclose(np.stack([lower, upper]), [[-1.0, -1.0], [2.0, 3.0]])
    assert grid.signed_distance(np.array([[-0.9, 1.0], [1.5, 2.5]])) == pytest.approx([-0.1, 1 / np.sqrt(2) - 1])


def _true_time_of_impact(collider, start, end, level, samples=2001):
    """First tau with phi = level found by dense sampling then bisection (inf when no sample reaches it)."""
    tau = np.linspace(0, 1, samples)
    path = start[:, None, :] + tau[None, :, None] * (end - start)[:, None, :]
    below = collider.signed_distance(path.reshape(-1, collider.dim)).reshape(len(start), samples) <= level
    first = np.where(below.any(axis=1), below.argmax(axis=1), -1)
    low, high = tau[np.maximum(first - 1, 0)], tau[np.maximum(first, 0)]
    for _ in range(60):
        middle = 0.5 * (low + high)
        reached = collider.signed_distance(start + middle[:, None] * (end - start)) <= level
        low, high = np.where(reached, low, middle), np.where(reached, middle, high)
    return np.where(first < 0, np.inf, np.where(first == 0, 0.0, high))


@pytest.mark.parametrize("shape, dim", CASES)
@pytest.mark.parametrize("level", [0.0, 0.2])
def test_time_of_impact_against_bisection(shape, dim, level):
    """Closed-form roots equal the true first root; conservative advancement is never later and at most
    TOI_TOLERANCE / cos(theta) earlier (theta between the move and the normal), and misses give inf."""
    collider, _ = EXAMPLES[shape](dim)
    candidates = _points(collider, 3000, seed=9)
    phi = collider.signed_distance(candidates)
    start, end = candidates[phi > level + 0.3][:40], candidates[phi < -0.15][:40]
    count = min(len(start), len(end))
    start, end = start[:count], end[:count]
    assert count >= 20
    tau, truth = collider.time_of_impact(start, end, distance=level), _true_time_of_impact(collider, start, end, level)
    assert np.all(np.isfinite(truth))
    if shape in CLOSED_FORM:
        np.testing.assert_allclose(tau, truth, atol=1e-9)
    else:
        step = end - start
        grad = collider.derivatives(start + truth[:, None] * step)[1]
        cosine = -np.einsum("ij,ij->i", grad, step) / np.linalg.norm(step, axis=1)
        crossing = cosine > 0.2  # transversal crossings: the tolerance in tau is TOI_TOLERANCE / cos(theta)
        assert np.count_nonzero(crossing) >= 10
        assert np.all(tau <= truth + 1e-12)
        assert np.all(truth[crossing] - tau[crossing] <= 1.01 * TOI_TOLERANCE / cosine[crossing] + 1e-12)
        gap = collider.signed_distance(start + tau[:, None] * step) - level
        assert np.all(gap <= TOI_TOLERANCE * np.linalg.norm(step, axis=1) * (1 + 1e-9))

    # moves that stay clear of the level (checked by sampling) give inf; starts below it give 0
    away = start + 0.3 * collider.derivatives(start)[1]
    clear = np.isinf(_true_time_of_impact(collider, start, away, level))
    assert np.count_nonzero(clear) >= 10
    assert np.all(np.isinf(collider.time_of_impact(start[clear], away[clear], distance=level)))
    np.testing.assert_array_equal(collider.time_of_impact(end, start, distance=level), 0.0)


@pytest.mark.parametrize("shape, dim", CASES)
def test_an_offset_equals_the_translated_shape(shape, dim):
    """A collider queried with offset o is the collider whose position arguments are moved by o."""
    collider, _ = EXAMPLES[shape](dim)
    offset = np.array([0.7, -0.4, 0.25])[:dim]
    moved = collider.translated(offset)
    points = _points(moved, 200, seed=10)
    np.testing.assert_allclose(collider.signed_distance(points, offset), moved.signed_distance(points), atol=1e-12)
    np.testing.assert_allclose(collider.signed_distance(points + offset, offset), collider.signed_distance(points), atol=1e-12)
    for ours, theirs in zip(collider.derivatives(points, offset), moved.derivatives(points)):
        np.testing.assert_allclose(ours, theirs, atol=1e-9)
    start, end = points[:100], points[100:]
    np.testing.assert_allclose(collider.time_of_impact(start, end, offset), moved.time_of_impact(start, end), atol=1e-5)
    if collider.bounding_box() is not None:
        np.testing.assert_allclose(collider.bounding_box(offset), moved.bounding_box(), atol=1e-12)


def test_closed_form_times_of_impact():
    """Hand-solved roots: a plane at z = 0 with level 1 crossed from z = 3 to -1 at tau = 1/2; a unit sphere at
    level 0.5 hit head-on from x = 3 to -3 at x = 1.5 (tau = 1/4); a capsule of radius 1 about (0,0,0)-(4,0,0)
    hit from the side at y = 1 (tau = 1/3) and along its axis at x = -1 (tau = 1/3)."""
    plane = Plane([0, 0, 1], [0, 0, 0])
    assert plane.time_of_impact(np.array([[1.0, 2, 3]]), np.array([[0.0, 0, -1]]), distance=1.0)[0] == pytest.approx(0.5)
    sphere = Sphere([0, 0, 0], 1)
    assert sphere.time_of_impact(np.array([[3.0, 0, 0]]), np.array([[-3.0, 0, 0]]), distance=0.5)[0] == pytest.approx(0.25)
    capsule = Capsule([0, 0, 0], [4, 0, 0], 1)
    start, end = np.array([[2.0, 3, 0], [-3.0, 0, 0]]), np.array([[2.0, -3, 0], [3.0, 0, 0]])
    np.testing.assert_allclose(capsule.time_of_impact(start, end), [1 / 3, 1 / 3])
    assert np.isinf(sphere.time_of_impact(np.array([[3.0, 2, 0]]), np.array([[-3.0, 2, 0]]))[0])  # passes at y = 2


@pytest.mark.parametrize("shape, dim", CASES)
def test_build_collider_from_config_arguments(shape, dim, tmp_path):
    collider, _ = EXAMPLES[shape](dim)
    arguments = {f.name: getattr(collider, f.name) for f in fields(collider) if f.init}
    if shape == "grid_sdf":  # from a file instead: the values only, origin and spacing from the config
        np.save(tmp_path / "grid.npy", collider.values)
        arguments = {"path": tmp_path / "grid.npy", "origin": collider.origin, "spacing": collider.spacing}
    built = build_collider(shape, dim, **arguments)
    assert type(built) is COLLIDERS[shape]
    points = _points(collider, 50, seed=11)
    np.testing.assert_allclose(built.signed_distance(points), collider.signed_distance(points), atol=1e-12)


GRID = np.zeros((3, 4))


@pytest.mark.parametrize("make, message", [
    (lambda: Sphere([0, 0], -1), "radius must be > 0, got -1"),
    (lambda: Sphere([0, 0, 0, 0], 1), "center must have 2 or 3 components"),
    (lambda: Sphere([0, np.nan], 1), "center must be finite"),
    (lambda: Sphere([0, 0], 1, velocity=[1, 2, 3]), "velocity must have 2 components"),
    (lambda: Plane([0, 0], [1, 1]), "normal must be nonzero"),
    (lambda: Plane([0, 1], [1, 1, 1]), "point must have 2 components"),
    (lambda: Box([0, 0], [1, 0]), "half_extents must be > 0"),
    (lambda: Box([0, 0], [1, 1, 1]), "half_extents must have 2 components"),
    (lambda: Capsule([1, 2], [1, 2], 1), "b must differ from a"),
    (lambda: Capsule([0, 0], [1, 0], 0), "radius must be > 0, got 0"),
    (lambda: Capsule([0, 0], [1, 0], "wide"), "radius must be > 0, got wide"),
    (lambda: Torus([0, 0], [0, 1], 2, 1), "center must have 3 components (a torus exists only in 3-D)"),
    (lambda: Torus([0, 0, 0], [0, 0, 0], 2, 1), "axis must be nonzero"),
    (lambda: Torus([0, 0, 0], [0, 0, 1], -2, 1), "major_radius must be > 0"),
    (lambda: Torus([0, 0, 0], [0, 0, 1], 2, np.nan), "minor_radius must be > 0"),
    (lambda: GridSDF(np.zeros(4), [0], 1), "values must be a 2-D or 3-D array"),
    (lambda: GridSDF(GRID, [0, 0, 0], 1), "origin has 3 components but values has 2 dimensions"),
    (lambda: GridSDF(GRID, [0, 0], [1, 1, 1]), "spacing has 3 components but values has 2 dimensions"),
    (lambda: GridSDF(GRID, [0, 0], [1, 0]), "spacing must be > 0"),
    (lambda: GridSDF(np.zeros((1, 4)), [0, 0], 1), "values must have at least 2 samples along every axis"),
    (lambda: GridSDF(np.where(GRID == 0, np.inf, 0), [0, 0], 1), "values must be finite: 12 of 12"),
    (lambda: build_collider("cone", 3), "unknown collider shape 'cone'; valid: box, capsule, grid_sdf, plane, sphere, torus"),
    (lambda: build_collider("torus", 2, center=[0, 0]), "dim: a torus exists only in 3-D"),
    (lambda: build_collider("sphere", 2, center=[0, 0, 0], radius=1), "dim is 2"),
    (lambda: build_collider("sphere", 3, center=[0, 0, 0], radius=1, colour=2), "colour"),
    (lambda: build_collider("sphere", 3, center=[0, 0, 0]), "radius"),
    (lambda: Sphere([0, 0], 1).time_of_impact(np.zeros((1, 2)), np.ones((1, 2)), distance=-1), "distance must be >= 0"),
    (lambda: Sphere([0, 0], 1).signed_distance(np.zeros((4, 3))), "points must have shape (k, 2)"),
    (lambda: Sphere([0, 0], 1).signed_distance(np.zeros((4, 2)), offset=[1, 2, 3]), "offset must have 2 components"),
])
def test_bad_input_names_the_argument(make, message):
    with pytest.raises(ValueError, match=re.escape(message)) as error:
        make()
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("write, arguments, message", [
    (lambda path: np.save(path.with_suffix(".npy"), GRID), {"spacing": 1}, "origin must be given"),
    (lambda path: np.savez(path, values=np.zeros((2, 2, 2)), spacing=1.0), {"origin": [0, 0]},
     "origin has 2 components but values has 3 dimensions"),
    (lambda path: np.savez(path, values=GRID, origin=[0, 0], spacing=[1, 1]), {"spacing": [-1, 1]}, "spacing must be > 0"),
    (lambda path: np.savez(path, values=np.zeros((4, 1)), origin=[0, 0], spacing=1.0), {}, "at least 2 samples"),
    (lambda path: np.savez(path, values=np.full((2, 2), np.nan), origin=[0, 0], spacing=1.0), {}, "values must be finite"),
    (lambda path: np.savez(path, sdf=GRID), {}, "has no array 'values' (it holds: sdf)"),
    (lambda path: path.with_suffix(".txt").write_text("0 0"), {}, "path must end in .npy or .npz"),
])
def test_bad_grid_files_name_the_problem(tmp_path, write, arguments, message):
    write(tmp_path / "grid.npz")
    path = next(tmp_path.iterdir())
    with pytest.raises(ValueError, match=re.escape(message)) as error:
        load_grid_sdf(path, **arguments)
    assert "\n" not in str(error.value)


def test_npz_arrays_are_overridden_by_arguments(tmp_path):
    np.savez(tmp_path / "grid.npz", values=np.arange(12.0).reshape(3, 4), origin=[5.0, 5.0], spacing=[2.0, 2.0])
    grid = load_grid_sdf(tmp_path / "grid.npz", origin=[0.0, 0.0])
    np.testing.assert_array_equal(grid.origin, [0.0, 0.0])
    np.testing.assert_array_equal(grid.spacing, [2.0, 2.0])
    assert grid.signed_distance(np.array([[2.0, 4.0]]))[0] == pytest.approx(6.0)  # sample (1, 2) = 4 + 2
