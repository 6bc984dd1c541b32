"""Theory checks of contact (systems/contact/model.py, build.py, params.py) through the mass-spring system, the
incremental potential, the line search's collision filter and the runner.

- IPC's barrier and friction mollifier against ipctk's scalar functions;
- the incremental potential with contact (IPC barrier on a sphere and a plane, lagged friction, penalty with
  contact damping): gradient and Hessian against central differences;
- IPC never lets a vertex through a plane, nor through a 4 mm plate, at any dt (the line search stops short of the
  time of impact), where a penalty must penetrate to push back and tunnels through the plate at dt = 0.1 s;
- Coulomb friction on a slope of tan(theta) = 0.1: sliding at g (sin theta - mu cos theta) for mu < tan(theta),
  held (creeping at IPC's smoothed static speed) for mu > tan(theta);
- the energy budget with friction: E + friction_dissipated - E(0) is backward Euler's own loss, M a^2 dt T / 2;
- every contact config error is one line naming its field, raised before anything is written;
- the contact numbers of a run in the results file.

The slope runs use a stiff 2 x 2 block (four vertices of 250 kg, springs of 1e9 N/m) rather than the course's soft
square: its elastic sag under its own weight stores ~1e-3 J, so what the tests measure is the contact and the
integrator, not the block's vibrations.
"""

from __future__ import annotations

import copy
import math
import subprocess
import sys
from pathlib import Path

import ipctk
import numpy as np
import pytest
import yaml

import simrun
from conftest import run_one, step_problem
from simrun.errors import ConfigError
from simrun.systems.contact.friction import mollifier
from simrun.systems.contact.model import barrier
from simrun.systems.mass_spring.params import MassSpringParams
from simrun.systems.mass_spring.system import MassSpring

GRAVITY = 9.81  # m/s^2, the systems' default
NEWTON = {"type": "newton", "tolerance": 1e-6, "max_iterations": 100}

# The slope of the course's example: normal (0.1, 1) through (0, -1), so tan(theta) = 0.1.
TAN_SLOPE = 0.1
SLOPE_ANGLE = math.atan(TAN_SLOPE)
SLOPE_NORMAL = np.array([TAN_SLOPE, 1.0]) / math.hypot(TAN_SLOPE, 1.0)
DOWN_SLOPE = np.array([1.0, -TAN_SLOPE]) / math.hypot(TAN_SLOPE, 1.0)
SLOPE_POINT = np.array([0.0, -1.0])
SLOPE = {"shape": "plane", "normal": [TAN_SLOPE, 1.0], "point": SLOPE_POINT.tolist()}
DHAT = 0.01  # m
BLOCK_MASS = 1000.0  # kg in all

# Central differences of E (kg m^2) and of its gradient: truncation STEP^2 |E'''| (|phi| >= 0.01 m) and round-off
# eps |E| / STEP; measured ~5e-10 of the terms compared, so the tests ask 1e-7
FD_STEP = 1e-7  # m, far below dhat and the friction's epsilon (epsv dt)


def _slope_start(gap: float) -> dict:
    """``initial`` of a unit square (rest centroid at the origin) turned to lie flat on the slope with its bottom edge
    ``gap`` (m) above it: rotated by -theta, centroid at SLOPE_POINT + (1/2 + gap) n."""
    return {"rotate": -math.degrees(SLOPE_ANGLE), "translate": (SLOPE_POINT + (0.5 + gap) * SLOPE_NORMAL).tolist()}


def block(mu: float, epsv: float, gap: float = DHAT, stiffness="auto") -> dict:
    """The stiff 2 x 2 block (1 m, 1000 kg, springs 1e9 N/m) on the slope, IPC with dhat = 1 cm, barrier stiffness
    ``stiffness`` (N) and friction (mu, epsv); its bottom edge starts ``gap`` above the slope, at rest (gap = dhat:
    no barrier energy at t = 0)."""
    return {"type": "mass_spring", "model": {"square": {"segments": 1, "size": 1.0}}, "spring_law": "squared_length",
            "stiffness": 1.0e9, "mass": {"per_vertex": BLOCK_MASS / 4}, "gravity": [0.0, -GRAVITY],
            "initial": _slope_start(gap),
            "contact": {"method": "ipc", "dhat": DHAT, "stiffness": stiffness, "friction": {"mu": mu, "epsv": epsv},
                        "colliders": [SLOPE]}}


# The course's elastic square (solid-sim-tutorial), bottom edge dhat/2 above the slope.
COURSE_SQUARE = {"type": "mass_spring", "model": {"square": {"segments": 4, "size": 1.0}},
                 "spring_law": "squared_length", "stiffness": 2.0e4, "mass": {"per_vertex": 40.0},
                 "gravity": [0.0, -GRAVITY], "initial": _slope_start(DHAT / 2),
                 "contact": {"method": "ipc", "dhat": DHAT, "friction": {"mu": 0.05, "epsv": 1.0e-3},
                             "colliders": [SLOPE]}}


def slide_acceleration(mu: float) -> float:
    """g (sin theta - mu cos theta) (m/s^2): Coulomb sliding down the slope."""
    return GRAVITY * (math.sin(SLOPE_ANGLE) - mu * math.cos(SLOPE_ANGLE))


def along_slope(result) -> tuple[np.ndarray, np.ndarray]:
    """(frame times (s), the centre of mass's position down the slope (m)): equal masses, so the vertex mean."""
    return result.samples["frame_t"], result.samples["frames"].mean(axis=1) @ DOWN_SLOPE


# -- 1. the barrier and the mollifier ---------------------------------------------------------------------------


def test_barrier_is_ipctks_on_squared_distances():
    """B(phi) = b(phi^2; dhat^2)/dhat^3 with ipctk's b; by the chain rule dB/dphi = 2 phi b'/dhat^3 and
    d^2B/dphi^2 = (4 phi^2 b'' + 2 b')/dhat^3; B, B' (and B'', the barrier is C^2) vanish at phi = dhat."""
    dhat = 2.0e-3
    phi = dhat * np.array([1e-4, 0.01, 0.1, 0.3, 0.5, 0.9, 0.999])
    value, first, second = barrier(phi, dhat)
    s, s_hat, scale = phi ** 2, dhat ** 2, dhat ** -3
    b = np.array([ipctk.barrier(si, s_hat) for si in s])
    b1 = np.array([ipctk.barrier_first_derivative(si, s_hat) for si in s])
    b2 = np.array([ipctk.barrier_second_derivative(si, s_hat) for si in s])
    np.testing.assert_allclose(value, scale * b, rtol=1e-11)
    np.testing.assert_allclose(first, scale * 2.0 * phi * b1, rtol=1e-11)
    np.testing.assert_allclose(second, scale * (4.0 * s * b2 + 2.0 * b1), rtol=1e-11)
    assert np.all(value > 0) and np.all(first < 0) and np.all(second > 0)  # repulsive and convex inside dhat
    at_reach = barrier(np.array([dhat]), dhat)
    assert at_reach[0][0] == 0.0 and at_reach[1][0] == 0.0 and abs(at_reach[2][0]) <= 1e-12 * scale


def test_mollifier_is_ipctks_smooth_friction():
    """f0, f1/y and (f2 y - f1)/y^3 are ipctk's smooth_friction_f0, _f1_over_x, _f2_x_minus_f1_over_x3, below
    (y < eps: the static, smoothed part) and above (y >= eps: f0 = y, Coulomb) the threshold."""
    epsilon = 3.0e-4
    speed = epsilon * np.array([1e-3, 0.2, 0.5, 0.99, 1.0, 1.5, 10.0, 1e3])
    f0, f1_over, curvature = mollifier(speed, epsilon)
    np.testing.assert_allclose(f0, [ipctk.smooth_friction_f0(y, epsilon) for y in speed], rtol=1e-13)
    np.testing.assert_allclose(f1_over, [ipctk.smooth_friction_f1_over_x(y, epsilon) for y in speed], rtol=1e-13)
    np.testing.assert_allclose(curvature, [ipctk.smooth_friction_f2_x_minus_f1_over_x3(y, epsilon) for y in speed],
                               rtol=1e-13)
    assert np.all(f0[speed >= epsilon] == speed[speed >= epsilon])  # sliding: f0 = y, f1 = 1


# -- 2. the incremental potential with contact against central differences ----------------------------------------

# Five vertices of a 3-D rope (springs between neighbours), built high above the colliders and then evaluated at
# START: vertices 0, 1 within dhat of the plane z = 0, vertices 2, 3 within dhat of the sphere, vertex 4 free.
FD_DHAT = 0.05
SPHERE_CENTER, SPHERE_RADIUS = np.array([1.0, 0.0, 0.5]), 0.3
START = np.array([[0.0, 0.0, 0.02], [0.3, 0.1, 0.035],
                  SPHERE_CENTER + (SPHERE_RADIUS + 0.02) * np.array([0.0, 0.0, 1.0]),
                  SPHERE_CENTER + (SPHERE_RADIUS + 0.03) * np.array([0.6, 0.0, 0.8]),
                  [0.6, 0.2, 0.4]])
ROPE_3D = {"type": "mass_spring", "model": {"rope": {"count": 5, "length": 1.0, "direction": [1.0, 0.0, 0.0],
                                                     "start": [0.0, 0.0, 3.0]}},
           "stiffness": 200.0, "mass": {"per_vertex": 0.2}}
IPC_COLLIDERS = [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.0]},
                 {"shape": "sphere", "center": SPHERE_CENTER.tolist(), "radius": SPHERE_RADIUS}]


def _tangent_step(normal: np.ndarray, length: float, turn: float) -> np.ndarray:
    """A step of ``length`` (m) across ``normal``, turned by ``turn`` (rad) in the tangent plane."""
    first = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[1]) < 0.9 else [1.0, 0.0, 0.0])
    first /= np.linalg.norm(first)
    second = np.cross(normal, first)
    return length * (math.cos(turn) * first + math.sin(turn) * second)


def _normals(points: np.ndarray) -> np.ndarray:
    """The outward normals at START's first four vertices: +z for the plane's, radial for the sphere's."""
    radial = points[2:4] - SPHERE_CENTER
    return np.vstack([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], radial / np.linalg.norm(radial, axis=1)[:, None]])


def _fd_check(problem, y: np.ndarray) -> None:
    """grad E against central differences of E, and Hess E against central differences of grad E, at y."""
    gradient, hessian = problem.gradient(y), problem.hessian(y)
    hessian = hessian.toarray() if hasattr(hessian, "toarray") else np.asarray(hessian)
    numeric_gradient, numeric_hessian = np.zeros(y.size), np.zeros((y.size, y.size))
    for j in range(y.size):
        step = np.zeros(y.size)
        step[j] = FD_STEP
        numeric_gradient[j] = (problem.value(y + step) - problem.value(y - step)) / (2 * FD_STEP)
        numeric_hessian[:, j] = (problem.gradient(y + step) - problem.gradient(y - step)) / (2 * FD_STEP)
    assert np.linalg.norm(numeric_gradient - gradient) <= 1e-7 * np.linalg.norm(gradient)
    # per row: the barrier's rows are 1e6 times the springs', which a whole-matrix norm would hide
    scale = np.abs(hessian).max(axis=1, keepdims=True)
    assert np.all(np.abs(numeric_hessian - hessian) <= 1e-7 * scale)
    assert np.allclose(hessian, hessian.T, rtol=1e-12, atol=1e-12 * scale.max())


def _build(**contact) -> MassSpring:
    return MassSpringParams(**{**ROPE_3D, "contact": contact}).build()


def test_ipc_barrier_derivatives_on_plane_and_sphere():
    """E(y) = 1/2 |y - y~|_M^2 + dt^2 (springs + gravity + kappa sum B(phi_c(y_i))): gradient and Hessian (with the
    sphere's curvature term kappa B' (I - n n^T)/|y - c|) against central differences, four vertices within dhat of
    a plane or a sphere at y (none touching), kappa from IPC's estimate at the step's start."""
    system = _build(method="ipc", dhat=FD_DHAT, colliders=IPC_COLLIDERS)
    dt, x = 0.01, START.ravel()
    v = np.random.default_rng(1).uniform(-0.3, 0.3, x.size)
    system.contact_form().begin_step(0.0, dt, x)
    problem, _ = step_problem(system, x, v, dt)
    # y: the vertices moved across and along their normals, every distance still in (0, dhat)
    normals = _normals(START)
    y = START.copy()
    y[:4] += np.array([0.004, -0.01, 0.006, -0.008])[:, None] * normals
    y[:4] += np.array([_tangent_step(n, 0.01, turn) for n, turn in zip(normals, (0.3, 1.2, 2.0, 4.0))])
    y = y.ravel()
    assert system.contact.active_count(y) == 4 and system.contact.minimum_distance(y) > 0.0
    assert problem.friction is None
    _fd_check(problem, y)


def test_ipc_friction_derivatives_sliding_and_sticking():
    """Friction adds dt^2 sum mu lambda_k f0(|w_k|; epsv dt), w_k = T_k (y_k - x_k) (lambda, T lagged at the step's
    start x): gradient dt^2 mu lambda f1 w/|w| and the Hessian sum mu lambda [f1/|w| T + (f2 |w| - f1)/|w|^3 w w^T]
    against central differences, with two contacts slower than epsv (|w| < epsv dt, the smoothed static part) and
    two faster (Coulomb's |f| = mu lambda)."""
    system = _build(method="ipc", dhat=FD_DHAT, friction={"mu": 0.4, "epsv": 0.5}, colliders=IPC_COLLIDERS)
    dt, x = 0.01, START.ravel()
    v = np.random.default_rng(2).uniform(-0.3, 0.3, x.size)
    system.contact_form().begin_step(0.0, dt, x)
    problem, _ = step_problem(system, x, v, dt)
    assert problem.friction is not None
    epsilon = 0.5 * dt  # epsv dt (m): the sliding speed as a displacement in one step
    normals = _normals(START)
    slides = np.array([0.3, 4.0, 0.5, 3.0]) * epsilon  # |w|/epsilon: slow, fast, slow, fast
    y = START.copy()
    turns = (0.3, 1.2, 2.0, 4.0)
    y[:4] += np.array([_tangent_step(n, length, turn) for n, length, turn in zip(normals, slides, turns)])
    y[:4] += np.array([0.003, -0.004, 0.002, 0.005])[:, None] * normals
    y = y.ravel()
    assert problem.friction.lag.vertices.tolist() == [0, 1, 2, 3]  # the contacts within dhat at the step's start
    step = (y - x).reshape(-1, 3)[:4]
    w = step - np.einsum("ij,ij->i", step, normals)[:, None] * normals  # T (y - x) with the lagged normals
    assert np.allclose(np.linalg.norm(w, axis=1), slides, rtol=1e-12)
    _fd_check(problem, y)


def test_penalty_derivatives_with_contact_damping():
    """Penalty k/2 min(phi, 0)^2 on a box (f = -k phi n inside, H = k n n^T on a face) with contact damping
    D = k_d n n^T taken at the step's start (E gains dt/2 (y - x)^T D (y - x)): gradient and Hessian against central
    differences, two vertices inside the box (away from its edges), one outside near it, two far."""
    box = {"shape": "box", "center": [0.0, 0.0, -0.5], "half_extents": [1.0, 1.0, 0.5]}  # top face z = 0
    system = _build(method="penalty", stiffness=3.0e4, damping=40.0, colliders=[box])
    dt = 0.01
    x = np.array([[0.1, 0.2, -0.01], [0.9, 0.0, -0.02], [0.5, -0.3, 0.02], [1.4, 0.0, 0.3], [0.6, 0.2, 0.4]]).ravel()
    v = np.random.default_rng(3).uniform(-0.3, 0.3, x.size)
    system.contact_form().begin_step(0.0, dt, x)
    problem, _ = step_problem(system, x, v, dt)
    assert problem.damping is not None and problem.damping.nnz > 0  # contact damping at the two inside vertices
    y = x + np.random.default_rng(4).uniform(-3e-3, 3e-3, x.size)
    assert system.contact.active_count(y) == 2 and system.contact_energy(y) > 0.0
    _fd_check(problem, y)


# -- 3. IPC never penetrates; a penalty must ---------------------------------------------------------------------


def _drop(dim: int, method: str = "ipc", **contact) -> dict:
    """Two vertices (0.1 kg each, one spring) dropped at rest from 0.5 m onto a tilted plane through the origin."""
    start, direction = ([0.0, 0.0, 0.5], [1.0, 0.0, 0.0]) if dim == 3 else ([0.0, 0.5], [1.0, 0.0])
    normal = [0.2, 0.1, 1.0] if dim == 3 else [0.2, 1.0]
    rope = {"count": 2, "length": 0.1, "direction": direction, "start": start}
    return {"type": "mass_spring", "model": {"rope": rope},
            "stiffness": 100.0, "mass": {"per_vertex": 0.1},
            "contact": {"method": method, "dhat": DHAT, **contact,
                        "colliders": [{"shape": "plane", "normal": normal, "point": [0.0] * dim}]}}


def _distances(frames: np.ndarray, normal: list) -> np.ndarray:
    """Signed distances (frames, vertices) to the plane through the origin with this normal."""
    return frames @ (np.array(normal) / np.linalg.norm(normal))


@pytest.mark.parametrize("stiffness", ["auto", 0.01])
@pytest.mark.parametrize("dt", [0.1, 0.03, 0.01])
@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2", "newmark"])
@pytest.mark.parametrize("dim", [3, 2])
def test_ipc_drop_never_penetrates(dim, integrator, dt, stiffness):
    """Falling 0.5 m (3.1 m/s at impact, ~0.3 m in one step of 0.1 s): every solver step is cut to
    (1 - 0.1) of its time of impact, so every distance stays > 0, on every step and at every frame, at any dt.
    With IPC's own stiffness the vertices stop near dhat; a barrier of kappa = 0.01 N lets the impact compress it to
    below dhat/100 (the step of M (y - y~) = -dt^2 kappa B'(phi), B' ~ -2 dhat/phi, ends at phi ~ 1e-6..1e-4 m),
    where a step that overshot would cross."""
    config = _drop(dim, stiffness=stiffness)
    result = run_one(config, integrator, dt, 1.0, solver=NEWTON)
    assert result.status == "ok", result.message
    assert result.attrs["max_active_contacts"] >= 1 and result.attrs["min_contact_distance"] < DHAT  # it landed
    if stiffness != "auto":
        assert result.attrs["min_contact_distance"] < DHAT / 100
    assert np.all(result.per_step["contact_distance"] > 0.0)
    assert result.attrs["min_contact_distance"] == result.per_step["contact_distance"].min() > 0.0
    assert np.all(_distances(result.samples["frames"], config["contact"]["colliders"][0]["normal"]) > 0.0)


# A plate 4 mm thick under the 3-D drop: one step of 0.1 s at impact (~0.3 m) can jump clean over it.
PLATE = {"shape": "box", "center": [0.0, 0.0, 0.0], "half_extents": [1.0, 1.0, 0.002]}


@pytest.mark.parametrize("method", ["ipc", "penalty"])
def test_thin_plate_tunnelling(method):
    """The 3-D drop onto a 4 mm plate at dt = 0.1 s. IPC: the time of impact cuts every solver step before the plate,
    so the vertices stay above its top face z = 2 mm at every frame, whatever the method (backward_euler, bdf2,
    newmark) and the solver: Newton's line search cuts its steps, vertex block descent each vertex's step and its
    Chebyshev extrapolation. Penalty (k = 1e3 N/m): backward Euler's third step, from z = 20.6 cm to -8.9 cm, meets no
    penetration at either end and so no force, and the vertices end below the plate: tunnelling (with every recorded
    distance positive)."""
    config = _drop(3, method=method, **({"stiffness": 1.0e3} if method == "penalty" else {}))
    config["contact"]["colliders"] = [PLATE]
    top = PLATE["half_extents"][2]
    vbd = {"type": "vbd", "tolerance": 1e-6, "max_iterations": 2000}
    runs = ([(integrator, NEWTON) for integrator in ("backward_euler", "bdf2", "newmark")]
            + [("backward_euler", vbd), ("backward_euler", {**vbd, "chebyshev_rho": 0.9})]
            if method == "ipc" else [("backward_euler", NEWTON)])
    for integrator, solver in runs:
        result = run_one(config, integrator, 0.1, 1.0, solver=solver)
        assert result.status == "ok", result.message
        heights = result.samples["frames"][:, :, 2]
        if method == "ipc":
            assert result.attrs["max_active_contacts"] == 2 and np.all(heights > top), (integrator, solver)
        else:
            assert np.all(heights[-1] < -top) and result.attrs["min_contact_distance"] > 0.0


@pytest.mark.parametrize("dim", [3, 2])
def test_penalty_drop_penetrates(dim):
    """The same drop with a penalty (k = 1e3 N/m) at dt = 0.1 s: a penalty pushes only from inside, so the vertices
    end at rest m g cos(alpha)/k = 0.96 mm deep (alpha the plane's tilt), and sank deeper at the impact."""
    config = _drop(dim, method="penalty", stiffness=1.0e3)
    result = run_one(config, "backward_euler", 0.1, 3.0, solver=NEWTON)
    assert result.status == "ok", result.message
    normal = np.array(config["contact"]["colliders"][0]["normal"])
    rest_depth = 0.1 * GRAVITY * normal[-1] / np.linalg.norm(normal) / 1.0e3
    final = _distances(result.samples["frames"][-1], normal)
    np.testing.assert_allclose(final, -rest_depth, rtol=1e-3)
    assert result.attrs["min_contact_distance"] < -2 * rest_depth


# -- 4. Coulomb friction on the slope ----------------------------------------------------------------------------


@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_block_slides_at_coulombs_acceleration(integrator):
    """mu = 0.05 < tan(theta) = 0.1: the block slides with a = g (sin theta - mu cos theta) = 0.48807 m/s^2. Both
    methods integrate a constant acceleration exactly up to a linear term (backward Euler: x_n = a t^2/2 +
    a dt t/2), so a quadratic fit of the centre of mass on t > 0.3 s (after the first contact's transient) gives a
    to the solver's tolerance: within 1e-4 (measured 3e-9 and 1.5e-6). Newmark's trapezoidal rule is not here: on
    this stiff block it gains energy at the contact (+5 kJ in 1 s at dt = 0.01) and the block hops."""
    result = run_one(block(mu=0.05, epsv=1e-3), integrator, 0.01, 1.0, solver=NEWTON)
    assert result.status == "ok", result.message
    t, s = along_slope(result)
    late = t > 0.3
    acceleration = 2.0 * np.polyfit(t[late], s[late], 2)[0]
    assert acceleration == pytest.approx(slide_acceleration(0.05), rel=1e-4)


def test_relagged_friction_slides_at_coulombs_acceleration_with_more_solves():
    """friction.lag_iterations = 2: each step solves three times, the last two with the normal forces and tangent
    bases lagged at the previous solution; on the sliding block (normal force and tangent constant) the motion is the
    same, a = g (sin theta - mu cos theta) within 1e-4, and every step costs at least three solves' iterations."""
    system = block(mu=0.05, epsv=1e-3)
    system["contact"]["friction"]["lag_iterations"] = 2
    relagged = run_one(system, "backward_euler", 0.01, 1.0, solver=NEWTON)
    once = run_one(block(mu=0.05, epsv=1e-3), "backward_euler", 0.01, 1.0, solver=NEWTON)
    assert relagged.status == "ok", relagged.message
    t, s = along_slope(relagged)
    late = t > 0.3
    assert 2.0 * np.polyfit(t[late], s[late], 2)[0] == pytest.approx(slide_acceleration(0.05), rel=1e-4)
    assert np.all(relagged.per_step["newton_iterations"] >= 3)
    assert relagged.per_step["newton_iterations"].sum() > once.per_step["newton_iterations"].sum()


def test_moving_collider_lifts_a_cloth_without_penetration():
    """A sphere rising at 0.5 m/s under a free 8 x 8 cloth (IPC, friction, backward Euler, dt = 0.01 s, 1 s):
    every step starts with the vertices within its reach carried along (their distance at t_n kept), so no step's
    smallest distance is negative; the cloth ends lifted with the sphere (its lowest vertex above its start)."""
    system = {"type": "cloth", "resolution": [8, 8], "pinned": [],
              "contact": {"method": "ipc", "dhat": 2.0e-3, "friction": {"mu": 0.2},
                          "colliders": [{"shape": "sphere", "center": [0.5, 0.5, -0.35], "radius": 0.3,
                                         "velocity": [0.0, 0.0, 0.5]}]}}
    result = run_one(system, "backward_euler", 0.01, 1.0, solver=NEWTON)
    assert result.status == "ok", result.message
    assert np.all(result.per_step["contact_distance"] > 0.0)
    assert result.samples["frames"][-1][:, 2].min() > 0.0


def _rope_on(plane_velocity: list[float], gap: float = 0.005) -> dict:
    """Two vertices 0.1 m apart resting ``gap`` above a plane through the origin with normal +y that moves with
    ``plane_velocity``; gravity, IPC (dhat = 1 cm, IPC's stiffness) and friction mu = 0.5."""
    return {"type": "mass_spring", "model": {"rope": {"count": 2, "length": 0.1, "direction": [1.0, 0.0],
                                                      "start": [0.0, gap]}},
            "stiffness": 100.0, "mass": {"per_vertex": 0.1}, "gravity": [0.0, -9.81],
            "contact": {"method": "ipc", "dhat": 0.01, "friction": {"mu": 0.5, "epsv": 1e-3},
                        "colliders": [{"shape": "plane", "normal": [0.0, 1.0], "point": [0.0, 0.0],
                                       "velocity": plane_velocity}]}}


@pytest.mark.parametrize("normal_speed", [0.0, 0.8, -0.3])
def test_a_moving_collider_drags_by_friction_lagged_where_it_was(normal_speed):
    """A conveyor: the plane moves at 1 m/s along x (and at normal_speed along its normal) under the resting pair.
    Friction is lagged at the step's start with the plane where it was then, so the pair within reach feels its
    normal force and is dragged along whatever the normal motion: 0.90, 0.96 and 0.87 m in 1 s (lagged at the
    plane's end position instead, a plane rising at 0.8 m/s found no contact and dragged nothing, and one sinking
    at 0.3 m/s a wrong normal force: 0.47 m); every step's distance stays positive."""
    result = run_one(_rope_on([1.0, normal_speed]), "backward_euler", 0.01, 1.0, solver=NEWTON)
    assert result.status == "ok", result.message
    assert np.all(result.per_step["contact_distance"] > 0.0)
    moved = result.samples["frames"][-1][:, 0] - result.samples["frames"][0][:, 0]
    assert np.all(moved > 0.8), moved


def test_a_carried_start_does_not_push_a_vertex_into_another_collider():
    """A lid 11 mm above the ground comes down at 0.5 m/s onto a pair resting 4 mm above the ground: carried along
    with the lid, the pair would start the step inside the ground; it stays instead (there is room: the lid ends the
    step 6 mm up), and the step ends with every distance positive."""
    system = _rope_on([0.0, 0.0], gap=0.004)
    system["contact"].pop("friction")
    system["contact"]["colliders"].append({"shape": "plane", "normal": [0.0, -1.0], "point": [0.0, 0.011],
                                           "velocity": [0.0, -0.5]})
    result = run_one(system, "backward_euler", 0.01, 0.01, solver=NEWTON)
    assert result.status == "ok", result.message
    assert np.all(result.per_step["contact_distance"] > 0.0)


def test_a_collider_faster_than_a_step_allows_fails_in_one_line():
    """The same lid at 2 m/s passes the ground's top within one 0.01 s step: no start is collision-free, and the run
    fails naming the collider and the vertex, instead of recording a negative distance."""
    system = _rope_on([0.0, 0.0], gap=0.004)
    system["contact"].pop("friction")
    system["contact"]["colliders"].append({"shape": "plane", "normal": [0.0, -1.0], "point": [0.0, 0.011],
                                           "velocity": [0.0, -2.0]})
    result = run_one(system, "backward_euler", 0.01, 0.02, solver=NEWTON)
    assert result.status == "failed"
    assert "overtook vertex" in result.message and "\n" not in result.message


def test_course_square_slides_at_coulombs_acceleration():
    """The course's soft square (k = 2e4 N/m, bottom edge dhat/2 above the slope), mu = 0.05, backward Euler:
    the centre of mass accelerates at g (sin theta - mu cos theta) within 2 % (its elastic vibrations, which
    backward Euler damps, perturb the fit on t > 0.5 s)."""
    result = run_one(COURSE_SQUARE, "backward_euler", 0.01, 2.0, solver=NEWTON)
    assert result.status == "ok", result.message
    t, s = along_slope(result)
    late = t > 0.5
    acceleration = 2.0 * np.polyfit(t[late], s[late], 2)[0]
    assert acceleration == pytest.approx(slide_acceleration(0.05), rel=0.02)


def test_block_held_by_static_friction():
    """mu = 0.11 > tan(theta) = 0.1, epsv = 1e-5 m/s, backward Euler: friction holds the block. IPC's smoothed
    static friction f1(v) = 2 v/epsv - (v/epsv)^2 (v < epsv) balances the slope's pull mu f1 = tan(theta) at the
    creep speed v = epsv (1 - sqrt(1 - tan(theta)/mu)) = 6.98e-6 m/s; so after the transient (t > 0.3 s; the block
    starts at dhat with no normal force, so the lagged friction lets it slide ~0.5 mm during the first steps) the
    centre of mass creeps at that speed within 0.1 % and moves less than 1 mm (7 micrometres) in 1 s."""
    epsv = 1.0e-5
    result = run_one(block(mu=0.11, epsv=epsv), "backward_euler", 0.01, 1.3, solver=NEWTON)
    assert result.status == "ok", result.message
    t, s = along_slope(result)
    late = t > 0.3 - 1e-9
    assert abs(s[-1] - s[late][0]) < 1e-3
    creep = np.polyfit(t[late], s[late], 1)[0]
    assert creep == pytest.approx(epsv * (1.0 - math.sqrt(1.0 - TAN_SLOPE / 0.11)), rel=1e-3)


# -- 5. the energy budget with friction --------------------------------------------------------------------------


def test_energy_budget_closes_with_friction():
    """Sliding block, mu = 0.05, backward Euler for T = 1 s. Each step under the constant net force M a takes
    M a dt v_{n+1} of work and gains M/2 (v_{n+1}^2 - v_n^2) = M a dt v_{n+1} - M a^2 dt^2/2 of kinetic energy, so
    E(T) + friction_dissipated(T) - E(0) = -M a^2 dt T/2 (E = kinetic + potential incl. contact): first order.
    Measured within 10 % of that at dt = 0.02 and 0.01 s, with a barrier stiff enough (1e9 N) that the block's
    settling into it, m g times a few microns, is far below (with IPC's own estimate it settles ~0.5 mm: ~5 J),
    and the ratio of the two gaps within 2 +- 0.2. friction_dissipated is the running sum of the per-step
    friction_work, and its total is Coulomb's mu M g cos(theta) times the distance slid within 1 %."""
    mu, duration = 0.05, 1.0
    gaps = {}
    for dt in (0.02, 0.01):
        result = run_one(block(mu=mu, epsv=1e-3, stiffness=1.0e9), "backward_euler", dt, duration, solver=NEWTON)
        assert result.status == "ok", result.message
        samples = result.samples
        energy = samples["kinetic_energy"] + samples["potential_energy"]
        dissipated = samples["friction_dissipated"]
        gaps[dt] = energy[-1] + dissipated[-1] - energy[0]
        theory = -BLOCK_MASS * slide_acceleration(mu) ** 2 * dt * duration / 2
        assert gaps[dt] == pytest.approx(theory, rel=0.1)
        # one sample per step: the cumulative loss is the per-step work summed
        assert dissipated.size == result.steps + 1
        np.testing.assert_allclose(dissipated[1:], np.cumsum(result.per_step["friction_work"]), rtol=1e-12, atol=1e-12)
        assert result.attrs["friction_work"] == pytest.approx(dissipated[-1], rel=1e-12)
        _, s = along_slope(result)
        coulomb = mu * BLOCK_MASS * GRAVITY * math.cos(SLOPE_ANGLE) * (s[-1] - s[0])
        assert dissipated[-1] == pytest.approx(coulomb, rel=0.01)
    assert gaps[0.02] / gaps[0.01] == pytest.approx(2.0, abs=0.2)


# -- 6. config errors --------------------------------------------------------------------------------------------

ROPE = {"type": "mass_spring", "model": {"rope": {"count": 2, "length": 0.1, "direction": [0.0, 0.0, -1.0],
                                                  "start": [0.0, 0.0, 0.5]}},
        "stiffness": 100.0, "mass": {"per_vertex": 0.1},
        "contact": {"method": "ipc", "dhat": DHAT, "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0]}]}}


def _experiment(system: dict | None = None, integrator: str = "backward_euler", solver: dict | None = None, **contact):
    system = copy.deepcopy(system or ROPE)
    system.setdefault("contact", {}).update(contact)
    return {"name": "contact-error", "system": system, "integrators": [integrator], "duration": 0.1,
            "sweep": {"dt": [0.01]}, **({"solver": solver} if solver else {})}


def _grid_file(tmp_path: Path) -> str:
    path = tmp_path / "field.npy"
    np.save(path, np.ones((4, 5, 6)))  # a 3-D array of samples
    return str(path)


CONFIG_ERRORS = {  # case: (config from tmp_path, [the field the message starts with, what else it says])
    "dhat-zero": (lambda tmp: _experiment(dhat=0), ["system.contact.dhat", "greater than 0"]),
    "mu-negative": (lambda tmp: _experiment(friction={"mu": -1}),
                    ["system.contact.friction.mu", "greater than or equal to 0"]),
    "epsv-zero": (lambda tmp: _experiment(friction={"mu": 0.1, "epsv": 0}),
                  ["system.contact.friction.epsv", "greater than 0"]),
    "ipc-explicit": (lambda tmp: _experiment(integrator="symplectic_euler"),
                     ["integrators", "symplectic_euler", "IPC"]),
    "ipc-midpoint": (lambda tmp: _experiment(integrator="implicit_midpoint"),
                     ["integrators", "implicit_midpoint", "IPC"]),
    "ipc-projective": (lambda tmp: _experiment(solver={"type": "projective_dynamics"}),
                       ["solver.type", "projective_dynamics", "IPC"]),
    "ipc-jacobi": (lambda tmp: _experiment(solver={"type": "jacobi_chebyshev"}), ["solver.type", "jacobi_chebyshev", "IPC"]),
    "friction-rk4": (lambda tmp: _experiment(integrator="rk4", method="penalty", friction={"mu": 0.3}),
                     ["integrators", "rk4", "friction"]),
    "self-penalty": (lambda tmp: _experiment(method="penalty", self=True), ["system.contact", "self", "ipc"]),
    "damping-ipc": (lambda tmp: _experiment(damping=1.0), ["system.contact.damping", "penalty"]),
    # the rope hangs down from z = 0.5 to 0.4: vertex 1 starts 5 cm inside the half-space z < 0.45
    "intersecting": (lambda tmp: _experiment(colliders=[{"shape": "plane", "normal": [0, 0, 1],
                                                         "point": [0, 0, 0.45]}]),
                     ["system.contact", "vertex 1", "inside", "collider 0"]),
    "grid-shape": (lambda tmp: _experiment(colliders=[{"shape": "grid_sdf", "file": _grid_file(tmp),
                                                       "origin": [0.0, 0.0], "spacing": [0.1, 0.1]}]),
                   ["system.contact.colliders[0]", "origin"]),
    "spring-mass": (lambda tmp: _experiment({"type": "spring_mass", "contact": {"method": "ipc"}}),
                    ["system.contact", "unknown"]),
}


@pytest.mark.parametrize("case", sorted(CONFIG_ERRORS))
def test_contact_config_errors(case, tmp_path):
    """Each bad contact config is one line naming its field (and what is wrong), raised by simrun.run when the config
    is loaded, before the output folder (let alone a results file) exists."""
    make, expected = CONFIG_ERRORS[case]
    output = tmp_path / "out"
    with pytest.raises(ConfigError) as raised:
        simrun.run(make(tmp_path), output=output, figures=False, progress=False, jobs=1)
    message = str(raised.value)
    assert "\n" not in message and message.startswith(expected[0]), message
    for part in expected[1:]:
        assert part in message, message
    assert not (output / "results.h5").exists() and not output.exists()


def test_contact_config_error_on_the_command_line(tmp_path):
    """`simrun config.yaml` with dhat: 0: exit status 2, the one line naming system.contact.dhat, no traceback,
    nothing written."""
    config = _experiment(dhat=0)
    config["output"] = str(tmp_path / "out")
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    executable = Path(sys.executable).parent / "simrun"
    finished = subprocess.run([str(executable), str(path)], capture_output=True, text=True, cwd=tmp_path)
    assert finished.returncode == 2
    assert "system.contact.dhat" in finished.stderr and "Traceback" not in finished.stderr + finished.stdout
    assert not (tmp_path / "out").exists()


# -- 7. the results file -----------------------------------------------------------------------------------------


def test_contact_numbers_in_the_results_file(tmp_path):
    """A 3-D IPC drop through simrun.run: the results file holds the per-step contact_distance and active_contacts
    and the run attrs min_contact_distance = min over steps, max_active_contacts = max over steps, and the last step's
    values are what the system computes from the last frame's positions."""
    config = {"name": "drop", "system": _drop(3), "integrators": ["backward_euler"], "duration": 0.6,
              "sweep": {"dt": [0.01]}, "solver": NEWTON}
    simrun.run(config, output=tmp_path / "out", figures=False, progress=False, jobs=1)
    stored = simrun.load(tmp_path / "out" / "results.h5")
    (run,) = stored.runs.values()
    distance, active = run["contact_distance"], run["active_contacts"]
    assert distance.shape == active.shape == (60,)
    assert run.attrs["min_contact_distance"] == distance.min() and 0.0 < distance.min() < DHAT
    assert run.attrs["max_active_contacts"] == active.max() == 2
    system = MassSpringParams(**config["system"]).build()
    last = run["frames"][-1].ravel()
    assert run["frame_t"][-1] == pytest.approx(0.6)
    assert distance[-1] == system.contact.minimum_distance(last)
    assert active[-1] == system.contact.active_count(last)


# -- rotating colliders -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_a_spinning_colliders_derivatives_are_those_of_its_distance(dim):
    """A box turning about an axis through a point off its centre (and translating), at t = 0.7 s: phi(p) =
    phi_0(R^T (p - c - v t) + c); its gradient R grad phi_0 and Hessian R Hess phi_0 R^T against central differences
    of phi and of the gradient, |grad phi| = 1 (a rigid motion keeps an SDF an SDF), and the velocity of the surface
    v + omega x (p - c(t)) against a difference of the carried points."""
    from simrun.systems.contact.colliders import build_collider
    from simrun.systems.contact.model import ColliderContact

    rng = np.random.default_rng(3)
    center = np.zeros(dim)
    box = build_collider("box", dim, center=center, half_extents=np.full(dim, 0.3), velocity=0.2 * np.ones(dim))
    axis = np.array([0.0, 0.0, 1.0]) if dim == 2 else np.array([1.0, 2.0, 2.0]) / 3.0
    contact = ColliderContact(box, None, (np.full(dim, 0.1), axis, 1.3))
    time = 0.7
    points = contact.carry(rng.uniform(-0.6, 0.6, (40, dim)), 0.0, time)
    phi, gradient, hessian = contact.derivatives(points, time)
    np.testing.assert_allclose(np.linalg.norm(gradient, axis=1), 1.0, rtol=1e-12)
    step = 1e-6
    for axis_index in range(dim):
        shift = np.zeros(dim)
        shift[axis_index] = step
        difference = (contact.signed_distance(points + shift, time) - contact.signed_distance(points - shift, time)) / (2 * step)
        smooth = np.abs(phi) > 1e-3  # away from the surface and the box's kinks, which central differences straddle
        np.testing.assert_allclose(difference[smooth], gradient[smooth, axis_index], atol=1e-7)
        hessian_column = (contact.derivatives(points + shift, time)[1] - contact.derivatives(points - shift, time)[1]) / (2 * step)
        np.testing.assert_allclose(hessian_column[smooth], hessian[smooth, :, axis_index], atol=1e-4)
    later = contact.carry(points, time, time + step)
    earlier = contact.carry(points, time, time - step)
    np.testing.assert_allclose((later - earlier) / (2 * step), contact.velocity_at(points, time), atol=1e-7)


def test_a_turntable_carries_a_block_round_by_friction():
    """A small square (4 vertices, 0.1 m, 0.4 kg) at rest on a floor turning at 90 deg/s about the vertical axis
    through the origin, its centre 0.5 m out; mu = 0.5. Friction (the floor's surface moves at omega x r) spins it up
    to turn with the floor (the centripetal omega^2 r = 1.23 m/s^2 is far below mu g = 4.9 m/s^2), so after 2 s its
    centre has turned through omega (2 s - the spin-up, a few hundredths of a second) at the same radius, and no
    step's distance to the floor is negative."""
    system = {"type": "mass_spring", "model": {"grid": {"resolution": [2, 2], "size": [0.1, 0.1]}}, "stiffness": 1.0e4,
              "mass": {"per_vertex": 0.1}, "gravity": [0.0, 0.0, -9.81], "initial": {"translate": [0.45, -0.05, 0.002]},
              "contact": {"method": "ipc", "dhat": 0.005, "friction": {"mu": 0.5, "epsv": 1e-4},
                          "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.0],
                                         "rotation": {"center": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "rate": 90.0}}]}}
    result = run_one(system, "backward_euler", 0.005, 2.0, solver=NEWTON)
    assert result.status == "ok", result.message
    assert np.all(result.per_step["contact_distance"] > 0.0)
    centre = result.samples["frames"][-1].mean(axis=0)
    angle = math.atan2(centre[1], centre[0]) % (2 * math.pi)
    assert math.hypot(centre[0], centre[1]) == pytest.approx(0.5, abs=0.02)
    assert math.degrees(angle) == pytest.approx(180.0, abs=8.0)
