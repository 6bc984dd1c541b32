"""Shells of the finite-element system against theory (docs/fem.md, "Shells"): finite-difference derivatives of every
membrane energy and of the discrete-shell hinges, invariance to rigid motions (turning the sheet over included), the
hinge energy of a fold of known angle, the membrane's plane-stress small-strain limit, the projection against numpy's
eigensystem, the area-keeping step, exact sensitivities in E, the grid source, and the refusals of bad shells."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import run_config_file

from simrun.experiment.config import load_experiment
from simrun.errors import ConfigError
from simrun.systems import SYSTEMS
from simrun.systems.fem import bending, linalg
from simrun.systems.fem.system import KEPT_VOLUME

MEMBRANES = ["stvk", "corotated", "neo_hookean", "stable_neo_hookean"]
YOUNG, POISSON, DENSITY, THICKNESS = 1.0e5, 0.3, 0.2, 1.0e-3
GRID = {"grid": {"resolution": [5, 4], "size": [1.0, 0.75]}}


def shell(model=GRID, material="stvk", bend=1.0e-3, **options):
    config = {"type": "fem", "model": model, "gravity": [0.0, 0.0, 0.0], "thickness": THICKNESS,
              "material": {"model": material, "youngs_modulus": YOUNG, "poisson_ratio": POISSON, "density": DENSITY},
              **({"bending": {"stiffness": bend}} if bend else {}), **options}
    return SYSTEMS["fem"].model_validate(config).build()


def crumpled(system, scale=0.05, seed=0):
    rng = np.random.default_rng(seed)
    return system.x0 + scale * rng.standard_normal(system.dof_count)


def rotation(seed=3):
    rng = np.random.default_rng(seed)
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# -- derivatives ------------------------------------------------------------------------------------------------------
def squeezed(system):
    """A crumpled sheet with one triangle's corner pushed to 3 % of its area (near collapse)."""
    x = crumpled(system, 0.01).reshape(-1, 3)
    a, b, c = system.elements[7]
    x[c] = x[a] + 0.97 * (x[b] - x[a]) / 2 + 0.03 * (x[c] - x[a] - (x[b] - x[a]) / 2)
    return x.ravel()


STATES = {"crumpled": crumpled, "stretched": lambda system: crumpled(system, 0.02) * 1.6, "squeezed": squeezed}


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize("material", MEMBRANES)
def test_gradient_and_hessian_equal_central_differences(material, state):
    """Membrane and hinges together, on a crumpled sheet, one stretched 1.6-fold and one with a triangle squeezed
    near collapse: dP/dx . d and H d against central differences of P and of the gradient (relative 1e-6), in two
    random directions."""
    system = shell(material=material)
    x = STATES[state](system)
    if state == "squeezed":
        assert system.volume_ratios(x).min() < 0.1
    hessian = system.pattern_matrix(system.hessian_data(x))
    step = 1e-6
    for seed in (1, 2):
        direction = np.random.default_rng(seed).standard_normal(system.dof_count)
        energy_change = (system.potential_energy(x + step * direction) - system.potential_energy(x - step * direction))
        assert energy_change / (2 * step) == pytest.approx(system.gradient(x) @ direction, rel=1e-6)
        gradient_change = (system.gradient(x + step * direction) - system.gradient(x - step * direction)) / (2 * step)
        np.testing.assert_allclose(gradient_change, hessian @ direction, atol=1e-6 * np.abs(hessian @ direction).max())


def test_hinge_derivatives_alone_equal_central_differences():
    """Bending without membrane stiffness' share: the hinge kernels' forces and blocks against differences of their
    energy, on a sheet folded well away from flat (angles up to about 1 rad)."""
    system = shell(bend=1.0)
    x = crumpled(system, scale=0.2, seed=4)
    hinges, stiffness, rest = system.hinges, system.hinge_stiffness, system.rest_angles
    forces = np.empty((len(hinges), 4, 3))
    bending.hinge_forces(x, hinges, stiffness, rest, forces)
    blocks = np.empty((len(hinges), 12, 12))
    bending.hinge_hessians(x, hinges, stiffness, rest, 0, blocks)
    step = 1e-6
    for h in range(len(hinges)):
        dofs = (3 * hinges[h][:, None] + np.arange(3)).ravel()
        for column, dof in enumerate(dofs):
            moved = [x.copy(), x.copy()]
            moved[0][dof] += step
            moved[1][dof] -= step
            energies = [bending.hinge_energies(y, hinges[h:h + 1], stiffness[h:h + 1], rest[h:h + 1])[0] for y in moved]
            assert (energies[0] - energies[1]) / (2 * step) == pytest.approx(forces[h].ravel()[column], rel=1e-5, abs=1e-9)
            pushed = [np.empty((1, 4, 3)), np.empty((1, 4, 3))]
            for y, out in zip(moved, pushed):
                bending.hinge_forces(y, hinges[h:h + 1], stiffness[h:h + 1], rest[h:h + 1], out)
            np.testing.assert_allclose((pushed[0] - pushed[1]).ravel() / (2 * step), blocks[h][:, column],
                                       atol=1e-5 * np.abs(blocks[h]).max())
        np.testing.assert_array_equal(blocks[h], blocks[h].T)


# -- invariance and closed forms --------------------------------------------------------------------------------------
@pytest.mark.parametrize("material", MEMBRANES)
def test_rigid_motions_cost_nothing_turning_over_included(material):
    """A rotation (also one that turns the sheet upside down) and a translation of the rest shape: no membrane or
    bending energy, no force."""
    system = shell(material=material)
    rest = system.rest
    scale = YOUNG * THICKNESS * 0.75
    for turn in (rotation(), np.diag([1.0, -1.0, -1.0])):
        moved = (rest @ turn.T + [0.3, -1.0, 2.0]).ravel()
        assert abs(system.elastic_energy(moved)) < 1e-12 * scale
        assert np.abs(system.gradient(moved)).max() < 1e-10 * scale


def fold(angle: float):
    """Two triangles (0, 1, 2) and (1, 0, 3) about the edge 0-1 along x, the second one turned by ``angle`` about it."""
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.8, 0.0], [0.6, -0.5, 0.0]])
    turned = points.copy()
    c, s = math.cos(angle), math.sin(angle)
    turned[3] = [0.6, -0.5 * c, -0.5 * s]
    return points, turned


@pytest.mark.parametrize("angle", [0.3, -0.3, 1.2, 2.5])
def test_a_fold_of_known_angle_has_the_discrete_shell_energy(tmp_path, angle):
    """E = k 3 |e|^2 / (A_1 + A_2) theta^2 for a flat rest hinge folded by theta (either way, and past a right
    angle), and zero energy at rest for a hinge whose rest shape is the folded one."""
    import meshio

    points, turned = fold(angle)
    cells = [("triangle", np.array([[0, 1, 2], [1, 0, 3]]))]
    meshio.write_points_cells(tmp_path / "flat.obj", points, cells)
    meshio.write_points_cells(tmp_path / "folded.obj", turned, cells)
    stiffness = 0.01
    flat = shell(model=str(tmp_path / "flat.obj"), bend=stiffness)
    areas = 0.5 * 0.8 + 0.5 * 0.5
    assert flat.bending_energy(turned.ravel()) == pytest.approx(stiffness * 3.0 / areas * angle ** 2, rel=1e-12)
    assert flat.bending_energy(points.ravel()) == 0.0
    folded = shell(model=str(tmp_path / "folded.obj"), bend=stiffness)
    assert folded.rest_angles[0] == pytest.approx(angle, rel=1e-12)
    assert folded.bending_energy(turned.ravel()) == pytest.approx(0.0, abs=1e-20)
    assert folded.bending_energy(points.ravel()) == pytest.approx(stiffness * 3.0 / areas * angle ** 2, rel=1e-12)


@pytest.mark.parametrize("material", MEMBRANES)
def test_uniaxial_stress_at_small_strain_is_plane_stress_elasticity(material):
    """A membrane stretched by eps along x and contracted by nu eps along y (uniaxial stress in plane stress) stores
    thickness x area x E eps^2 / 2, for every energy to O(eps): the plane-stress lambda and the stable neo-Hookean's
    re-parametrisation of d = 2."""
    system = shell(material=material, bend=0.0)
    eps = 1e-5
    stretched = system.rest * [1.0 + eps, 1.0 - POISSON * eps, 1.0]
    expected = THICKNESS * 0.75 * YOUNG * eps ** 2 / 2
    assert system.elastic_energy(stretched.ravel()) == pytest.approx(expected, rel=1e-4)
    # and the stress across it vanishes: no force along y on the free edges but at the corners' share
    sheared = system.rest * [1.0 + eps, 1.0, 1.0]
    assert system.elastic_energy(sheared.ravel()) > expected  # held at its width, the sheet is stiffer


def test_the_grid_is_the_cloths_grid():
    """{grid} gives the mass-spring cloth's vertices (row by row along x) and triangles, and its vertex names."""
    from simrun.systems.vertex.grids import GridModel

    system = shell(model={"grid": {"resolution": [4, 3], "size": [1.5, 1.0], "height": 0.2}})
    grid = GridModel(resolution=(4, 3), size=(1.5, 1.0), height=0.2).build()
    np.testing.assert_array_equal(system.rest, grid.vertices)
    np.testing.assert_array_equal(system.elements, grid.triangles)
    assert system.mesh.named_vertices["top_left"].tolist() == grid.named_vertices["top_left"].tolist()
    assert system.vertex_masses.sum() == pytest.approx(DENSITY * 1.5, rel=1e-14)
    assert len(system.hinges) == len(system.mesh.edges()) - 2 * (3 + 2)  # interior edges: all but the boundary's


# -- projection -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [6, 9, 12])
def test_dense_projection_equals_numpys_eigensystem(size):
    """project_dense (Cholesky test, then cyclic Jacobi) against numpy's eigh with the negative eigenvalues clamped to 0
    or mirrored, on random symmetric matrices with some negative eigenvalues and on PSD ones (left unchanged)."""
    rng = np.random.default_rng(size)
    scratch, vectors, values = np.empty((size, size)), np.empty((size, size)), np.empty(2 * size)
    for trial in range(20):
        basis, _ = np.linalg.qr(rng.standard_normal((size, size)))
        spectrum = rng.uniform(-1.0, 3.0, size) * 10.0 ** rng.uniform(-2, 2)
        if trial % 4 == 0:
            spectrum = np.abs(spectrum)
        matrix = (basis * spectrum) @ basis.T
        matrix = 0.5 * (matrix + matrix.T)
        for mode, change in ((1, lambda w: np.maximum(w, 0.0)), (2, np.abs)):
            projected = matrix.copy()
            linalg.project_dense(projected, size, mode, 1e-12, scratch, values, vectors)
            w, v = np.linalg.eigh(matrix)
            np.testing.assert_allclose(projected, (v * change(w)) @ v.T, atol=1e-12 * np.abs(w).max())
            if spectrum.min() > 0:
                assert np.array_equal(projected, matrix)


@pytest.mark.parametrize("material", MEMBRANES)
def test_projected_hessian_is_psd_and_exact_where_the_exact_one_is(material):
    """clamp and abs give PSD Hessians on a crumpled, compressed sheet; a sheet stretched uniformly keeps its exact
    (already PSD) membrane Hessian."""
    system = shell(material=material)
    x = 0.8 * crumpled(system, 0.05)
    for mode in ("clamp", "abs"):
        projected = system.pattern_matrix(system.hessian_data(x, mode)).toarray()
        lowest = np.linalg.eigvalsh(projected).min()
        assert lowest > -1e-9 * np.abs(projected).max()
    stretched = (system.rest * [1.1, 1.05, 1.0]).ravel()
    flat = shell(material=material, bend=0.0)
    np.testing.assert_array_equal(flat.hessian_data(stretched, "clamp"), flat.hessian_data(stretched))


# -- the area-keeping step ---------------------------------------------------------------------------------------------
def test_the_step_filter_keeps_a_tenth_of_every_triangles_area():
    """Along random directions long enough to flatten triangles, the step returned keeps every triangle at or above
    KEPT_VOLUME of its area at x, and one of them at it."""
    system = shell()
    rng = np.random.default_rng(7)
    x = crumpled(system, 0.02)
    cut = 0
    for _ in range(20):
        direction = rng.standard_normal(system.dof_count)
        t = system.max_step(x, direction)
        start, end = system.volume_ratios(x), system.volume_ratios(x + t * direction)
        assert np.all(end / start >= KEPT_VOLUME - 1e-9)
        if t < 1.0:
            cut += 1
            assert (end / start).min() == pytest.approx(KEPT_VOLUME, abs=1e-9)
    assert cut > 10


# -- calibration's exact sensitivity --------------------------------------------------------------------------------
def test_the_gradient_moves_linearly_in_youngs_modulus():
    """parameter_derivative of a shell: d(grad P)/dE equals the gradient's difference quotient between two moduli
    (exactly linear), the hinges unchanged."""
    system = shell(material="neo_hookean")
    config = {"type": "fem", "model": GRID, "gravity": [0.0, 0.0, 0.0], "thickness": THICKNESS,
              "material": {"model": "neo_hookean", "youngs_modulus": YOUNG * 1.5, "poisson_ratio": POISSON,
                           "density": DENSITY}, "bending": {"stiffness": 1.0e-3}}
    changed = SYSTEMS["fem"].model_validate(config).build()
    derivative = system.parameter_derivative(changed, 0.5 * YOUNG)
    x = crumpled(system)
    np.testing.assert_allclose(derivative.gradient(x), (changed.gradient(x) - system.gradient(x)) / (0.5 * YOUNG),
                               rtol=1e-9, atol=1e-12 * np.abs(system.gradient(x)).max() / YOUNG)


# -- bad input --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("change, message", [
    ({"thickness": None}, "system.thickness: grid 5x4 is a shell"),
    ({"material": {"model": "linear"}}, "system.material.model: linear elasticity is not rotation invariant"),
    ({"model": {"box": {"size": [1, 1, 1], "cells": [1, 1, 1]}}, "bending": {"stiffness": 1.0}, "thickness": None},
     "system.bending: the model is a tetrahedral solid"),
    ({"model": {"square": {"segments": 2}}, "bending": None}, "system.thickness: the model is a 2-D solid"),
    ({"thickness": 0.0}, "system.thickness"),
    ({"bending": {"model": "cubic_shell", "stiffness": 1.0}}, "discrete_shell"),
])
def test_bad_shells_are_one_line_naming_the_field(change, message):
    system = {"type": "fem", "model": GRID, "thickness": THICKNESS, "bending": {"stiffness": 1e-3},
              "material": {"model": "stvk"}}
    for key, value in change.items():
        if value is None:
            system.pop(key, None)
        elif key == "material":
            system[key] = {**system[key], **value}
        else:
            system[key] = value
    config = {"name": "bad", "system": system, "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        load_experiment(config)
    text = str(error.value)
    assert message in text and "\n" not in text


def test_a_non_manifold_edge_is_refused_for_bending_naming_its_vertices(tmp_path):
    """Three triangles on the edge 0-1: refused with bending, naming the edge; simulated without it."""
    import meshio

    points = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], dtype=float)
    meshio.write_points_cells(tmp_path / "fan.obj", points, [("triangle", np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))])
    config = {"name": "bad", "system": {"type": "fem", "model": str(tmp_path / "fan.obj"), "thickness": 1e-3,
                                        "material": {"model": "stvk"}, "bending": {"stiffness": 1e-3}},
              "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match=r"^system.bending: the edge between vertices 0 and 1 is shared by 3 triangles"):
        load_experiment(config)
    del config["system"]["bending"]
    load_experiment(config)


# -- runs ---------------------------------------------------------------------------------------------------------------
def test_a_shell_draped_on_a_sphere_with_ipc_never_penetrates(tmp_path):
    """A stable neo-Hookean shell with bending and self-contact falls onto a sphere on a plane, IPC contact with
    friction on its own triangles: every step keeps a positive distance to the colliders, and the sheet ends at rest
    on them (below its start, above the plane)."""
    config = {"name": "shell_ipc", "system": {
        "type": "fem", "model": {"grid": {"resolution": [8, 8], "size": [0.5, 0.5], "height": 0.05}},
        "material": {"model": "stable_neo_hookean", "youngs_modulus": 1.0e6, "poisson_ratio": 0.3, "density": 0.5},
        "thickness": 1.0e-3, "bending": {"stiffness": 1.0e-3},
        "contact": {"method": "ipc", "dhat": 1.0e-3, "self_contact": True, "friction": {"mu": 0.3, "epsv": 1.0e-3},
                    "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.0]},
                                  {"shape": "sphere", "center": [0.25, 0.25, -0.05], "radius": 0.08}]}},
        "integrators": ["backward_euler"], "solver": {"type": "newton", "tolerance": 1.0e-8, "max_iterations": 50},
        "duration": 0.4, "sweep": {"dt": [0.005]}}
    stored = run_config_file(config, tmp_path)
    assert stored.status.name.lower() == "ok"
    assert stored.series("contact_distance").min() > 0.0
    assert stored.series("active_contacts").max() > 0
    last = stored["frames"][-1]
    assert 0.0 < last[:, 2].min() and last[:, 2].max() < 0.05
