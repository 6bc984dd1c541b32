"""Vertex block descent on shells (systems/fem/shell_vbd_kernels.py) against theory and the generic paths it
replaces:

1. a triangle's vertex block in closed form is membrane.py's exact tangent A contracted with the shape gradient, for
   every membrane energy; a hinge's angle derivatives in one vertex are the blocks of bending.py's theta_z, theta_zz;
2. the vertex blocks without projection are the diagonal blocks of the full gradient and Hessian (the generic
   the generic ``VertexForm``), gravity and a collider included; projected, they are the sums of each triangle's and each
   hinge's raw block projected by numpy's eigh;
3. the change of P when one vertex moves is the difference of energies where that is resolved, and the second-order
   model g . s + s^T H s / 2 where the step is far below P's round-off;
4. the step's kept fraction is the global area filter's (membrane.area_keeping_step) for a direction that moves one
   vertex;
5. the compiled sweep is the numpy sweep to round-off with pins, a sliding vertex, Rayleigh damping and a collider,
   from a start that makes it backtrack and cut steps; one thread and two bit for bit; E never increases; run to
   convergence it lands on Newton's step;
6. an IMEX part with the hinges alone sweeps its own terms, not the whole's.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import agreeing_sweeps, compiled_solve_energies, cut_and_halved, step_problem, sweeps_by_thread_count
from simrun.solvers import VertexBlockDescent, solver_params
from simrun.solvers.dofs import free_dofs
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.solvers.vbd import IncrementalParts, colour_plans
from simrun.systems import SYSTEMS
from simrun.systems.forms import VertexForm
from simrun.systems.fem import bending, membrane, shell_terms, shell_vbd_kernels
from simrun.systems.fem.materials import CODES as MATERIALS
from simrun.systems.fem.system import KEPT_VOLUME

MEMBRANES = ["stvk", "corotated", "neo_hookean", "stable_neo_hookean"]
GRID = {"grid": {"resolution": [7, 6], "size": [1.0, 0.8]}}
SLIDING = 24  # an interior vertex of the 7 x 6 grid


def shell(material="stvk", bend=1.0e-2, density=0.2, **options):
    config = {"type": "fem", "model": GRID, "gravity": [0.0, 0.0, -9.81], "thickness": 1.0e-3,
              "material": {"model": material, "youngs_modulus": 1.0e5, "poisson_ratio": 0.3, "density": density},
              **({"bending": {"stiffness": bend}} if bend else {}), **options}
    return SYSTEMS["fem"].model_validate(config).build()


def crumpled(system, scale=0.03, seed=0):
    return system.x0 + scale * np.random.default_rng(seed).standard_normal(system.dof_count)


def relative(a, b) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


# -- 1. the closed forms ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("material", MEMBRANES)
def test_the_triangles_vertex_terms_are_its_tangent_contracted_with_the_shape_gradient(material):
    rng = np.random.default_rng(2)
    model, mu, lam = MATERIALS[material], 3.0e3, 7.0e3
    P, A, work = np.empty((3, 2)), np.empty((6, 6)), np.empty((4, 3, 3))
    stress, K = np.empty(3), np.empty((3, 3))
    for trial in range(8):
        F = np.eye(3, 2) + 0.3 * rng.standard_normal((3, 2))
        n = rng.standard_normal(2)
        membrane.membrane_terms(model, F, mu, lam, P, A, True, work)
        shell_terms.membrane_vertex_terms(model, F, n[0], n[1], mu, lam, stress, K)
        expected = np.einsum("j,ijkl,l->ik", n, A.reshape(3, 2, 3, 2), n)
        np.testing.assert_allclose(stress, P @ n, rtol=0.0, atol=1e-12 * np.abs(P @ n).max())
        np.testing.assert_allclose(K, expected, rtol=0.0, atol=1e-12 * np.abs(expected).max())


def test_a_hinges_angle_derivatives_in_one_vertex_are_blocks_of_the_full_ones():
    """theta_z and theta_zz of bending.py (tested against differences in test_fem_shells.py) mapped to vertex a:
    block a - 1 for a wing or vertex 1, minus the three blocks' sum (and the sum of all nine) for vertex 0; random
    hinges folded either way, past a right angle too."""
    rng = np.random.default_rng(7)
    z, gradient, hessian, work = np.empty((3, 3)), np.empty(9), np.empty((9, 9)), np.empty((4, 9, 9))
    along, curvature, points = np.empty(3), np.empty((3, 3)), np.empty((10, 3))
    hinges = np.array([[0, 1, 2, 3]], dtype=np.uint64)
    for trial in range(20):
        x = rng.standard_normal(12)
        bending._hinge_vectors(x, np.arange(4), z)
        bending._angle_derivatives(z, gradient, hessian, True, work)
        blocks = hessian.reshape(3, 3, 3, 3).transpose(0, 2, 1, 3)  # [block_p, block_q, i, j]
        expected = {0: (-gradient.reshape(3, 3).sum(axis=0), blocks.sum(axis=(0, 1)))}
        expected.update({a: (gradient[3 * a - 3:3 * a], blocks[a - 1, a - 1]) for a in (1, 2, 3)})
        for corner, (first, second) in expected.items():
            shell_terms.hinge_angle_block(x, hinges, 0, corner, along, curvature, points)
            np.testing.assert_allclose(along, first, rtol=0.0, atol=1e-12 * np.abs(first).max())
            np.testing.assert_allclose(curvature, second, rtol=0.0, atol=1e-11 * np.abs(second).max())


# -- 2. the blocks --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("bend", [1.0e-2, 0.0])
@pytest.mark.parametrize("material", MEMBRANES)
def test_raw_vertex_blocks_are_the_diagonal_blocks_of_the_gradient_and_hessian(material, bend):
    system = shell(material, bend, contact={"method": "penalty", "stiffness": 50.0,
                                            "colliders": [{"shape": "sphere", "center": [0.5, 0.4, -0.3],
                                                           "radius": 0.35}]})
    x = crumpled(system)
    inside = np.linalg.norm(x.reshape(-1, 3) - [0.5, 0.4, -0.3], axis=1) < 0.35
    assert inside.any() and not inside.all()
    vertices = np.arange(system.vertex_count)
    gradient, hessian = system.vertex_form().blocks(x, vertices, False)
    generic_gradient, generic_hessian = VertexForm(system).blocks(x, vertices, False)
    assert relative(gradient, generic_gradient) < 1e-12
    assert relative(hessian, generic_hessian) < 1e-12


def raw_term_blocks(system, x):
    """(each triangle's raw Hessian block at each corner (t, 3, 3, 3), each hinge's at each of its vertices
    (h, 4, 3, 3)), from the element and hinge loops of membrane.py and bending.py."""
    triangles = np.empty((len(system.elements), 9, 9))
    membrane.element_hessians(x, system.elements, system.shape_gradients, system.volumes, system.mu, system.lam,
                              system._model, 0, triangles)
    hinges = np.empty((len(system.hinges), 12, 12))
    bending.hinge_hessians(x, system.hinges, system.hinge_stiffness, system.rest_angles, 0, hinges)
    return (np.stack([triangles[:, 3 * a:3 * a + 3, 3 * a:3 * a + 3] for a in range(3)], axis=1),
            np.stack([hinges[:, 3 * a:3 * a + 3, 3 * a:3 * a + 3] for a in range(4)], axis=1))


@pytest.mark.parametrize("material", ["stvk", "neo_hookean", "corotated"])
@pytest.mark.parametrize("mode", ["clamp", "abs"])
def test_projected_blocks_sum_each_terms_block_projected_by_eigh(material, mode):
    """A crumpled sheet squeezed to 70 % in its plane: the membranes' blocks are indefinite in compression, and every
    hinge away from its rest angle has an indefinite block (theta_aa's curvature term)."""
    system = shell(material, 1.0e-2)
    x = (crumpled(system, 0.01).reshape(-1, 3) * [0.7, 0.7, 1.0]).ravel()
    triangles, hinges = raw_term_blocks(system, x)
    expected = np.zeros((system.vertex_count, 3, 3))
    for blocks, owners in ((triangles, system.elements), (hinges, system.hinges)):
        values, vectors = np.linalg.eigh(blocks)
        assert (values < -1e-9 * np.abs(values).max()).any(), "some blocks must be indefinite"
        values = np.maximum(values, 0.0) if mode == "clamp" else np.abs(values)
        np.add.at(expected, owners.ravel(), np.einsum("ecij,ecj,eckj->ecik", vectors, values, vectors).reshape(-1, 3, 3))
    _, hessian = system.vertex_form().blocks(x, np.arange(system.vertex_count), mode)
    assert relative(hessian, expected) < 1e-11
    assert np.all(np.linalg.eigvalsh(hessian) >= -1e-10 * np.abs(hessian).max())


# -- 3. and 4. the energy change and the kept fraction ------------------------------------------------------------------
@pytest.mark.parametrize("material", MEMBRANES)
def test_energy_changes_are_differences_and_resolve_steps_below_the_roundoff_of_p(material):
    system = shell(material, 1.0e-2)
    x = crumpled(system)
    vertices = system.vertex_form().colouring()[0]
    direction = np.random.default_rng(4).standard_normal((vertices.size, 3))
    energy = system.potential_energy(x)
    steps = 1e-3 * direction
    changes = system.vertex_form().energy_changes(x, vertices, steps)
    for k, vertex in enumerate(vertices):
        moved = x.copy()
        moved[3 * vertex:3 * vertex + 3] += steps[k]
        difference = system.potential_energy(moved) - energy
        assert abs(changes[k] - difference) <= 1e-9 * abs(difference) + 1e-14 * abs(energy)
    # a step of 1e-11 m: the change is g . s + s^T H s / 2 to O(|s|^3), where P's differences are off by more than 1e-6
    # of it; the hinges' change is k_h (theta' - theta)(...), theta' - theta resolved to atan2's round-off eps |theta|
    steps = 1e-11 * direction
    changes = system.vertex_form().energy_changes(x, vertices, steps)
    gradient, hessian = system.vertex_form().blocks(x, vertices, False)
    model_changes = np.einsum("ki,ki->k", gradient, steps) + 0.5 * np.einsum("ki,kij,kj->k", steps, hessian, steps)
    assert np.finfo(float).eps * abs(energy) > 1e-6 * np.abs(model_changes).min()
    angles = bending.rest_angles(x, system.hinges) - system.rest_angles
    hinge_roundoff = 8 * np.finfo(float).eps * np.pi * 2.0 * np.max(system.hinge_stiffness * np.abs(angles)) * 12
    np.testing.assert_allclose(changes, model_changes, rtol=1e-6, atol=hinge_roundoff)
    assert hinge_roundoff < 1e-3 * np.abs(model_changes).max()


def test_the_kept_fraction_is_the_area_filters_for_one_vertex():
    system = shell("neo_hookean")
    x = crumpled(system, 0.01)
    vertices = system.vertex_form().colouring()[0]
    # in the sheet's plane (a move across it adds area) and long enough to collapse triangles
    steps = 0.4 * np.random.default_rng(9).standard_normal((vertices.size, 3)) * [1.0, 1.0, 0.0]
    fractions = system.vertex_form().step_fractions(x, vertices, steps)
    assert (fractions < 1.0).any() and (fractions == 1.0).any()
    for k, vertex in enumerate(vertices):
        direction = np.zeros_like(x)
        direction[3 * vertex:3 * vertex + 3] = steps[k]
        expected = membrane.area_keeping_step(x, direction, system.elements, KEPT_VOLUME)
        assert fractions[k] == pytest.approx(expected, rel=1e-9)


# -- 5. the sweep ---------------------------------------------------------------------------------------------------------
def constrained(material, **options):
    """Pinned along its top edge, one vertex sliding in an oblique plane, Rayleigh damping, gravity, a sphere below;
    a hundred times heavier than ``shell``'s sheet, so that some vertices' Newton steps in the thrown start are long
    enough to be cut to the kept area or halved (counted below)."""
    return shell(material, 1.0e-2, density=20.0, pinned="top", constraints=[{"vertices": [SLIDING], "normal": [0.3, -0.5, 0.8]}],
                 damping=[{"model": "rayleigh", "alpha": 0.2, "beta": 0.005}],
                 contact={"method": "penalty", "stiffness": 50.0,
                          "colliders": [{"shape": "sphere", "center": [0.5, 0.4, -0.45], "radius": 0.5}]}, **options)


def thrown(system, dt=0.05):
    """The first step's problem from the sheet crumpled and squeezed to 80 %, with random velocities of 6 m/s in its
    plane and 1 m/s across: y~ lies triangles away, so that the first sweeps cut steps to the kept area and halve
    some."""
    x = (crumpled(system, 0.02).reshape(-1, 3) * [0.8, 0.8, 1.0]).ravel()
    x[system.fixed_dofs] = system.x0[system.fixed_dofs]
    velocity = (np.random.default_rng(8).standard_normal((system.vertex_count, 3)) * [6.0, 6.0, 1.0]).ravel()
    velocity[system.fixed_dofs] = 0.0
    return step_problem(system, x, velocity, dt)


def plans_of(system):
    return colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding), 3)


def test_no_two_vertices_of_a_colour_share_a_triangle_or_a_hinge():
    """What the sweep's parallel steps rely on: the hinges' wings are coupled, two triangles apart."""
    system = shell()
    colour_of = np.empty(system.vertex_count, dtype=int)
    for number, colour in enumerate(system.vertex_form().colouring()):
        colour_of[colour] = number
    for group in (system.elements, system.hinges):
        colours = colour_of[group]
        assert all(len(set(row)) == len(row) for row in colours.tolist())


@pytest.mark.parametrize("projection", ["clamp", "abs"])
@pytest.mark.parametrize("material", MEMBRANES)
def test_the_compiled_sweep_is_the_numpy_sweep(material, projection):
    system = constrained(material)
    problem, start = thrown(system)
    solver = VertexBlockDescent(spd_projection=projection)
    sweep, parts = system.vertex_form().sweep(), IncrementalParts.of(problem)
    assert sweep is not None and sweep.colliders[0].size == 1 and parts.damping_weight > 0.0
    # by the fourth sweep St. Venant-Kirchhoff's finite energy has let a triangle be squeezed to 6e-4 of its area, and
    # its corners' blocks have a condition of 5e4: LAPACK's solve in the numpy sweep and the compiled elimination part
    # at about 1e4 eps of the move there (4e-12 with abs, 2e-15 elsewhere)
    for y, swept, _ in agreeing_sweeps(solver, problem, start, plans_of(system), sweep, parts, 4, tolerance=1e-11):
        assert problem.value(swept) <= problem.value(y) * (1 + ENERGY_ROUNDOFF)
    np.testing.assert_array_equal(swept[system.fixed_dofs], start[system.fixed_dofs])
    normal = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    assert (swept - start)[3 * SLIDING:3 * SLIDING + 3] @ normal == pytest.approx(0.0, abs=1e-14)


def test_the_sweep_backtracks_and_cuts_steps_from_the_thrown_start():
    """The thrown St. Venant-Kirchhoff sheet: a Newton step of some vertex would collapse a triangle (cut to the kept
    area) and some raise E (halved), so the comparison above exercises both."""
    system = constrained("stvk")
    problem, start = thrown(system)
    cut, halved = cut_and_halved(problem, start, plans_of(system))
    assert cut > 0 and halved > 0


def test_one_thread_and_two_give_the_same_sweep_bit_for_bit():
    system = shell("stable_neo_hookean", model={"grid": {"resolution": [24, 24], "size": [1.0, 1.0]}}, pinned="top")
    problem, start = step_problem(system, crumpled(system, 0.005), np.zeros(system.dof_count), 1.0 / 60.0)
    plans = plans_of(system)
    assert max(plan.vertices.size for plan in plans) > shell_vbd_kernels.CHUNK, "a colour must span several chunks"
    solver, sweep, parts = VertexBlockDescent(), system.vertex_form().sweep(), IncrementalParts.of(problem)
    results = sweeps_by_thread_count(solver, start, plans, sweep, parts)
    assert np.array_equal(results[0], results[-1])


@pytest.mark.parametrize("material", ["neo_hookean", "stvk"])
def test_the_solver_takes_the_compiled_sweep_and_the_energy_never_increases(monkeypatch, material):
    system = constrained(material)
    problem, start = thrown(system)
    y, energies_seen = compiled_solve_energies(monkeypatch, VertexBlockDescent, problem, start, tolerance=1e-10,
                                               max_iterations=60)
    assert energies_seen.size > 10
    assert np.all(np.diff(energies_seen) <= ENERGY_ROUNDOFF * np.abs(energies_seen[:-1]))
    assert energies_seen[-1] < energies_seen[0]
    assert np.all(system.volume_ratios(y) > 0.0)


def test_vbd_reaches_newtons_backward_euler_step_of_a_hanging_shell():
    """Run to convergence, VBD's minimiser of the incremental potential is Newton's (the same step, two solvers)."""
    system = shell("stable_neo_hookean", 1.0e-2, pinned="top")
    problem, start = step_problem(system, system.x0, system.v0, 0.01)
    newton = solver_params(type="newton", tolerance=1e-12, max_iterations=50).build()
    reference, _ = newton.minimize(problem, start)
    vbd = solver_params(type="vbd", tolerance=1e-9, max_iterations=5000, chebyshev_rho=0.9).build()
    y, stats = vbd.minimize(problem, start)
    assert stats.converged
    moved = np.max(np.abs(reference - start))
    assert np.max(np.abs(y - reference)) < 1e-4 * moved


# -- 6. a part of an IMEX split -------------------------------------------------------------------------------------------
def test_a_part_with_the_hinges_alone_sweeps_its_own_terms():
    """The whole's sweep, built first, is not the part's: the part has no membrane energy and no gravity, and its
    blocks are the diagonal blocks of its own Hessian; the complement has the membrane and gravity but no hinges."""
    system = shell("stvk", 1.0e-2)
    x = crumpled(system)
    vertices = np.arange(system.vertex_count)
    whole = system.vertex_form().sweep()
    bending_part = system.with_terms(["bending"])
    rest_part = system.with_terms(["bending"], complement=True)
    assert bending_part.vertex_form().sweep() is not whole and bending_part.vertex_form().sweep().membrane == 0
    assert len(rest_part.vertex_form().sweep().hinges) == 0
    for part in (bending_part, rest_part):
        gradient, hessian = part.vertex_form().blocks(x, vertices, False)
        generic_gradient, generic_hessian = VertexForm(part).blocks(x, vertices, False)
        assert relative(gradient, generic_gradient) < 1e-12
        assert relative(hessian, generic_hessian) < 1e-12
    total, _ = system.vertex_form().blocks(x, vertices, False)
    np.testing.assert_allclose(bending_part.vertex_form().blocks(x, vertices, False)[0]
                               + rest_part.vertex_form().blocks(x, vertices, False)[0], total, atol=1e-12 * np.abs(total).max())


@pytest.mark.parametrize("mode", [1, 2])
def test_the_closed_form_3x3_projection_is_numpys_eigensystem(mode):
    """project_block_3 against eigh with the negative eigenvalues clamped or mirrored, on random symmetric matrices
    with one, two and three negative eigenvalues spread over four decades, repeated ones (the rotations' fallback), a
    rank-one PSD matrix (left as it is) and a diagonal one."""
    rng = np.random.default_rng(mode)
    change = (lambda w: np.maximum(w, 0.0)) if mode == 1 else np.abs
    copy, values, vectors = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    spectra = [rng.uniform(-1.0, 1.0, 3) * 10.0 ** rng.uniform(-2, 2, 3) for _ in range(60)]
    spectra += [np.array([-2.0, -2.0, 5.0]), np.array([-3.0, 1.0, 1.0]), np.array([-1.0, -1.0, -1.0]),
                np.array([0.0, 0.0, 4.0]), np.array([-1e-3, 2.0, 7.0]), np.array([-5.0, -1e-4, 3.0])]
    for number, spectrum in enumerate(spectra):
        basis = np.linalg.qr(rng.standard_normal((3, 3)))[0] if number != len(spectra) - 1 else np.eye(3)
        matrix = (basis * spectrum) @ basis.T
        matrix = 0.5 * (matrix + matrix.T)
        projected = matrix.copy()
        shell_terms.project_block_3(projected, mode, copy, values, vectors)
        w, v = np.linalg.eigh(matrix)
        np.testing.assert_allclose(projected, (v * change(w)) @ v.T, rtol=0.0, atol=1e-12 * np.abs(w).max())
        if spectrum.min() >= 0.0:
            assert np.array_equal(projected, matrix)
