"""Every system of the registry against the System contract (systems/base.py, docs/systems.md), parametrised over
``simrun.systems.SYSTEMS``, the installed plug-ins (entry points ``simrun.systems``) and the example plug-ins of
tests/plugins: a new system is checked here as soon as it is registered.

The checks themselves are ``simrun.contracts.system`` (so that ``simrun check-system`` runs the same ones for a
user): each is asserted here for every system. Each system is tried at the small instances of ``EXAMPLES``; a
system without an entry there is tried at its default parameters. The state x = x0 + 0.05 L z (L =
length_scale, z ~ N(0, I), seeded) is generic: no symmetry of x0 hides a wrong sign or a missing term.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import sys
from dataclasses import fields
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import make_runs
from simrun.execution.measures import moving_dofs, on_paths
from simrun.execution.simulate import simulate
from simrun.integrators import State
from simrun.systems import SYSTEMS, Capabilities, System, SystemParams, plugins
from simrun.plugins import is_path
from simrun.contracts.system import CHECKS, ROUND_OFF, check_params, generic_state, held_dofs, max_abs, stable_dt

PLUGIN_FOLDER = Path(__file__).parent / "plugins"  # the example plug-ins (the one of docs/systems.md among them)


@contextlib.contextmanager
def importable(folder: Path):
    """``folder`` on sys.path for the block: its modules, once imported, stay in sys.modules."""
    sys.path.insert(0, str(folder))
    try:
        yield
    finally:
        sys.path.remove(str(folder))


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
    # every spring law and damping model, both dimensions, every kind of constraint (oblique sliding
    # filters, a prescribed rotation) and contact: the contract holds with all of them
    "mass_spring": [
        ("square-2d-squared-length", {"model": {"square": {"segments": 2, "size": 0.4}}, "spring_law": "squared_length",
                                      "stiffness": {"stretch": 80.0, "shear": 20.0}, "mass": {"per_vertex": 0.02},
                                      "damping": [{"model": "relative", "coefficient": 0.01}, {"model": "drag", "coefficient": 0.02}],
                                      "pinned": ["top_left"], "constraints": [{"vertices": [1], "normal": [1.0, 2.0]}],
                                      "prescribed": [{"vertices": [8], "rotation": {"center": [0.0, 0.0], "rate": 30.0}}],
                                      "initial": {"scale": [1.2, 1.0]}}),
        ("grid-3d-contact", {"model": {"grid": {"resolution": [4, 3], "size": [0.3, 0.2]}}, "stiffness": 50.0,
                             "mass": {"density": 2.0}, "pinned": ["bottom_left"],
                             "damping": [{"model": "spring", "coefficient": 0.05}, {"model": "rayleigh", "alpha": 0.1, "beta": 0.01}],
                             "constraints": [{"vertices": ["top_right"], "direction": [1.0, 1.0, 0.5]}],
                             "prescribed": [{"vertices": [1], "velocity": [0.0, 0.0, 0.2]}],
                             "initial": {"spin": [0.4, -0.2, 1.5]},
                             "contact": {"ground": {"height": 0.0, "stiffness": 2e3},
                                         "sphere": {"center": [0.15, 0.1, -0.05], "radius": 0.08, "stiffness": 2e3}}}),
        ("rope-3d", {"model": {"rope": {"count": 5, "length": 0.5, "direction": [1.0, 0.0, 0.0], "bend": True}},
                     "stiffness": {"stretch": 100.0, "bend": 1.0}, "mass": {"total": 0.05}, "pinned": ["first"]}),
    ],
    # every energy, both dimensions, every kind of constraint, the element damping models and penalty contact
    "fem": [
        ("box-neo-hookean-rayleigh", {"model": {"box": {"size": [0.3, 0.1, 0.1], "cells": [3, 1, 1]}},
                                      "material": {"model": "neo_hookean", "youngs_modulus": 1e4}, "pinned": "left",
                                      "damping": [{"model": "rayleigh", "alpha": 0.1, "beta": 0.01}]}),
        ("square-corotated-constraints", {"model": {"square": {"segments": 2, "size": 0.4}},
                                          "material": {"model": "corotated", "youngs_modulus": 1e4},
                                          "pinned": ["top_left"], "constraints": [{"vertices": [1], "normal": [1.0, 2.0]}],
                                          "prescribed": [{"vertices": [8], "rotation": {"center": [0.0, 0.0], "rate": 30.0}}],
                                          "initial": {"scale": [1.2, 1.0]}}),
        ("box-stable-neo-hookean-contact", {"model": {"box": {"size": [0.2, 0.2, 0.1], "cells": [2, 2, 1]}},
                                            "material": {"model": "stable_neo_hookean", "youngs_modulus": 1e4},
                                            "contact": {"ground": {"height": 0.02, "stiffness": 2e3}},
                                            "damping": [{"model": "drag", "coefficient": 0.05}],
                                            "initial": {"spin": [0.4, -0.2, 1.5]}}),
        ("square-stvk", {"model": {"square": {"segments": 2, "size": 0.4}}, "material": {"model": "stvk"}}),
        ("box-linear-prescribed", {"model": {"box": {"size": [0.2, 0.2, 0.1], "cells": [2, 2, 1]}},
                                   "material": {"model": "linear"},
                                   "prescribed": [{"vertices": "x_max", "velocity": [0.1, 0.0, 0.0]}]}),
        ("box-corotated-consistent-mass", {"model": {"box": {"size": [0.2, 0.1, 0.1], "cells": [2, 1, 1]}},
                                           "material": {"model": "corotated", "youngs_modulus": 1e4},
                                           "mass": "consistent", "pinned": "left",
                                           "prescribed": [{"vertices": "x_max", "velocity": [0.0, 0.1, 0.0]}],
                                           "initial": {"spin": [0.4, -0.2, 1.5]}}),
        ("shell-stvk-bending-sphere", {"model": {"grid": {"resolution": [4, 3], "size": [0.3, 0.2]}},
                                       "material": {"model": "stvk", "youngs_modulus": 1e5, "density": 0.5},
                                       "thickness": 1e-3, "bending": {"stiffness": 1e-3}, "pinned": ["top_left"],
                                       "damping": [{"model": "rayleigh", "alpha": 0.1, "beta": 1e-4}],
                                       "contact": {"sphere": {"center": [0.15, 0.1, -0.05], "radius": 0.06,
                                                              "stiffness": 2e3}},
                                       "initial": {"spin": [0.4, -0.2, 1.5]}}),
    ],
    # the plug-in of docs/systems.md; at the test state some of its springs are compressed (the projection acts)
    "pendulum_chain:ChainParams": [
        ("defaults", {}),
        ("one-mass-linear", {"count": 1, "hardening": 0.0, "stiffness": 50.0, "angle": 1.2}),
    ],
}
EXAMPLE_PLUGINS = [name for name in EXAMPLES if is_path(name)]
with importable(PLUGIN_FOLDER):
    for _name in EXAMPLE_PLUGINS:
        plugins.resolve(_name)

# the built-in systems, the installed plug-ins, the example plug-ins
NAMES = [*plugins.names(), *EXAMPLE_PLUGINS]
CASES = [pytest.param(name, params, id=f"{name}-{label}")
         for name in NAMES for label, params in EXAMPLES.get(name, [("defaults", {})])]

STEP_COUNT = 20
INTEGRATORS = ("backward_euler", "symplectic_euler")


def model(name: str, params: dict) -> SystemParams:
    return plugins.resolve(name).model_validate({"type": name, **params})


def build(name: str, params: dict) -> System:
    return model(name, params).build()


# -- the registry ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(SYSTEMS))
def test_the_registry_maps_config_names_to_params_models_of_their_system_class(name):
    """SYSTEMS[name] is a SystemParams whose type tag is the name and whose build() is a system_class."""
    params_model = SYSTEMS[name]
    assert issubclass(params_model, SystemParams) and issubclass(params_model.system_class, System)
    params = params_model()
    assert params.type == name
    system = params.build()
    assert type(system) is params_model.system_class
    assert params.dof_count == system.dof_count
    assert params_model.system_class.records_state_per_sample == system.records_state_per_sample


# -- the contract (runner/contracts/system.py) ------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_every_name_resolves_to_a_params_model_that_builds_its_system_class(name):
    """plugins.resolve(name) is a SystemParams with a `type` field that keeps the name as written, and its
    build() is a system_class with params.dof_count degrees of freedom (contract.check_params)."""
    params = model(name, dict(EXAMPLES.get(name, [("", {})])[0][1]))
    assert params.type == name
    check, system = check_params(params)
    assert check.passed, str(check)
    assert isinstance(system, System)


@pytest.mark.parametrize("check", list(CHECKS))
@pytest.mark.parametrize("name, params", CASES)
def test_the_system_meets_the_contract(name, params, check):
    """Each clause of the contract, as runner/contracts/system.py measures it (its docstrings give the formulas and
    tolerances): shapes of the state, the gradient and the Hessian against central differences (relative
    1e-6), the SPD projection, the Hessian pattern, damping D = D^T >= 0, forces zero on fixed dofs, the
    observables and their layout, the capabilities, the test frequency, the energy reference, a short run.
    A clause that does not apply (no damping, no pattern, no test frequency) is skipped."""
    result = CHECKS[check](build(name, params))
    if result.passed is None:
        pytest.skip(result.detail)
    assert result.passed, str(result)


def replay(system: System, run) -> list[State]:
    """The states of the run, step by step, from the run's own integrator and a fresh solver: (x, v) at every step."""
    solver = run.solver.build()
    state = run.integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    states = [state]
    moving = moving_dofs(system)
    for step in range(1, run.step_count + 1):
        state, _ = run.integrator.step(system, state, run.dt, solver)
        if moving.size:  # as the runner does: the vertices on prescribed paths put on their paths after each step
            state = on_paths(system.constraints, moving, state, step * run.dt)
        states.append(state)
    return states


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("name, params", CASES)
def test_a_run_records_the_observables_of_its_states(name, params, integrator):
    """Through config -> expand_runs -> simulate, 20 steps: every recorded observable equals
    system.observables(x, v) (relative 1e-12) at the state recorded with it. Small systems record (x, v) in each
    sample; frame-recording ones keep x in frames of frame_shape + (vertex_dim,): there, where a frame and a sample share a
    time, x is the frame's and v that of the same step replayed with the run's integrator, whose x must be the frame.
    (A plug-in's type goes through the config as written: ``pendulum_chain:ChainParams``.)"""
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
        vertex_dim = getattr(system, "vertex_dim", 3)
        assert frames.shape[1:] == (system.dof_count // vertex_dim, vertex_dim)
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
    held = held_dofs(system)  # the fixed dofs not on a prescribed path
    np.testing.assert_array_equal(final_x[held], system.x0[held])
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


def mass_spring_capabilities(params) -> dict:
    """No test frequency, not planar; frames of the model's dimension, (ny, nx) for grids and squares."""
    model = params.spring_model()
    return {"test_frequency": None, "planar": False, "frame_shape": model.grid_shape, "vertex_dim": model.dim}


# what each system of the registry must declare; a system missing here is held to the generic checks only
EXPECTED_CAPABILITIES = {"spring_mass": spring_mass_capabilities, "circular_motion": circular_motion_capabilities,
                         "cloth": cloth_capabilities, "mass_spring": mass_spring_capabilities}


@pytest.mark.parametrize("name, params", CASES)
def test_capabilities_are_what_the_system_is(name, params):
    """The values each system of the registry must declare (EXPECTED_CAPABILITIES); the generic clauses
    (length_scale, energy_scale, dof_count, frame_shape, planar) are contract.check_capabilities."""
    if name not in EXPECTED_CAPABILITIES:
        pytest.skip(f"{name} is held to the generic clauses only")
    params_model = model(name, params)
    capabilities = params_model.build().capabilities
    for key, value in EXPECTED_CAPABILITIES[name](params_model).items():
        assert getattr(capabilities, key) == value, key


@pytest.mark.parametrize("name, params", CASES)
def test_capabilities_round_trip_through_hdf5_attributes(name, params, tmp_path):
    """as_attrs() has exactly the fields' names; h5py stores and returns them with their types and values:
    floats (NaN for no test frequency), an int64 array (empty for no frames), a bool, an int."""
    capabilities = build(name, params).capabilities
    attrs = capabilities.as_attrs()
    assert set(attrs) == {field.name for field in fields(Capabilities)} - {"oscillator"} | {"natural_frequency", "damping_ratio"}
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
    oscillator = capabilities.oscillator  # (w0, zeta), or None: NaN in both attributes
    assert np.array_equal([stored["natural_frequency"], stored["damping_ratio"]],
                          [np.nan, np.nan] if oscillator is None else list(oscillator), equal_nan=True)


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
    positions = generic_state(system).reshape(-1, 3)
    depths = [np.maximum(-contact.collider.signed_distance(positions), 0.0) for contact in system.contact.colliders]
    assert label == "contact-damped" and len(depths) == 2 and all(depth.any() for depth in depths)
