"""IPC contact through ipctk (systems/contact/mesh_contact.py): derivatives against finite differences,
projections against their definition, CCD and intersection reports against the geometry of the step,
friction against IPC's formula D(w) = sum_c mu lambda_c f0(|T_c^T w_c|; eps), and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

from simrun.systems.contact.mesh_contact import MeshContact, boundary_edges

DHAT = 0.1  # m: the scenes below sit 0.3 to 0.7 dhat above their obstacle
FD_STEP = 1e-6  # m: the barrier varies over the distances (>= 0.03 m here): differences err by ~(h/d)^2 ~ 1e-9


def grid(nx: int, ny: int, spacing: float, origin=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """An nx x ny vertex grid in the plane z = 0 (m) and its triangles (two per cell)."""
    xs, ys = np.meshgrid(origin[0] + spacing * np.arange(nx), origin[1] + spacing * np.arange(ny))
    vertices = np.c_[xs.ravel(), ys.ravel(), np.zeros(nx * ny)]
    index = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return vertices, np.vstack([np.c_[a, b, d], np.c_[a, d, c]])


def square(low: float, high: float, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An obstacle: the square [low, high]^2 at height z, two triangles sharing the diagonal (low, low)-(high, high)."""
    corners = np.array([[low, low, z], [high, low, z], [high, high, z], [low, high, z]])
    return corners, np.array([[0, 1, 2], [0, 2, 3]])


def hovering_cloth(seed: int = 0):
    """A 5x5-vertex cloth (4x4 cells, 0.25 m) 0.3-0.7 dhat above a square obstacle, offset so that no vertex
    lies exactly over the obstacle's diagonal edge (where the closest feature switches): 25 point-triangle
    pairs, and edge-edge and point-edge pairs with that diagonal."""
    rest, triangles = grid(5, 5, 0.25, origin=(0.07, 0.11))
    contact = MeshContact(rest, triangles, obstacles=[square(-1.0, 2.0)], dhat=DHAT)
    x = rest.copy()
    x[:, 2] = np.random.default_rng(seed).uniform(0.3, 0.7, len(x)) * DHAT
    return contact, x.ravel()


def planar_square():
    """2-D: a square of four triangles around a centre vertex (which is not on the surface), its bottom
    corners 0.4 and 0.6 dhat above y = 0, over a peaked obstacle polyline whose apex (0.3, 0) lies 0.046 m
    below the bottom edge and whose sides are more than dhat from the square: one point-edge pair."""
    rest = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]])
    triangles = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    peak = (np.array([[-2.0, -1.0], [0.3, 0.0], [3.0, -1.0]]), np.array([[0, 1], [1, 2]]))
    contact = MeshContact(rest, triangles, obstacles=[peak], dhat=DHAT)
    x = rest.copy()
    x[:, 1] += np.array([0.4, 0.6, 0.6, 0.4, 0.5]) * DHAT
    return contact, x.ravel()


def folded_patch():
    """Self-contact: a 4 x 7 grid (0.2 m) folded over its middle row, the upper layer 0.3-0.7 dhat above the
    lower one and shifted sideways so no vertex sits exactly over another (no obstacles)."""
    nx, ny, s = 4, 7, 0.2
    rest, triangles = grid(nx, ny, s)
    x = rest.copy().reshape(ny, nx, 3)
    rng = np.random.default_rng(3)
    for j in range(4, ny):  # rows past the fold (row 3) come back over rows 2, 1, 0
        x[j, :, 1] = (6 - j) * s + 0.07
        x[j, :, 0] += 0.053
        x[j, :, 2] = rng.uniform(0.3, 0.7, nx) * DHAT
    return MeshContact(rest, triangles, self_contact=True, dhat=DHAT), x.ravel()


SCENES = {"cloth_over_square": hovering_cloth, "planar_square": planar_square, "folded_patch": folded_patch}


def central_gradient(f, x: np.ndarray, step: float = FD_STEP) -> np.ndarray:
    """Entry i: (f(x + h e_i) - f(x - h e_i)) / 2h."""
    return np.array([(f(x + e) - f(x - e)) / (2 * step) for e in np.eye(len(x)) * step])


def central_jacobian(g, x: np.ndarray, step: float = FD_STEP) -> np.ndarray:
    """Column i: (g(x + h e_i) - g(x - h e_i)) / 2h."""
    return np.array([(g(x + e) - g(x - e)) / (2 * step) for e in np.eye(len(x)) * step]).T


@pytest.mark.parametrize("name", sorted(SCENES))
def test_barrier_gradient_and_hessian_match_finite_differences(name):
    """dB/dx = central differences of B, d^2B/dx^2 = central differences of dB/dx (error O(h^2))."""
    contact, x = SCENES[name]()
    assert contact.active_count(x) > 0
    g = contact.barrier_gradient(x)
    assert g.shape == x.shape
    np.testing.assert_allclose(central_gradient(contact.barrier_energy, x), g, rtol=1e-6, atol=1e-7 * np.abs(g).max())
    hessian = contact.barrier_hessian(x)
    assert isinstance(hessian, scipy.sparse.csr_matrix) and hessian.shape == (len(x), len(x))
    h = hessian.toarray()
    np.testing.assert_allclose(central_jacobian(contact.barrier_gradient, x), h, rtol=1e-6, atol=1e-7 * np.abs(h).max())
    assert np.allclose(h, h.T, rtol=0, atol=1e-12 * np.abs(h).max())


@pytest.mark.parametrize("name", sorted(SCENES))
@pytest.mark.parametrize("project", ["clamp", "abs", True])
def test_projected_hessians_have_no_negative_eigenvalue(name, project):
    """The raw Hessian is indefinite here; each projected one is PSD (to round-off of its largest eigenvalue)."""
    contact, x = SCENES[name]()
    raw = np.linalg.eigvalsh(contact.barrier_hessian(x).toarray())
    projected = np.linalg.eigvalsh(contact.barrier_hessian(x, project=project).toarray())
    assert raw.min() < -1e-6 * raw.max()
    assert projected.min() >= -1e-12 * projected.max()


def test_unknown_projection_lists_the_valid_ones():
    contact, x = hovering_cloth()
    with pytest.raises(ValueError, match="'clamp', 'abs'"):
        contact.barrier_hessian(x, project="mirror")


def test_off_surface_vertices_have_no_contact_derivatives():
    """The 2-D square's centre vertex (4) is inside it: zero gradient and empty Hessian rows."""
    contact, x = planar_square()
    assert np.array_equal(contact.surface_vertices, [0, 1, 2, 3])
    assert np.all(contact.barrier_gradient(x)[8:] == 0)
    assert contact.barrier_hessian(x)[8:].nnz == 0


def test_barrier_value_minimum_distance_and_active_count():
    """A flat cloth at height z above the square: one point-triangle pair per vertex, each at distance z, and
    B = 9 b(z^2) / dhat^3 with b(s) = -(s - dhat^2)^2 ln(s / dhat^2)."""
    rest, triangles = grid(3, 3, 0.25, origin=(1.0, 0.1))  # > dhat from the square's diagonal and border
    contact = MeshContact(rest, triangles, obstacles=[square(-1.0, 2.0)], dhat=DHAT)
    x = rest.copy()
    z = 0.4 * DHAT
    x[:, 2] = z
    assert contact.minimum_distance(x.ravel()) == pytest.approx(z, rel=1e-12)
    assert contact.active_count(x.ravel()) == 9
    s, s_hat = z**2, DHAT**2
    assert contact.barrier_energy(x.ravel()) == pytest.approx(9 * -(s - s_hat) ** 2 * np.log(s / s_hat) / DHAT**3, rel=1e-12)
    x[:, 2] = 1.5 * DHAT
    assert contact.minimum_distance(x.ravel()) == np.inf and contact.active_count(x.ravel()) == 0


def test_filters_keep_model_pairs_out_without_self_contact_and_obstacle_pairs_always():
    """The folded patch touches itself only with self_contact; two overlapping obstacles never collide."""
    folded, x = folded_patch()
    rest, triangles = grid(4, 7, 0.2)  # folded_patch's rest shape
    assert folded.active_count(x) > 0
    assert MeshContact(rest, triangles, obstacles=[square(10.0, 11.0)], dhat=DHAT).active_count(x) == 0
    stacked = [square(-1.0, 2.0, 0.0), square(-1.0, 2.0, 0.01)]
    lone_vertex = np.array([[0.5, 0.5, 1.0]])  # far above both
    assert MeshContact(lone_vertex, None, obstacles=stacked, dhat=DHAT).active_count(lone_vertex.ravel()) == 0


def test_collision_free_step_stops_before_the_obstacle():
    """A vertex pushed from 0.5 dhat above the plane to 0.5 dhat below it meets the plane at t = 0.5: the
    certified fraction lies in [0.8 * 0.5, 0.5) (Tight Inclusion's conservative rescaling 0.8), and there
    the cloth is intersection-free at a positive distance."""
    rest, triangles = grid(5, 5, 0.25, origin=(0.07, 0.11))
    contact = MeshContact(rest, triangles, obstacles=[square(-1.0, 2.0)], dhat=DHAT)
    start = rest.copy()
    start[:, 2] = 0.5 * DHAT
    end = start.copy()
    end[12, 2] = -0.5 * DHAT
    alpha = contact.collision_free_step(start.ravel(), end.ravel())
    assert 0.4 <= alpha < 0.5
    reached = start.ravel() + alpha * (end.ravel() - start.ravel())
    assert contact.intersection(reached) is None and contact.initial_check(reached) is None
    assert contact.minimum_distance(reached) > 0
    clear = start.copy()
    clear[:, :2] += 0.3  # sliding along the plane, 0.5 dhat above it
    assert contact.collision_free_step(start.ravel(), clear.ravel()) == 1.0


def test_collision_free_step_in_2d():
    """The square translated down by twice the bottom edge's height over the apex (2 x 0.046 m) meets it at
    t = 0.5."""
    contact, x = planar_square()
    end = x.copy()
    end[1::2] -= 2 * 0.46 * DHAT
    alpha = contact.collision_free_step(x, end)
    assert 0.4 <= alpha < 0.5
    reached = x + alpha * (end - x)
    assert contact.intersection(reached) is None and contact.minimum_distance(reached) > 0
    assert contact.collision_free_step(x, x + np.tile([0.2, 0.1], 5)) == 1.0


def test_intersection_names_the_crossing_elements():
    """A cloth tilted through the plane crosses it; one hovering above it does not."""
    contact, x = hovering_cloth()
    assert contact.intersection(x) is None and contact.initial_check(x) is None
    through = x.reshape(-1, 3).copy()
    through[:, 2] = 0.5 * DHAT - 0.5 * through[:, 0]
    report = contact.intersection(through.ravel())
    assert report is not None and "edge" in report and "triangle" in report
    assert contact.initial_check(through.ravel()) == report


def test_intersection_in_2d_names_the_edges():
    """Sunk by 0.06 m, only the bottom edge (0, 1) crosses the obstacle, around its apex."""
    contact, x = planar_square()
    assert contact.intersection(x) is None
    sunk = x.copy()
    sunk[1::2] -= 0.06
    report = contact.intersection(sunk)
    assert report is not None and "model edge (0, 1)" in report and "obstacle 0 edge" in report


def test_initial_check_reports_a_touching_pair():
    """A vertex model (no elements) with vertex 1 on the plane: no intersection, a pair at distance 0."""
    points = np.array([[0.5, 0.3, 0.05], [0.6, 0.2, 0.0]])
    contact = MeshContact(points, None, obstacles=[square(-1.0, 2.0)], dhat=DHAT)
    assert contact.intersection(points.ravel()) is None
    report = contact.initial_check(points.ravel())
    assert report is not None and "model vertex 1" in report and "obstacle 0 triangle 0" in report
    assert contact.initial_check(points.ravel() + np.array([0, 0, 0.01, 0, 0, 0.01])) is None


def test_barrier_stiffness_helpers():
    """ipctk's adaptive kappa (IPC) for B = b / dhat^3: kappa = -g_B . g_E / |g_B|^2 clamped to
    [kappa_min, 100 kappa_min], kappa_min = dhat^3 1e11 m_avg / (4 s0 b''(s0)), s0 = (1e-8 L)^2,
    b(s) = -(s - dhat^2)^2 ln(s / dhat^2); kappa doubles (up to the cap) only when a shrinking minimum
    distance is below 1e-9 L."""
    contact, x = hovering_cloth()
    s0, s_hat = (1e-8 * contact.bbox_diagonal) ** 2, DHAT**2
    b2 = -2 * np.log(s0 / s_hat) - 4 * (s0 - s_hat) / s0 + (s0 - s_hat) ** 2 / s0**2
    average_mass = 1.0
    kappa_min = DHAT**3 * 1e11 * average_mass / (4 * s0 * b2)
    g_barrier = contact.barrier_gradient(x)
    ratio = 3 * kappa_min  # a balance inside the clamp
    kappa, max_kappa = contact.initial_barrier_stiffness(x, -ratio * g_barrier, average_mass)
    assert kappa == pytest.approx(ratio, rel=1e-12) and max_kappa == pytest.approx(100 * kappa_min, rel=1e-9)
    assert contact.initial_barrier_stiffness(x, -1e3 * kappa_min * g_barrier, average_mass)[0] == max_kappa
    assert contact.initial_barrier_stiffness(x, g_barrier, average_mass)[0] == pytest.approx(kappa_min, rel=1e-9)
    tiny = 1e-10 * contact.bbox_diagonal
    assert contact.update_barrier_stiffness(2 * tiny, tiny, 10.0, 1.0) == 2.0
    assert contact.update_barrier_stiffness(tiny, 2 * tiny, 10.0, 1.0) == 1.0  # growing
    assert contact.update_barrier_stiffness(2e3 * tiny, 1e3 * tiny, 10.0, 1.0) == 1.0  # not small enough
    assert contact.update_barrier_stiffness(2 * tiny, tiny, 1.5, 1.0) == 1.5  # capped
    assert contact.update_barrier_stiffness(np.inf, np.inf, 10.0, 1.0) == 1.0  # no contact


# -- friction -----------------------------------------------------------------------------------------------

KAPPA, MU, EPS = 50.0, 0.4, 1e-3  # barrier stiffness, Coulomb coefficient, eps = eps_v * b (m)
FRICTION_FD_STEP = 1e-5 * EPS  # f0 curves over ~eps: differences err by ~(h/eps)^2 = 1e-10


def cloth_over_one_triangle():
    """A 4x4-vertex cloth 0.3-0.7 dhat above the square's lower-right triangle, > dhat from its diagonal and
    border: each vertex has exactly one contact, a point-triangle pair with normal +z."""
    rest, triangles = grid(4, 4, 0.25, origin=(1.0, -0.8))
    contact = MeshContact(rest, triangles, obstacles=[square(-1.0, 3.0)], dhat=DHAT)
    x = rest.copy()
    x[:, 2] = np.random.default_rng(5).uniform(0.3, 0.7, len(x)) * DHAT
    return contact, x.ravel()


def sliding_motion(count: int, seed: int = 7) -> np.ndarray:
    """w (m) for `count` vertices: tangential parts in random directions, magnitudes alternately 0.3 eps and
    3 eps (away from |u| = eps), plus a normal part that friction ignores."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0, 2 * np.pi, count)
    speed = np.where(np.arange(count) % 2 == 0, 0.3 * EPS, 3.0 * EPS)
    return np.c_[speed * np.cos(angle), speed * np.sin(angle), rng.uniform(-1, 1, count) * EPS].ravel()


def f0(y: np.ndarray, eps: float) -> np.ndarray:
    """IPC's smoothed friction mollifier (Li et al. 2020): y >= eps: y; else -y^3/(3 eps^2) + y^2/eps + eps/3."""
    return np.where(y >= eps, y, -y**3 / (3 * eps**2) + y**2 / eps + eps / 3)


def test_friction_energy_is_ipcs_lagged_coulomb_potential():
    """D(w) = sum_i mu lambda_i f0(|w_i,xy|; eps) with lambda_i = kappa |dB/dx_i| at x_lag (one point-triangle
    contact per vertex, normal z)."""
    contact, x = cloth_over_one_triangle()
    lag = contact.lag_friction(x, KAPPA, MU)
    assert contact.friction_count(lag) == 16
    normal_force = KAPPA * np.linalg.norm(contact.barrier_gradient(x).reshape(-1, 3), axis=1)
    np.testing.assert_allclose(np.sort(lag.normal_forces()), np.sort(normal_force), rtol=1e-12)
    w = sliding_motion(16)
    tangential = np.linalg.norm(w.reshape(-1, 3)[:, :2], axis=1)
    expected = np.sum(MU * normal_force * f0(tangential, EPS))
    assert contact.friction_energy(lag, w, EPS) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("scene", [cloth_over_one_triangle, hovering_cloth], ids=["one_triangle", "mixed_pairs"])
def test_friction_gradient_and_hessian_match_finite_differences(scene):
    """dD/dw = central differences of D, d^2D/dw^2 = central differences of dD/dw, with tangential motions
    below and above eps."""
    contact, x = scene()
    lag = contact.lag_friction(x, KAPPA, MU)
    w = sliding_motion(len(x) // 3)
    energy = lambda v: contact.friction_energy(lag, v, EPS)  # noqa: E731
    gradient = lambda v: contact.friction_gradient(lag, v, EPS)  # noqa: E731
    g = gradient(w)
    np.testing.assert_allclose(central_gradient(energy, w, FRICTION_FD_STEP), g, rtol=1e-6, atol=1e-7 * np.abs(g).max())
    h = contact.friction_hessian(lag, w, EPS).toarray()
    np.testing.assert_allclose(central_jacobian(gradient, w, FRICTION_FD_STEP), h, rtol=1e-6, atol=1e-7 * np.abs(h).max())
    projected = np.linalg.eigvalsh(contact.friction_hessian(lag, w, EPS, project="clamp").toarray())
    assert projected.min() >= -1e-12 * projected.max()


def test_friction_force_opposes_sliding_with_magnitude_mu_lambda():
    """For |w_xy| >> eps, f0 = |u|: the force -dD/dw_i = -mu lambda_i w_i,xy / |w_i,xy|, no normal part."""
    contact, x = cloth_over_one_triangle()
    lag = contact.lag_friction(x, KAPPA, MU)
    normal_force = KAPPA * np.linalg.norm(contact.barrier_gradient(x).reshape(-1, 3), axis=1)
    w = sliding_motion(16).reshape(-1, 3)
    w[:, :2] *= 100 / np.linalg.norm(w[:, :2], axis=1, keepdims=True) * EPS  # |u| = 100 eps
    force = -contact.friction_gradient(lag, w.ravel(), EPS).reshape(-1, 3)
    direction = w[:, :2] / np.linalg.norm(w[:, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(force[:, :2], -MU * normal_force[:, None] * direction, rtol=1e-10, atol=1e-14)
    assert np.all(force[:, 2] == 0)


def test_no_friction_without_a_coefficient():
    contact, x = cloth_over_one_triangle()
    lag = contact.lag_friction(x, KAPPA, 0.0)
    w = sliding_motion(16)
    assert contact.friction_energy(lag, w, EPS) == 0.0
    assert not contact.friction_gradient(lag, w, EPS).any()
    assert contact.friction_hessian(lag, w, EPS).count_nonzero() == 0


def test_a_lag_belongs_to_its_contact():
    contact, x = cloth_over_one_triangle()
    other, _ = cloth_over_one_triangle()
    with pytest.raises(ValueError, match="another MeshContact"):
        other.friction_energy(contact.lag_friction(x, KAPPA, MU), np.zeros_like(x), EPS)


# -- bad input ------------------------------------------------------------------------------------------------

def test_boundary_edges_are_the_edges_of_one_triangle():
    triangles = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    assert sorted(map(tuple, np.sort(boundary_edges(triangles), axis=1))) == [(0, 1), (0, 3), (1, 2), (2, 3)]


_REST, _TRIANGLES = grid(3, 3, 0.25)
_PLANE = square(-1.0, 2.0)
_COLLINEAR = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([[0, 1, 3], [0, 1, 2]]))
_SHORT = (np.array([[0.0, -1.0], [1.0, -1.0]]), [[0, 1], [1, 1]])

# case: (arguments of MeshContact, the message it must raise)
BAD_INPUT = {
    "degenerate obstacle triangle": (dict(rest=_REST, triangles=_TRIANGLES, obstacles=[_PLANE, _COLLINEAR]),
                                     r"obstacles\[1\] triangle 1 \[0, 1, 2\] is degenerate"),
    "self-contact without triangles": (dict(rest=_REST, triangles=None, edges=[[0, 1]], obstacles=[_PLANE], self_contact=True),
                                       "self-contact needs a model with triangles"),
    "nothing to collide": (dict(rest=_REST, triangles=_TRIANGLES), "nothing to collide"),
    "obstacle index out of range": (dict(rest=_REST, triangles=_TRIANGLES, obstacles=[(_PLANE[0], [[0, 1, 4]])]),
                                    r"obstacles\[0\] triangles: element 0 \[0, 1, 4\] has an index out of range for 4 vertices"),
    "model index out of range": (dict(rest=_REST, triangles=_TRIANGLES + 1, obstacles=[_PLANE]),
                                 r"^triangles: element 3 \[5, 6, 9\] has an index out of range for 9 vertices"),
    "dimension mismatch": (dict(rest=_REST[:, :2], triangles=_TRIANGLES, obstacles=[_PLANE]),
                           r"obstacles\[0\]: vertices must have shape \(m, 2\) for a 2-D model"),
    "2-D obstacle of triangles": (dict(rest=_REST[:, :2], triangles=_TRIANGLES, obstacles=[(_PLANE[0][:, :2], _PLANE[1])]),
                                  r"obstacles\[0\] edges: expected shape \(k, 2\)"),
    "zero-length obstacle edge": (dict(rest=_REST[:, :2], triangles=_TRIANGLES, obstacles=[_SHORT]),
                                  r"obstacles\[0\] edge 1 \[1, 1\] has zero length"),
    "non-positive dhat": (dict(rest=_REST, triangles=_TRIANGLES, obstacles=[_PLANE], dhat=0.0), "dhat: must be a positive distance"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUT))
def test_bad_input_is_refused_with_its_name(case):
    arguments, message = BAD_INPUT[case]
    with pytest.raises(ValueError, match=message):
        MeshContact(**{"dhat": DHAT, **arguments})
