"""Every FEM material (systems/fem/materials/, parametrised over the registry MATERIALS) against finite differences of
its own energy, so that a new material is checked without editing this file:

1. a solid's stress P against psi, and its tangent A = dP/dF against P, in each dimension it models;
2. a shell's membrane form (3 x 2 F) the same way, where it is a shell's membrane;
3. vertex block descent's terms at each vertex (its gradient, its unprojected block, the energy's change when it alone
   moves) against the elements' energy;
4. its Lame re-parametrisation: the Hessian at rest is linear elasticity's with the same E and nu, where it says so;
5. what the registry says of it: its energy at an inverted element, a tangent PSD everywhere, the shells it refuses.

A central difference with step h errs by h^2 / 6 f''' plus round-off eps |f| / h: the tolerances below hold for
third derivatives up to 600 times the scale compared (the moduli, or the largest entry), deformations within 30 % of
the rest shape; ``test_a_wrong_stress_fails_the_check`` shows they are tight enough to see an error of 1e-4.
"""

from __future__ import annotations

import numpy as np
import pytest

from simrun.systems import SYSTEMS
from simrun.systems.fem import energies, membrane, projection
from simrun.systems.fem.materials import CODES, MATERIALS, energy_parameters, lame, shell_materials
from simrun.systems.fem.system import KEPT_VOLUME
from simrun.systems.fem.vertex import FemSweep, ShellSweep
from simrun.systems.vertex.errors import ModelError

STEP = 1e-4  # the central differences' step, in F (dimensionless) or in x (m, on unit-sized meshes)
EPS = np.finfo(float).eps
MU, LAM = 1.0, 2.0  # Pa: moduli of order 1, so that the scale of psi, P and A is theirs


def tolerance(scale: float) -> float:
    """The central difference's error bound at STEP for a quantity of size ``scale`` (the module docstring)."""
    return (100.0 * STEP ** 2 + 100.0 * EPS / STEP) * scale


def central_difference(function, x: np.ndarray) -> np.ndarray:
    """d function / dx at x by central differences of step STEP: shape function's + x's."""
    columns = []
    for k in range(x.size):
        step = np.zeros(x.size)
        step[k] = STEP
        columns.append((np.asarray(function((x.ravel() + step).reshape(x.shape)))
                        - np.asarray(function((x.ravel() - step).reshape(x.shape)))) / (2.0 * STEP))
    return np.moveaxis(np.array(columns), 0, -1).reshape(np.shape(function(x)) + x.shape)


def deformations(rows: int, columns: int) -> list[np.ndarray]:
    """A few F (rows x columns) within 30 % of a rotation of the rest shape, their volume (area) ratio above 0.5."""
    found = []
    rng = np.random.default_rng(7)
    while len(found) < 3:
        q, _ = np.linalg.qr(rng.standard_normal((rows, rows)))
        q[:, 0] *= np.sign(np.linalg.det(q))  # a rotation (Householder's Q of a 2 x 2 is always a reflection)
        F = q @ (np.eye(rows, columns) + 0.15 * rng.standard_normal((rows, columns)))
        if np.sqrt(np.linalg.det(F.T @ F)) > 0.5 and (rows != columns or np.linalg.det(F) > 0.5):
            found.append(np.ascontiguousarray(F))
    return found


def solid_terms(code: int, F: np.ndarray, mu: float = MU, lam: float = LAM) -> tuple[float, np.ndarray, np.ndarray]:
    """(psi, P, A) of a d x d F through energies.material_terms."""
    d = F.shape[0]
    P, A = np.empty((d, d)), np.empty((d * d, d * d))
    psi = energies.material_terms(code, np.ascontiguousarray(F), d, mu, lam, P, A, True,
                                  np.empty((energies.WORK_SLOTS, d, d)))
    return psi, P, A


def membrane_terms(code: int, F: np.ndarray, mu: float = MU, lam: float = LAM) -> tuple[float, np.ndarray, np.ndarray]:
    """(psi, P, A) of a 3 x 2 F through membrane.membrane_terms."""
    P, A = np.empty((3, 2)), np.empty((6, 6))
    psi = membrane.membrane_terms(code, np.ascontiguousarray(F), mu, lam, P, A, True, np.empty((4, 3, 3)))
    return psi, P, A


def solid_cases():
    return [pytest.param(name, d, id=f"{name}-{d}d") for name, material in MATERIALS.items()
            for d in material.solid_dims]


SHELLS = [name for name, material in MATERIALS.items() if material.shells]


def _check_derivatives(terms, code: int, F: np.ndarray) -> None:
    """P against psi and A against P, at F."""
    _, P, A = terms(code, F)
    size = F.size
    stress = central_difference(lambda G: terms(code, G)[0], F)
    assert np.max(np.abs(stress - P)) <= tolerance(MU + LAM + np.max(np.abs(P)))
    tangent = central_difference(lambda G: terms(code, G)[1], F).reshape(size, size)
    assert np.max(np.abs(tangent - A)) <= tolerance(MU + LAM + np.max(np.abs(A)))


# -- 1, 2: psi, P, A -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "d"), solid_cases())
def test_a_solids_stress_and_tangent_are_its_energys_derivatives(name, d):
    for F in deformations(d, d):
        _check_derivatives(solid_terms, CODES[name], F)


@pytest.mark.parametrize("name", SHELLS)
def test_a_membranes_stress_and_tangent_are_its_energys_derivatives(name):
    """A 3 x 2 F: the triangle turned out of its rest plane and stretched; A's columns are dP/dF_kl (2 k + l)."""
    for F in deformations(3, 2):
        _check_derivatives(membrane_terms, CODES[name], F)


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_a_wrong_stress_fails_the_check(name):
    """The tolerance sees a stress off by a relative 1e-4: the checks above can fail."""
    F = deformations(3, 3)[0]
    code = CODES[name]
    _, P, _ = solid_terms(code, F)
    stress = central_difference(lambda G: solid_terms(code, G)[0], F)
    assert np.max(np.abs(stress - P * (1.0 + 1e-4))) > tolerance(MU + LAM + np.max(np.abs(P)))


# -- 3: vertex block descent's terms ---------------------------------------------------------------------------------
def _system(name: str, kind: str):
    models = {"2d": {"square": {"segments": 2, "size": 1.0}},
              "3d": {"box": {"size": [1.0, 1.0, 1.0], "cells": [1, 1, 1]}},
              "shell": {"grid": {"resolution": [3, 3], "size": [1.0, 1.0]}}}
    config = {"type": "fem", "model": models[kind], "gravity": [0.0] * (2 if kind == "2d" else 3),
              "material": {"model": name, "youngs_modulus": 10.0, "poisson_ratio": 0.3}}
    if kind == "shell":
        config["thickness"] = 0.1
    system = SYSTEMS["fem"].model_validate(config).build()
    rng = np.random.default_rng(11)
    x = system.x0 + 0.05 * rng.standard_normal(system.dof_count)
    return system, x, (ShellSweep if kind == "shell" else FemSweep).of(system, KEPT_VOLUME)


def vertex_cases():
    cases = []
    for name, material in MATERIALS.items():
        if material.vbd:
            cases += [pytest.param(name, f"{d}d", id=f"{name}-{d}d") for d in material.solid_dims]
            cases += [pytest.param(name, "shell", id=f"{name}-shell")] if material.shells else []
    return cases


@pytest.mark.parametrize(("name", "kind"), vertex_cases())
def test_vertex_terms_are_the_element_energys(name, kind):
    """At every vertex i, the others held: dE/dx_i (E the elements' energy) by differences of E, the block by
    differences of that gradient (unprojected, it is the diagonal block of E's Hessian), and the energy's change when
    the vertex alone moves, exactly (to the sum's round-off)."""
    system, x, sweep = _system(name, kind)
    d = system.dim
    vertices = np.arange(system.vertex_count)
    gradient, hessian = sweep.blocks(x, vertices, False)
    scale = np.max(np.abs(hessian)) + np.max(np.abs(gradient))

    def moved(i, u):
        y = x.copy()
        y[d * i:d * i + d] += u
        return y

    for i in vertices:
        numeric = central_difference(lambda u: system.elastic_energy(moved(i, u)), np.zeros(d))
        assert np.max(np.abs(numeric - gradient[i])) <= tolerance(scale), i
        block = central_difference(lambda u: sweep.blocks(moved(i, u), np.array([i]), False)[0][0], np.zeros(d))
        assert np.max(np.abs(block - hessian[i])) <= tolerance(scale), i
    steps = 0.02 * np.random.default_rng(5).standard_normal((vertices.size, d))
    changes, _ = sweep.changes(x, vertices, steps)
    before = system.elastic_energy(x)
    for i in vertices:
        after = system.elastic_energy(moved(i, steps[i]))
        assert abs(changes[i] - (after - before)) <= 64 * EPS * (abs(before) + abs(after)), i


# -- 4: the Lame re-parametrisation -----------------------------------------------------------------------------------
def _rest_cases():
    return [pytest.param(name, d, id=f"{name}-{d}d") for name, material in MATERIALS.items()
            if material.linear_at_rest for d in material.solid_dims]


@pytest.mark.parametrize(("name", "d"), _rest_cases())
def test_the_hessian_at_rest_is_linear_elasticitys(name, d):
    """A(I) with the material's (mu, lambda) of E and nu equals linear elasticity's with the Lame parameters."""
    youngs, poisson = np.array([3.0]), np.array([0.3])
    mu, lam = energy_parameters(name, d, youngs, poisson)
    mu_linear, lam_linear = lame(youngs, poisson)
    _, _, A = solid_terms(CODES[name], np.eye(d), float(mu[0]), float(lam[0]))
    _, _, linear = solid_terms(CODES["linear"], np.eye(d), float(mu_linear[0]), float(lam_linear[0]))
    assert np.max(np.abs(A - linear)) <= 1e-12 * np.max(np.abs(linear))


@pytest.mark.parametrize("name", [name for name in SHELLS if MATERIALS[name].linear_at_rest])
def test_a_membranes_hessian_at_rest_is_plane_stress_linear_elasticitys(name):
    """The in-plane block of A at F = [I; 0] (rows 0 and 1 of F: A's first four rows and columns) equals 2-D linear
    elasticity's with plane stress lambda = E nu / (1 - nu^2)."""
    youngs, poisson = np.array([3.0]), np.array([0.3])
    mu, lam = energy_parameters(name, 2, youngs, poisson, shell=True)
    mu_linear = lame(youngs, poisson)[0]
    lam_linear = youngs * poisson / (1.0 - poisson ** 2)
    _, _, A = membrane_terms(CODES[name], np.eye(3, 2), float(mu[0]), float(lam[0]))
    _, _, linear = solid_terms(CODES["linear"], np.eye(2), float(mu_linear[0]), float(lam_linear[0]))
    assert np.max(np.abs(A[:4, :4] - linear)) <= 1e-12 * np.max(np.abs(linear))


# -- 5: what the registry says ----------------------------------------------------------------------------------------
def test_every_material_has_its_own_code():
    assert sorted(CODES.values()) == list(range(len(MATERIALS)))


@pytest.mark.parametrize(("name", "d"), solid_cases())
def test_an_inverted_element_is_as_the_registry_says(name, d):
    """psi at an inverted F (J = -0.5) is finite, with a finite stress, where the material is defined there, and
    infinite with a NaN stress where it is not."""
    F = np.diag([1.0] * (d - 1) + [-0.5])
    psi, P, _ = solid_terms(CODES[name], F)
    if MATERIALS[name].defined_where_inverted:
        assert np.isfinite(psi) and np.all(np.isfinite(P))
    else:
        assert psi == np.inf and np.all(np.isnan(P))


@pytest.mark.parametrize(("name", "d"), [case for case in solid_cases()
                                         if MATERIALS[case.values[0]].projection == "never_needed"])
def test_a_tangent_that_needs_no_projection_is_psd_everywhere(name, d):
    """Its tangent has no negative eigenvalue, inverted elements included, and the projection leaves it as it is."""
    for F in [*deformations(d, d), np.diag([1.0] * (d - 1) + [-0.5]), 3.0 * np.eye(d)]:
        _, _, A = solid_terms(CODES[name], F)
        assert np.linalg.eigvalsh(A).min() >= -1e-12 * np.abs(A).max()
        projected = A.copy()
        assert not projection.project_tangent(CODES[name], np.ascontiguousarray(F), d, MU, LAM, projected, 1,
                                              projection.projection_scratch(d))
        assert np.array_equal(projected, A)


@pytest.mark.parametrize("name", [name for name, material in MATERIALS.items() if not material.shells])
def test_a_shell_refuses_a_material_that_is_no_membrane(name):
    """The config's error gives the registry's reason and names every material a shell may take."""
    config = {"type": "fem", "model": {"grid": {"resolution": [3, 3], "size": [1.0, 1.0]}}, "thickness": 0.1,
              "material": {"model": name}}
    with pytest.raises((ModelError, ValueError)) as error:
        SYSTEMS["fem"].model_validate(config).build()
    message = str(error.value)
    assert MATERIALS[name].not_for_shells in message
    assert all(shell in message for shell in shell_materials()) and set(shell_materials()) == set(SHELLS)
