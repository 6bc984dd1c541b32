"""The mass-spring system against known answers.

Sections, one per theme:
1. derivatives: finite differences of P and of its gradient, both spring laws, 2-D and 3-D; the damping
   matrices against the lectures' per-spring and per-vertex forces; the course code's energy formula;
2. two vertices and one spring are the `spring_mass` test equation, for every integrator;
3. a stiff two-vertex pendulum swings with the small-angle period;
4. a grid model is the former cloth bit for bit, and a quad mesh of the grid gives the grid's springs;
5. constraints: sliding vertices stay on their planes and lines for every integrator, nonlinear solver and
   linear solver; pins never move; prescribed vertices are on their paths; momentum along free directions;
6. MPCG on the filtered system gives the direct solver's Newton direction, from either start;
7. the energy budget E + dissipated - prescribed work = E0 closes to the method's order;
8. the course code's square demo.
"""

from __future__ import annotations

import math
from pathlib import Path

import meshio
import numpy as np
import pytest
import scipy.linalg
from scipy.spatial.transform import Rotation

import simrun
from conftest import needs_linear_solver, run_one
from simrun.integrators import INTEGRATORS, IncrementalPotential
from simrun.solvers.dofs import free_dofs
from simrun.solvers.linear import LINEAR_SOLVERS, MPCG_STARTS, ModifiedPCG
from simrun.solvers.params import SOLVERS
from simrun.systems.mass_spring.laws import SPRING_LAWS
from simrun.systems.mass_spring.params import MassSpringParams
from simrun.systems.vertex.damping import DAMPING_MODELS
from simrun.systems.vertex.grids import GridModel, grid_quads


def build(**config):
    """The MassSpring system of a `system:` mapping (without its `type`)."""
    return MassSpringParams(**config).build()


def deformed(system, seed: int, scale: float) -> np.ndarray:
    """x0 plus Gaussian noise of this standard deviation (m) on every coordinate."""
    return system.x0 + scale * np.random.default_rng(seed).standard_normal(system.dof_count)


def spring_lengths(system, x: np.ndarray) -> np.ndarray:
    positions = x.reshape(-1, system.dim)
    return np.linalg.norm(positions[system.first] - positions[system.second], axis=1)


def relative_max_error(value: np.ndarray, reference: np.ndarray) -> float:
    return float(np.max(np.abs(value - reference)) / np.max(np.abs(reference)))


# ==================================================================================================
# 1. Derivatives and damping matrices
# ==================================================================================================
FD_STEP = 1e-6  # central differences: truncation ~ FD_STEP^2, round-off ~ eps / FD_STEP, both ~1e-10 relative
FD_TOLERANCE = 1e-8  # relative to the largest entry; observed 1e-11 to 2e-10

CONTACT_3D = {"ground": {"height": 0.02, "stiffness": 3000.0},
              "sphere": {"center": [0.15, 0.1, 0.12], "radius": 0.15, "stiffness": 5000.0}}
MODELS = {
    "square-2d": dict(model={"square": {"segments": 3, "size": 0.6}},
                      stiffness={"stretch_x": 100.0, "stretch_y": 70.0, "shear": 30.0}),
    "rope-2d": dict(model={"rope": {"count": 6, "length": 0.5, "direction": [1.0, 0.5], "bend": True}},
                    stiffness={"stretch": 100.0, "bend": 5.0}),
    "grid-3d-contact": dict(model={"grid": {"resolution": [4, 3], "size": [0.3, 0.2]}},
                            stiffness={"stretch": 100.0, "shear": 30.0, "bend": 5.0}, contact=CONTACT_3D),
    "rope-3d": dict(model={"rope": {"count": 6, "length": 0.5, "direction": [1.0, 1.0, 1.0], "bend": True}},
                    stiffness={"stretch": 100.0, "bend": 5.0}),
}


@pytest.mark.parametrize("law", sorted(SPRING_LAWS))
@pytest.mark.parametrize("model", sorted(MODELS))
def test_gradient_and_hessian_match_finite_differences(model, law):
    """dP/dx against central differences of P and d^2P/dx^2 against central differences of dP/dx (FD_TOLERANCE),
    at a random state with compressed and stretched springs (and penalty contact touching in 3-D)."""
    system = build(**MODELS[model], spring_law=law, mass={"total": 0.3})
    x = deformed(system, seed=len(model), scale=0.03)
    lengths = spring_lengths(system, x)
    assert (lengths < system.rest_length).any() and (lengths > system.rest_length).any()
    if "contact" in MODELS[model]:
        positions = x.reshape(-1, 3)
        assert (positions[:, 2] < 0.02).any(), "the ground must touch"
        assert (np.linalg.norm(positions - CONTACT_3D["sphere"]["center"], axis=1) < 0.15).any(), "the sphere must touch"
    basis = np.eye(system.dof_count)
    fd_gradient = np.array([(system.potential_energy(x + FD_STEP * e) - system.potential_energy(x - FD_STEP * e)) / (2 * FD_STEP)
                            for e in basis])
    assert relative_max_error(system.gradient(x), fd_gradient) < FD_TOLERANCE
    hessian = system.hessian(x).toarray()
    fd_hessian = np.array([(system.gradient(x + FD_STEP * e) - system.gradient(x - FD_STEP * e)) / (2 * FD_STEP) for e in basis]).T
    assert relative_max_error(hessian, fd_hessian) < FD_TOLERANCE
    assert np.max(np.abs(hessian - hessian.T)) <= 1e-14 * np.max(np.abs(hessian))


@pytest.mark.parametrize("law", sorted(SPRING_LAWS))
def test_projected_hessian_is_positive_semidefinite_where_the_raw_one_is_not(law):
    """Compressed springs make the raw Hessian indefinite (hookean: k (1 - l0/L) < 0 across the spring; squared
    length: 2k (s - 1) < 0 across, 2k (3s - 1) < 0 along for s < 1/3); the SPD projection clamps each spring's
    factors at 0, so every block and their sum are PSD."""
    system = build(**MODELS["rope-3d"], spring_law=law, gravity=[0.0, 0.0, 0.0])
    x = deformed(system, seed=3, scale=0.05)
    raw = np.linalg.eigvalsh(system.hessian(x).toarray())
    projected = system.hessian(x, project_spd=True).toarray()
    assert raw.min() < -1e-3 * raw.max()
    assert np.linalg.eigvalsh(projected).min() >= -1e-12 * np.abs(projected).max()


@pytest.mark.parametrize("model", ["square-2d", "grid-3d-contact"])
def test_spring_energies_are_the_lecture_and_course_formulas(model):
    """Hookean W = k/2 (L - l0)^2; squared length W = l0^2 k/2 (L^2/l0^2 - 1)^2, as the course code writes it
    (solid-sim-tutorial, 1_mass_spring/MassSpringEnergy.py: ``l2 * 0.5 * k * (diff.dot(diff) / l2 - 1) ** 2``);
    P adds -sum m g . x. Rest lengths from the rest shape, stiffness per spring kind."""
    config = {key: value for key, value in MODELS[model].items() if key != "contact"}
    hookean = build(**config, spring_law="hookean", mass={"total": 0.3})
    squared = build(**config, spring_law="squared_length", mass={"total": 0.3})
    x = deformed(hookean, seed=5, scale=0.03)
    rest = hookean.rest
    l0_squared = np.sum((rest[hookean.first] - rest[hookean.second]) ** 2, axis=1)
    positions = x.reshape(-1, hookean.dim)
    length_squared = np.sum((positions[hookean.first] - positions[hookean.second]) ** 2, axis=1)
    k = hookean.stiffness
    hookean_energy = sum(0.5 * k[e] * (math.sqrt(length_squared[e]) - math.sqrt(l0_squared[e])) ** 2 for e in range(k.size))
    course_energy = sum(l0_squared[e] * 0.5 * k[e] * (length_squared[e] / l0_squared[e] - 1.0) ** 2 for e in range(k.size))
    gravity_energy = -sum(hookean.vertex_masses[i] * np.dot(hookean.gravity, positions[i]) for i in range(len(positions)))
    assert hookean.spring_energy(x) == pytest.approx(hookean_energy, rel=1e-13)
    assert squared.spring_energy(x) == pytest.approx(course_energy, rel=1e-13)
    assert squared.potential_energy(x) == pytest.approx(course_energy + gravity_energy, rel=1e-13)


DAMPED_MODELS = {
    "grid-3d": dict(model={"grid": {"resolution": [3, 3], "size": [0.3, 0.2]}}, stiffness={"stretch": 100.0, "shear": 30.0, "bend": 5.0}),
    "square-2d": dict(model={"square": {"segments": 2, "size": 0.6}}, stiffness={"stretch_x": 100.0, "stretch_y": 70.0, "shear": 30.0}),
}
DAMPING_TERMS = {"spring": {"model": "spring", "coefficient": 0.7}, "relative": {"model": "relative", "coefficient": 0.4},
                 "drag": {"model": "drag", "coefficient": 0.3}, "rayleigh": {"model": "rayleigh", "alpha": 0.5, "beta": 0.02}}


def lecture_damping_force(system, model: str, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The damping force of one DAMPING_TERMS entry written out per spring or vertex (lecture formulas):
    spring -k_d ((v_i - v_j) . u) u, relative -k_d (v_i - v_j), drag -k_d v_i, rayleigh -(alpha M + beta K_rest) v
    with K_rest the sum over springs of W''(l0) u0 u0^T (k for hookean, 4 k for the squared length)."""
    term = DAMPING_TERMS[model]
    dim = system.dim
    positions, velocities = x.reshape(-1, dim), v.reshape(-1, dim)
    force = np.zeros_like(velocities)
    if model == "drag":
        return (-term["coefficient"] * velocities).ravel()
    if model == "rayleigh":
        force = -term["alpha"] * system.vertex_masses[:, None] * velocities
        positions = system.rest
        curvature = 1.0 if system.law.name == "hookean" else 4.0
    for e, (i, j) in enumerate(zip(system.first, system.second)):
        u = (positions[i] - positions[j]) / np.linalg.norm(positions[i] - positions[j])
        relative = velocities[i] - velocities[j]
        if model == "spring":
            pair = -term["coefficient"] * np.dot(relative, u) * u
        elif model == "relative":
            pair = -term["coefficient"] * relative
        else:
            pair = -term["beta"] * curvature * system.stiffness[e] * np.dot(relative, u) * u
        force[i] += pair
        force[j] -= pair
    return force.ravel()


@pytest.mark.parametrize("law", sorted(SPRING_LAWS))
@pytest.mark.parametrize("model", sorted(DAMPED_MODELS))
@pytest.mark.parametrize("damping", sorted(DAMPING_MODELS))
def test_damping_matrix_is_the_lecture_force_and_symmetric_psd(damping, model, law):
    """f = -D v with D symmetric PSD, equal to the per-spring / per-vertex force of the lectures; all four
    models together give the sum of the four matrices."""
    config = dict(DAMPED_MODELS[model], spring_law=law, mass={"total": 0.3})
    system = build(**config, damping=[DAMPING_TERMS[damping]])
    x = deformed(system, seed=11, scale=0.03)
    v = np.random.default_rng(12).standard_normal(system.dof_count)
    matrix = system.damping_matrix(x).toarray()
    assert np.max(np.abs(matrix - matrix.T)) <= 1e-14 * np.max(np.abs(matrix))
    assert np.linalg.eigvalsh(matrix).min() >= -1e-12 * np.max(np.abs(matrix))
    expected = lecture_damping_force(system, damping, x, v)
    assert np.max(np.abs(system.damping_force(x, v) - expected)) <= 1e-13 * np.max(np.abs(expected))
    combined = build(**config, damping=list(DAMPING_TERMS.values())).damping_matrix(x).toarray()
    parts = sum(build(**config, damping=[term]).damping_matrix(x).toarray() for term in DAMPING_TERMS.values())
    assert np.max(np.abs(combined - parts)) <= 1e-14 * np.max(np.abs(parts))


@pytest.mark.parametrize("law", sorted(SPRING_LAWS))
@pytest.mark.parametrize("model", sorted(DAMPED_MODELS))
@pytest.mark.parametrize("damping", sorted(DAMPING_MODELS))
def test_a_damped_step_has_the_finite_difference_gradient_and_hessian(damping, model, law):
    """Backward Euler's step problem with each damping model, E(y) = 1/2 |y - y~|_M^2 + h^2 [P(y) + (y - x_n)^T D
    (y - x_n) / (2 h)], D taken at x_n: its gradient against central differences of E, its Hessian against central
    differences of the gradient (FD_TOLERANCE), so that every damping model's matrix enters the step consistently."""
    system = build(**DAMPED_MODELS[model], spring_law=law, mass={"total": 0.3}, damping=[DAMPING_TERMS[damping]])
    x = deformed(system, seed=5, scale=0.03)
    v = np.random.default_rng(6).standard_normal(system.dof_count)
    h = 0.01
    problem = IncrementalPotential(system, x + h * v, h * h, velocity_origin=x, velocity_divisor=h, damping_at=x,
                                   step_start=(x, v, h))
    y = x + h * v + 1e-3 * np.random.default_rng(7).standard_normal(system.dof_count)
    basis = np.eye(system.dof_count)
    fd_gradient = np.array([(problem.value(y + FD_STEP * e) - problem.value(y - FD_STEP * e)) / (2 * FD_STEP)
                            for e in basis])
    free = np.ones(system.dof_count, dtype=bool)
    free[system.fixed_dofs] = False  # the problem's gradient is zero there (pinned vertices do not move)
    assert relative_max_error(problem.gradient(y)[free], fd_gradient[free]) < FD_TOLERANCE
    hessian = problem.hessian(y)
    hessian = hessian.toarray() if hasattr(hessian, "toarray") else hessian
    fd_hessian = np.array([(problem.gradient(y + FD_STEP * e) - problem.gradient(y - FD_STEP * e)) / (2 * FD_STEP)
                           for e in basis]).T
    assert relative_max_error(hessian[np.ix_(free, free)], fd_hessian[np.ix_(free, free)]) < FD_TOLERANCE


# ==================================================================================================
# 2. Two vertices and one spring are the spring_mass test equation
# ==================================================================================================
SPRING = dict(stiffness=40.0, mass=0.5, x0=0.3, v0=0.4)  # k (N/m), m (kg), q0 (m), q'0 (m/s): w = 8.9 rad/s
REST_LENGTH = 1.0  # l0 (m)


@pytest.fixture(scope="module")
def two_vertex_model(tmp_path_factory):
    """An npz model: vertex 0 at the origin, vertex 1 on the x axis at l0 + q0, one spring of rest length l0."""
    path = tmp_path_factory.mktemp("models") / "two_vertices.npz"
    np.savez(path, vertices=np.array([[0.0, 0.0], [REST_LENGTH + SPRING["x0"], 0.0]]), springs=np.array([[0, 1]]),
             rest_lengths=np.array([REST_LENGTH]))
    return str(path)


@pytest.mark.parametrize("damping", [0.0, 0.7])
@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_two_vertices_reproduce_spring_mass(name, damping, two_vertex_model):
    """With one end pinned at the origin and no gravity, the free end's x - l0 obeys m q'' + d q' + k q = 0:
    the same numbers as `spring_mass` (relative 1e-12 over 200 steps), its y stays 0, the pin stays put."""
    dt, duration = 0.01, 2.0
    reference = run_one({"type": "spring_mass", **SPRING, "damping": damping}, name, dt, duration, record={"every": 1})
    result = run_one({"type": "mass_spring", "model": two_vertex_model, "stiffness": SPRING["stiffness"],
                      "mass": {"per_vertex": SPRING["mass"]}, "gravity": [0.0, 0.0], "pinned": [0], "damping": damping,
                      "initial": {"velocity": [SPRING["v0"], 0.0]}},
                     name, dt, duration, record={"every": 1, "frames_every": 1})
    assert reference.status == result.status == "ok"
    q = reference.samples["positions"][:, 0]
    frames = result.samples["frames"]
    assert frames.shape == (round(duration / dt) + 1, 2, 2)
    assert np.max(np.abs(frames[:, 1, 0] - REST_LENGTH - q)) <= 1e-12 * np.max(np.abs(q))
    assert np.max(np.abs(frames[:, 1, 1])) == 0.0 and np.max(np.abs(frames[:, 0])) == 0.0
    energy = reference.samples["energy"]
    assert np.max(np.abs(result.samples["energy"] - energy)) <= 1e-12 * energy[0]


# ==================================================================================================
# 3. The stiff pendulum
# ==================================================================================================
def test_stiff_pendulum_swings_with_the_small_angle_period():
    """A pinned vertex and a mass on a hookean spring with k L / (m g) = 1e6, released at rest at 0.05 rad:
    period 2 pi sqrt(L/g) within 0.5 %. Sharper: implicit midpoint lengthens a period by (w dt)^2/12 and the
    amplitude by theta0^2/16 (Landau & Lifshitz, Mechanics, sec. 28), together within 2e-5."""
    length, mass, g, theta0, dt = 1.0, 0.1, 9.81, 0.05, 0.01
    result = run_one({"type": "mass_spring", "model": {"rope": {"count": 2, "length": length,
                                                                "direction": [math.sin(theta0), -math.cos(theta0)]}},
                      "stiffness": 1e6 * mass * g / length, "mass": {"per_vertex": mass}, "gravity": [0.0, -g],
                      "pinned": ["first"]}, "implicit_midpoint", dt, 4.5, record={"frames_every": 1})
    assert result.status == "ok"
    horizontal, t = result.samples["frames"][:, 1, 0], result.samples["frame_t"]
    before = np.flatnonzero(np.sign(horizontal[1:]) != np.sign(horizontal[:-1]))
    crossings = t[before] - horizontal[before] * dt / (horizontal[before + 1] - horizontal[before])  # linear interpolation
    assert crossings.size >= 4
    period = 2.0 * float(np.mean(np.diff(crossings)))
    small_angle = 2.0 * math.pi * math.sqrt(length / g)
    assert abs(period - small_angle) <= 0.005 * small_angle
    predicted = small_angle * (1.0 + theta0 ** 2 / 16.0) * (1.0 + (2.0 * math.pi / small_angle * dt) ** 2 / 12.0)
    assert abs(period - predicted) <= 2e-5 * small_angle


# ==================================================================================================
# 4. The grid is the former cloth
# ==================================================================================================
CLOTH_CONTACT = {"sphere": {"center": [0.5, 0.4, -0.35], "radius": 0.3, "stiffness": 5000.0},
                 "ground": {"height": -0.2, "stiffness": 4000.0}}
CLOTH_SYSTEMS = {
    "cloth": {"type": "cloth", "resolution": [6, 5], "size": [1.0, 0.8], "mass": 0.7, "stretch_stiffness": 3000.0,
              "shear_stiffness": 300.0, "bend_stiffness": 5.0, "damping": 0.2, "pinned": ["top_left", 7],
              "initial_spin": [0.0, 0.5, 1.0], "contact": CLOTH_CONTACT},
    "mass_spring": {"type": "mass_spring", "model": {"grid": {"resolution": [6, 5], "size": [1.0, 0.8]}},
                    "stiffness": {"stretch": 3000.0, "shear": 300.0, "bend": 5.0}, "mass": {"total": 0.7, "by": "equal"}, "damping": 0.2,
                    "pinned": ["top_left", 7], "initial": {"spin": [0.0, 0.5, 1.0]}, "contact": CLOTH_CONTACT},
}
CLOTH_INTEGRATORS = ["symplectic_euler", "rk4", "backward_euler", "implicit_midpoint", "bdf2", "newmark", "generalized_alpha",
                     "exponential_rosenbrock_euler", "semi_implicit_backward_euler"]


# The recording's arithmetic is the same as today's, operation for operation, but BLAS (OpenBLAS picks its kernels
# by CPU) and numpy's SIMD reductions round differently on another machine: measured on an AMD EPYC against the
# recording, the largest difference is 3e-13 of a series' size (Newmark's energy after 60 steps; 1e-20 in the first
# explicit steps). A change of the model or of a method moves them by orders of magnitude more.
RECORDING_ROUND_OFF = 1e-11


def _cloth_runs(system: str, output: Path) -> dict:
    results = simrun.run({"name": f"bits_{system}", "system": CLOTH_SYSTEMS[system], "integrators": CLOTH_INTEGRATORS,
                          "solver": {"type": "newton", "tolerance": 1e-9, "max_iterations": 30}, "duration": 0.3,
                          "sweep": {"dt": [0.005]}, "record": {"max_frames": 1000}},
                         output=output, figures=False, progress=False, jobs=1)
    return {run.attrs["integrator"]: {key: run[key] for key in ("frames", "energy", "newton_iterations")}
            for run in results.runs.values()}


def test_grid_model_equals_the_former_cloth(tmp_path):
    """tests/data/cloth_before_mass_spring.npz holds frames, energies and Newton iterations recorded by the cloth
    code before the rewrite. The `cloth` config and its `mass_spring` equivalent give the same series bit for bit;
    against the recording, every Newton iteration count is the same, the explicit methods diverge at the same step,
    and frames and energies agree to the other machine's round-off (RECORDING_ROUND_OFF of each series' size)."""
    stored = np.load(Path(__file__).parent / "data" / "cloth_before_mass_spring.npz")
    runs = {system: _cloth_runs(system, tmp_path / system) for system in CLOTH_SYSTEMS}
    assert set(runs["cloth"]) == set(runs["mass_spring"]) == set(CLOTH_INTEGRATORS)
    for name, series in runs["cloth"].items():
        for key, values in series.items():
            assert np.array_equal(values, runs["mass_spring"][name][key]), f"{name}/{key}: cloth against mass_spring"
            recorded = stored[f"{name}/{key}"]
            if key == "newton_iterations":
                assert np.array_equal(values, recorded), f"{name}/{key}"
                continue
            assert values.shape == recorded.shape, f"{name}/{key}"
            assert np.array_equal(np.isfinite(values), np.isfinite(recorded)), f"{name}/{key}"
            finite = np.isfinite(recorded)
            scale = np.abs(recorded[finite]).max()
            assert np.abs(values[finite] - recorded[finite]).max() <= RECORDING_ROUND_OFF * scale, f"{name}/{key}"


def test_grid_as_an_obj_quad_mesh_gives_the_same_springs(tmp_path):
    """A grid written as quads to an OBJ file and loaded as `model: path.obj` has the grid's springs as unordered
    pairs, each with the grid's rest length and, per kind (stretch, shear, bend), the same stiffness."""
    grid_source = {"resolution": [6, 5], "size": [1.0, 0.8]}
    grid = GridModel(**grid_source).build()
    path = tmp_path / "grid.obj"
    quads = grid_quads(np.arange(grid.vertex_count).reshape(grid.grid_shape))
    meshio.write(path, meshio.Mesh(grid.vertices, [("quad", quads.astype(np.int32))]))
    stiffness = {"stretch": 3000.0, "shear": 300.0, "bend": 5.0}

    def springs(system) -> dict:
        return {(min(i, j), max(i, j)): (k, l0) for i, j, k, l0 in
                zip(system.first.tolist(), system.second.tolist(), system.stiffness.tolist(), system.rest_length.tolist())}

    from_grid = springs(build(model={"grid": grid_source}, stiffness=stiffness))
    from_mesh = springs(build(model=str(path), stiffness=stiffness))
    assert len(from_grid) == grid.spring_count
    assert from_mesh == from_grid


# ==================================================================================================
# 5. Constraints: sliding, pinned, prescribed; momentum along the free directions
# ==================================================================================================
PLANE_NORMAL = np.array([0.3, -0.5, 0.8])  # oblique: kept as 3x3 filters S = I - n n^T
LINE_DIRECTION = np.array([1.0, 0.4, -0.7])  # oblique: S = u u^T
VELOCITY = np.array([0.05, 0.0, 0.02])
ROTATION = dict(center=np.array([0.1, 0.2, 0.0]), axis=np.array([0.0, 1.0, 1.0]), rate=30.0)  # deg/s
GRID_SIZE = 0.3  # m, the model size the round-off tolerances refer to
# vertex = row * 4 + col on a 4 x 4 grid with 0.1 m spacing
ON_PLANE, ON_LINE, ON_Z_PLANE, ON_Y_LINE, PINNED, MOVED, TURNED = [15, 10], [3], [0], [5], [12], [13], [14]


def constrained_cloth(oblique: bool = True) -> dict:
    """A small cloth with every kind of constraint: oblique and axis-aligned planes and lines, a pin,
    a vertex moving at constant velocity and one turning about an axis."""
    sliding = [{"vertices": ON_Z_PLANE, "normal": [0.0, 0.0, 1.0]}, {"vertices": ON_Y_LINE, "direction": [0.0, 1.0, 0.0]}]
    if oblique:
        sliding += [{"vertices": ON_PLANE, "normal": PLANE_NORMAL.tolist()}, {"vertices": ON_LINE, "direction": LINE_DIRECTION.tolist()}]
    return {"type": "mass_spring", "model": {"grid": {"resolution": [4, 4], "size": [GRID_SIZE, GRID_SIZE]}},
            "stiffness": {"stretch": 60.0, "shear": 10.0, "bend": 1.0}, "mass": {"total": 0.2},
            "damping": [{"model": "spring", "coefficient": 0.02}], "pinned": PINNED, "constraints": sliding,
            "prescribed": [{"vertices": MOVED, "velocity": VELOCITY.tolist()},
                           {"vertices": TURNED, "rotation": {"center": ROTATION["center"].tolist(),
                                                             "axis": ROTATION["axis"].tolist(), "rate": ROTATION["rate"]}}],
            "initial": {"spin": [0.2, 0.5, 1.0]}}


def assert_constraints_hold(result, oblique: bool = True) -> None:
    """Every frame: sliding vertices on their plane / line through their start (1e-12 of the model size), pins
    exactly where they started, prescribed vertices on their paths x0 + v t and the rotation R(w t) about
    the axis (Rodrigues, through scipy); and each sliding vertex moved along its allowed directions."""
    frames, t = result.samples["frames"], result.samples["frame_t"]
    assert frames.shape[0] > 10
    moved = frames - frames[0]
    tolerance = 1e-12 * GRID_SIZE
    normal = PLANE_NORMAL / np.linalg.norm(PLANE_NORMAL)
    direction = LINE_DIRECTION / np.linalg.norm(LINE_DIRECTION)
    if oblique:
        assert np.max(np.abs(moved[:, ON_PLANE] @ normal)) <= tolerance
        along = moved[:, ON_LINE] @ direction
        assert np.max(np.abs(moved[:, ON_LINE] - along[..., None] * direction)) <= tolerance
    assert np.max(np.abs(moved[:, ON_Z_PLANE, 2])) <= tolerance
    assert np.max(np.abs(moved[:, ON_Y_LINE][..., [0, 2]])) <= tolerance
    assert np.array_equal(frames[:, PINNED], np.broadcast_to(frames[0, PINNED], frames[:, PINNED].shape))
    assert np.max(np.abs(frames[:, MOVED] - (frames[0, MOVED] + t[:, None, None] * VELOCITY))) <= tolerance
    rotations = Rotation.from_rotvec(np.radians(ROTATION["rate"]) * t[:, None] * ROTATION["axis"] / np.linalg.norm(ROTATION["axis"]))
    turned = ROTATION["center"] + rotations.apply(frames[0, TURNED[0]] - ROTATION["center"])
    assert np.max(np.abs(frames[:, TURNED[0]] - turned)) <= tolerance
    sliders = ON_PLANE + ON_LINE + ON_Z_PLANE + ON_Y_LINE if oblique else ON_Z_PLANE + ON_Y_LINE
    assert np.min(np.max(np.abs(moved[:, sliders]), axis=(0, 2))) > 1e-4, "every sliding vertex must move"


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_constraints_hold_for_every_integrator(name):
    """Explicit methods filter the force (S f), implicit ones the Newton direction: see assert_constraints_hold."""
    result = run_one(constrained_cloth(), name, 0.002, 0.1, record={"frames_every": 1})
    assert result.status == "ok"
    assert_constraints_hold(result)


# 77 iterations at most on this cloth for jacobi_chebyshev; PD with Chebyshev similar
NONLINEAR_SOLVER_OPTIONS = {"jacobi_chebyshev": {"max_iterations": 200},
                            "projective_dynamics": {"max_iterations": 2000, "chebyshev_rho": 0.99},
                            "vbd": {"max_iterations": 2000}}


@pytest.mark.parametrize("solver", sorted(SOLVERS))
def test_constraints_hold_for_every_nonlinear_solver(solver):
    """Every solver's direction is filtered (solvers/base.py), whatever it is: Newton, L-BFGS, descent, Jacobi."""
    result = run_one(constrained_cloth(), "backward_euler", 0.002, 0.1, record={"frames_every": 1},
                     solver={"type": solver, **NONLINEAR_SOLVER_OPTIONS.get(solver, {})})
    assert result.status == "ok"
    assert_constraints_hold(result)


def linear_solver_cases() -> list:
    """(linear solver, mpcg start, oblique sliders) for every registered linear solver: mpcg with both starts;
    jacobi also on axis-aligned constraints only."""
    cases = []
    for name in sorted(LINEAR_SOLVERS):
        marks = [needs_linear_solver(name)]
        if name == "mpcg":
            cases += [pytest.param(name, start, True, marks=marks, id=f"mpcg-{start}") for start in MPCG_STARTS]
        elif name == "jacobi":
            cases += [pytest.param(name, "zero", False, marks=marks, id="jacobi-axis-aligned"),
                      pytest.param(name, "zero", True, marks=marks, id="jacobi-oblique")]
        else:
            cases.append(pytest.param(name, "zero", True, marks=marks, id=name))
    return cases


@pytest.mark.parametrize("linear_solver, start, oblique", linear_solver_cases())
def test_constraints_hold_for_every_linear_solver(linear_solver, start, oblique):
    """The reduced solvers solve S A S + I - S on the free dofs, mpcg applies the 3x3 filters itself."""
    result = run_one(constrained_cloth(oblique), "backward_euler", 0.002, 0.1, record={"frames_every": 1},
                     solver={"type": "newton", "linear_solver": linear_solver, "mpcg_start": start})
    assert result.status == "ok"
    assert_constraints_hold(result, oblique)


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_momentum_along_a_sliding_plane_is_conserved(name):
    """Every vertex slides in a plane with the same oblique normal n, no gravity, no pins: the spring and
    damping forces cancel in pairs and S = I - n n^T is the same at every vertex, so sum_i S f_i = 0. The
    momentum along the plane stays P0 (to round-off: 1e-12 of M max|v|) and the component along n stays 0;
    every integrator here is linear in the forces, so each conserves it."""
    normal = PLANE_NORMAL / np.linalg.norm(PLANE_NORMAL)
    total_mass, dt = 0.12, 0.005
    result = run_one({"type": "mass_spring", "model": {"grid": {"resolution": [3, 3], "size": [0.3, 0.2]}},
                      "stiffness": {"stretch": 50.0, "shear": 10.0, "bend": 1.0}, "mass": {"total": total_mass},
                      "gravity": [0.0, 0.0, 0.0], "damping": [{"model": "spring", "coefficient": 0.02}],
                      "constraints": [{"vertices": list(range(9)), "normal": PLANE_NORMAL.tolist()}],
                      "initial": {"scale": [1.2, 0.9, 1.0], "velocity": [0.3, -0.2, 0.5], "spin": [0.5, 1.0, 2.0]}},
                     name, dt, 0.2, record={"frames_every": 1})
    assert result.status == "ok"
    momentum, frames = result.samples["momentum"], result.samples["frames"]
    speed = np.max(np.linalg.norm(np.diff(frames, axis=0), axis=2)) / dt
    in_plane = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    assert np.linalg.norm(momentum[0] @ in_plane) > 0.01  # kg m/s: a momentum to conserve
    assert np.max(np.abs((momentum - momentum[0]) @ in_plane)) <= 1e-12 * total_mass * speed
    assert np.max(np.abs(momentum @ normal)) <= 1e-12 * total_mass * speed
    assert result.samples["spring_energy"].max() > 1e-3  # the springs pull


# ==================================================================================================
# 6. MPCG on the filtered system
# ==================================================================================================
# a 5 x 4 grid: vertex 15 is the top left corner, 19 the top right one
MPCG_CLOTH = {"model": {"grid": {"resolution": [5, 4], "size": [0.4, 0.3]}}, "stiffness": {"stretch": 200.0, "shear": 50.0, "bend": 2.0},
              "mass": {"total": 0.1}, "damping": [{"model": "spring", "coefficient": 0.05}], "pinned": [15],
              "constraints": [{"vertices": [19], "normal": PLANE_NORMAL.tolist()},
                              {"vertices": [0, 1], "direction": LINE_DIRECTION.tolist()},
                              {"vertices": [10], "normal": [1.0, 0.0, 0.0]}],
              "initial": {"velocity": [0.1, 0.2, -0.3], "spin": [0.3, 0.2, 1.0]}}


def allowed_directions(config: dict, system) -> np.ndarray:
    """Z (dofs x r): an orthonormal basis of the directions the constraints allow, built vertex by vertex
    (free: e_x, e_y, e_z; plane: two vectors across n; line: u; pinned: none)."""
    blocks = {vertex: np.eye(3) for vertex in range(system.vertex_count)}
    for vertex in config["pinned"]:
        blocks[vertex] = np.zeros((3, 0))
    for entry in config["constraints"]:
        vertices = entry["vertices"]
        if "normal" in entry:
            n = np.array(entry["normal"]) / np.linalg.norm(entry["normal"])
            basis = scipy.linalg.null_space(n[None, :])
        else:
            basis = (np.array(entry["direction"]) / np.linalg.norm(entry["direction"]))[:, None]
        for vertex in vertices:
            blocks[vertex] = basis
    columns = []
    for vertex, basis in blocks.items():
        for column in basis.T:
            full = np.zeros(system.dof_count)
            full[3 * vertex:3 * vertex + 3] = column
            columns.append(full)
    return np.array(columns).T


@pytest.mark.parametrize("start", ["zero", "filtered"])
def test_mpcg_gives_the_newton_direction_of_the_constrained_subspace(start):
    """One Newton direction of backward Euler's incremental potential on a cloth with oblique and axis-aligned
    sliding vertices and a pin: p = Z (Z^T A Z)^-1 Z^T b (Z: the allowed directions), which the direct solver on
    S A S + I - S and MPCG with the 3x3 filters (from p0 = 0 or from S (y~ - y)) both find to 1e-8."""
    system = build(**MPCG_CLOTH)
    assert system.sliding is not None and system.fixed_dofs.size > 3  # oblique filters and fixed dofs both
    dt = 0.01
    x = deformed(system, seed=2, scale=0.005)
    problem = IncrementalPotential(system, x + dt * system.v0, dt * dt, velocity_origin=x, velocity_divisor=dt, damping_at=x)
    y = problem.start_point(x)
    matrix, rhs = problem.hessian(y), -problem.gradient(y)
    basis = allowed_directions(MPCG_CLOTH, system)
    reduced = basis.T @ matrix.toarray() @ basis
    assert np.linalg.eigvalsh(reduced).min() > 0
    exact = basis @ np.linalg.solve(reduced, basis.T @ rhs)
    free = free_dofs(system.dof_count, system.fixed_dofs, system.sliding)
    direct, _ = LINEAR_SOLVERS["direct"]().solve(matrix, rhs, free)
    mpcg, iterations = ModifiedPCG(1e-12, 1000, start=start).solve(matrix, rhs, free, guess=problem.direction_guess(y))
    assert relative_max_error(direct, exact) < 1e-8
    assert relative_max_error(mpcg, exact) < 1e-8
    assert 0 < iterations < basis.shape[1]
    outside = np.eye(system.dof_count) - basis @ basis.T
    assert np.max(np.abs(outside @ mpcg)) <= 1e-14 * np.max(np.abs(mpcg))


def mpcg_start_point(solve_with_newton_step: bool):
    """The point one Newton iteration reaches when the linear solver may not iterate (MPCG with 0 iterations
    returns its start): with mpcg_start filtered, y + S (y~ - y) (Ascher & Boxerman's p0 = S g + (I - S) z)."""
    system = build(**MPCG_CLOTH)
    dt = 0.01
    problem = IncrementalPotential(system, system.x0 + dt * system.v0, dt * dt, velocity_origin=system.x0,
                                   velocity_divisor=dt, damping_at=system.x0)
    start = problem.start_point(system.x0)
    solver = SOLVERS["newton"](max_iterations=1, linear_solver=ModifiedPCG(1e-10, 0, start="filtered"))
    y = solver.newton_step(problem, start)[0] if solve_with_newton_step else solver.minimize(problem, start)[0]
    expected = start + system.constraints.filter(problem.direction_guess(start))
    return y, expected


def test_mpcg_filtered_start_is_the_first_newton_step_of_minimize():
    y, expected = mpcg_start_point(solve_with_newton_step=False)
    assert np.max(np.abs(expected - y)) <= 1e-15 and np.max(np.abs(expected - build(**MPCG_CLOTH).x0)) > 1e-4


def test_mpcg_filtered_start_is_used_by_the_semi_implicit_newton_step():
    y, expected = mpcg_start_point(solve_with_newton_step=True)
    assert np.max(np.abs(expected - y)) <= 1e-15


@pytest.mark.parametrize("name", ["backward_euler", "implicit_midpoint"])
def test_mpcg_starts_reach_the_same_steps(name, record_property):
    """mpcg from p0 = 0 and from p0 = S (y~ - y) converge to the same trajectory (1e-10 m) as the direct solver on a
    cloth with sliding and pinned vertices; the linear iteration counts of both starts are recorded (printed)."""
    config = {"type": "mass_spring", **MPCG_CLOTH, "model": {"grid": {"resolution": [6, 6], "size": [0.5, 0.5]}}, "pinned": ["top_left"],
              "constraints": [{"vertices": "top_right", "normal": PLANE_NORMAL.tolist()},
                              {"vertices": [0, 1], "direction": LINE_DIRECTION.tolist()},
                              {"vertices": [33, 34], "direction": [1.0, 0.0, 0.0]}], "initial": {}}
    frames, counts = {}, {}
    for linear_solver, start in (("direct", "zero"), ("mpcg", "zero"), ("mpcg", "filtered")):
        result = run_one(config, name, 0.01, 0.3, record={"frames_every": 1},
                         solver={"linear_solver": linear_solver, "mpcg_start": start})
        assert result.status == "ok"
        frames[linear_solver, start] = result.samples["frames"]
        counts[linear_solver, start] = (int(result.per_step["linear_iterations"].sum()), int(result.per_step["newton_iterations"].sum()))
    for key in (("mpcg", "zero"), ("mpcg", "filtered")):
        assert np.max(np.abs(frames[key] - frames["direct", "zero"])) <= 1e-10
    message = (f"{name}: mpcg linear iterations (Newton iterations) over 30 steps: zero start {counts['mpcg', 'zero']}, "
               f"filtered start {counts['mpcg', 'filtered']}")
    record_property("mpcg_iterations", message)
    print(message)


# ==================================================================================================
# 7. The energy budget
# ==================================================================================================
FREE_MODEL = {"type": "mass_spring", "model": {"grid": {"resolution": [3, 3], "size": [0.3, 0.2]}},
              "stiffness": {"stretch": 50.0, "shear": 10.0, "bend": 1.0}, "mass": {"total": 0.12, "by": "equal"}, "gravity": [0.0, 0.0, 0.0],
              "initial": {"spin": [0.4, -0.2, 1.5], "velocity": [0.1, 0.0, 0.3], "scale": 1.1}}
# D independent of x; weak enough for leapfrog's explicit damping kicks at these steps
BUDGET_DAMPING = {"drag": {"model": "drag", "coefficient": 0.02}, "relative": {"model": "relative", "coefficient": 0.05},
                  "rayleigh": {"model": "rayleigh", "alpha": 0.5, "beta": 0.01}}
BUDGET_DT = (0.01, 0.005)
BUDGET_DURATION = 0.5


def budget_residual(damping: dict, name: str, dt: float) -> float:
    """max_t |E(t) + dissipated(t) - E0| / E0 over a run."""
    result = run_one({**FREE_MODEL, "damping": [damping]}, name, dt, BUDGET_DURATION)
    assert result.status == "ok"
    energy, dissipated = result.samples["energy"], result.samples["dissipated_energy"]
    assert dissipated[-1] > 0.3 * energy[0]  # the damping matters
    return float(np.max(np.abs(energy + dissipated - energy[0])) / energy[0])


@pytest.mark.parametrize("name", ["implicit_midpoint", "leapfrog"])
@pytest.mark.parametrize("damping", sorted(BUDGET_DAMPING))
def test_energy_budget_closes_at_second_order(damping, name):
    """E + dissipated = E0 up to the method's error: halving dt divides the residual by ~4 (observed order >= 1.75)."""
    coarse, fine = (budget_residual(BUDGET_DAMPING[damping], name, dt) for dt in BUDGET_DT)
    assert math.log2(coarse / fine) >= 1.75


@pytest.mark.parametrize("damping", sorted(BUDGET_DAMPING))
def test_average_vector_field_closes_the_budget_exactly(damping):
    """AVF loses exactly h v_mid^T D v_mid per step, the recorded dissipation, and conserves E up to its
    quadrature (3 Gauss points): the budget closes to 1e-7 of E0, far below the midpoint rule's 1e-4."""
    assert budget_residual(BUDGET_DAMPING[damping], "average_vector_field", BUDGET_DT[0]) <= 1e-7


@pytest.mark.parametrize("name", ["implicit_midpoint", "average_vector_field"])
def test_energy_budget_closes_at_second_order_with_spring_damping(name):
    coarse, fine = (budget_residual({"model": "spring", "coefficient": 0.05}, name, dt) for dt in BUDGET_DT)
    assert math.log2(coarse / fine) >= 1.75


def test_energy_budget_closes_with_a_moving_pin():
    """A chain pinned at one end and pulled at the other (prescribed velocity): E + dissipated - work - E0 shrinks
    at order 2 >= 1.5 for implicit midpoint, and the work of the puller against the springs is positive."""
    chain = {"type": "mass_spring", "model": {"rope": {"count": 5, "length": 0.4, "direction": [1.0, 0.0]}}, "stiffness": 20.0,
             "mass": {"per_vertex": 0.05}, "gravity": [0.0, 0.0], "pinned": ["first"],
             "damping": [BUDGET_DAMPING["relative"]], "prescribed": [{"vertices": "last", "velocity": [0.3, 0.1]}]}
    residuals = []
    for dt in BUDGET_DT:
        result = run_one(chain, "implicit_midpoint", dt, 1.0)
        assert result.status == "ok"
        energy, dissipated, work = (result.samples[key] for key in ("energy", "dissipated_energy", "prescribed_work"))
        assert work[-1] > 10 * energy[0] and dissipated[-1] > 0
        residuals.append(float(np.max(np.abs(energy + dissipated - work - energy[0])) / work[-1]))
    assert math.log2(residuals[0] / residuals[1]) >= 1.5


@pytest.mark.parametrize("integrator", ["implicit_midpoint", "newmark", "bdf2", "average_vector_field"])
@pytest.mark.parametrize("damping", ["relative", "spring"])
def test_energy_budget_closes_at_second_order_on_a_curved_path(integrator, damping):
    """A chain pinned at one end whose other end turns on a circle (prescribed rotation, 90 deg/s), with pairwise
    damping: E + dissipated - work - E0 shrinks at order 2 (>= 1.8) for the second-order methods. Each step's unknown
    puts the turning vertex on its circle (integrators/base.py on_paths); held at y~, its extrapolation along the
    velocity, it is off the arc by O(h^2), and the budget closed at first order."""
    chain = {"type": "mass_spring", "model": {"rope": {"count": 5, "length": 0.4, "direction": [1.0, 0.0]}}, "stiffness": 20.0,
             "mass": {"per_vertex": 0.05}, "gravity": [0.0, 0.0], "pinned": ["first"],
             "damping": [{"model": damping, "coefficient": 0.05}],
             "prescribed": [{"vertices": "last", "rotation": {"center": [0.2, 0.0], "rate": 90.0}}]}
    residuals = []
    for dt in (0.004, 0.002):
        result = run_one(chain, integrator, dt, 1.0)
        assert result.status == "ok"
        energy, dissipated, work = (result.samples[key] for key in ("energy", "dissipated_energy", "prescribed_work"))
        assert dissipated[-1] > 0 and abs(work[-1]) > 0
        residuals.append(float(np.max(np.abs(energy + dissipated - work - energy[0])) / abs(work[-1])))
    assert math.log2(residuals[0] / residuals[1]) >= 1.8


# ==================================================================================================
# 8. The course code's square
# ==================================================================================================
def test_course_square_released_from_a_stretch():
    """The demo of solid-sim-tutorial 1_mass_spring: a 4 x 4 cell square with squared-length springs k = 1e5 N/m,
    40 kg per vertex, stretched 1.4x along x, no gravity, backward Euler at h = 0.004 s. E0 is the course
    formula's energy of the stretched square (20 horizontal springs and 32 diagonals stretched: 103680 J);
    no external force, so the momentum stays 0, and the state keeps its mirror symmetries, so the angular
    momentum stays 0; backward Euler only loses energy, so E decreases monotonically."""
    size, segments, k, mass = 1.0, 4, 1e5, 40.0
    result = run_one({"type": "mass_spring", "model": {"square": {"segments": segments, "size": size}}, "spring_law": "squared_length",
                      "stiffness": k, "mass": {"per_vertex": mass}, "gravity": [0.0, 0.0], "initial": {"scale": [1.4, 1.0]}},
                     "backward_euler", 0.004, 1.0)
    assert result.status == "ok"
    step = size / segments
    rest = {(i, j): np.array([-size / 2 + i * step, -size / 2 + j * step]) for i in range(segments + 1) for j in range(segments + 1)}
    pairs = [((i, j), (i + 1, j)) for i in range(segments) for j in range(segments + 1)]
    pairs += [((i, j), (i, j + 1)) for i in range(segments + 1) for j in range(segments)]
    pairs += [pair for i in range(segments) for j in range(segments) for pair in (((i, j), (i + 1, j + 1)), ((i + 1, j), (i, j + 1)))]
    stretch = np.array([1.4, 1.0])
    course_energy = sum(np.sum((rest[a] - rest[b]) ** 2) * 0.5 * k
                        * (np.sum(((rest[a] - rest[b]) * stretch) ** 2) / np.sum((rest[a] - rest[b]) ** 2) - 1.0) ** 2 for a, b in pairs)
    energy = result.samples["energy"]
    assert energy[0] == pytest.approx(course_energy, rel=1e-12) and course_energy == pytest.approx(103680.0, rel=1e-12)
    frames = result.samples["frames"]
    speed = np.max(np.linalg.norm(np.diff(frames, axis=0), axis=2)) / (result.samples["frame_t"][1] - result.samples["frame_t"][0])
    total_mass = mass * (segments + 1) ** 2
    assert np.max(np.abs(result.samples["momentum"])) <= 1e-12 * total_mass * speed
    assert np.max(np.abs(result.samples["angular_momentum"])) <= 1e-12 * total_mass * speed * size
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    assert energy[-1] < 0.01 * energy[0]
