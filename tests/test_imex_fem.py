"""IMEX splits of the finite-element system (systems/fem/split.py, integrators/imex.py) against theory.

- The split: for every term of a tet box (gravity, Rayleigh and drag damping, penalty contact, a consistent mass) and
  of a shell with bending hinges, the part with the term and its complement have energies, gradients, Hessians (SPD
  projected or not), damping matrices and forces that sum to the whole's, and the whole's mass, pins and state.
- IMEX Euler with every term of an undamped hanging box implicit is backward Euler. With gravity explicit it is
  still backward Euler: gravity is constant, so the explicit kick h M^-1 f_g moves the predictor to
  x_n + h v_n + h^2 M^-1 f_g, and 1/2 |y - x_n - h v_n - h^2 M^-1 f_g|_M^2 + h^2 P_el(y) differs from backward
  Euler's 1/2 |y - x_n - h v_n|_M^2 + h^2 (P_el(y) - f_g . y) by a constant: the same minimiser, the same velocity
  (y - x_n) / h.
- A shell with its membrane implicit and its hinges explicit is bounded by the bending frequency alone (K_E - K_I:
  the flat membrane has no stiffness across its plane): a run at half that bound is stable and stores it, where the
  same step taken fully explicitly blows up on the membrane's in-plane modes.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

from conftest import run_one

from simrun.errors import ConfigError
from simrun.execution.measures import explicit_frequency
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.systems import SYSTEMS
from test_integrators import TIGHT_SOLVER

GRAVITY = [0.0, 0.0, -9.81]
BOX = {"type": "fem", "model": {"box": {"size": [0.3, 0.1, 0.1], "cells": [2, 2, 2]}}, "gravity": GRAVITY,
       "material": {"model": "neo_hookean", "youngs_modulus": 2.0e4, "poisson_ratio": 0.3, "density": 1000.0},
       "pinned": "left"}
SHELL = {"type": "fem", "model": {"grid": {"resolution": [5, 4], "size": [1.0, 0.75]}}, "gravity": GRAVITY,
         "thickness": 1.0e-3, "bending": {"stiffness": 1.0e-3}, "pinned": [0, 4],
         "material": {"model": "stvk", "youngs_modulus": 1.0e5, "poisson_ratio": 0.3, "density": 0.2}}
DAMPING = [{"model": "rayleigh", "alpha": 0.3, "beta": 0.02}, {"model": "drag", "coefficient": 0.05}]
GROUND = {"method": "penalty", "stiffness": 1.0e4, "damping": 5.0,
          "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.03]}]}
SYSTEMS_UNDER_SPLIT = {
    "box": (dict(BOX, damping=DAMPING, contact=GROUND, mass="consistent"), ("elastic", "drag", "gravity", "contact")),
    "shell": (dict(SHELL, damping=DAMPING), ("elastic", "bending", "drag", "gravity")),
}


def build(config):
    return SYSTEMS["fem"].model_validate(config).build()


def dense(matrix, dof_count=None):
    """The matrix as an array; None (a part without damping) as zeros of (dof_count, dof_count)."""
    if matrix is None:
        return np.zeros((dof_count, dof_count))
    return matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix)


@pytest.fixture(scope="module", params=sorted(SYSTEMS_UNDER_SPLIT))
def split_system(request):
    config, terms = SYSTEMS_UNDER_SPLIT[request.param]
    return build(config), terms


def test_the_terms_are_the_ones_that_act(split_system):
    system, terms = split_system
    assert system.energy_terms == terms
    assert system.with_terms(()) is None and system.with_terms(terms, complement=True) is None  # no force left
    assert system.with_terms(terms) is not None


@pytest.mark.parametrize("pick", range(5))  # both systems have four terms
def test_the_parts_sum_to_the_whole(split_system, pick):
    """Term ``pick`` of the system's terms (the last pick: the first two together) and its complement, at a random
    deformed x with velocities: P, grad P, the Hessian (plain and SPD projected), D and f sum to the whole's within
    1e-10 of its scale; the parts keep the whole's masses, pins and state."""
    system, terms = split_system
    names = terms[:2] if pick == len(terms) else (terms[pick],)
    named, other = system.with_terms(names), system.with_terms(names, complement=True)
    assert set(named.energy_terms) == set(names) and set(other.energy_terms) == set(terms) - set(names)
    rng = np.random.default_rng(7)
    x = system.x0 + 0.01 * rng.standard_normal(system.dof_count)
    v = rng.standard_normal(system.dof_count)

    def assert_sums(evaluate):
        whole = evaluate(system)
        scale = np.max(np.abs(whole))
        assert scale > 0.0
        np.testing.assert_allclose(evaluate(named) + evaluate(other), whole, rtol=0.0, atol=1e-10 * scale)

    assert_sums(lambda part: np.array([part.potential_energy(x)]))
    assert_sums(lambda part: part.gradient(x))
    assert_sums(lambda part: dense(part.hessian(x)))
    assert_sums(lambda part: dense(part.hessian(x, project_spd=True)))
    assert_sums(lambda part: dense(part.damping_matrix(x), system.dof_count))
    assert_sums(lambda part: part.force(x, v))
    for part in (named, other):
        assert part.in_hessian_pattern(part.hessian(x))
        assert part.hessian_pattern.nnz <= system.hessian_pattern.nnz  # rebuilt for the part's own blocks
        np.testing.assert_array_equal(part.mass, system.mass)
        np.testing.assert_array_equal(part.fixed_dofs, system.fixed_dofs)
        np.testing.assert_array_equal(part.x0, system.x0)
        np.testing.assert_array_equal(part.v0, system.v0)
        if system.mass_correction is not None:
            np.testing.assert_array_equal(dense(part.mass_correction), dense(system.mass_correction))
        np.testing.assert_allclose(part.acceleration(x, v)[system.fixed_dofs], 0.0)


def hanging_box_steps(method, steps=8, dt=0.02):
    """The box pinned at its left face, undamped, falling from rest under gravity."""
    system = build(BOX)
    state = State(0.0, system.x0.copy(), system.v0.copy())
    for _ in range(steps):
        state, _ = method.step(system, state, dt, TIGHT_SOLVER)
    return system, state


@pytest.mark.parametrize("implicit", [["elastic", "gravity"], ["elastic"]])
def test_imex_euler_on_a_hanging_box_is_backward_euler(implicit):
    """Every term implicit, or gravity explicit (constant: the same minimiser, see the module docstring): eight
    steps of IMEX Euler equal backward Euler's to the solver's tolerance, and the box has sagged well beyond that."""
    system, split = hanging_box_steps(INTEGRATORS["imex"](scheme="euler", implicit=implicit))
    _, reference = hanging_box_steps(INTEGRATORS["backward_euler"]())
    assert np.max(np.abs(reference.x - system.x0)) > 1e-3
    np.testing.assert_allclose(split.x, reference.x, rtol=0.0, atol=1e-10)
    np.testing.assert_allclose(split.v, reference.v, rtol=0.0, atol=1e-8)


def test_a_split_naming_a_spring_kind_is_refused_in_one_line():
    config = {"name": "bad", "system": BOX, "integrators": [{"type": "imex", "implicit": ["stretch"]}],
              "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        expand_runs(load_experiment(config)[0])
    message = str(error.value)
    assert "implicit: the system has no term 'stretch'; its terms are elastic, gravity" in message
    assert "\n" not in message


def test_a_shell_with_explicit_bending_is_stable_at_half_the_bending_bound():
    """The stored bound is the bending hinges' (K_E - K_I at the flat rest shape, whose membrane has no stiffness
    across its plane), a tenth of the fully explicit one or less; IMEX Euler runs 1 s at half of 2/w and gains no
    energy, symplectic Euler blows up at that step."""
    system = build(SHELL)
    split = INTEGRATORS["imex"](scheme="euler", implicit=["elastic"])
    bending_frequency = explicit_frequency(system, split)
    explicit = explicit_frequency(system, INTEGRATORS["symplectic_euler"]())
    part = system.with_terms(["bending"])
    assert bending_frequency == pytest.approx(explicit_frequency(part, INTEGRATORS["symplectic_euler"]()), rel=1e-6)
    assert 0.0 < 10.0 * bending_frequency < explicit
    dt = 0.5 * 2.0 / bending_frequency
    result = run_one(SHELL, {"type": "imex", "implicit": ["elastic"]}, dt, 1.0)
    assert result.status == "ok", result.message
    assert result.attrs["explicit_frequency"] == pytest.approx(bending_frequency, rel=1e-9)
    assert np.all(np.isfinite(result.samples["frames"]))
    energy = np.asarray(result.samples["energy"])  # the membrane's backward Euler only takes energy out
    assert np.all(np.isfinite(energy)) and energy.max() <= energy[0] + 1e-3 * np.abs(result.samples["gravity_energy"]).max()
    assert run_one(SHELL, {"type": "symplectic_euler"}, dt, 1.0).status == "diverged"
