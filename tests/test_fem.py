"""The finite-element system against theory: finite-difference derivatives of every energy in 2-D and 3-D, rest and
rigid-motion invariance, closed-form energies of uniform deformations, the small-strain limit, the projection, the
inversion-free step, a bar's axial frequency and the refusals of bad meshes and materials (docs/fem.md)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

from simrun.experiment.config import load_experiment
from simrun.errors import ConfigError
from simrun.systems import SYSTEMS
from simrun.systems.fem import energies, projection
from simrun.systems.fem.materials import MATERIALS, lame

ENERGIES = sorted(MATERIALS)
YOUNG, POISSON, DENSITY = 2.0e4, 0.3, 1000.0
BOX = {"box": {"size": [0.3, 0.2, 0.1], "cells": [3, 2, 1]}}
SQUARE = {"square": {"segments": 3, "size": 0.3}}


def fem(model=BOX, material="neo_hookean", **options):
    config = {"type": "fem", "model": model, "gravity": [0.0] * (3 if "box" in model else 2),  # elastic forces alone
              "material": {"model": material, "youngs_modulus": YOUNG, "poisson_ratio": POISSON, "density": DENSITY},
              **options}
    return SYSTEMS["fem"].model_validate(config).build()


def deformed(system, scale: float, seed: int = 0) -> np.ndarray:
    """x0 moved by a random field of size ``scale`` times the body's extent (no element inverted for scale <= 0.05)."""
    rng = np.random.default_rng(seed)
    extent = float(np.max(np.ptp(system.rest, axis=0)))
    return system.x0 + scale * extent * rng.standard_normal(system.dof_count)


def rotation(dim: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q, r = np.linalg.qr(rng.standard_normal((dim, dim)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def psi(material: str, F: np.ndarray, mu: float, lam: float) -> float:
    """The energy densities of docs/fem.md written out in numpy, independently of the kernels (mu, lam: the Lame
    parameters of E and nu; the stable neo-Hookean's re-parametrised here)."""
    d = F.shape[0]
    J = np.linalg.det(F)
    identity = np.eye(d)
    if material == "linear":
        strain = 0.5 * (F + F.T) - identity
        return mu * np.sum(strain * strain) + 0.5 * lam * np.trace(strain) ** 2
    if material == "stvk":
        green = 0.5 * (F.T @ F - identity)
        return mu * np.sum(green * green) + 0.5 * lam * np.trace(green) ** 2
    if material == "neo_hookean":
        return 0.5 * mu * (np.sum(F * F) - d) - mu * math.log(J) + 0.5 * lam * math.log(J) ** 2
    if material == "corotated":
        u, _, vt = np.linalg.svd(F)
        R = u @ np.diag([1.0] * (d - 1) + [np.linalg.det(u @ vt)]) @ vt
        return mu * np.sum((F - R) ** 2) + 0.5 * lam * (J - 1.0) ** 2
    mu_s = mu * (d + 1) / d
    lam_s = lam + mu_s * (d * (d + 1) - 2) / (d + 1) ** 2
    alpha = 1.0 + mu_s * d / ((d + 1) * lam_s)
    invariant = np.sum(F * F)
    value = (0.5 * mu_s * (invariant - d) + 0.5 * lam_s * (J - alpha) ** 2 - 0.5 * mu_s * math.log(invariant + 1.0))
    return value - (0.5 * lam_s * (1.0 - alpha) ** 2 - 0.5 * mu_s * math.log(d + 1.0))


def fd_gradient(function, x, step):
    gradient = np.empty_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = step
        gradient[i] = (function(x + e) - function(x - e)) / (2 * step)
    return gradient


# -- derivatives ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", [BOX, SQUARE], ids=["3d", "2d"])
@pytest.mark.parametrize("material", ENERGIES)
@pytest.mark.parametrize("scale", [0.002, 0.05], ids=["near-rest", "large"])
def test_gradient_and_hessian_against_finite_differences(model, material, scale):
    """Central differences of the energy give the gradient, and of the gradient the Hessian, to the differences' own
    truncation and round-off (relative 1e-6 of the largest entry)."""
    system = fem(model, material)
    x = deformed(system, scale)
    step = 1e-6 * float(np.max(np.ptp(system.rest, axis=0)))
    gradient = system.gradient(x)
    numeric = fd_gradient(system.potential_energy, x, step)
    assert np.max(np.abs(gradient - numeric)) <= 1e-6 * np.max(np.abs(gradient))
    hessian = system.hessian(x).toarray()
    columns = np.column_stack([(system.gradient(x + step * e) - system.gradient(x - step * e)) / (2 * step)
                               for e in np.eye(system.dof_count)])
    assert np.max(np.abs(hessian - columns)) <= 1e-6 * np.max(np.abs(hessian))
    assert np.max(np.abs(hessian - hessian.T)) <= 1e-12 * np.max(np.abs(hessian))


@pytest.mark.parametrize("model", [BOX, SQUARE], ids=["3d", "2d"])
@pytest.mark.parametrize("material", ["neo_hookean", "stable_neo_hookean", "corotated"])
def test_derivatives_near_inversion(model, material):
    """One element squeezed to 5 % of its volume (still positive): the derivatives hold where the energies' curvature
    is largest."""
    system = fem(model, material)
    d = system.dim
    x = system.x0.copy().reshape(-1, d)
    element = system.elements[0]
    centre = x[element].mean(axis=0)
    x[element[0]] = centre + 0.05 * (x[element[0]] - centre) + 0.3 * (x[element[1]] - centre)
    x = x.ravel()
    assert 0 < system.volume_ratios(x)[0] < 0.3
    step = 1e-7 * float(np.max(np.ptp(system.rest, axis=0)))
    gradient = system.gradient(x)
    assert np.max(np.abs(gradient - fd_gradient(system.potential_energy, x, step))) <= 1e-5 * np.max(np.abs(gradient))
    hessian = system.hessian(x).toarray()
    columns = np.column_stack([(system.gradient(x + step * e) - system.gradient(x - step * e)) / (2 * step)
                               for e in np.eye(system.dof_count)])
    assert np.max(np.abs(hessian - columns)) <= 1e-5 * np.max(np.abs(hessian))


@pytest.mark.parametrize("model", [BOX, SQUARE], ids=["3d", "2d"])
@pytest.mark.parametrize("material", ENERGIES)
@pytest.mark.parametrize("mode", ["clamp", "abs"])
def test_projected_hessians_are_psd_and_exact_where_the_exact_one_is(model, material, mode):
    """Each element's block is projected: the sum is PSD at a large deformation, and at rest (where every energy's
    Hessian is linear elasticity's, PSD) the projection changes nothing."""
    system = fem(model, material)
    x = deformed(system, 0.08)
    projected = system.hessian(x, project_spd=mode).toarray()
    lowest = scipy.linalg.eigvalsh(projected)[0]
    assert lowest >= -1e-10 * np.max(np.abs(projected))
    at_rest = system.hessian(system.x0).toarray()
    assert np.array_equal(system.hessian(system.x0, project_spd=mode).toarray(), at_rest) or np.allclose(
        system.hessian(system.x0, project_spd=mode).toarray(), at_rest, rtol=0, atol=1e-10 * np.max(np.abs(at_rest)))


def test_element_projection_leaves_a_psd_tangent_alone_and_fixes_an_indefinite_one():
    """A = d^2 psi / dF^2 of a compressed StVK element is indefinite; clamp sets its negative eigenvalues to 0
    and keeps the eigenvectors, abs mirrors them."""
    d = 3
    F = np.diag([0.4, 1.0, 1.0]) + 0.05
    A = tangent(energies.STVK, F, 3.0, 2.0)
    values, vectors = np.linalg.eigh(A)
    assert values[0] < 0
    for mode, expected in ((1, np.maximum(values, 0)), (2, np.abs(values))):
        projected = A.copy()
        assert projection.project_tangent(energies.STVK, F, d, 3.0, 2.0, projected, mode, projection.projection_scratch(d))
        assert np.allclose(projected, (vectors * expected) @ vectors.T, atol=1e-12 * np.abs(values).max())


def tangent(model: int, F: np.ndarray, mu: float, lam: float) -> np.ndarray:
    d = F.shape[0]
    P, A = np.empty((d, d)), np.empty((d * d, d * d))
    energies.material_terms(model, np.ascontiguousarray(F), d, mu, lam, P, A, True, np.empty((energies.WORK_SLOTS, d, d)))
    return A


def deformations(d: int, seed: int = 7) -> list[np.ndarray]:
    """Deformation gradients that test an SVD: rest, rotations, random large ones, equal and nearly equal singular
    values (the flip quotients' 0/0), near-flat elements and inverted ones (det F < 0)."""
    generator = np.random.default_rng(seed)
    turn = scipy.linalg.expm(np.triu(generator.standard_normal((d, d)), 1) - np.triu(generator.standard_normal((d, d)), 1).T)
    turn = turn if np.linalg.det(turn) > 0 else -turn if d == 3 else turn[::-1]
    cases = [np.eye(d), turn, turn @ np.diag([1.3] * d), turn @ np.diag([1.2, 1.2 + 1e-9] + [0.7] * (d - 2)),
             np.diag([1.0, 1e-7] + [1.0] * (d - 2)), np.diag([-0.3] + [1.1] * (d - 1)) @ turn]
    cases += [np.eye(d) + 0.4 * generator.standard_normal((d, d)) for _ in range(40)]
    cases += [np.eye(d) + 0.01 * generator.standard_normal((d, d)) for _ in range(10)]
    return cases


ANALYTIC = {"corotated": energies.COROTATED, "stvk": energies.STVK, "neo_hookean": energies.NEO_HOOKEAN,
            "stable_neo_hookean": energies.STABLE_NEO_HOOKEAN}


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("material", sorted(ANALYTIC))
@pytest.mark.parametrize("mode", [1, 2], ids=["clamp", "abs"])
def test_the_analytic_projection_equals_the_numerical_one(d, material, mode):
    """The projection from the analytic eigensystem (signed SVD, the Hessian in the singular values, closed-form flip
    and twist eigenvalues) equals numpy's eigh of A with its eigenvalues clamped or mirrored, to 1e-8 of |A|, for
    every deformation above; elements where it is PSD are left bit for bit."""
    model, (mu, lam) = ANALYTIC[material], lame(YOUNG, POISSON)
    scratch = projection.projection_scratch(d)
    projected_any = False
    for F in deformations(d):
        if material == "neo_hookean" and np.linalg.det(F) <= 0.0:
            continue  # undefined there
        A = tangent(model, F, mu, lam)
        values, vectors = np.linalg.eigh(0.5 * (A + A.T))
        expected = (vectors * (np.maximum(values, 0.0) if mode == 1 else np.abs(values))) @ vectors.T
        projected = A.copy()
        changed = projection.project_tangent(model, np.ascontiguousarray(F), d, mu, lam, projected, mode, scratch)
        scale = np.max(np.abs(A))
        assert np.max(np.abs(projected - expected)) <= 1e-8 * scale, F
        assert changed == (values[0] < -1e-12 * np.max(np.abs(values)))
        assert changed or np.array_equal(projected, A)
        projected_any |= changed
    assert projected_any


# -- invariance, uniform deformations, small strain -------------------------------------------------------------------
@pytest.mark.parametrize("model", [BOX, SQUARE], ids=["3d", "2d"])
@pytest.mark.parametrize("material", sorted(set(ENERGIES) - {"linear"}))
def test_rest_and_rigid_motions_have_zero_energy_and_force(model, material):
    """psi(R) = 0 and P(R) = 0 for every rotation R, so a rigidly moved body stores nothing and feels no force (the
    linear energy is not rotation invariant: left out)."""
    system = fem(model, material)
    d = system.dim
    rest = system.rest
    moved = (rest @ rotation(d).T + np.arange(1, d + 1)).ravel()
    scale = YOUNG * float(np.sum(system.volumes))
    for x in (system.x0, moved):
        assert abs(system.elastic_energy(x)) <= 1e-12 * scale
        assert np.max(np.abs(system.gradient(x))) <= 1e-11 * YOUNG * float(np.max(np.ptp(rest, axis=0))) ** (d - 1)


@pytest.mark.parametrize("material", ENERGIES)
@pytest.mark.parametrize("deformation", ["stretch", "shear", "mixed"])
def test_uniform_deformation_energy_is_volume_times_psi(material, deformation):
    """x = F X for every vertex: every element has that F, so the energy is the box's volume times psi(F) (written out
    in numpy above, independently of the kernels) to 1e-12."""
    F = {"stretch": np.diag([1.3, 1.0, 1.0]), "shear": np.array([[1.0, 0.4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
         "mixed": np.array([[1.1, 0.2, -0.1], [0.05, 0.9, 0.15], [0.0, -0.1, 1.2]])}[deformation]
    system = fem(BOX, material)
    x = (system.rest @ F.T).ravel()
    mu, lam = lame(YOUNG, POISSON)
    volume = 0.3 * 0.2 * 0.1
    expected = volume * psi(material, F, mu, lam)
    assert system.elastic_energy(x) == pytest.approx(expected, rel=1e-12)
    assert np.all(np.isclose(system.volume_ratios(x), np.linalg.det(F), rtol=1e-13))


@pytest.mark.parametrize("material", ENERGIES)
def test_uniform_deformation_energy_in_2d(material):
    F = np.array([[1.2, 0.3], [-0.1, 0.8]])
    system = fem(SQUARE, material)
    x = (system.rest @ F.T).ravel()
    mu, lam = lame(YOUNG, POISSON)
    assert system.elastic_energy(x) == pytest.approx(0.09 * psi(material, F, mu, lam), rel=1e-12)


@pytest.mark.parametrize("model", [BOX, SQUARE], ids=["3d", "2d"])
@pytest.mark.parametrize("material", ENERGIES)
def test_small_strain_limit_is_linear_elasticity(model, material):
    """At rest every energy's Hessian equals linear elasticity's with the same E and nu, to 1e-10 (the stable
    neo-Hookean through its Lame re-parametrisation)."""
    linear = fem(model, "linear").hessian(fem(model, "linear").x0).toarray()
    system = fem(model, material)
    assert np.max(np.abs(system.hessian(system.x0).toarray() - linear)) <= 1e-10 * np.max(np.abs(linear))


def test_the_box_is_cut_into_conforming_tets():
    """cells[0] x cells[1] x cells[2] cubes, six positive tets each, filling the box exactly; every interior face
    shared by two tets (a conforming mesh: the boundary is the box's surface, 2 triangles per square)."""
    system = fem()
    assert system.elements.shape == (3 * 2 * 1 * 6, 4)
    assert np.all(system.volumes > 0) and np.sum(system.volumes) == pytest.approx(0.3 * 0.2 * 0.1, rel=1e-14)
    faces = system.mesh.boundary_faces()
    assert len(faces) == 2 * 2 * (3 * 2 + 3 * 1 + 2 * 1)
    normals = np.cross(system.rest[faces[:, 1]] - system.rest[faces[:, 0]], system.rest[faces[:, 2]] - system.rest[faces[:, 0]])
    outward = np.einsum("ij,ij->i", normals, system.rest[faces].mean(axis=1) - system.rest.mean(axis=0))
    assert np.all(outward > 0)


def test_lumped_mass_is_density_times_volume():
    system = fem()
    assert system.vertex_masses.sum() == pytest.approx(DENSITY * 0.3 * 0.2 * 0.1, rel=1e-14)
    equal = fem(mass={"total": 2.0, "by": "equal"})
    assert np.allclose(equal.vertex_masses, 2.0 / equal.vertex_count)


# -- the inversion-free step ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", [BOX, SQUARE], ids=["3d", "2d"])
def test_the_step_filter_keeps_a_tenth_of_every_volume(model):
    """max_step along a direction that would turn elements inside out stops where the first element keeps exactly
    10 % of its volume at the start, and no element is below that there."""
    system = fem(model)
    rng = np.random.default_rng(5)
    x = deformed(system, 0.01)
    direction = 0.5 * float(np.max(np.ptp(system.rest, axis=0))) * rng.standard_normal(system.dof_count)
    fraction = system.max_step(x, direction)
    assert 0 < fraction < 1
    start = system.volume_ratios(x)
    end = system.volume_ratios(x + fraction * direction) / start
    assert end.min() == pytest.approx(kernels_fraction(), abs=1e-9)
    assert np.all(end >= kernels_fraction() - 1e-9)
    assert system.max_step(x, 1e-6 * direction) == 1.0


def kernels_fraction() -> float:
    from simrun.systems.fem.system import KEPT_VOLUME

    return KEPT_VOLUME


# -- a bar's axial vibration ------------------------------------------------------------------------------------------
def test_a_fixed_free_bar_vibrates_axially_at_its_first_mode():
    """nu = 0, one end pinned: the first axial mode of the continuum is f = sqrt(E / rho) / (4 L); the lumped FE model's
    lowest axial eigenfrequency (K_rest v = w^2 M v) with 20 elements along the bar is within 2 % of it."""
    length, young, density = 1.0, 1.0e5, 1000.0
    system = SYSTEMS["fem"].model_validate({
        "type": "fem", "model": {"box": {"size": [length, 0.05, 0.05], "cells": [20, 1, 1]}}, "gravity": [0, 0, 0],
        "material": {"model": "stable_neo_hookean", "youngs_modulus": young, "poisson_ratio": 0.0, "density": density},
        "pinned": "left"}).build()
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    mass = system.mass[free]
    values, vectors = scipy.linalg.eigh(system.projective_form().rest_stiffness().toarray()[np.ix_(free, free)], np.diag(mass))
    # a mode's share of kinetic energy in x: the axial modes' is ~1, the bending and torsion modes' ~0
    weighted = mass[:, None] * vectors ** 2
    axial_share = weighted[free % 3 == 0].sum(axis=0) / weighted.sum(axis=0)
    first_axial = int(np.flatnonzero(axial_share > 0.9)[0])
    frequency = math.sqrt(values[first_axial]) / (2 * math.pi)
    assert frequency == pytest.approx(math.sqrt(young / density) / (4 * length), rel=0.02)


# -- bad input --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("change, message", [
    ({"material": {"poisson_ratio": 0.5}}, "system.material.poisson_ratio"),
    ({"material": {"poisson_ratio": -1.0}}, "system.material.poisson_ratio"),
    ({"material": {"youngs_modulus": 0.0}}, "system.material.youngs_modulus"),
    ({"material": {"density": -1.0}}, "system.material.density"),
    ({"material": {"model": "ogden"}}, "stable_neo_hookean"),
    ({"damping": [{"model": "spring", "coefficient": 0.1}]}, "rayleigh"),
    ({"pinned": "top_left"}, "no vertex set 'top_left'"),
    ({"mass": {"matrix": "consistent", "per_vertex": 1.0}}, "takes a total"),
    ({"model": {"box": {"size": [1, 1, 1], "cells": [1, 1, 0]}}}, "cells >= 1"),
])
def test_bad_input_is_one_line_naming_the_field(change, message):
    system = {"type": "fem", "model": BOX}
    for key, value in change.items():
        system[key] = {**system.get(key, {}), **value} if isinstance(value, dict) and key == "material" else value
    config = {"name": "bad", "system": system, "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        load_experiment(config)
    text = str(error.value)
    assert message in text and "\n" not in text


def test_an_inverted_start_is_refused_naming_the_element(tmp_path):
    """A start state (initial.file) with one vertex pushed through the opposite edge of its triangles."""
    rest = fem(SQUARE).rest.copy()
    rest[5] = [0.2, 0.2]  # vertex 5 of the 3 x 3 square (-0.05, 0.05): across its neighbours
    np.savez(tmp_path / "start.npz", vertices=rest)
    config = {"name": "bad", "system": {"type": "fem", "model": SQUARE, "initial": {"file": str(tmp_path / "start.npz")}},
              "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match=r"system.initial: element \d+ \(vertices .*\) is inverted in the start state"):
        load_experiment(config)


def test_a_mesh_file_with_mixed_orientation_or_flat_elements_is_refused(tmp_path):
    import meshio

    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    for name, cells, message in (("mixed", [[0, 1, 2, 3], [1, 2, 3, 4], [1, 0, 2, 3]], "element 2 .*inverted at rest"),
                                 ("flat", [[0, 1, 2, 3], [0, 1, 2, 2]], "element 1 .*zero volume"),
                                 ("surface", None, "no tetra or triangle cells")):
        path = tmp_path / f"{name}.vtu"
        meshio.write(path, meshio.Mesh(points, [("tetra", np.array(cells))] if cells else [("line", np.array([[0, 1]]))]))
        config = {"name": "bad", "system": {"type": "fem", "model": str(path)}, "integrators": ["backward_euler"],
                  "sweep": {"dt": [0.01]}}
        with pytest.raises(ConfigError, match=message):
            load_experiment(config)


def test_a_mesh_file_keeps_its_vertex_order_and_turns_a_clockwise_2d_mesh(tmp_path):
    import meshio

    points = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    clockwise = np.array([[0, 2, 1], [0, 3, 2]])
    path = tmp_path / "square.vtk"
    meshio.write(path, meshio.Mesh(points, [("triangle", clockwise)]))
    system = SYSTEMS["fem"].model_validate({"type": "fem", "model": str(path)}).build()
    assert system.dim == 2 and np.array_equal(system.rest, points[:, :2])
    assert np.all(system.mesh.rest_volumes() > 0) and np.sum(system.volumes) == pytest.approx(1.0)


def test_the_fem_square_is_the_course_code_s_triangulation():
    """solid-sim-tutorial 6_inv_free/square_mesh.py: vertex i (n + 1) + j at (-L/2 + i h, -L/2 + j h), and the cell
    (i, j)'s two triangles along the diagonal its parity picks, in the course code's order."""
    system = fem({"square": {"segments": 2, "size": 1.0}}, "neo_hookean")
    assert np.allclose(system.rest[1], [-0.5, 0.0]) and np.allclose(system.rest[3], [0.0, -0.5])
    assert system.elements.tolist() == [[0, 3, 4], [0, 4, 1], [1, 4, 2], [4, 5, 2],
                                        [3, 6, 4], [6, 7, 4], [4, 7, 8], [4, 8, 5]]


def test_rayleigh_damping_is_alpha_m_plus_beta_k_rest():
    system = fem(damping=[{"model": "rayleigh", "alpha": 0.3, "beta": 0.02}])
    expected = 0.3 * np.diag(system.mass) + 0.02 * system.projective_form().rest_stiffness().toarray()
    assert np.allclose(system.damping_matrix(deformed(system, 0.05)).toarray(), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_results_do_not_depend_on_the_thread_count():
    """Each element writes its own rows; the scatters run in element order: the same bits with 1 thread and with all."""
    import numba

    system = fem(BOX, "stable_neo_hookean")
    x = deformed(system, 0.05)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = (system.elastic_energy(x), system.gradient(x), system.hessian_data(x, True))
    finally:
        numba.set_num_threads(threads)
    many = (system.elastic_energy(x), system.gradient(x), system.hessian_data(x, True))
    assert one[0] == many[0] and np.array_equal(one[1], many[1]) and np.array_equal(one[2], many[2])


def test_sparse_pattern_is_the_elements():
    """The Hessian's pattern holds exactly the pairs of dofs that share an element."""
    system = fem(SQUARE)
    pattern = system.hessian_pattern.toarray() != 0
    expected = np.zeros_like(pattern)
    for element in system.elements:
        dofs = (2 * element[:, None] + np.arange(2)).ravel()
        expected[np.ix_(dofs, dofs)] = True
    assert np.array_equal(pattern, expected)
    assert scipy.sparse.issparse(system.hessian(system.x0))


# -- the course code's own numbers ------------------------------------------------------------------------------------
COURSE = np.load(Path(__file__).with_name("data") / "course_fem_square.npz")


def course_square(**options):
    return SYSTEMS["fem"].model_validate({
        "type": "fem", "model": {"square": {"segments": 4, "size": 1.0}}, "mass": {"total": 1000.0, "by": "equal"},
        "material": {"model": "neo_hookean", "youngs_modulus": 1.0e5, "poisson_ratio": 0.4, "density": 1000.0},
        **options}).build()


def test_the_course_code_s_neo_hookean_energy_and_gradient():
    """solid-sim-tutorial 6_inv_free's NeoHookeanEnergy.val and .grad at a deformed state of its own square
    (tests/data/make_course_fem_square.py made the numbers): the same to 1e-12 relative."""
    system = course_square()
    assert np.array_equal(system.rest, COURSE["rest"]) and np.array_equal(system.elements, COURSE["elements"])
    assert np.allclose(system.vertex_masses, COURSE["masses"], rtol=1e-15)
    x = COURSE["deformed"].ravel()
    assert system.elastic_energy(x) == pytest.approx(float(COURSE["energy"]), rel=1e-12)
    gradient = system.gradient(x) + system._gravity_force  # the elements' part alone
    assert np.max(np.abs(gradient - COURSE["gradient"].ravel())) <= 1e-12 * np.max(np.abs(COURSE["gradient"]))


def test_the_course_code_s_backward_euler_trajectory():
    """20 backward Euler steps of h = 0.01 s from the square stretched 1.4x, under gravity: the course code's
    step_forward (projected Newton, its filtered line search, tolerance 1e-10 m/s) and simrun's backward Euler with
    Newton to 1e-11 reach the same positions at every step to 1e-8 m."""
    from simrun.integrators import INTEGRATORS, State
    from simrun.solvers import solver_params

    system = course_square(initial={"scale": [float(COURSE["stretch"]), 1.0]})
    assert np.allclose(system.x0, COURSE["trajectory"][0].ravel(), rtol=0, atol=1e-15)
    integrator = INTEGRATORS["backward_euler"]()
    solver = solver_params(type="projected_newton", tolerance=1e-11).build()
    state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    for expected in COURSE["trajectory"][1:]:
        state, stats = integrator.step(system, state, float(COURSE["dt"]), solver)
        assert stats.converged
        assert np.max(np.abs(state.x - expected.ravel())) <= 1e-8


# -- tetrahedralize ---------------------------------------------------------------------------------------------------
def test_a_closed_surface_is_filled_with_tets_once_and_read_from_the_cache(tmp_path, monkeypatch):
    """fTetWild fills an icosphere of radius 0.1 m: the tets' volume is the surface's enclosed volume to 1 % (its
    envelope is 1e-3 of the box's diagonal), every tet is positive, and the second build reads the cached mesh, the
    same arrays (fTetWild itself gives a different mesh at every call)."""
    import trimesh

    monkeypatch.setenv("SIMRUN_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    ball.export(tmp_path / "ball.obj")
    config = {"type": "fem", "model": {"tetrahedralize": {"surface": "ball.obj", "edge_length": 0.04}}}
    first = SYSTEMS["fem"].model_validate(config)
    system = first.build()
    assert system.dim == 3 and np.all(system.mesh.rest_volumes() > 0)
    assert float(np.sum(system.volumes)) == pytest.approx(ball.volume, rel=0.01)
    again = SYSTEMS["fem"].model_validate(config).build()
    assert np.array_equal(again.rest, system.rest) and np.array_equal(again.elements, system.elements)
    assert set(first.input_files()) == {"model.tetrahedralize.surface", "model.tetrahedralize.tets"}
    assert list((tmp_path / "cache" / "tetrahedralize").glob("ball-*.npz")) and not list(tmp_path.glob("*.stl"))


def test_an_open_surface_is_refused_naming_an_edge(tmp_path, monkeypatch):
    import trimesh

    monkeypatch.setenv("SIMRUN_CACHE", str(tmp_path / "cache"))
    ball = trimesh.creation.icosphere(subdivisions=1)
    trimesh.Trimesh(ball.vertices, ball.faces[:-1], process=False).export(tmp_path / "open.obj")
    config = {"name": "bad", "system": {"type": "fem", "model": {"tetrahedralize": {"surface": str(tmp_path / "open.obj"),
                                                                                    "edge_length": 0.2}}},
              "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match=r"the surface is not closed: 3 edges .*vertices \[\d+, \d+\]"):
        load_experiment(config)


# -- calibration's derivatives ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("material", ENERGIES)
@pytest.mark.parametrize("key, value", [("material.youngs_modulus", YOUNG), ("damping.0.beta", 0.02),
                                        ("damping.0.alpha", 0.3), ("material.regions.0.youngs_modulus", 3.0 * YOUNG)])
def test_parameter_derivatives_are_exact(material, key, value):
    """d(grad P)/dtheta and dD/dtheta for Young's modulus (everywhere, or in a region), and Rayleigh's beta and alpha:
    the system built at theta + 1 minus the system at theta, exactly (both are linear in theta)."""
    config = {"type": "fem", "model": BOX, "gravity": [0.0, 0.0, -9.81],
              "material": {"model": material, "youngs_modulus": YOUNG, "poisson_ratio": POISSON, "density": DENSITY,
                           "regions": [{"box": [[0.0, 0.0, 0.0], [0.15, 0.2, 0.1]], "youngs_modulus": 3.0 * YOUNG}]},
              "damping": [{"model": "rayleigh", "alpha": 0.3, "beta": 0.02}]}

    def built(theta):
        mapping = {**config, "material": {**config["material"], "regions": [dict(config["material"]["regions"][0])]},
                   "damping": [dict(config["damping"][0])]}
        parts = key.split(".")
        target = mapping
        for part in parts[:-1]:
            target = target[int(part)] if part.isdigit() else target[part]
        target[parts[-1]] = theta
        return SYSTEMS["fem"].model_validate(mapping).build()

    system, changed = built(value), built(value * 1.5)
    derivative = system.parameter_derivative(changed, value * 0.5)
    assert derivative is not None
    x = deformed(system, 0.03)
    expected = (changed.gradient(x) - system.gradient(x)) / (value * 0.5)
    assert np.allclose(derivative.gradient(x), expected, rtol=0, atol=1e-9 * np.max(np.abs(system.gradient(x))))
    damping = (changed.damping_matrix(x) - system.damping_matrix(x)).toarray() / (value * 0.5)
    got = np.zeros_like(damping) if derivative.damping is None else derivative.damping(x).toarray()
    assert np.allclose(got, damping, rtol=0, atol=1e-9 * np.max(np.abs(system.damping_matrix(x).toarray())))
