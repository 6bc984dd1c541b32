"""Vertex block descent on finite-element solids (systems/fem/vbd_kernels.py) against theory and the generic
paths it replaces:

1. each vertex's block K = n^T A n in closed form equals the contraction of the material's exact tangent A, for every
   energy, in 2-D and 3-D;
2. the vertex blocks without projection are the diagonal blocks of the full gradient and Hessian (the generic
   the generic ``VertexForm``), colliders included; projected, they are the sums of the elements' raw blocks each
   projected by numpy's eigh;
3. the change of P when one vertex moves is the difference of energies where that is resolved, and the second-order
   model g . s + s^T H s / 2 where the step is far below P's round-off;
4. the step's kept fraction is the global step filter's (kernels.inversion_free_step) for a direction that moves one
   vertex;
5. the compiled sweep is the numpy sweep to round-off with pins, sliding vertices and Rayleigh damping, from a start
   that makes it backtrack and cut steps; the same with one thread and two, bit for bit; E never increases.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import agreeing_sweeps, compiled_solve_energies, cut_and_halved, step_problem, sweeps_by_thread_count
from test_fem import BOX, ENERGIES, SQUARE, deformed, fem
from simrun.solvers import VertexBlockDescent
from simrun.solvers.dofs import free_dofs
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.solvers.vbd import IncrementalParts, colour_plans
from simrun.systems import SYSTEMS
from simrun.systems.forms import VertexForm
from simrun.systems.fem import energies, kernels, vbd_kernels
from simrun.systems.fem.materials import CODES as MATERIALS
from simrun.systems.fem.system import KEPT_VOLUME

MODELS = [pytest.param(BOX, id="tets"), pytest.param(SQUARE, id="triangles")]


def gravity(model) -> list[float]:
    return [0.0, 0.0, -9.81] if "box" in model else [0.0, -9.81]


def relative(a, b) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("material", ENERGIES)
def test_the_vertex_block_is_the_tangent_contracted_with_the_shape_gradient(dim, material):
    rng = np.random.default_rng(5)
    model, mu, lam = MATERIALS[material], 3.0e3, 7.0e3
    for trial in range(6):
        F = np.eye(dim) + 0.3 * rng.standard_normal((dim, dim))
        if np.linalg.det(F) <= 0.0:
            F[:, 0] = -F[:, 0]
        n = rng.standard_normal(dim)
        P, A = np.empty((dim, dim)), np.empty((dim * dim, dim * dim))
        work = np.empty((energies.WORK_SLOTS, dim, dim))
        energies.material_terms(model, F, dim, mu, lam, P, A, True, work)
        expected = np.einsum("j,ijkl,l->ik", n, A.reshape(dim, dim, dim, dim), n)
        K = np.empty((dim, dim))
        vbd_kernels.vertex_stiffness(model, F, n, dim, mu, lam, A, K, np.empty((energies.WORK_SLOTS, dim, dim)))
        np.testing.assert_allclose(K, expected, rtol=0.0, atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("material", ENERGIES)
def test_raw_vertex_blocks_are_the_diagonal_blocks_of_the_gradient_and_hessian(model, material):
    system = fem(model, material, gravity=gravity(model))
    x = deformed(system, 0.04)
    vertices = np.arange(system.vertex_count)
    gradient, hessian = system.vertex_form().blocks(x, vertices, False)
    generic_gradient, generic_hessian = VertexForm(system).blocks(x, vertices, False)
    assert relative(gradient, generic_gradient) < 1e-12
    assert relative(hessian, generic_hessian) < 1e-12


def test_colliders_add_their_blocks_as_in_the_full_hessian():
    system = fem(BOX, "stable_neo_hookean", gravity=[0.0, 0.0, -9.81],
                 contact={"method": "penalty", "stiffness": 1e4,
                          "colliders": [{"shape": "plane", "normal": [0.1, 0.0, 1.0], "point": [0.0, 0.0, 0.03]}]})
    x = deformed(system, 0.02)
    inside = x.reshape(-1, 3)[:, 2] < 0.03
    assert inside.any() and not inside.all()
    vertices = np.arange(system.vertex_count)
    for projection in (False, "clamp"):
        gradient, hessian = system.vertex_form().blocks(x, vertices, projection)
        generic_gradient, generic_hessian = VertexForm(system).blocks(x, vertices, False)
        assert relative(gradient, generic_gradient) < 1e-12
        if not projection:
            assert relative(hessian, generic_hessian) < 1e-12
    assert system.vertex_form().sweep().colliders[0].size == 1  # the compiled sweep takes the plane (test_vbd_colliders.py)


def element_vertex_blocks(system, x):
    """Every element's raw Hessian block at each of its corners, (elements, corners, d, d), from the element loops."""
    d, corners = system.dim, system.elements.shape[1]
    blocks = np.empty((len(system.elements), corners * d, corners * d))
    kernels.element_hessians(x, system.elements, system.shape_gradients, system.volumes, system.mu, system.lam,
                             system._model, 0, blocks)
    return np.stack([blocks[:, a * d:(a + 1) * d, a * d:(a + 1) * d] for a in range(corners)], axis=1)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("material, scales", [("stvk", (1.0, 1.0)), ("neo_hookean", (20.0, 1.0)),
                                              ("corotated", (0.2, 0.2))])
@pytest.mark.parametrize("mode", ["clamp", "abs"])
def test_projected_blocks_sum_each_elements_block_projected_by_eigh(model, material, scales, mode):
    """Indefinite blocks: St. Venant-Kirchhoff elements compressed by a random field; neo-Hookean ones stretched 20x
    along x (its block mu |n|^2 I + (mu + lambda (1 - ln J)) / J^2 c c^T, c = J F^-T n, is indefinite past
    ln J = 1 + 2 mu / lambda for n across the stretch: projected in closed form for tets); co-rotated ones squeezed to
    0.2 in two axes (its rotation's derivative grows as 1 / (sigma_1 + sigma_2))."""
    system = fem(model, material)
    noise = deformed(system, 0.004 if material in ("neo_hookean", "corotated") else 0.08, seed=2) - system.x0
    x = system.x0.reshape(-1, system.dim) * np.array(scales + (1.0,) * (system.dim - 2)) + noise.reshape(-1, system.dim)
    x = x.ravel()
    if material == "neo_hookean":
        assert np.all(system.volume_ratios(x) > 0.0)
    raw = element_vertex_blocks(system, x)
    values, vectors = np.linalg.eigh(raw)
    assert (values < -1e-9 * np.abs(values).max()).any(), "some elements' blocks must be indefinite"
    values = np.maximum(values, 0.0) if mode == "clamp" else np.abs(values)
    projected = np.einsum("ecij,ecj,eckj->ecik", vectors, values, vectors)
    expected = np.zeros((system.vertex_count, system.dim, system.dim))
    np.add.at(expected, system.elements.ravel(), projected.reshape(-1, system.dim, system.dim))
    _, hessian = system.vertex_form().blocks(x, np.arange(system.vertex_count), mode)
    assert relative(hessian, expected) < 1e-12
    assert np.all(np.linalg.eigvalsh(hessian) >= -1e-10 * np.abs(hessian).max())


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("poisson_ratio", [-0.95, 0.0, 0.45])
def test_stable_neo_hookean_blocks_are_positive_definite_for_every_deformation(model, poisson_ratio):
    """(mu - mu/(I_C + 1)) |n|^2 I + 2 mu/(I_C + 1)^2 w w^T + lambda c c^T with the re-parametrised lambda > 0 for every
    nu > -1: no element's block needs a projection, inverted or not."""
    config = {"type": "fem", "model": model, "gravity": [0.0] * (3 if "box" in model else 2),
              "material": {"model": "stable_neo_hookean", "youngs_modulus": 2.0e4, "poisson_ratio": poisson_ratio,
                           "density": 1000.0}}
    system = SYSTEMS["fem"].model_validate(config).build()
    assert np.all(system.lam > 0.0)
    x = deformed(system, 0.3, seed=6)
    assert np.any(system.volume_ratios(x) < 0.0), "some elements inverted"
    raw = element_vertex_blocks(system, x)
    values = np.linalg.eigvalsh(raw)
    assert np.all(values > 1e-9 * np.abs(values).max())
    _, projected = system.vertex_form().blocks(x, np.arange(system.vertex_count), "clamp")
    _, exact = system.vertex_form().blocks(x, np.arange(system.vertex_count), False)
    np.testing.assert_array_equal(projected, exact)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("material", ENERGIES)
def test_energy_changes_are_differences_and_resolve_steps_below_the_roundoff_of_p(model, material):
    system = fem(model, material, gravity=gravity(model))
    x = deformed(system, 0.03)
    vertices = system.vertex_form().colouring()[0]
    rng = np.random.default_rng(4)
    direction = rng.standard_normal((vertices.size, system.dim))
    energy = system.potential_energy(x)
    # a step of 1 mm: the difference of energies is resolved to ~1e-16 |P| / |dP|
    steps = 1e-3 * direction
    changes = system.vertex_form().energy_changes(x, vertices, steps)
    for k, vertex in enumerate(vertices):
        moved = x.copy()
        moved[system.dim * vertex:system.dim * vertex + system.dim] += steps[k]
        difference = system.potential_energy(moved) - energy
        assert abs(changes[k] - difference) <= 1e-9 * abs(difference) + 1e-14 * abs(energy)
    # a step of 1e-11 m: the change is g . s + s^T H s / 2 to O(|s|^3), where P's differences are off by more than 1e-6
    # of it (the co-rotated energy's change is a difference of its elements' energies: resolved to their round-off)
    steps = 1e-11 * direction
    changes = system.vertex_form().energy_changes(x, vertices, steps)
    gradient, hessian = system.vertex_form().blocks(x, vertices, False)
    model_changes = np.einsum("ki,ki->k", gradient, steps) + 0.5 * np.einsum("ki,kij,kj->k", steps, hessian, steps)
    assert np.finfo(float).eps * abs(energy) > 1e-6 * np.abs(model_changes).min()
    roundoff = np.finfo(float).eps * abs(energy) if material == "corotated" else 0.0
    np.testing.assert_allclose(changes, model_changes, rtol=1e-6, atol=roundoff)


@pytest.mark.parametrize("model", MODELS)
def test_the_kept_fraction_is_the_step_filters_for_one_vertex(model):
    system = fem(model, "neo_hookean")
    x = deformed(system, 0.02)
    vertices = system.vertex_form().colouring()[0]
    rng = np.random.default_rng(9)
    extent = float(np.ptp(system.rest, axis=0).max())
    steps = 0.3 * extent * rng.standard_normal((vertices.size, system.dim))  # long enough to flatten some elements
    fractions = system.vertex_form().step_fractions(x, vertices, steps)
    assert (fractions < 1.0).any() and (fractions == 1.0).any()
    for k, vertex in enumerate(vertices):
        direction = np.zeros_like(x)
        direction[system.dim * vertex:system.dim * vertex + system.dim] = steps[k]
        expected = kernels.inversion_free_step(x, direction, system.elements, KEPT_VOLUME)
        assert fractions[k] == pytest.approx(expected, rel=1e-12)


def constrained(model, material):
    """Pinned on one side, one vertex sliding in an oblique plane, Rayleigh damping, gravity."""
    if "box" in model:
        options = {"pinned": "left", "constraints": [{"vertices": [23], "normal": [0.3, -0.5, 0.8]}]}
    else:
        options = {"pinned": [0, 1], "constraints": [{"vertices": [14], "direction": [1.0, 2.0]}]}
    return fem(model, material, gravity=gravity(model), damping=[{"model": "rayleigh", "alpha": 0.2, "beta": 0.005}],
               **options)


def squeezed(system):
    """x0 pressed to 70 % along its first axis with noise."""
    positions = system.x0.reshape(-1, system.dim).copy()
    positions[:, 0] *= 0.7
    positions += 0.01 * np.random.default_rng(3).standard_normal(positions.shape)
    return positions.ravel()


def thrown(system, dt=0.05):
    """The first step's problem from the squeezed shape with random velocities of 60 m/s: y~ lies several elements
    away, so that the first sweeps cut steps to the kept volume and halve some (the numbers checked below)."""
    velocity = 60.0 * np.random.default_rng(8).standard_normal(system.dof_count)
    return step_problem(system, squeezed(system), velocity, dt)


@pytest.mark.parametrize("projection", ["clamp", "abs"])
@pytest.mark.parametrize("material", ENERGIES)
@pytest.mark.parametrize("model", MODELS)
def test_the_compiled_sweep_is_the_numpy_sweep(model, material, projection):
    system = constrained(model, material)
    assert np.all(system.volume_ratios(squeezed(system)) > 0.0)
    problem, start = thrown(system)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding),
                         system.dim)
    solver = VertexBlockDescent(spd_projection=projection)
    sweep, parts = system.vertex_form().sweep(), IncrementalParts.of(problem)
    assert sweep is not None and parts.damping_weight > 0.0
    for y, swept, _ in agreeing_sweeps(solver, problem, start, plans, sweep, parts, 4):
        assert problem.value(swept) <= problem.value(y) * (1 + ENERGY_ROUNDOFF)
    y = swept
    np.testing.assert_array_equal(y[system.fixed_dofs], start[system.fixed_dofs])


def test_the_sweep_backtracks_and_cuts_steps_from_a_squeezed_start():
    """The thrown neo-Hookean box: a Newton step of some vertex would flatten an element (cut to the kept volume) and
    some raise E (halved), so the comparison above exercises both."""
    system = constrained(BOX, "neo_hookean")
    problem, start = thrown(system)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding), 3)
    cut, halved = cut_and_halved(problem, start, plans)
    assert cut > 0 and halved > 0


def test_one_thread_and_two_give_the_same_sweep_bit_for_bit():
    system = fem({"box": {"size": [1.2, 0.2, 0.2], "cells": [24, 4, 4]}}, "stable_neo_hookean",
                 gravity=[0.0, 0.0, -9.81], pinned="left")
    problem, start = step_problem(system, deformed(system, 0.01), np.zeros(system.dof_count), 1.0 / 60.0)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding), 3)
    assert max(plan.vertices.size for plan in plans) > vbd_kernels.CHUNK, "a colour must span several chunks"
    solver, sweep, parts = VertexBlockDescent(), system.vertex_form().sweep(), IncrementalParts.of(problem)
    results = sweeps_by_thread_count(solver, start, plans, sweep, parts)
    assert np.array_equal(results[0], results[-1])


@pytest.mark.parametrize("material", ["neo_hookean", "stvk"])
def test_the_solver_takes_the_compiled_sweep_and_the_energy_never_increases(monkeypatch, material):
    system = constrained(BOX, material)
    problem, start = thrown(system)
    y, energies_seen = compiled_solve_energies(monkeypatch, VertexBlockDescent, problem, start, tolerance=1e-10,
                                               max_iterations=60)
    assert energies_seen.size > 10
    assert np.all(np.diff(energies_seen) <= ENERGY_ROUNDOFF * np.abs(energies_seen[:-1]))
    assert energies_seen[-1] < energies_seen[0]
    if material == "neo_hookean":  # infinite at J <= 0; St. Venant-Kirchhoff's finite energy lets the 60 m/s throw
        assert np.all(system.volume_ratios(y) > 0.0)  # flatten elements by 90 % a sweep, down to round-off and through


def test_vbd_reaches_newtons_backward_euler_step_of_a_hanging_box():
    """Run to convergence, VBD's minimiser of the incremental potential is Newton's (the same step, two solvers)."""
    from simrun.solvers import solver_params

    system = fem({"box": {"size": [0.4, 0.1, 0.1], "cells": [8, 2, 2]}}, "stable_neo_hookean",
                 gravity=[0.0, 0.0, -9.81], pinned="left")
    problem, start = step_problem(system, system.x0, system.v0, 0.01)
    newton = solver_params(type="newton", tolerance=1e-12, max_iterations=50).build()
    reference, _ = newton.minimize(problem, start)
    vbd = solver_params(type="vbd", tolerance=1e-9, max_iterations=5000, chebyshev_rho=0.9).build()
    y, stats = vbd.minimize(problem, start)
    assert stats.converged
    moved = np.max(np.abs(reference - start))
    assert np.max(np.abs(y - reference)) < 1e-4 * moved


def test_the_first_root_shortcut_is_the_root_search_where_it_applies():
    """kernels._first_root returns 2.0 at once where c0 + min(c1, 0) + min(c2, 0) + min(c3, 0) > 0 (the cubic cannot
    reach 0 on [0, 1]); everywhere, small steps and large, it is the first crossing of the full search, or 2.0."""
    rng = np.random.default_rng(4)
    shortcuts = 0
    for scale in (1e-3, 0.1, 1.0, 5.0):
        for c1, c2, c3 in scale * rng.standard_normal((400, 3)):
            c0 = 0.9
            crossings = kernels.cubic_crossings(c0, c1, c2, c3)
            expected = crossings[0] if len(crossings) else 2.0
            shortcuts += c0 + min(c1, 0.0) + min(c2, 0.0) + min(c3, 0.0) > 0.0
            assert kernels._first_root(c0, c1, c2, c3) == expected
    assert 0 < shortcuts < 1600, "both paths must be taken"
