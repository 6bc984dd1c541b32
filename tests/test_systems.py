"""Every system of the registry against the System contract (systems/base.py), parametrised over
``simrun.systems.SYSTEMS``: a new system is checked here as soon as it is registered.

Each system is tried at the small instances of ``EXAMPLES``; a registered system without an entry there
is tried at its default parameters. The state x = x0 + 0.05 L z (L = length_scale, z ~ N(0, I),
seeded) is generic: no symmetry of x0 hides a wrong sign or a missing term.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import fields

import h5py
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from conftest import make_runs
from simrun.integrators import State
from simrun.simulate import simulate
from simrun.systems import SYSTEMS, Capabilities, System, SystemParams

# Small instances that reach every branch of their system: names of the registry -> (id, params).
# The cloth's ground (z = 0, the cloth's own plane) and sphere touch the cloth at the test state and in the run.
EXAMPLES: dict[str, list[tuple[str, dict]]] = {
    "spring_mass": [
        ("undamped", {"mass": 0.3, "stiffness": 37.0, "x0": 0.7, "v0": -0.4}),
        ("damped", {"mass": 0.3, "stiffness": 37.0, "damping": 1.7, "x0": 0.7, "v0": -0.4}),
    ],
    "circular_motion": [
        (f"{force}-{dimension}d", {"force": force, "dimension": dimension, "mass": 2.0, "radius": 1.5, "angular_velocity": 1.3})
        for force in ("linear", "gravity") for dimension in (2, 3)
    ],
    "cloth": [
        ("contact-damped", {"resolution": (4, 3), "size": (0.3, 0.2), "mass": 0.12, "stretch_stiffness": 50.0,
                            "shear_stiffness": 10.0, "bend_stiffness": 1.0, "damping": 0.05, "pinned": ["top_left", 1],
                            "initial_spin": (0.4, -0.2, 1.5),
                            "contact": {"ground": {"height": 0.0, "stiffness": 2e3},
                                        "sphere": {"center": (0.15, 0.1, -0.05), "radius": 0.08, "stiffness": 2e3}}}),
        ("free-undamped", {"resolution": (3, 4), "size": (0.2, 0.3), "mass": 0.12, "stretch_stiffness": 50.0,
                           "shear_stiffness": 10.0, "bend_stiffness": 1.0, "pinned": [], "height": 0.1,
                           "initial_velocity": (0.1, 0.0, 0.3)}),
    ],
}

CASES = [pytest.param(name, params, id=f"{name}-{label}")
         for name in SYSTEMS for label, params in EXAMPLES.get(name, [("defaults", {})])]

PERTURBATION = 0.05  # of the length scale: springs stay far from zero length, the orbit far from the centre
SEED = 20240607
FD_STEP = 1e-6  # of the length scale
# central differences err by h^2/6 |P'''| (1e-12 relative) plus round-off eps |P|/h (1e-10 relative):
# 1e-6 of the largest entry leaves room for the stiff penalty terms next to the soft springs
FD_TOLERANCE = 1e-6
PSD_TOLERANCE = 1e-9  # eigenvalues >= -1e-9 max|eigenvalue|: round-off of a projected (or exactly singular) matrix
ROUND_OFF = 1e-12  # the same formulas on the same numbers, in another order
DENSE_LIMIT = 400  # dof: above, derivatives are probed along random directions and eigenvalues found by Lanczos
PROBE_COUNT = 8
STEP_COUNT = 20
INTEGRATORS = ("backward_euler", "symplectic_euler")


def build(name: str, params: dict) -> System:
    return SYSTEMS[name](type=name, **params).build()


def generic_state(system: System) -> np.ndarray:
    """x0 + 0.05 L z with a seeded z ~ N(0, I) (m): the test state."""
    return system.x0 + PERTURBATION * system.length_scale * np.random.default_rng(SEED).standard_normal(system.dof_count)


def generic_velocity(system: System) -> np.ndarray:
    """v0 + z with a seeded z ~ N(0, I) (m/s), zero on the fixed dofs."""
    v = system.v0 + np.random.default_rng(SEED + 1).standard_normal(system.dof_count)
    v[system.fixed_dofs] = 0.0
    return v


def dense(matrix) -> np.ndarray:
    return matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix, dtype=float)


def eigenvalue_range(matrix) -> tuple[float, float]:
    """(smallest eigenvalue, largest |eigenvalue|) of a symmetric matrix: LAPACK when small, Lanczos when large."""
    if matrix.shape[0] <= DENSE_LIMIT:
        eigenvalues = np.linalg.eigvalsh(dense(matrix))
        return float(eigenvalues[0]), float(np.abs(eigenvalues).max())
    operator = scipy.sparse.csr_matrix(matrix)
    largest = float(abs(scipy.sparse.linalg.eigsh(operator, k=1, which="LM", return_eigenvectors=False)[0]))
    # the smallest eigenvalue of A is the largest of the shifted -A + s I, s = |A|: a well separated end for Lanczos
    shifted = scipy.sparse.linalg.eigsh(largest * scipy.sparse.identity(matrix.shape[0]) - operator, k=1, which="LA",
                                        return_eigenvectors=False)[0]
    return largest - float(shifted), largest


def probes(system: System) -> np.ndarray:
    """Directions (columns) along which derivatives are compared: all unit vectors, or seeded random unit vectors."""
    n = system.dof_count
    if n <= DENSE_LIMIT:
        return np.eye(n)
    directions = np.random.default_rng(SEED + 2).standard_normal((n, PROBE_COUNT))
    return directions / np.linalg.norm(directions, axis=0)


def max_abs(values) -> float:
    values = np.abs(np.asarray(values, dtype=float))
    return float(values.max()) if values.size else 0.0


def assert_symmetric(matrix, what: str) -> None:
    """A = A^T to round-off of the largest entry."""
    matrix = scipy.sparse.csr_matrix(matrix)
    assert max_abs((matrix - matrix.T).data) <= ROUND_OFF * max_abs(matrix.data), f"{what} is not symmetric"


def assert_symmetric_psd(matrix, what: str) -> None:
    """A = A^T to round-off and every eigenvalue >= -1e-9 max|eigenvalue|."""
    assert_symmetric(matrix, what)
    smallest, largest = eigenvalue_range(matrix)
    assert smallest >= -PSD_TOLERANCE * largest, f"{what} has the eigenvalue {smallest:.3g} (largest |eigenvalue| {largest:.3g})"


# -- the registry ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(SYSTEMS))
def test_the_registry_maps_config_names_to_params_models_of_their_system_class(name):
    """SYSTEMS[name] is a SystemParams whose type tag is the name and whose build() is a system_class."""
    model = SYSTEMS[name]
    assert issubclass(model, SystemParams) and issubclass(model.system_class, System)
    params = model()
    assert params.type == name
    system = params.build()
    assert type(system) is model.system_class
    assert params.dof_count == system.dof_count
    assert model.system_class.records_state_per_sample == system.records_state_per_sample


# -- the static model ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name, params", CASES)
def test_mass_and_initial_state_have_the_shape_of_the_dofs(name, params):
    """mass > 0 and finite, x0, v0 finite; all of shape (dof_count,); dof_count = params.dof_count; v0 = 0 where fixed."""
    model = SYSTEMS[name](type=name, **params)
    system = model.build()
    n = system.dof_count
    assert isinstance(n, numbers.Integral) and n == model.dof_count and n >= 1
    for array in (system.mass, system.x0, system.v0):
        assert array.shape == (n,) and np.all(np.isfinite(array))
    assert np.all(system.mass > 0)
    assert system.fixed_dofs.ndim == 1 and np.all((system.fixed_dofs >= 0) & (system.fixed_dofs < n))
    assert np.all(system.v0[system.fixed_dofs] == 0.0)


@pytest.mark.parametrize("name, params", CASES)
def test_gradient_is_the_central_difference_of_the_potential(name, params):
    """g(x) . e = (P(x + h e) - P(x - h e)) / (2 h) + O(h^2) along every probe e, h = 1e-6 L; relative error < 1e-6."""
    system = build(name, params)
    x = generic_state(system)
    h = FD_STEP * system.length_scale
    directions = probes(system)
    gradient = system.gradient(x)
    assert gradient.shape == (system.dof_count,)
    expected = gradient @ directions
    differences = np.array([(system.potential_energy(x + h * e) - system.potential_energy(x - h * e)) / (2 * h)
                            for e in directions.T])
    assert max_abs(differences - expected) <= FD_TOLERANCE * max_abs(expected)


@pytest.mark.parametrize("name, params", CASES)
def test_hessian_is_the_symmetric_central_difference_of_the_gradient(name, params):
    """H(x) e = (g(x + h e) - g(x - h e)) / (2 h) + O(h^2) along every probe e (relative error < 1e-6), H = H^T."""
    system = build(name, params)
    x = generic_state(system)
    h = FD_STEP * system.length_scale
    directions = probes(system)
    hessian = system.hessian(x)
    assert hessian.shape == (system.dof_count, system.dof_count)
    expected = np.asarray(hessian @ directions)
    differences = np.array([(system.gradient(x + h * e) - system.gradient(x - h * e)) / (2 * h) for e in directions.T]).T
    assert max_abs(differences - expected) <= FD_TOLERANCE * max_abs(expected)
    assert_symmetric(hessian, "hessian(x)")


@pytest.mark.parametrize("name, params", CASES)
def test_projected_hessian_is_psd_and_changes_nothing_that_is_psd_already(name, params):
    """hessian(x, project_spd=True) is symmetric PSD; at x0 and the test state, wherever hessian(x) is PSD
    already, the projection returns it (to round-off of the largest entry)."""
    system = build(name, params)
    for x in (system.x0, generic_state(system)):
        projected = system.hessian(x, project_spd=True)
        assert_symmetric_psd(projected, "hessian(x, project_spd=True)")
        hessian = system.hessian(x)
        smallest, largest = eigenvalue_range(hessian)
        if smallest >= -PSD_TOLERANCE * largest:
            difference = scipy.sparse.csr_matrix(projected) - scipy.sparse.csr_matrix(hessian)
            assert max_abs(difference.data) <= ROUND_OFF * max(largest, 1e-300)


@pytest.mark.parametrize("name, params", CASES)
def test_hessian_pattern_holds_the_hessian_the_damping_and_the_diagonal(name, params):
    """pattern_matrix(hessian_data(x, p)) = hessian(x, p) for p in (False, True); every nonzero of D(x) and
    every diagonal entry lies in hessian_pattern, and diagonal_positions point at the diagonal."""
    system = build(name, params)
    if system.hessian_pattern is None:
        pytest.skip(f"{name} has no fixed Hessian pattern")
    pattern = system.hessian_pattern
    n = system.dof_count
    x = generic_state(system)
    for project_spd in (False, True):
        data = system.hessian_data(x, project_spd)
        assert data.shape == (pattern.nnz,)
        difference = system.pattern_matrix(data) - scipy.sparse.csr_matrix(system.hessian(x, project_spd))
        assert max_abs(difference.data) <= ROUND_OFF * max_abs(data)
    rows = np.repeat(np.arange(n), np.diff(pattern.indptr))
    assert np.array_equal(rows[system.diagonal_positions], np.arange(n))
    assert np.array_equal(pattern.indices[system.diagonal_positions], np.arange(n))
    in_pattern = scipy.sparse.csr_matrix((np.ones(pattern.nnz), pattern.indices, pattern.indptr), shape=pattern.shape)
    damping = system.damping_matrix(x)
    for matrix, what in ((system.hessian(x), "the Hessian"), (damping, "the damping matrix")):
        if matrix is None:
            continue
        nonzero = scipy.sparse.csr_matrix(matrix, copy=True)
        nonzero.data = (nonzero.data != 0).astype(float)
        outside = nonzero - nonzero.multiply(in_pattern)
        assert not outside.count_nonzero(), f"{what} has nonzeros outside hessian_pattern"


@pytest.mark.parametrize("name, params", CASES)
def test_damping_is_a_symmetric_psd_matrix_times_the_velocity(name, params):
    """D(x) = D^T >= 0 (damping only dissipates: v . f_d = -v^T D v <= 0) and damping_force(x, v) = -D(x) v."""
    system = build(name, params)
    x, v = generic_state(system), generic_velocity(system)
    damping = system.damping_matrix(x)
    if damping is None:
        assert not system.is_damped and system.damping_force(x, v) is None
        return
    assert system.is_damped
    assert damping.shape == (system.dof_count, system.dof_count)
    assert_symmetric_psd(damping, "damping_matrix(x)")
    expected = -np.asarray(damping @ v)
    np.testing.assert_allclose(system.damping_force(x, v), expected, rtol=0, atol=ROUND_OFF * max(max_abs(expected), 1e-300))


@pytest.mark.parametrize("name, params", CASES)
def test_force_is_minus_the_gradient_plus_damping_and_zero_on_fixed_dofs(name, params):
    """f(x, v) = -g(x) - D(x) v on the free dofs, 0 on the fixed ones; acceleration = f / m, kick = v + dt f / m."""
    system = build(name, params)
    x, v = generic_state(system), generic_velocity(system)
    damping = system.damping_matrix(x)
    expected = -system.gradient(x) - (np.asarray(damping @ v) if damping is not None else 0.0)
    expected[system.fixed_dofs] = 0.0
    scale = max(max_abs(expected), 1e-300)
    force = system.force(x, v)
    np.testing.assert_allclose(force, expected, rtol=0, atol=ROUND_OFF * scale)
    assert np.all(force[system.fixed_dofs] == 0.0)
    np.testing.assert_allclose(system.acceleration(x, v), expected / system.mass, rtol=0,
                               atol=ROUND_OFF * max_abs(expected / system.mass))
    dt = 1e-3
    np.testing.assert_allclose(system.kick(x, v, dt), v + dt * expected / system.mass, rtol=0,
                               atol=ROUND_OFF * max_abs(v + dt * expected / system.mass))


# -- observables ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, params", CASES)
def test_written_observables_are_the_observables_flattened_in_layout_order(name, params):
    """observables(x, v) holds KE = 1/2 v^T M v, P(x), E = KE + P and p = sum_i m_i v_i; write_observables(x, v, row)
    puts them into row[:observable_width] (each value flattened, in observable_layout order), touches nothing after
    it, and returns the energy."""
    system = build(name, params)
    x, v = generic_state(system), generic_velocity(system)
    observed = system.observables(x, v)
    assert [(key, np.shape(value)) for key, value in observed.items()] == list(system.observable_layout)
    assert observed["kinetic_energy"] == pytest.approx(0.5 * float(np.sum(system.mass * v * v)), rel=ROUND_OFF)
    assert observed["potential_energy"] == pytest.approx(system.potential_energy(x), rel=ROUND_OFF, abs=ROUND_OFF * system.energy_scale())
    assert observed["energy"] == pytest.approx(observed["kinetic_energy"] + observed["potential_energy"], rel=ROUND_OFF)
    momenta = (system.mass * v).reshape(-1, system.dim)
    np.testing.assert_allclose(observed["momentum"], momenta.sum(axis=0), rtol=0, atol=ROUND_OFF * max_abs(momenta) * len(momenta))
    expected = np.concatenate([np.ravel(value) for value in observed.values()])
    assert expected.size == system.observable_width
    row = np.full(system.observable_width + 2, np.nan)
    energy = system.write_observables(x, v, row)
    np.testing.assert_allclose(row[:-2], expected, rtol=ROUND_OFF, atol=ROUND_OFF * max_abs(expected))
    assert np.isnan(row[-2:]).all()
    assert energy == pytest.approx(observed["energy"], rel=ROUND_OFF)


def stable_dt(system: System) -> float:
    """0.1 / (the fastest rate of the system): w_max^2 <= max_i sum_j |H_ij| / m_i (Gershgorin on M^-1 H) and the
    damping rate max_i sum_j |D_ij| / m_i, both at x0 and at the test state (where the contacts touch)."""
    rate = 0.0
    for x in (system.x0, generic_state(system)):
        for matrix, power in ((system.hessian(x, project_spd=True), 0.5), (system.damping_matrix(x), 1.0)):
            if matrix is not None:
                row_sums = np.asarray(abs(scipy.sparse.csr_matrix(matrix)).sum(axis=1)).ravel()
                rate = max(rate, float((row_sums / system.mass).max()) ** power)
    return 0.1 / rate if rate > 0 else 0.01


def replay(system: System, run) -> list[State]:
    """The states of the run, step by step, from the run's own integrator and a fresh solver: (x, v) at every step."""
    solver = run.solver.build()
    state = run.integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    states = [state]
    for _ in range(run.step_count):
        state, _ = run.integrator.step(system, state, run.dt, solver)
        states.append(state)
    return states


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("name, params", CASES)
def test_a_run_records_the_observables_of_its_states(name, params, integrator):
    """Through config -> expand_runs -> simulate, 20 steps: every recorded observable equals
    system.observables(x, v) (relative 1e-12) at the state recorded with it. Small systems record (x, v) in each
    sample; frame-recording ones keep x in frames of frame_shape + (3,): there, where a frame and a sample share a
    time, x is the frame's and v that of the same step replayed with the run's integrator, whose x must be the frame."""
    system = build(name, params)
    dt = stable_dt(system)
    (run,) = make_runs({"type": name, **params}, [integrator], [dt], duration=STEP_COUNT * dt,
                       record={"every": 1, "frames_every": 1})
    result = simulate(run)
    assert result.status == "ok", result.message
    assert result.steps == run.step_count
    samples = result.samples
    t = samples["t"]
    assert t.size == run.step_count + 1 and t[0] == 0.0
    if system.records_state_per_sample:
        assert "frames" not in samples
        states = list(zip(samples["positions"], samples["velocities"]))
        np.testing.assert_array_equal(states[0][0], system.x0)
        np.testing.assert_array_equal(states[0][1], system.v0)
        rows = list(range(t.size))
    else:
        frames, frame_t = samples["frames"], samples["frame_t"]
        assert frames.shape[1:] == (math.prod(system.frame_shape), 3)
        replayed = replay(system, run)
        times = {float(time): row for row, time in enumerate(t)}
        states, rows = [], []
        for frame, time in zip(frames, frame_t):
            step = round(time / run.dt)
            assert time == pytest.approx(step * run.dt, rel=0, abs=1e-12 * run.dt)
            x = frame.ravel()
            np.testing.assert_allclose(x, replayed[step].x, rtol=0, atol=ROUND_OFF * max_abs(replayed[step].x))
            if float(time) in times:
                states.append((x, replayed[step].v))
                rows.append(times[float(time)])
        np.testing.assert_array_equal(frames[0].ravel(), system.x0)
        np.testing.assert_allclose(frames[-1].ravel(), replayed[-1].x, rtol=0, atol=ROUND_OFF * max_abs(replayed[-1].x))
        assert rows[0] == 0 and np.array_equal(states[0][1], system.v0)
        assert rows[-1] == t.size - 1
    assert len(rows) > 0
    final_x = states[-1][0]
    np.testing.assert_array_equal(final_x[system.fixed_dofs], system.x0[system.fixed_dofs])
    expected = [system.observables(x, v) for x, v in states]
    for key in system.observables(system.x0, system.v0):
        wanted = np.array([values[key] for values in expected], dtype=float)
        recorded = samples[key][rows]
        np.testing.assert_allclose(recorded, wanted, rtol=ROUND_OFF, atol=ROUND_OFF * max(max_abs(wanted), 1e-300),
                                   err_msg=f"recorded {key} differs from observables at the recorded states")


# -- capabilities --------------------------------------------------------------------------------------
def spring_mass_capabilities(params) -> dict:
    """w = sqrt(k/m) when undamped, else None; not planar (one dof)."""
    return {"test_frequency": math.sqrt(params.stiffness / params.mass) if params.damping == 0 else None, "planar": False,
            "frame_shape": None}


def circular_motion_capabilities(params) -> dict:
    """w with the linear force (P = m w^2 |x|^2 / 2), None with gravity; planar in both dimensions."""
    return {"test_frequency": params.angular_velocity if params.force == "linear" else None, "planar": True,
            "frame_shape": None}


def cloth_capabilities(params) -> dict:
    """No test frequency, not planar; frames are (ny, nx) for resolution (nx, ny)."""
    nx, ny = params.resolution
    return {"test_frequency": None, "planar": False, "frame_shape": (ny, nx)}


# what each system of the registry must declare; a system missing here is held to the generic checks only
EXPECTED_CAPABILITIES = {"spring_mass": spring_mass_capabilities, "circular_motion": circular_motion_capabilities,
                         "cloth": cloth_capabilities}


@pytest.mark.parametrize("name, params", CASES)
def test_capabilities_are_what_the_system_is(name, params):
    """The declared values (EXPECTED_CAPABILITIES), and for every system: length_scale = max|x0| (1 when 0) > 0,
    0 < energy_scale = energy_scale() < inf, dof_count, frame_shape None iff x and v are sampled (else
    3 prod(frame_shape) = dof_count); planar: one body of dim >= 2 with x0, v0 and the force at in-plane states
    in the x-y plane."""
    model = SYSTEMS[name](type=name, **params)
    system = model.build()
    capabilities = system.capabilities
    assert isinstance(capabilities, Capabilities) and system.capabilities is capabilities  # built once
    if name in EXPECTED_CAPABILITIES:
        for key, value in EXPECTED_CAPABILITIES[name](model).items():
            assert getattr(capabilities, key) == value, key
    start = max_abs(system.x0)
    assert capabilities.length_scale == (start if start > 0 else 1.0) and capabilities.length_scale > 0
    assert 0 < capabilities.energy_scale < math.inf and capabilities.energy_scale == system.energy_scale()
    assert capabilities.dof_count == system.dof_count
    if system.records_state_per_sample:
        assert capabilities.frame_shape is None
    else:
        assert all(isinstance(size, int) for size in capabilities.frame_shape)
        assert 3 * math.prod(capabilities.frame_shape) == system.dof_count
    if capabilities.planar:
        assert system.dim >= 2 and system.dof_count == system.dim
        assert not system.x0[2:].any() and not system.v0[2:].any()
        x, v = generic_state(system), generic_velocity(system)
        x[2:], v[2:] = 0.0, 0.0
        assert not system.force(x, v)[2:].any()


@pytest.mark.parametrize("name, params", CASES)
def test_test_frequency_is_the_frequency_of_the_system(name, params):
    """With a test frequency w the system is uncoupled copies of q'' + w^2 q = 0: undamped, H(x) = w^2 M at x0 and
    the test state, and (where an exact solution is known) back at (x0, v0) after one period 2 pi / w."""
    system = build(name, params)
    w = system.capabilities.test_frequency
    if w is None:
        pytest.skip(f"{name} declares no test frequency here")
    assert w > 0 and not system.is_damped
    for x in (system.x0, generic_state(system)):
        hessian = dense(system.hessian(x))
        np.testing.assert_allclose(hessian, w * w * np.diag(system.mass), rtol=ROUND_OFF, atol=ROUND_OFF * max_abs(hessian))
    exact = system.exact_solution(np.array([2 * math.pi / w]))
    if exact is not None:
        scale = max(system.length_scale, max_abs(system.v0) / w)
        np.testing.assert_allclose(exact[0][0], system.x0, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(exact[1][0], system.v0, rtol=0, atol=1e-12 * scale * w)


@pytest.mark.parametrize("name, params", CASES)
def test_capabilities_round_trip_through_hdf5_attributes(name, params, tmp_path):
    """as_attrs() has exactly the fields' names; h5py stores and returns them with their types and values:
    floats (NaN for no test frequency), an int64 array (empty for no frames), a bool, an int."""
    capabilities = build(name, params).capabilities
    attrs = capabilities.as_attrs()
    assert set(attrs) == {field.name for field in fields(Capabilities)}
    with h5py.File(tmp_path / "capabilities.h5", "w") as file:
        file.create_group("run").attrs.update(attrs)
    with h5py.File(tmp_path / "capabilities.h5", "r") as file:
        stored = dict(file["run"].attrs)
    assert set(stored) == set(attrs)
    for key in ("test_frequency", "length_scale", "energy_scale"):
        assert isinstance(stored[key], float)
    frequency = stored["test_frequency"]
    assert (math.isnan(frequency) and capabilities.test_frequency is None) or frequency == capabilities.test_frequency
    assert stored["length_scale"] == capabilities.length_scale and stored["energy_scale"] == capabilities.energy_scale
    assert isinstance(stored["frame_shape"], np.ndarray) and stored["frame_shape"].dtype == np.int64
    assert tuple(stored["frame_shape"].tolist()) == (capabilities.frame_shape or ())
    assert isinstance(stored["planar"], (bool, np.bool_)) and bool(stored["planar"]) == capabilities.planar
    assert isinstance(stored["dof_count"], numbers.Integral) and stored["dof_count"] == capabilities.dof_count


def test_cloth_frames_are_rows_of_the_grid():
    """Frames reshape to frame_shape + (3,) = (ny, nx, 3): along axis 0 only y grows, along axis 1 only x
    (vertex = row * nx + col); a non-square grid tells (ny, nx) from (nx, ny)."""
    system = SYSTEMS["cloth"](resolution=(4, 3), size=(0.3, 0.2)).build()
    grid = system.frame(system.x0).reshape(*system.capabilities.frame_shape, 3)
    assert grid.shape == (3, 4, 3)
    assert np.all(np.diff(grid[..., 0], axis=1) > 0) and np.all(np.diff(grid[..., 0], axis=0) == 0)
    assert np.all(np.diff(grid[..., 1], axis=0) > 0) and np.all(np.diff(grid[..., 1], axis=1) == 0)


def test_the_contact_example_touches_at_the_test_state():
    """The cloth example of EXAMPLES tests contact: both the ground and the sphere push some vertex at the test state."""
    label, params = EXAMPLES["cloth"][0]
    system = build("cloth", params)
    depths = [depth for depth, *_ in system._penetration(generic_state(system).reshape(-1, 3))]
    assert label == "contact-damped" and len(depths) == 2 and all(depth.any() for depth in depths)
