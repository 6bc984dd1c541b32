"""The consistent mass matrix of the finite-element system (docs/fem.md, "Mass and damping") against theory: its
element blocks in closed form, its rows against the lumped shares, the exact kinetic energy of a rigid rotation,
the bounds that consistent and lumped masses put on a bar's axial frequency, energy conservation by the implicit
midpoint rule, explicit methods through M^-1 f, and the refusals of methods that take M as a diagonal."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

from simrun.experiment.config import load_experiment
from simrun.errors import ConfigError
from simrun.systems import SYSTEMS

BOX = {"box": {"size": [0.4, 0.2, 0.1], "cells": [4, 2, 1]}}
DENSITY = 1000.0


def fem(mass="consistent", model=BOX, **options):
    config = {"type": "fem", "model": model, "gravity": [0.0] * (2 if "square" in model else 3),
              "material": {"model": "linear", "youngs_modulus": 1.0e5, "poisson_ratio": 0.3, "density": DENSITY},
              "mass": mass}
    config.update(options)
    return SYSTEMS["fem"].model_validate(config).build()


def mass_matrix(system) -> np.ndarray:
    matrix = scipy.sparse.diags_array(system.mass)
    if system.mass_correction is not None:
        matrix = matrix + system.mass_correction
    return matrix.toarray()


@pytest.mark.parametrize("model", [BOX, {"square": {"segments": 3, "size": 0.3}},
                                   {"grid": {"resolution": [4, 3], "size": [0.3, 0.2]}}])
def test_the_blocks_are_the_shape_functions_integrals_and_the_rows_the_lumped_shares(model):
    """A tet's block is m_e/20 (1 + delta_ab) I, a triangle's m_e/12 (1 + delta_ab) I; every row of M sums to the
    lumped mass of its dof, and M is symmetric positive definite."""
    options = {"thickness": 1e-3, "material": {"model": "stvk", "density": DENSITY}} if "grid" in model else {}
    system = fem(model=model, **options)
    lumped = fem(mass="lumped", model=model, **options)
    matrix = mass_matrix(system)
    np.testing.assert_allclose(matrix.sum(axis=1), lumped.mass, rtol=1e-13)
    np.testing.assert_array_equal(system.mass, lumped.mass)
    assert np.allclose(matrix, matrix.T, rtol=0, atol=1e-15 * matrix.max())
    assert np.linalg.eigvalsh(matrix).min() > 0
    # the couplings: vertices a != b of element 0 get m_e / (k (k + 1)) from every element that holds both, and no
    # coupling across components; the diagonal is twice that share, which the lumped m_e / k absorbs
    element, d = system.elements[0], system.dim
    k = len(element)
    masses = DENSITY * system.mesh.rest_volumes()
    for a in range(k):
        for b in range(k):
            if a != b:
                shared = [e for e, vertices in enumerate(system.elements) if element[a] in vertices and element[b] in vertices]
                assert matrix[d * element[a], d * element[b]] == pytest.approx(masses[shared].sum() / (k * (k + 1)),
                                                                              rel=1e-12)
                assert matrix[d * element[a], d * element[b] + 1] == 0.0


def test_a_rigid_rotation_has_the_exact_kinetic_energy():
    """v = w x (X - c) is linear, so P1 elements hold it exactly and the consistent mass integrates rho |v|^2
    exactly: 1/2 w^T I w with the box's moment of inertia; the lumped mass overestimates it."""
    system, lumped = fem(), fem(mass="lumped")
    size = np.array([0.4, 0.2, 0.1])
    mass = DENSITY * np.prod(size)
    inertia = mass / 12.0 * np.diag([size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2])
    spin = np.array([0.3, -1.2, 2.0])
    v = np.cross(spin, system.rest - size / 2).ravel()
    exact = 0.5 * spin @ inertia @ spin
    assert system.kinetic_energy(v) == pytest.approx(exact, rel=1e-12)
    assert lumped.kinetic_energy(v) > 1.05 * exact
    # and the momenta: linear momentum 0 about the centroid, angular momentum I w
    np.testing.assert_allclose(system.momentum(v), 0.0, atol=1e-12 * mass)
    centred = (system.rest - size / 2).ravel()
    np.testing.assert_allclose(system.angular_momentum(centred, v), inertia @ spin, rtol=1e-12)


def test_consistent_and_lumped_masses_bracket_the_bars_axial_frequency():
    """Consistent mass over-, lumped mass under-estimates a fixed-free bar's first axial frequency sqrt(E/rho)/(4L)
    (the Rayleigh quotient with the exact and the lumped kinetic energy), both within 0.1 % at 20 elements."""
    frequencies = {}
    for mass in ("consistent", "lumped"):
        system = SYSTEMS["fem"].model_validate({
            "type": "fem", "model": {"box": {"size": [1.0, 0.05, 0.05], "cells": [20, 1, 1]}}, "gravity": [0, 0, 0],
            "material": {"model": "stable_neo_hookean", "youngs_modulus": 1e5, "poisson_ratio": 0.0, "density": 1000.0},
            "pinned": "left", "mass": mass}).build()
        free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
        matrix = mass_matrix(system)[np.ix_(free, free)]
        values, vectors = scipy.linalg.eigh(system.projective_form().rest_stiffness().toarray()[np.ix_(free, free)], matrix)
        weighted = vectors * (matrix @ vectors)
        axial = int(np.flatnonzero(weighted[free % 3 == 0].sum(axis=0) / weighted.sum(axis=0) > 0.9)[0])
        frequencies[mass] = math.sqrt(values[axial]) / (2 * math.pi)
    exact = math.sqrt(1e5 / 1000.0) / 4.0
    assert frequencies["lumped"] < exact < frequencies["consistent"]
    assert frequencies["consistent"] == pytest.approx(exact, rel=1e-3)
    assert frequencies["lumped"] == pytest.approx(exact, rel=1e-3)


def run(tmp_path, integrators, mass="consistent", duration=0.2, dt=0.002, **system):
    from simrun.cli import main
    from simrun.results.reader import load
    import yaml

    config = {"name": "mass", "system": {
        "type": "fem", "model": {"box": {"size": [0.4, 0.1, 0.1], "cells": [4, 1, 1]}}, "gravity": [0.0, 0.0, 0.0],
        "material": {"model": "linear", "youngs_modulus": 1.0e5, "poisson_ratio": 0.3, "density": 1000.0},
        "mass": mass, "pinned": "left", "initial": {"velocity": [0.0, 0.0, 0.1]}, **system},
        "integrators": integrators, "solver": {"type": "newton", "tolerance": 1e-11, "max_iterations": 20},
        "duration": duration, "sweep": {"dt": [dt]}}
    path = tmp_path / "mass.yaml"
    path.write_text(yaml.safe_dump(config))
    assert main([str(path), "--output", str(tmp_path / "out"), "-q", "--no-plots"]) == 0
    return {stored.integrator: stored for stored in load(tmp_path / "out" / "results.h5").runs.values()}


def test_implicit_midpoint_conserves_the_consistent_energy_and_explicit_methods_solve_with_m(tmp_path):
    """A linear-elastic cantilever set moving: implicit midpoint keeps 1/2 v^T M v + P to round-off (the energy is
    quadratic); RK4, which takes M^-1 f by a solve, follows it to O(dt^4); backward Euler damps it."""
    runs = run(tmp_path, ["implicit_midpoint", "rk4", "backward_euler"], dt=0.001)
    for stored in runs.values():
        assert stored.status.name.lower() == "ok"
    energy = runs["implicit_midpoint"].series("energy")
    assert np.ptp(energy) < 1e-9 * energy[0]
    rk4 = runs["rk4"].series("energy")
    assert np.abs(rk4 / energy[0] - 1).max() < 1e-3
    np.testing.assert_allclose(runs["rk4"]["frames"][-1], runs["implicit_midpoint"]["frames"][-1], atol=2e-4)
    assert runs["backward_euler"].series("energy")[-1] < 0.9 * energy[0]


@pytest.mark.parametrize("integrator, solver, message", [
    ("exponential_rosenbrock_euler", "newton", "takes M as a diagonal"),
    ("backward_euler", "vbd", "consistent mass matrix couples the vertices"),
])
def test_methods_that_take_m_as_a_diagonal_are_refused(integrator, solver, message):
    from simrun.experiment.sweep import expand_runs

    config = {"name": "bad", "system": {"type": "fem", "model": BOX, "mass": "consistent"},
              "integrators": [integrator], "solver": {"type": solver}, "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        expand_runs(load_experiment(config)[0])
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("mass, message", [
    ({"matrix": "consistent", "per_vertex": 0.1}, "takes a total"),
    ({"matrix": "consistent", "total": 1.0, "by": "equal"}, "takes a total"),
])
def test_consistent_mass_takes_element_masses_only(mass, message):
    config = {"name": "bad", "system": {"type": "fem", "model": BOX, "mass": mass},
              "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match=message):
        load_experiment(config)


def test_sliding_constraints_with_consistent_mass_are_refused():
    config = {"name": "bad", "system": {"type": "fem", "model": BOX, "mass": "consistent",
                                        "constraints": [{"vertices": [1], "normal": [0.0, 0.0, 1.0]}]},
              "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError, match="system.mass: a consistent mass matrix couples a sliding vertex"):
        load_experiment(config)


def test_a_total_scales_the_consistent_matrix():
    system = fem(mass={"matrix": "consistent", "total": 2.0})
    assert mass_matrix(system).sum() / 3 == pytest.approx(2.0, rel=1e-13)


def test_the_drivers_work_closes_the_budget_with_a_consistent_mass(tmp_path):
    """One end pinned, the other pulled sideways at constant velocity for 0.1 s and let go: with implicit midpoint on
    the linear energy, E - W_prescribed stays at E0 (the drivers' power takes M a on their dofs, which a consistent
    M couples to the free dofs' accelerations), to 1e-6 of the work done."""
    runs = run(tmp_path, ["implicit_midpoint"], duration=0.2, dt=0.0005, initial={},
               prescribed=[{"vertices": "x_max", "velocity": [0.0, 0.0, 0.05], "until": 0.1}])
    stored = runs["implicit_midpoint"]
    assert stored.status.name.lower() == "ok"
    energy, work = stored.series("energy"), stored.series("prescribed_work")
    assert work[-1] > 0
    assert np.abs(energy - work - energy[0]).max() < 1e-6 * work[-1]  # the diagonal M alone leaves 7 %


def test_a_released_vertex_joins_the_consistent_solve():
    """After a path's release its vertices' accelerations come from M a = f like the others' (not the path's)."""
    system = fem(pinned="x_min", prescribed=[{"vertices": "x_max", "velocity": [0.0, 0.0, 0.1], "until": 0.1}])
    x = system.x0 + 1e-3 * np.random.default_rng(0).standard_normal(system.dof_count)
    held = system.acceleration(x, system.v0)
    moving = system.constraints.moving_dofs
    assert np.all(held[moving] == 0.0)
    released = system.released(0.1)
    acceleration = released.acceleration(x, released.v0)
    assert np.abs(acceleration[moving]).max() > 0
    free = np.setdiff1d(np.arange(released.dof_count), released.fixed_dofs)  # the pins' rows hold their reactions
    force = released.force(x, released.v0)
    np.testing.assert_allclose((mass_matrix(released) @ acceleration)[free], force[free], atol=1e-9 * np.abs(force).max())
    assert np.all(acceleration[released.fixed_dofs] == 0.0)
