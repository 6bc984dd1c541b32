"""Vertex block descent against theory (Chen et al., "Vertex block descent", SIGGRAPH 2024).

1. the blocks: MassSpring's per-vertex gradient and Hessian blocks (from each vertex's springs) are the
   diagonal blocks of the full gradient and Hessian, and its energy changes the changes of P; the incremental
   potential's blocks (inertia, damping) are those of its own gradient and Hessian;
2. the colouring is proper: no two vertices of a colour share a spring (or a Hessian block);
3. the energy never increases along the iterations (vertices of a colour are independent, so the sum of
   the local changes is the change of E, and each is made <= 0);
4. the solution is the minimiser: a backward Euler step of the hanging cloth (configs/cloth_hang.yaml) against
   Newton at 1e-12, within the strong-convexity bound |y - y*|_2 <= |g(y)|_2 / mu; pinned and sliding vertices;
5. on a linear 1-dof spring one sweep is the exact solution (one vertex, a quadratic E: its Newton step).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import step_problem, stretched_cloth_state
from simrun.integrators import INTEGRATORS, IncrementalPotential, State
from simrun.solvers import Newton, VertexBlockDescent, solver_params
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.solvers.vbd import ColourPlan
from simrun.systems import ClothParams, SpringMassParams
from simrun.systems.forms import VertexForm
from simrun.systems.patterns import diagonal_blocks
from simrun.systems.mass_spring.params import MassSpringParams
from simrun.systems.mass_spring.laws import SPRING_LAWS

CONFIGS = Path(__file__).parent.parent / "configs"


def backward_euler_problem(system, x, v, dt):
    return step_problem(system, x, v, dt)


def free_hessian_floor(problem, y, fixed) -> tuple[float, np.ndarray]:
    """mu, the smallest eigenvalue of E's Hessian on the free dofs at y, and the free dofs."""
    hessian = problem.hessian(y)
    dense = hessian.toarray() if hasattr(hessian, "toarray") else np.asarray(hessian)
    free = np.setdiff1d(np.arange(dense.shape[0]), fixed)
    return float(np.linalg.eigvalsh(dense[np.ix_(free, free)]).min()), free


# ==================================================================================================
# 1. Blocks
# ==================================================================================================
CONTACT_3D = {"ground": {"height": 0.02, "stiffness": 3000.0},
              "sphere": {"center": [0.15, 0.1, 0.05], "radius": 0.12, "stiffness": 5000.0}}
MODELS = {
    # a 3-D cloth pressed into the ground and a sphere, under gravity
    "grid-3d-contact": dict(model={"grid": {"resolution": [5, 4], "size": [0.3, 0.2]}},
                            stiffness={"stretch": 100.0, "shear": 30.0, "bend": 5.0}, contact=CONTACT_3D),
    # the course's 2-D square with every damping model
    "square-2d-damped": dict(model={"square": {"segments": 3, "size": 0.6}},
                             stiffness={"stretch_x": 100.0, "stretch_y": 70.0, "shear": 30.0},
                             damping=[{"model": "spring", "coefficient": 0.3}, {"model": "drag", "coefficient": 0.1},
                                      {"model": "rayleigh", "alpha": 0.2, "beta": 0.01}]),
}
BLOCK_TOLERANCE = 1e-12  # relative to the largest entry: the same sums in another order


def deformed(system, seed: int, scale: float) -> np.ndarray:
    return system.x0 + scale * np.random.default_rng(seed).standard_normal(system.dof_count)


@pytest.mark.parametrize("project_spd", [False, "clamp", "abs"])
@pytest.mark.parametrize("law", sorted(SPRING_LAWS))
@pytest.mark.parametrize("model", sorted(MODELS))
def test_mass_spring_blocks_are_the_diagonal_blocks_of_the_gradient_and_hessian(model, law, project_spd):
    """Per colour: MassSpring's vertex form (the springs at each vertex) equals the generic VertexForm (rows of the full
    gradient, diagonal blocks of the full Hessian), and its energy_changes equals P(x + u_i) - P(x)."""
    system = MassSpringParams(**MODELS[model], spring_law=law).build()
    x = deformed(system, 1, 0.03)
    rng = np.random.default_rng(2)
    colliders = system.contact.colliders if system.contact is not None else ()
    touching = sum(int((contact.collider.signed_distance(x.reshape(-1, system.dim)) < 0).sum()) for contact in colliders)
    assert ("contact" in MODELS[model]) == (touching > 0), "the contact models must touch"
    energy = abs(system.potential_energy(x))
    for colour in system.vertex_form().colouring():
        gradient, hessian = system.vertex_form().blocks(x, colour, project_spd)
        generic_gradient, generic_hessian = VertexForm(system).blocks(x, colour, project_spd)
        assert np.abs(gradient - generic_gradient).max() <= BLOCK_TOLERANCE * np.abs(generic_gradient).max()
        assert np.abs(hessian - generic_hessian).max() <= BLOCK_TOLERANCE * np.abs(generic_hessian).max()
        steps = 0.01 * rng.standard_normal((colour.size, system.dim))
        changes = system.vertex_form().energy_changes(x, colour, steps)
        assert np.abs(changes - VertexForm(system).energy_changes(x, colour, steps)).max() <= 1e-12 * energy



@pytest.mark.parametrize("isolated", [False, True])
def test_the_incidences_of_a_vertex_set_sum_to_each_vertex(isolated):
    """IncidentSprings.summing adds each vertex's incidences: by np.add.reduceat over the incidences sorted by vertex,
    or, where a vertex of the set has none (a free particle), through a sparse matrix of ones (reduceat has no empty
    sum). Both give, per vertex, the sum over the springs at it, in their order: checked against a loop."""
    from types import SimpleNamespace
    from simrun.systems.mass_spring.blocks import SpringVertexForm
    first, second = np.array([0, 1, 2, 0, 3]), np.array([1, 2, 3, 2, 1])  # vertex 4 has no spring
    system = SimpleNamespace(vertex_count=5, dim=3, first=first, second=second, stiffness=np.arange(1.0, 6.0),
                             rest_length=np.ones(5), rest_length_squared=np.ones(5), identity=np.eye(3),
                             vertex_masses=np.ones(5), gravity=np.zeros(3))
    vertices = np.array([4, 0, 2]) if isolated else np.array([0, 2, 3])
    part = SpringVertexForm(system).incident(vertices)
    values = np.random.default_rng(4).standard_normal((part.owner.size, 2))
    expected = np.zeros((vertices.size, 2))
    for incidence, owner in enumerate(part.owner):
        expected[owner] += values[incidence]
    assert np.array_equal(part.summing(values), expected)
    assert np.array_equal(np.sort(part.owner), part.owner)  # sorted by vertex
    # each incidence pairs its vertex with the spring's other end
    ends = set(zip(first.tolist(), second.tolist())) | set(zip(second.tolist(), first.tolist()))
    assert all((int(vertices[owner]), int(dofs[0]) // 3) in ends for owner, dofs in zip(part.owner, part.other_dofs))

@pytest.mark.parametrize("law", sorted(SPRING_LAWS))
def test_energy_changes_resolve_steps_far_below_the_roundoff_of_p(law):
    """For u ~ 1e-9 m, P(x + u) - P(x) is round-off (~eps |P|), while the change formed without cancellation
    matches its second-order model g . u + u^T H u / 2 (error O(|u|^3)) to 1e-6."""
    system = MassSpringParams(**MODELS["grid-3d-contact"], spring_law=law).build()
    x = deformed(system, 3, 0.03)
    colour = system.vertex_form().colouring()[0]
    steps = 1e-9 * np.random.default_rng(4).standard_normal((colour.size, system.dim))
    gradient, hessian = system.vertex_form().blocks(x, colour)
    model = np.einsum("ki,ki->k", gradient, steps) + 0.5 * np.einsum("ki,kij,kj->k", steps, hessian, steps)
    changes = system.vertex_form().energy_changes(x, colour, steps)
    assert np.abs(changes - model).max() <= 1e-6 * np.abs(model).max()


def test_incremental_potential_blocks_are_those_of_its_gradient_and_hessian():
    """A damped 2-D square (no pins, so E's gradient is unfiltered): M_i + s K_ii + (s/b) D_ii and
    M_i (y_i - y~_i) + s dP/dy_i + (s/b) (D (y - a))_i are the blocks of E's Hessian and gradient, and the energy
    changes are E(y + u_i) - E(y)."""
    system = MassSpringParams(**MODELS["square-2d-damped"]).build()
    assert system.fixed_dofs.size == 0 and system.damping_matrix(system.x0) is not None
    x = deformed(system, 5, 0.02)
    v = np.random.default_rng(6).standard_normal(system.dof_count)
    problem, _ = backward_euler_problem(system, x, v, 0.01)
    y = deformed(system, 7, 0.02)
    gradient_rows, hessian = problem.gradient(y).reshape(-1, system.dim), problem.hessian(y)
    rng = np.random.default_rng(8)
    for colour in problem.vertex_colouring():
        gradient, blocks = problem.vertex_blocks(y, colour)
        assert np.abs(gradient - gradient_rows[colour]).max() <= BLOCK_TOLERANCE * np.abs(gradient_rows).max()
        expected = diagonal_blocks(hessian, colour, system.dim)
        assert np.abs(blocks - expected).max() <= BLOCK_TOLERANCE * np.abs(expected).max()
        steps = 1e-3 * rng.standard_normal((colour.size, system.dim))
        changes = problem.vertex_energy_changes(y, colour, steps)
        for vertex, step, change in zip(colour, steps, changes):
            moved = y.copy()
            moved[system.dim * vertex:system.dim * (vertex + 1)] += step
            assert change == pytest.approx(problem.value(moved) - problem.value(y), rel=1e-8, abs=1e-14 * abs(problem.value(y)))


# ==================================================================================================
# 2. Colouring
# ==================================================================================================
def test_the_colouring_is_proper_and_covers_every_vertex_once():
    """No spring (so no Hessian or damping block) joins two vertices of a colour; the generic colouring (from the
    Hessian's pattern) is proper too; a greedy colouring needs at most max degree + 1 colours."""
    system = ClothParams(resolution=(7, 6), damping=0.1).build()
    for colouring in (system.vertex_form().colouring(), VertexForm(system).colouring()):
        assert np.array_equal(np.sort(np.concatenate(colouring)), np.arange(system.vertex_count))
        colour_of = np.empty(system.vertex_count, dtype=int)
        for index, colour in enumerate(colouring):
            colour_of[colour] = index
        assert np.all(colour_of[system.first] != colour_of[system.second])
        degree = np.bincount(np.concatenate([system.first, system.second]), minlength=system.vertex_count)
        assert len(colouring) <= degree.max() + 1
    pattern = system.hessian_pattern.toarray() != 0
    for colour in system.vertex_form().colouring():
        dofs = (3 * colour[:, None] + np.arange(3)).ravel()
        coupling = pattern[np.ix_(dofs, dofs)].reshape(colour.size, 3, colour.size, 3).any(axis=(1, 3))
        assert np.array_equal(coupling, np.eye(colour.size, dtype=bool))


# ==================================================================================================
# 3. Energy descent
# ==================================================================================================
CLOTH = dict(resolution=(6, 6), mass=1.0, stretch_stiffness=200.0, shear_stiffness=50.0, bend_stiffness=5.0,
             damping=0.5, pinned=["top_left", "top_right", "bottom_left", "bottom_right"])


def stretched_cloth_step():
    """The cloth stretched by 10 % in its plane and bulged, with random velocities: one backward Euler step."""
    system = ClothParams(**CLOTH).build()
    return backward_euler_problem(system, *stretched_cloth_state(system), 0.02)


def compressed_cloth_step():
    """A poor start: the cloth squeezed to half its size with a little noise out of plane (springs compressed,
    their raw blocks indefinite), at rest."""
    system = ClothParams(**{**CLOTH, "mass": 0.1}).build()
    positions = system.x0.reshape(-1, 3).copy()
    centre = positions.mean(axis=0)
    positions[:, :2] = centre[:2] + 0.5 * (positions[:, :2] - centre[:2])
    positions[:, 2] = 0.01 * np.random.default_rng(0).standard_normal(len(positions))
    return backward_euler_problem(system, positions.ravel(), np.zeros(system.dof_count), 0.05)


@pytest.mark.parametrize("chebyshev_rho", [0.0, 0.9])
@pytest.mark.parametrize("spd_projection", ["clamp", "abs"])
@pytest.mark.parametrize("build", [stretched_cloth_step, compressed_cloth_step], ids=["stretched", "compressed"])
def test_the_energy_never_increases(build, spd_projection, chebyshev_rho):
    """E(y_{k+1}) <= E(y_k) up to the round-off of E at every iteration, and in 60 sweeps E goes at least 90 % of
    the way down to the energy of Newton's solution (a stationary point; the compressed problem is not convex)."""
    problem, start = build()
    energies = []
    solver = VertexBlockDescent(tolerance=1e-8, max_iterations=60, spd_projection=spd_projection,
                                chebyshev_rho=chebyshev_rho, callback=lambda y, g: energies.append(problem.value(y)))
    solver.minimize(problem, start)
    energies = np.array(energies)
    assert energies.size > 5
    assert np.all(np.diff(energies) <= ENERGY_ROUNDOFF * np.abs(energies[:-1]))
    reference, _ = Newton(tolerance=1e-12, max_iterations=100).minimize(problem, start)
    assert energies[0] - energies[-1] >= 0.9 * (energies[0] - problem.value(reference))


# ==================================================================================================
# 4. The minimiser
# ==================================================================================================
@pytest.fixture(scope="module")
def hanging_cloth_step():
    """A backward Euler step (dt = 0.01 s) of configs/cloth_hang.yaml's cloth mid-fall: 10 Newton steps from rest, then
    the step's problem, its start (x_n), Newton's solution at 1e-12, and mu at it."""
    config = yaml.safe_load((CONFIGS / "cloth_hang.yaml").read_text())["system"]
    config.pop("type")
    system = ClothParams(**config).build()
    newton = Newton(tolerance=1e-12, max_iterations=50)
    state = State(0.0, system.x0, system.v0)
    for _ in range(10):
        state, stats = INTEGRATORS["backward_euler"]().step(system, state, 0.01, newton)
        assert stats.converged
    problem, start = backward_euler_problem(system, state.x, state.v, 0.01)
    reference, stats = newton.minimize(problem, start)
    assert stats.converged and stats.iterations >= 3, "the step must be nonlinear"
    mu, free = free_hessian_floor(problem, reference, system.fixed_dofs)
    assert mu > 0
    return system, problem, start, reference, mu, free


@pytest.mark.parametrize("options", [{}, {"chebyshev_rho": 0.95}], ids=["plain", "chebyshev"])
def test_vbd_reaches_newtons_backward_euler_step_of_the_hanging_cloth(hanging_cloth_step, options):
    """|y - y*|_2 <= |g(y)|_2 / mu (strong convexity; 2x for the variation of mu between y and y*), with the residual
    at VBD's tolerance; the pinned corners never move."""
    system, problem, start, reference, mu, free = hanging_cloth_step
    solver = solver_params(type="vbd", tolerance=1e-6, max_iterations=3000, **options).build()
    y, stats = solver.minimize(problem, start)
    assert stats.converged, stats
    gradient = problem.gradient(y)
    assert stats.residual == pytest.approx(np.abs(gradient).max(), rel=1e-12)
    assert np.linalg.norm(y - reference) <= 2.0 * np.linalg.norm(gradient[free]) / mu
    assert np.array_equal(y[system.fixed_dofs], start[system.fixed_dofs])


PLANE_NORMAL, LINE_DIRECTION = np.array([0.3, -0.5, 0.8]), np.array([1.0, 2.0, -0.5])


def test_vbd_keeps_pinned_and_sliding_vertices_on_their_constraints():
    """A 4 x 4 cloth with a pinned vertex, axis-aligned and oblique sliding planes and lines: VBD's solution is
    projected Newton's (filtered, 1e-12) within the strong-convexity bound, pins stay exactly, and each sliding
    vertex moved only along its plane or line (to 1e-12 of its move)."""
    system = constrained_cloth()
    problem, start = backward_euler_problem(system, system.x0, system.v0, 0.02)
    reference, stats = solver_params(type="projected_newton", tolerance=1e-12).build().minimize(problem, start)
    assert stats.converged
    y, stats = VertexBlockDescent(tolerance=1e-9, max_iterations=500).minimize(problem, start)
    assert stats.converged, stats
    moved = (y - start).reshape(-1, 3)
    assert np.array_equal(moved[12], np.zeros(3))
    assert abs(moved[0, 2]) == 0.0 and np.all(moved[5, [0, 2]] == 0.0)
    normal, direction = PLANE_NORMAL / np.linalg.norm(PLANE_NORMAL), LINE_DIRECTION / np.linalg.norm(LINE_DIRECTION)
    assert np.all(np.abs(moved[[15, 10]] @ normal) <= 1e-12 * np.linalg.norm(moved[[15, 10]], axis=1))
    assert np.linalg.norm(moved[3] - (moved[3] @ direction) * direction) <= 1e-12 * np.linalg.norm(moved[3])
    assert np.min(np.linalg.norm(moved[[0, 5, 15, 10, 3]], axis=1)) > 1e-5, "every sliding vertex must move"
    # the bound on the constrained subspace: E restricted to it is strongly convex with mu >= that of the free dofs
    mu, free = free_hessian_floor(problem, reference, system.fixed_dofs)
    assert mu > 0
    assert np.linalg.norm(y - reference) <= 2.0 * np.linalg.norm(problem.gradient(y)) / mu


def constrained_cloth():
    """test_vbd_keeps_pinned_and_sliding_vertices_on_their_constraints's cloth: a pin, sliding planes and lines."""
    return MassSpringParams(
        model={"grid": {"resolution": [4, 4], "size": [0.3, 0.3]}}, stiffness={"stretch": 60.0, "shear": 10.0, "bend": 1.0},
        mass={"total": 0.2}, damping=[{"model": "spring", "coefficient": 0.02}], pinned=[12],
        constraints=[{"vertices": [0], "normal": [0.0, 0.0, 1.0]}, {"vertices": [5], "direction": [0.0, 1.0, 0.0]},
                     {"vertices": [15, 10], "normal": PLANE_NORMAL.tolist()}, {"vertices": [3], "direction": LINE_DIRECTION.tolist()}],
        initial={"spin": [0.2, 0.5, 1.0]}).build()


@pytest.mark.parametrize("path", ["numpy", "compiled"])
def test_a_colours_sweep_residual_is_the_filtered_gradient_of_its_vertices(path):
    """A colour swept alone from y meets E at y itself: its sweep's residual is the largest |S_i g_i(y)|_inf of its
    vertices (pins zeroed, sliding vertices filtered), to round-off; for every colour."""
    from simrun.solvers.dofs import free_dofs
    from simrun.solvers.vbd import IncrementalParts, colour_plans

    system = constrained_cloth()
    problem, start = backward_euler_problem(system, system.x0, system.v0, 0.02)
    free = free_dofs(system.dof_count, system.fixed_dofs, system.sliding)
    plans = colour_plans(system.vertex_form().colouring(), free, 3)
    solver = VertexBlockDescent()
    for plan in plans:
        if path == "numpy":
            _, _, residual = solver._sweep(problem, start, [plan])
        else:
            _, _, residual = solver._compiled_sweep(start, [plan], system.vertex_form().sweep(), IncrementalParts.of(problem))
        gradient = free.zero_fixed(np.array(problem.gradient(start))).reshape(-1, 3)
        expected = np.abs(gradient[plan.vertices]).max()
        assert expected > 0.0
        assert residual == pytest.approx(expected, rel=1e-12)


def filtered_residual(system, problem, y) -> float:
    """|S g(y)|_inf: the residual a solve reports (pins zeroed, sliding vertices filtered)."""
    from simrun.solvers.dofs import free_dofs

    return float(np.abs(free_dofs(system.dof_count, system.fixed_dofs, system.sliding).zero_fixed(
        np.array(problem.gradient(y)))).max())


class CountedGradients:
    """A problem whose full gradients are counted."""

    def __init__(self, problem):
        self.problem, self.gradients = problem, 0

    def gradient(self, y):
        self.gradients += 1
        return self.problem.gradient(y)

    def __getattr__(self, name):
        return getattr(self.problem, name)


def test_a_solve_evaluates_the_full_gradient_only_where_the_sweeps_residual_meets_the_threshold_and_at_its_end():
    """Ten sweeps that cannot converge cost two full gradients (the start's and the end's, which the solve reports),
    not eleven; with a callback, which records every iterate's gradient, eleven. Both solves land on the same y."""
    system = constrained_cloth()
    problem, start = backward_euler_problem(system, system.x0, system.v0, 0.02)
    counted = CountedGradients(problem)
    y, stats = VertexBlockDescent(tolerance=1e-300, max_iterations=10).minimize(counted, start)
    assert counted.gradients == 2 and stats.iterations == 10 and not stats.converged
    assert stats.residual == filtered_residual(system, problem, y)
    watched = CountedGradients(problem)
    seen = []
    y_watched, stats_watched = VertexBlockDescent(tolerance=1e-300, max_iterations=10,
                                                  callback=lambda y, g: seen.append(y)).minimize(watched, start)
    assert watched.gradients == 11 and len(seen) == 11
    assert np.array_equal(y, y_watched) and stats.residual == stats_watched.residual


@pytest.mark.parametrize("options", [{}, {"chebyshev_rho": 0.9}], ids=["plain", "chebyshev"])
def test_convergence_is_found_by_the_full_gradient_at_most_one_sweep_late(options):
    """The full gradient at every sweep (a callback asks for it) finds convergence at sweep k; the sweep's residual
    as the gate finds it at k or k + 1, and the solve reports the residual of the y it returns."""
    system = constrained_cloth()
    problem, start = backward_euler_problem(system, system.x0, system.v0, 0.02)
    residuals = []
    _, every = VertexBlockDescent(tolerance=1e-9, max_iterations=500, callback=lambda y, g: residuals.append(
        np.abs(g).max()), **options).minimize(problem, start)
    y, gated = VertexBlockDescent(tolerance=1e-9, max_iterations=500, **options).minimize(problem, start)
    assert every.converged and gated.converged and every.iterations > 10
    assert gated.iterations in (every.iterations, every.iterations + 1)
    assert gated.residual == filtered_residual(system, problem, y) <= 1e-9 * residuals[0]


# ==================================================================================================
# 5. One vertex, quadratic energy: one sweep is exact
# ==================================================================================================
def test_one_sweep_solves_the_linear_damped_spring_exactly():
    """m (y - y~) + h^2 k y + h d (y - x_n) = 0 gives y = (m y~ + h d x_n) / (m + h^2 k + h d): one vertex, one
    colour, a quadratic E, so the first Newton step of the 1 x 1 block is the solution (generic blocks, dense D)."""
    m, k, d, dt = 2.0, 50.0, 0.3, 0.1
    system = SpringMassParams(mass=m, stiffness=k, damping=d, x0=1.0, v0=0.5).build()
    problem, start = backward_euler_problem(system, system.x0, system.v0, dt)
    y_tilde = system.x0[0] + dt * system.v0[0]
    exact = (m * y_tilde + dt * d * system.x0[0]) / (m + dt * dt * k + dt * d)
    y, stats = solver_params(type="vbd", tolerance=1e-12).build().minimize(problem, start)
    assert stats.converged and stats.iterations == 1
    assert y[0] == pytest.approx(exact, rel=4 * np.finfo(float).eps)


# ==================================================================================================
# The per-vertex solve and the refusal
# ==================================================================================================
def test_a_vertex_whose_block_is_singular_is_skipped_and_the_others_take_their_newton_steps():
    """The paper's small-determinant rule: u_i = 0 where |det H_i| <= floor |H_i|_F^d, u_i = -H_i^{-1} g_i elsewhere."""
    rng = np.random.default_rng(9)
    factors = rng.standard_normal((4, 3, 3))
    hessian = factors @ factors.transpose(0, 2, 1) + 0.5 * np.eye(3)
    hessian[2] = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])  # rank 1: det 0
    gradient = rng.standard_normal((4, 3))
    expected = -np.linalg.solve(hessian[[0, 1, 3]], gradient[[0, 1, 3], :, None])[:, :, 0]
    plan = ColourPlan(np.arange(4), np.zeros(0, dtype=np.intp), np.zeros((0, 3, 3)), np.zeros(4, dtype=bool),
                      np.zeros((4, 3, 3)))
    steps = VertexBlockDescent(determinant_floor=1e-12)._newton_steps(gradient.copy(), hessian.copy(), plan)
    assert np.array_equal(steps[2], np.zeros(3))
    assert np.allclose(steps[[0, 1, 3]], expected, rtol=1e-12, atol=0.0)


def test_the_refusal_names_what_vbd_needs():
    cloth = ClothParams(resolution=(3, 3)).build()
    assert VertexBlockDescent.refusal(cloth, "incremental_potential") is None
    assert "no vertex blocks" in VertexBlockDescent.refusal(cloth, "segment_potential")

    class NoVertices:
        dim, dof_count = 2, 3

    assert "no vertices" in VertexBlockDescent.refusal(NoVertices(), "incremental_potential")
    assert isinstance(IncrementalPotential(cloth, cloth.x0, 1e-4).vertex_colouring(), list)
