"""The fast paths of the small systems and the cloth give the generic results: bit for bit where the same operations run,
within round-off where LAPACK is called directly. No timing here: that is benchmarks/."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

from conftest import run_one
from simrun.integrators import IncrementalPotential
from simrun.integrators.base import add_diagonal
from simrun.solvers.base import SMALL_VECTOR, _free_dofs, max_norm
from simrun.solvers.dofs import free_dofs
from simrun.solvers.linear import LINEAR_SOLVERS, _dense_solve
from simrun.systems import CircularMotionParams, ClothParams, SpringMassParams


@pytest.mark.parametrize("size", range(0, 2 * SMALL_VECTOR + 2))
def test_max_norm_is_numpys_max_abs_with_nan_inf_and_signed_zeros(size):
    """max_norm(v) == np.max(np.abs(v)) (0 for an empty v), NaN propagated, on both sides of SMALL_VECTOR."""
    rng = np.random.default_rng(size)
    for _ in range(100):
        vector = rng.standard_normal(size) * 10.0 ** rng.integers(-300, 300)
        if size and rng.random() < 0.3:
            vector[rng.integers(size)] = rng.choice([np.nan, np.inf, -np.inf, -0.0])
        expected = float(np.max(np.abs(vector))) if size else 0.0
        result = max_norm(vector)
        assert type(result) is float
        assert (math.isnan(expected) and math.isnan(result)) or result == expected


def test_free_dofs_without_fixed_dofs_is_the_cached_all_free_object():
    free = _free_dofs(3, np.zeros(0, dtype=np.intp))
    assert free.all_free and free.count == 3
    assert _free_dofs(3, None) is free
    assert _free_dofs(5, [1]).fixed.tolist() == free_dofs(5, [1]).fixed.tolist() == [1]


@pytest.mark.parametrize("size", [2, 3, 6])
def test_dense_solve_is_scipy_solve(size):
    """The direct LAPACK calls give scipy.linalg.solve's result: bit for bit for general and SPD matrices."""
    rng = np.random.default_rng(size)
    for _ in range(30):
        matrix = rng.standard_normal((size, size))
        spd = matrix @ matrix.T + 0.1 * np.eye(size)
        rhs = rng.standard_normal(size)
        np.testing.assert_array_equal(_dense_solve(matrix, rhs, False), scipy.linalg.solve(matrix, rhs, check_finite=False))
        np.testing.assert_array_equal(_dense_solve(spd, rhs, True),
                                      scipy.linalg.solve(spd, rhs, assume_a="pos", check_finite=False))
        # an indefinite matrix handed in as SPD falls back to the general solve: the solution, within round-off
        indefinite = matrix + matrix.T
        np.testing.assert_allclose(indefinite @ _dense_solve(indefinite, rhs, True), rhs, rtol=0, atol=1e-8 * np.abs(rhs).max()
                                   * np.linalg.cond(indefinite))


@pytest.mark.parametrize("name", ["direct", "cg"])
@pytest.mark.parametrize("size", [1, 2, 3])
def test_reduced_solve_without_fixed_dofs_equals_the_restricted_path(name, size):
    """The shortcut for a float64 array with every dof free gives what restrict -> _solve -> extend gives."""
    rng = np.random.default_rng(size)
    solver = LINEAR_SOLVERS[name]()
    free = _free_dofs(size, None)
    for _ in range(10):
        matrix = rng.standard_normal((size, size))
        matrix = matrix @ matrix.T + size * np.eye(size)
        rhs = rng.standard_normal(size)
        generic = solver._solve(free.restrict_matrix(matrix), free.restrict(rhs), True)
        fast = solver.solve(matrix, rhs, free, spd=True)
        np.testing.assert_array_equal(fast[0], free.extend(generic[0]))
        assert fast[1] == generic[1]
    # not float64 or fixed dofs: the restricted path, which converts and drops the fixed rows
    np.testing.assert_array_equal(solver.solve(np.eye(size, dtype=np.float32) * 2, np.ones(size), free)[0], np.full(size, 0.5))
    if size > 1:
        pinned = solver.solve(2 * np.eye(size), np.ones(size), free_dofs(size, [0]))[0]
        np.testing.assert_array_equal(pinned, np.r_[0.0, np.full(size - 1, 0.5)])


def test_dense_solve_raises_and_warns_as_scipy_does():
    with pytest.raises(np.linalg.LinAlgError):
        _dense_solve(np.ones((2, 2)), np.ones(2), False)
    with pytest.raises(np.linalg.LinAlgError):
        _dense_solve(np.ones((2, 2)), np.ones(2), True)
    nearly = np.array([[1.0, 1.0], [1.0, 1.0 + 1e-17 + 2e-16]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _dense_solve(nearly, np.array([1.0, 0.0]), False)
    assert any(issubclass(w.category, scipy.linalg.LinAlgWarning) for w in caught)


def test_add_diagonal_in_place_equals_the_copy_and_leaves_shared_matrices_alone():
    rng = np.random.default_rng(0)
    matrix, diagonal = rng.standard_normal((4, 4)), rng.standard_normal(4)
    original = matrix.copy()
    copied = add_diagonal(matrix, diagonal)
    np.testing.assert_array_equal(matrix, original)
    in_place = add_diagonal(matrix, diagonal, in_place=True)
    assert in_place is matrix
    np.testing.assert_array_equal(in_place, copied)
    transposed = original.T  # not C-contiguous: copied even when in_place is asked for
    np.testing.assert_array_equal(add_diagonal(transposed, diagonal, in_place=True), original.T + np.diag(diagonal))


def _deformed_cloth(damping: float, contact: bool = False):
    params = {"resolution": (7, 6), "damping": damping}
    if contact:
        params["contact"] = {"ground": {"height": -0.02}, "sphere": {"center": (0.5, 0.5, -0.05), "radius": 0.1}}
    system = ClothParams(**params).build()
    rng = np.random.default_rng(3)
    x = system.x0 + 0.05 * rng.standard_normal(system.dof_count)
    v = rng.standard_normal(system.dof_count)
    return system, x, v


@pytest.mark.parametrize("damping", [0.0, 0.3])
@pytest.mark.parametrize("project_spd", [False, True])
def test_cloth_hessian_in_its_pattern_equals_the_sum_of_sparse_matrices(damping, project_spd):
    """M + s K + (s/b) D filled into the fixed pattern has the values of the generic sparse sums, bit for bit."""
    system, x, v = _deformed_cloth(damping, contact=True)
    dt = 0.01
    problem = IncrementalPotential(system, x + dt * v, dt * dt, velocity_origin=x, velocity_divisor=dt, damping_at=x)
    assert problem._in_pattern
    generic = dt * dt * system.hessian(x, project_spd=project_spd)
    if problem.damping is not None:
        generic = generic + problem.damping_weight * problem.damping
    generic = add_diagonal(generic, system.mass)
    fast = problem.hessian(x, project_spd=project_spd)
    np.testing.assert_array_equal(fast.toarray(), generic.toarray())
    assert np.array_equal(fast.indptr, system.hessian_pattern.indptr)  # one pattern for every step


def test_cloth_geometry_cache_gives_fresh_results_and_sees_in_place_changes():
    """Energies, gradients and Hessians with the last x's geometry kept equal those of a fresh cloth."""
    system, x, v = _deformed_cloth(0.2, contact=True)
    fresh = ClothParams(resolution=(7, 6), damping=0.2, contact=system.params.contact).build
    for point in (x, x + 0.01, x):
        system.potential_energy(point)  # fills the cache at this point
        reference = fresh()
        assert system.potential_energy(point) == reference.potential_energy(point)
        np.testing.assert_array_equal(system.gradient(point), reference.gradient(point))
        np.testing.assert_array_equal(system.hessian_data(point, True), reference.hessian_data(point, True))
        np.testing.assert_array_equal(system.damping_matrix(point).data, reference.damping_matrix(point).data)
    changed = x.copy()
    system.gradient(changed)
    changed[5] += 0.1  # changed in place after the call: the cache compares values, not identities
    np.testing.assert_array_equal(system.gradient(changed), fresh().gradient(changed))


@pytest.mark.parametrize("params", [SpringMassParams(), CircularMotionParams(), CircularMotionParams(dimension=3),
                                    ClothParams(resolution=(4, 3), initial_spin=(0.3, -0.2, 1.0))])
def test_observables_equal_their_generic_formulas(params):
    """The shared momenta, the per-component sums and the moment-matrix cross product give the textbook
    sums: the energies bit for bit, the momenta within round-off of their terms."""
    system = params.build()
    rng = np.random.default_rng(1)
    x = system.x0 + 0.1 * rng.standard_normal(system.dof_count)
    v = system.v0 + rng.standard_normal(system.dof_count)
    observed = system.observables(x, v)
    momenta = (system.mass * v).reshape(-1, system.dim)
    assert observed["kinetic_energy"] == 0.5 * float(np.dot(system.mass * v, v)) == system.kinetic_energy(v)
    assert observed["energy"] == system.total_energy(x, v)
    round_off = 1e-14 * np.abs(momenta).sum()
    np.testing.assert_allclose(observed["momentum"], momenta.sum(axis=0), rtol=0, atol=round_off)
    if system.dim == 3:
        moments = np.cross(x.reshape(-1, 3), momenta)
        np.testing.assert_allclose(observed["angular_momentum"], moments.sum(axis=0), rtol=0,
                                   atol=1e-14 * np.abs(x).max() * np.abs(momenta).sum())
    elif system.dim == 2:
        positions = x.reshape(-1, 2)
        lz = np.sum(positions[:, 0] * momenta[:, 1] - positions[:, 1] * momenta[:, 0])
        np.testing.assert_array_equal(observed["angular_momentum"], [0.0, 0.0, lz])  # one particle: the same products


@pytest.mark.parametrize("integrator", ["symplectic_euler", "backward_euler"])
@pytest.mark.parametrize("damping", [0.0, 0.5])
def test_the_loop_records_what_the_generic_observables_give(integrator, damping):
    """simulate(): t is exactly dt n, every sample is system.observables of the recorded state, the energy
    budget of a damped spring closes, and an explicit method's per-step statistics stay zero."""
    system_config = {"type": "spring_mass", "stiffness": 4.0, "damping": damping}
    dt = 0.01
    result = run_one(system_config, integrator, dt, 2.0, record={"every": 1})
    assert result.status == "ok"
    samples = result.samples
    np.testing.assert_array_equal(samples["t"], dt * np.arange(samples["t"].size))
    system = SpringMassParams(stiffness=4.0, damping=damping).build()
    for row in (0, 57, samples["t"].size - 1):
        observed = system.observables(samples["positions"][row], samples["velocities"][row])
        for key, value in observed.items():
            np.testing.assert_array_equal(samples[key][row], value)
    if damping == 0.0:
        assert not system.is_damped and np.all(samples["dissipated_energy"] == 0.0)
    else:
        assert system.is_damped and samples["dissipated_energy"][-1] > 0.0
        # energy plus dissipated work stays near E0: the budget is first order in dt for these methods
        budget = samples["energy"] + samples["dissipated_energy"]
        assert abs(budget[-1] - budget[0]) < 0.05 * budget[0]
    if integrator == "symplectic_euler":
        assert not any(np.any(values) for values in result.per_step.values())
    else:
        assert np.all(result.per_step["newton_iterations"] >= 1)


SMALL_SYSTEMS = [
    SpringMassParams(stiffness=37.0, mass=0.3),
    SpringMassParams(stiffness=37.0, mass=0.3, damping=1.7),
    CircularMotionParams(force="linear", mass=2.0, angular_velocity=1.3),
    CircularMotionParams(force="linear", mass=2.0, angular_velocity=1.3, dimension=3),
    CircularMotionParams(force="gravity", mass=2.0, angular_velocity=1.3),
    CircularMotionParams(force="gravity", mass=2.0, angular_velocity=1.3, dimension=3),
]


@pytest.mark.parametrize("params", SMALL_SYSTEMS,
                         ids=["spring", "damped-spring", "circular-linear", "circular-linear-3d", "kepler", "kepler-3d"])
def test_small_systems_step_path_equals_the_generic_formulas(params):
    """The systems' own acceleration, kick and total_energy equal the base class's M^-1 (-dP/dx - D v),
    v + dt M^-1 f and KE + P."""
    from simrun.systems.base import System as GenericSystem

    system = params.build()
    rng = np.random.default_rng(5)
    for _ in range(20):
        x = system.x0 + rng.standard_normal(system.dof_count)
        v = rng.standard_normal(system.dof_count)
        np.testing.assert_allclose(system.acceleration(x, v), GenericSystem.acceleration(system, x, v), rtol=1e-14, atol=1e-14)
        dt = rng.uniform(1e-4, 0.1)
        np.testing.assert_allclose(system.kick(x, v, dt), v + dt * GenericSystem.acceleration(system, x, v), rtol=1e-14, atol=1e-14)
        assert system.total_energy(x, v) == pytest.approx(GenericSystem.total_energy(system, x, v), rel=1e-14)


WRITTEN_OBSERVABLE_SYSTEMS = [
    *SMALL_SYSTEMS,
    ClothParams(resolution=(4, 3), initial_spin=(0.3, -0.2, 1.0), damping=0.2,
                contact={"ground": {"height": -0.02}, "sphere": {"center": (0.5, 0.5, -0.05), "radius": 0.1}}),
]


@pytest.mark.parametrize("params", WRITTEN_OBSERVABLE_SYSTEMS, ids=lambda params: f"{params.type}")
def test_written_observables_are_the_observables_dictionary_flattened(params):
    """write_observables fills a row with observables(x, v)'s values, in its key order, to round-off, and
    returns the energy; the layout names every key with its shape."""
    system = params.build()
    rng = np.random.default_rng(7)
    for _ in range(10):
        x = system.x0 + 0.1 * rng.standard_normal(system.dof_count)
        v = system.v0 + rng.standard_normal(system.dof_count)
        observed = system.observables(x, v)
        assert [(key, np.shape(value)) for key, value in observed.items()] == list(system.observable_layout)
        expected = np.concatenate([np.ravel(value) for value in observed.values()])
        row = np.full(system.observable_width + 2, np.nan)  # the two extra cells must stay untouched
        energy = system.write_observables(x, v, row)
        np.testing.assert_allclose(row[:-2], expected, rtol=1e-14, atol=1e-14 * np.abs(expected).max())
        assert np.isnan(row[-2:]).all()
        assert energy == row[0] and energy == pytest.approx(observed["energy"], rel=1e-14)


@pytest.mark.parametrize("system_config", [
    {"type": "circular_motion", "force": "linear", "angular_velocity": 1.3},
    {"type": "circular_motion", "force": "gravity", "dimension": 3},
], ids=["circular-linear", "kepler-3d"])
def test_the_recorded_rows_of_circular_motion_are_its_observables(system_config):
    """Samples from the scalar row writer equal system.observables of the recorded states, to round-off."""
    result = run_one(system_config, "symplectic_euler", 0.01, 3.0, record={"every": 1})
    assert result.status == "ok"
    system = CircularMotionParams(**{k: v for k, v in system_config.items() if k != "type"}).build()
    for row in (0, 1, 123, result.samples["t"].size - 1):
        observed = system.observables(result.samples["positions"][row], result.samples["velocities"][row])
        for key, value in observed.items():
            np.testing.assert_allclose(result.samples[key][row], value, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("contact", [False, True])
def test_cloth_gradient_is_the_per_spring_formula_scattered(contact):
    """The flat gather, the |delta|^2 product and the incidence-matrix scatter give the textbook
    dP/dx = sum_springs k (L - l0) u (+ at i, - at j) - m g (+ contact), within round-off."""
    system, x, v = _deformed_cloth(0.0, contact=contact)
    positions = x.reshape(-1, 3)
    delta = positions[system.first] - positions[system.second]
    length = np.linalg.norm(delta, axis=1)
    spring_force = (system.stiffness * (length - system.rest_length))[:, None] * (delta / length[:, None])
    expected = np.zeros_like(positions)
    np.add.at(expected, system.first, spring_force)
    np.add.at(expected, system.second, -spring_force)
    expected = expected.ravel() - np.tile(system.vertex_mass * system.gravity, system.vertex_count)
    touching = []
    for collider in (system.contact.colliders if system.contact is not None else ()):
        phi, normal = collider.collider.distance_and_normal(positions)
        depth = np.maximum(-phi, 0.0)
        expected -= (collider.stiffness * depth[:, None] * normal).ravel()
        touching.append(depth.any())
    if contact:
        assert any(touching), "no vertex touches: the test shows nothing"
    gradient = system.gradient(x)
    np.testing.assert_allclose(gradient, expected, rtol=0, atol=1e-14 * 16 * np.abs(spring_force).max())
    geometry = system._springs(x)
    np.testing.assert_allclose(geometry.length, length, rtol=1e-15)
    np.testing.assert_array_equal(geometry.direction, delta / geometry.length[:, None])
    assert system.spring_energy(x) == 0.5 * float(np.dot(system.stiffness * (geometry.length - system.rest_length),
                                                 geometry.length - system.rest_length))


def test_cloth_observables_are_the_generic_ones_with_the_parts_of_the_potential():
    """Energies and momenta as the base class computes them, and the three parts that sum to P(x), bit for bit."""
    from simrun.systems.base import System as GenericSystem

    system, x, v = _deformed_cloth(0.2, contact=True)
    observed = system.observables(x, v)
    generic = GenericSystem.observables(system, x, v)
    for key, value in generic.items():
        np.testing.assert_array_equal(observed[key], value)
    assert observed["spring_energy"] == system.spring_energy(x)
    assert observed["gravity_energy"] == system.gravity_energy(x)
    assert observed["contact_energy"] == system.contact_energy(x) > 0.0
    assert observed["potential_energy"] == system.potential_energy(x)


@pytest.mark.parametrize("every", [1, 2, 3])
def test_a_run_that_stops_records_its_last_step_once(every):
    """A diverged run keeps the regular samples and frames and the step it stopped at, each once.
    Forward Euler at h w = 5 multiplies the spring's energy by 26 per step: past 1e6 at step 5."""
    dt = 0.5
    result = run_one({"type": "spring_mass", "stiffness": 100.0}, "forward_euler", dt, 100.0, record={"every": every})
    assert result.status == "diverged" and result.steps == 5 and result.t_diverged == 5 * dt
    expected = sorted(set(range(0, 6, every)) | {5})
    np.testing.assert_array_equal(result.samples["t"], dt * np.array(expected))
    np.testing.assert_allclose(result.samples["energy"], 0.5 * 100.0 * (1 + 25.0) ** np.array(expected), rtol=1e-14)

    cloth = run_one({"type": "cloth", "resolution": [4, 3]}, "symplectic_euler", 0.05, 10.0,
                    record={"every": every, "frames_every": 2})
    assert cloth.status == "diverged"
    steps = cloth.steps
    np.testing.assert_allclose(cloth.samples["t"], 0.05 * np.array(sorted(set(range(0, steps + 1, every)) | {steps})), rtol=1e-15)
    np.testing.assert_allclose(cloth.samples["frame_t"], 0.05 * np.array(sorted(set(range(0, steps + 1, 2)) | {steps})), rtol=1e-15)


class _CopiedGradients:
    """An incremental potential seen through the generic contract: no fresh_gradient, so the solver copies."""

    def __init__(self, problem):
        self.fixed_dofs, self.residual_floor = problem.fixed_dofs, problem.residual_floor
        self.value, self.gradient, self.hessian = problem.value, problem.gradient, problem.hessian


@pytest.mark.parametrize("solver_type", ["newton", "projected_newton"])
@pytest.mark.parametrize("params", SMALL_SYSTEMS, ids=["spring", "damped-spring", "circular-linear", "circular-linear-3d",
                                                       "kepler", "kepler-3d"])
def test_solves_without_gradient_copies_equal_the_copying_path(params, solver_type):
    """A problem whose gradients are fresh arrays (no copy, best iterate kept by reference) gives the
    generic path's y, best iterate and statistics, bit for bit."""
    from simrun.solvers import solver_params

    system = params.build()
    solver = solver_params(type=solver_type, linear_solver="direct").build()
    rng = np.random.default_rng(11)
    for _ in range(5):
        x = system.x0 + 0.1 * rng.standard_normal(system.dof_count)
        v = system.v0 + rng.standard_normal(system.dof_count)
        dt = 0.05
        problem = IncrementalPotential(system, x + dt * v, dt * dt, velocity_origin=x, velocity_divisor=dt, damping_at=x)
        assert problem.fresh_gradient
        fast, generic = solver.solve(problem, x), solver.solve(_CopiedGradients(problem), x)
        np.testing.assert_array_equal(fast.y, generic.y)
        np.testing.assert_array_equal(fast.best, generic.best)
        assert fast.stats == generic.stats and fast.stats.iterations >= 1
        assert solver.minimize(problem, x)[1] == fast.stats
