"""Projective dynamics on finite elements (docs/fem.md): the as-rigid-as-possible energy, the co-rotated one with
nu = 0, is mu ||F - R||^2 = (w/2) dist(F, SO(d))^2 (Bouaziz et al. 2014), whose local step is each element's polar
rotation and whose global matrix is A = M + s sum_e w V B_e^T B_e. Checked against an independent local-global
step written here in numpy, against Newton's step, for monotone descent, and for the refusal of every other energy."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from conftest import step_problem
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.errors import ConfigError
from simrun.solvers import Newton, ProjectiveDynamics
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.systems import SYSTEMS

ARAP = {"model": "corotated", "youngs_modulus": 1.0e5, "poisson_ratio": 0.0, "density": 1000.0}


def arap(model=None, **options):
    config = {"type": "fem", "model": model or {"box": {"size": [0.4, 0.1, 0.1], "cells": [4, 1, 1]}},
              "material": ARAP, "pinned": "left", **options}
    if "grid" in config["model"]:
        config.update(thickness=1e-3, material={**ARAP, "density": 1.0}, pinned=["top_left", "top_right"])
    return SYSTEMS["fem"].model_validate(config).build()


def bent_start(system, seed=0):
    rng = np.random.default_rng(seed)
    rest = system.rest
    x = rest.copy()
    x[:, -1] += 0.2 * rest[:, 0] ** 2  # bent along its length, plus noise
    x = x.ravel() + 0.005 * rng.standard_normal(system.dof_count)
    x[system.fixed_dofs] = system.x0[system.fixed_dofs]
    return x


def local_global(system, problem, y):
    """One local-global step of projective dynamics, from scratch: R_e the polar rotation of F_e at y (the closest
    rotation, det +1; for a shell the closest 3 x 2 matrix with orthonormal columns), then A y' = M y~ + s sum_e w_e B_e^T vec(R_e) - the gravity term, on the free dofs."""
    d, k = system.dim, system.elements.shape[1]
    n = system.dof_count
    rows, cols, values, rhs = [], [], [], np.zeros(n)
    x = y.reshape(-1, d)
    for element, g, volume, mu in zip(system.elements, system.shape_gradients, system.volumes, system.mu):
        F = sum(np.outer(x[element[a]], g[a]) for a in range(k))
        U, _, Vt = np.linalg.svd(F, full_matrices=False)
        if F.shape[0] == F.shape[1] and np.linalg.det(U @ Vt) < 0:
            U[:, -1] *= -1
        R = U @ Vt  # a shell's F is 3 x 2: the closest matrix with orthonormal columns
        weight = 2.0 * mu * volume
        for a in range(k):
            rhs[d * element[a]:d * element[a] + d] += problem.scale * weight * (R @ g[a])
            for b in range(k):
                for i in range(d):
                    rows.append(d * element[a] + i)
                    cols.append(d * element[b] + i)
                    values.append(problem.scale * weight * float(g[a] @ g[b]))
    matrix = scipy.sparse.csr_matrix((values, (rows, cols)), shape=(n, n)) + scipy.sparse.diags(system.mass)
    rhs += system.mass * problem.y_tilde - problem.scale * (-system._gravity_force)
    free = np.setdiff1d(np.arange(n), system.fixed_dofs)
    result = y.copy()
    fixed = system.fixed_dofs
    rhs_free = rhs[free] - matrix[free][:, fixed] @ y[fixed]
    result[free] = scipy.sparse.linalg.spsolve(matrix[free][:, free].tocsc(), rhs_free)
    return result


@pytest.mark.parametrize("model", [None, {"square": {"segments": 3, "size": 0.3}},
                                   {"grid": {"resolution": [4, 3], "size": [0.3, 0.2]}}],
                         ids=["tets", "triangles-2d", "shell"])
def test_one_pd_iteration_is_the_local_global_step(model):
    """The solver's plain iteration y - A^-1 grad E equals the local-global pair computed independently, to 1e-10."""
    system = arap(model)
    x = bent_start(system) if model is None else system.x0 + 0.01 * np.random.default_rng(1).standard_normal(system.dof_count)
    x[system.fixed_dofs] = system.x0[system.fixed_dofs]
    problem, _ = step_problem(system, x, np.zeros(system.dof_count), dt=0.01)
    y, _ = ProjectiveDynamics(max_iterations=1, tolerance=1e-30).minimize(problem, x)
    expected = local_global(system, problem, x)
    np.testing.assert_allclose(y, expected, atol=1e-10 * np.abs(expected).max())


def test_pd_descends_and_reaches_newtons_step():
    """Plain PD never raises the incremental potential, and converges to the step Newton finds."""
    system = arap()
    x = bent_start(system)
    problem, _ = step_problem(system, x, np.zeros(system.dof_count), dt=0.01)
    energies = []
    y, stats = ProjectiveDynamics(tolerance=1e-9, max_iterations=3000,
                                  callback=lambda y, g: energies.append(problem.value(y))).minimize(problem, x)
    assert stats.converged
    energies = np.array(energies)
    assert np.all(np.diff(energies) <= ENERGY_ROUNDOFF * np.abs(energies[:-1]))
    reference, _ = Newton(tolerance=1e-12, max_iterations=50).minimize(problem, x)
    np.testing.assert_allclose(y, reference, atol=1e-6 * np.ptp(system.rest))


@pytest.mark.parametrize("material, message", [
    ({"model": "neo_hookean"}, "not neo_hookean"),
    ({"model": "corotated", "poisson_ratio": 0.3}, "a volume term"),
])
def test_every_other_energy_is_refused_in_one_line(material, message):
    config = {"name": "bad", "system": {"type": "fem", "model": {"box": {"size": [0.4, 0.1, 0.1], "cells": [2, 1, 1]}},
                                        "material": material},
              "integrators": ["backward_euler"], "solver": {"type": "projective_dynamics"}, "sweep": {"dt": [0.01]}}
    with pytest.raises(ConfigError) as error:
        expand_runs(load_experiment(config)[0])
    text = str(error.value)
    assert message in text and "as-rigid-as-possible" in text and "\n" not in text
