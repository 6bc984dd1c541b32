"""Finite-element runs against theory and the shipped FEM configs (docs/fem.md): a bar vibrating in its first axial
mode loses energy under backward Euler by exactly the method's factor 1 / (1 + (h w)^2) per step and keeps it under
implicit midpoint; the shipped square and soft drop run as their comments say."""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.linalg

from simrun.cli import main
from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.results import load
from simrun.solvers import solver_params
from simrun.systems import SYSTEMS

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
LENGTH, YOUNG, DENSITY = 1.0, 1.0e5, 1000.0
# m at the free end: strains of 1e-4, where the neo-Hookean bar is linear to about that (a smaller amplitude drowns
# its energy in the round-off of psi's cancelling terms, eps mu d V)
AMPLITUDE = 1e-4
# how closely each material's energy follows the linear theory at that amplitude: exactly (linear elasticity) or to
# the neo-Hookean energy's terms beyond quadratic
AGREEMENT = {"linear": 1e-9, "neo_hookean": 2e-3}


def bar(tmp_path: Path, material: str = "neo_hookean"):
    """A fixed-free bar (20 x 1 x 1 cells, nu = 0) started in its lowest axial mode, at rest; (system, w rad/s)."""
    config = {"type": "fem", "model": {"box": {"size": [LENGTH, 0.05, 0.05], "cells": [20, 1, 1]}}, "gravity": [0, 0, 0],
              "material": {"model": material, "youngs_modulus": YOUNG, "poisson_ratio": 0.0, "density": DENSITY},
              "pinned": "left"}
    rest = SYSTEMS["fem"].model_validate(config).build()
    free = np.setdiff1d(np.arange(rest.dof_count), rest.fixed_dofs)
    mass = rest.mass[free]
    values, vectors = scipy.linalg.eigh(rest.projective_form().rest_stiffness().toarray()[np.ix_(free, free)], np.diag(mass))
    weighted = mass[:, None] * vectors ** 2
    first = int(np.flatnonzero(weighted[free % 3 == 0].sum(axis=0) / weighted.sum(axis=0) > 0.9)[0])
    shape = np.zeros(rest.dof_count)
    shape[free] = vectors[:, first]
    shape *= AMPLITUDE / np.max(np.abs(shape))
    np.savez(tmp_path / "mode.npz", vertices=(rest.x0 + shape).reshape(-1, 3))
    system = SYSTEMS["fem"].model_validate({**config, "initial": {"file": str(tmp_path / "mode.npz")}}).build()
    return system, math.sqrt(values[first])


def run(system, name: str, dt: float, steps: int) -> list[float]:
    integrator = INTEGRATORS[name]()
    solver = solver_params(type="newton", tolerance=1e-13).build()
    state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    energies = [system.total_energy(state.x, state.v)]
    for _ in range(steps):
        state, stats = integrator.step(system, state, dt, solver)
        assert stats.converged
        energies.append(system.total_energy(state.x, state.v))
    return energies


@pytest.mark.parametrize("material", sorted(AGREEMENT))
@pytest.mark.parametrize("hw", [0.3, 1.0, 3.0])
def test_backward_euler_damps_the_bar_s_first_mode_by_its_amplification_factor(tmp_path, hw, material):
    """Backward Euler on q'' = -w^2 q multiplies (w q, q') by |R(i h w)| = 1/sqrt(1 + (h w)^2) times a rotation, so the
    mode's energy by exactly 1/(1 + (h w)^2) every step: the linear bar's energy follows that factor to round-off, the
    neo-Hookean bar's to its nonlinearity at strains of 1e-4."""
    system, w = bar(tmp_path, material)
    energies = np.array(run(system, "backward_euler", hw / w, 4))
    assert np.allclose(energies[1:] / energies[:-1], 1.0 / (1.0 + hw * hw), rtol=AGREEMENT[material], atol=0.0)


@pytest.mark.parametrize("material", sorted(AGREEMENT))
def test_implicit_midpoint_keeps_the_bar_s_energy(tmp_path, material):
    """The implicit midpoint rule conserves quadratic invariants: 100 steps at h w = 1 keep the vibrating linear bar's
    energy to round-off and the neo-Hookean bar's to its terms beyond quadratic (Newton to 1e-13)."""
    system, w = bar(tmp_path, material)
    energies = np.array(run(system, "implicit_midpoint", 1.0 / w, 100))
    assert np.max(np.abs(energies / energies[0] - 1.0)) < AGREEMENT[material]


def run_config(tmp_path: Path, name: str, *overrides: str) -> Path:
    output = tmp_path / name
    arguments = [str(CONFIGS / f"{name}.yaml"), "--output", str(output), "-q", "--no-plots"]
    for override in overrides:
        arguments += ["--set", override]
    assert main(arguments) == 0
    return output / "results.h5"


def test_the_shipped_square_rings_and_each_method_damps_as_expected(tmp_path):
    """configs/fem_square.yaml at its three smallest steps: every implicit run ends ok; backward Euler takes most of
    the energy, implicit midpoint and Newmark keep it to a few percent, and no element inverts."""
    results = load(run_config(tmp_path, "fem_square", "sweep.dt=[0.00125,0.0025,0.005]", "duration=1.0"))
    summary = results.summary
    implicit = summary[summary["integrator"] != "symplectic_euler"]
    assert set(implicit["status"]) == {"ok"}
    drift = {(row.integrator, row.dt): abs(row.max_rel_energy_drift) for row in summary.itertuples()}
    for dt in (0.00125, 0.0025, 0.005):
        assert drift[("backward_euler", dt)] > 0.9
        assert drift[("implicit_midpoint", dt)] < 0.05 and drift[("newmark", dt)] < 0.05
    for run_ in results.runs.values():
        if run_.status.name.lower() == "ok":
            assert np.min(run_.series("volume_ratio_min")) > 0.0


def test_the_shipped_soft_drop_lands_without_penetrating(tmp_path):
    """configs/soft_drop.yaml through the landing (to 0.2 s) with backward Euler: every step converges, the smallest
    contact distance stays positive and within dhat once it lands, every element keeps volume, and friction and the
    landing slow the sideways motion."""
    path = run_config(tmp_path, "soft_drop", "duration=0.2", "integrators=[backward_euler]")
    results = load(path)
    (stored,) = results.runs.values()
    assert stored.status.name.lower() == "ok"
    with h5py.File(path, "r") as file:
        group = file["runs"][stored.run_id]
        distance = group["contact_distance"][()]
        assert np.all(group["newton_iterations"][()] < 100)
    assert np.all(distance > 0.0) and distance.min() < 1e-3
    assert np.min(stored.series("volume_ratio_min")) > 0.1
    frames = stored["frames"]  # one per step (20 steps, at most 60 frames): the mean x advance per step
    advance = np.diff(frames[:, :, 0].mean(axis=1))
    assert advance[-1] < 0.9 * advance[0]


def test_calibration_recovers_young_s_modulus_from_the_same_method(tmp_path):
    """Noise-free markers of a sagging neo-Hookean bar made by backward Euler at dt = 0.01 s with E = 2e4 Pa: the fit
    of E with the same method and dt, from 1e4 Pa, recovers it within 1 % (with the exact forward sensitivities of
    Fem.parameter_derivative)."""
    import simrun

    config = {"name": "fit_young", "output": str(tmp_path / "fit"),
              "system": {"type": "fem", "model": {"box": {"size": [0.4, 0.05, 0.05], "cells": [8, 1, 1]}},
                         "material": {"model": "neo_hookean", "youngs_modulus": 2.0e4, "poisson_ratio": 0.3},
                         "pinned": "left"},
              "integrators": ["backward_euler"], "solver": {"type": "newton", "tolerance": 1e-10},
              "duration": 0.3, "sweep": {"dt": [0.01]},
              "fit": {"observed": {"synthetic": {"integrator": "backward_euler", "dt": 0.01}},
                      "markers": [8, 17, 26, 35],
                      "parameters": {"system.material.youngs_modulus": {"start": 1.0e4, "bounds": [1.0e3, 1.0e6]}}}}
    results = simrun.fit(config, jobs=1, figures=False, progress=False)
    table = results.fits.table
    fitted = table[table["integrator"] == "backward_euler"]
    (value,) = fitted["system.material.youngs_modulus"].to_numpy()
    assert value == pytest.approx(2.0e4, rel=0.01)


def test_a_static_cantilever_converges_to_euler_bernoulli_with_refinement():
    """A stable neo-Hookean cantilever (1 m x 0.1 m x 0.1 m, nu = 0, E = 1e8 Pa) sagging under its own weight: Euler-
    Bernoulli's tip deflection is q L^4 / (8 E I), q = rho g A, I = h^4 / 12. Linear tets lock in bending: with 8 x 1 x
    1 cells the tip sags 21 % of that, with 16 x 2 x 2 50 %, 32 x 4 x 4 80 % (64 x 8 x 8: 94 %, docs/fem.md); the
    error shrinks at a rising rate toward 2 (0.66, 1.30, 1.87), linear elements' order. The static state is backward
    Euler at dt = 100 s from rest (the inertia term is 1e-10 of the stiffness), three steps with the velocity
    zeroed."""
    length, side, young, density, gravity = 1.0, 0.1, 1.0e8, 1000.0, 9.81
    exact = density * gravity * side * side * length ** 4 / (8.0 * young * side ** 4 / 12.0)
    ratios = []
    for n in (1, 2, 4):
        system = SYSTEMS["fem"].model_validate({
            "type": "fem", "model": {"box": {"size": [length, side, side], "cells": [8 * n, n, n]}},
            "material": {"model": "stable_neo_hookean", "youngs_modulus": young, "poisson_ratio": 0.0, "density": density},
            "pinned": "left", "gravity": [0.0, 0.0, -gravity]}).build()
        integrator = INTEGRATORS["backward_euler"]()
        solver = solver_params(type="newton", tolerance=1e-10).build()
        state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
        for _ in range(3):
            state, stats = integrator.step(system, state, 100.0, solver)
            assert stats.converged
            state = State(state.t, state.x, np.zeros_like(state.v), state.aux)
        tip = (state.x - system.x0).reshape(-1, 3)[system.mesh.named_vertices["x_max"], 2].mean()
        ratios.append(-tip / exact)
    assert ratios == pytest.approx([0.207, 0.499, 0.797], abs=0.005)
    errors = 1.0 - np.array(ratios)
    assert np.all(np.diff(np.log2(errors[:-1] / errors[1:])) > 0)  # the rate rises toward the asymptotic 2


def test_the_shipped_twisted_bar_is_turned_then_released(tmp_path):
    """configs/twisted_bar.yaml to 0.8 s at dt = 2.5 ms: the turning end does work until its release at 0.5 s and
    none after; from there implicit midpoint keeps the energy to 2 % (its error on the neo-Hookean energy, which is
    not quadratic: 8 % at dt = 5 ms) while backward Euler takes most of it; the released end leaves the path it
    would have followed."""
    results = load(run_config(tmp_path, "twisted_bar", "sweep.dt=[0.0025]", "duration=0.8",
                              "integrators=[backward_euler,implicit_midpoint]"))
    energies = {}
    for stored in results.runs.values():
        assert stored.status.name.lower() == "ok"
        t, energy, work = (stored.series(key) for key in ("t", "energy", "prescribed_work"))
        released = t >= 0.5 - 1e-9
        assert work[released][0] > 100 * energy[0] and np.ptp(work[released]) == 0.0
        energies[stored.integrator] = energy[released] / energy[released][0]
        frames, frame_t = stored["frames"], stored["frame_t"]
        end = np.flatnonzero(np.isclose(frames[0, :, 0], 1.0))
        center = np.array([0.05, 0.05])
        first, last = (frames[index, end][:, 1:] - center for index in (0, -1))  # (y, z) about the bar's axis
        angle = np.arctan2(last[:, 1], last[:, 0]) - np.arctan2(first[:, 1], first[:, 0])
        path_angle = math.radians(180.0) * frame_t[-1]  # where the path would have turned them by the end
        assert np.min(np.abs(np.angle(np.exp(1j * (angle - path_angle))))) > 0.2
    assert np.max(np.abs(energies["implicit_midpoint"] - 1.0)) < 0.02
    assert energies["backward_euler"][-1] < 0.5


MIXED_SQUARE = {"model": {"square": {"segments": 4, "size": 1.0}}, "gravity": [0.0, 0.0], "initial": {"scale": [1.4, 1.0]}}


def mixed_sweep(systems: list[dict]) -> dict:
    base = {key: value for key, value in systems[0].items() if key != "label"}  # a label names swept values only
    return {"name": "mixed", "system": base, "integrators": ["backward_euler"], "duration": 0.1,
            "sweep": {"dt": [0.01], "system": systems}}


def test_a_mass_spring_model_and_a_finite_element_model_of_the_same_mesh_run_in_one_sweep(tmp_path):
    """sweep.system holds whole systems: the course square as springs and as neo-Hookean triangles, each named by its
    label in the run ids and the stored swept values; both start from the same vertices and run to the end."""
    fem_square = {"label": "neo-Hookean", "type": "fem", **MIXED_SQUARE,
                  "material": {"model": "neo_hookean", "youngs_modulus": 1.0e5, "poisson_ratio": 0.4, "density": 1000.0}}
    springs = {"label": "springs", "type": "mass_spring", **MIXED_SQUARE, "stiffness": 1.0e4, "mass": {"total": 1000.0}}
    path = tmp_path / "mixed.yaml"
    path.write_text(json.dumps(mixed_sweep([fem_square, springs])))
    assert main([str(path), "--output", str(tmp_path / "out"), "-q", "--no-plots"]) == 0
    results = load(tmp_path / "out" / "results.h5")
    runs = sorted(results.runs.values(), key=lambda run: run.run_id)
    assert [run.run_id for run in runs] == ["0000-backward_euler-dt=0.01-system=neo-Hookean",
                                            "0001-backward_euler-dt=0.01-system=springs"]
    assert [run.swept["system"] for run in runs] == ["neo-Hookean", "springs"]
    assert [run.system_params["type"] for run in runs] == ["fem", "mass_spring"]
    assert all(run.status.name.lower() == "ok" for run in runs)
    assert np.array_equal(runs[0]["frames"][0], runs[1]["frames"][0])


def test_swept_systems_without_labels_are_named_by_type_and_clashing_labels_are_refused():

    fem_square = {"type": "fem", **MIXED_SQUARE}
    springs = {"type": "mass_spring", **MIXED_SQUARE}
    runs = expand_runs(load_experiment(mixed_sweep([fem_square, springs, {**springs, "stiffness": 10.0}]))[0])
    assert [run.swept["system"] for run in runs] == ["fem", "mass_spring#2", "mass_spring#3"]
    with pytest.raises(ConfigError, match="two values are named 'same'"):
        expand_runs(load_experiment(mixed_sweep([{"label": "same", **fem_square}, {"label": "same", **springs}]))[0])


def test_the_shipped_cloth_fem_falls_freely_then_rests_on_the_sphere(tmp_path):
    """configs/cloth_fem.yaml with backward Euler at dt = 4 ms to 0.6 s: the spring cloth, the shell and the bare
    membrane each fall freely (no stretch, so no elastic energy) until the first contact at the free-fall time
    sqrt(2 x 0.3 m / g) = 0.247 s, land on the sphere (the vertex nearest its top within 5 mm of its surface) and
    keep their triangles' areas within 10 %; the shell's hinges store bending energy, the bare membrane has none."""
    results = load(run_config(tmp_path, "cloth_fem", "sweep.dt=[0.004]", "duration=0.6",
                              "integrators=[backward_euler]"))
    center, radius = np.array([0.5, 0.5, -0.6]), 0.3
    landing = math.sqrt(2 * 0.3 / 9.81)
    for stored in results.runs.values():
        label = stored.swept["system"]
        # Newton on the springs' penalty contact stalls above its tolerance at two steps of 150 (as in cloth_sphere)
        assert stored.status.name.lower() == "ok" or (label == "springs" and int(stored.message.split()[0]) <= 2), \
            stored.run_id
        t, contact = stored.series("t"), stored.series("contact_energy")
        first = t[np.flatnonzero(contact > 0)[0]]
        assert abs(first - landing) < 3 * 0.004, (stored.run_id, first)
        frames = stored["frames"]
        top = int(np.argmin(np.linalg.norm(frames[0][:, :2] - center[:2], axis=1)))
        assert abs(np.linalg.norm(frames[-1][top] - center) - radius) < 5e-3, stored.run_id
        if label != "springs":
            assert stored.series("volume_ratio_min").min() > 0.9 and stored.series("volume_ratio_max").max() < 1.1
            before = t < landing - 0.01
            assert np.abs(stored.series("elastic_energy")[before]).max() < 1e-9
            bending_energy = stored.series("bending_energy")
            assert (bending_energy.max() > 1e-6) if label == "stvk_shell" else (bending_energy.max() == 0.0)


def test_a_sweep_of_whole_systems_needs_no_base_system():
    """Without a top-level `system`, the first swept system (less its label) is the base; without either, the config
    is refused naming `system`."""
    fem_square = {"label": "neo-Hookean", "type": "fem", **MIXED_SQUARE}
    springs = {"label": "springs", "type": "mass_spring", **MIXED_SQUARE, "stiffness": 1.0e4, "mass": {"total": 1000.0}}
    config = mixed_sweep([fem_square, springs])
    del config["system"]
    experiment, _ = load_experiment(config)
    assert experiment.system.type == "fem" and not hasattr(experiment.system, "label")
    assert [run.system.type for run in expand_runs(experiment)] == ["fem", "mass_spring"]
    del config["sweep"]["system"]
    with pytest.raises(ConfigError, match="system"):
        load_experiment(config)


def test_a_cold_compilation_cache_runs_in_parallel_workers(tmp_path):
    """A fresh install's first parallel run of finite elements compiles the kernels in the pool's workers, after the
    worker has limited numba's threads: that limit must not touch NUMBA_NUM_THREADS once numba's pool is running
    (every compilation re-reads the variable and refuses a change). A fresh cache folder makes the compilation
    cold; the command runs in its own process, as a user's would."""
    import os
    import subprocess
    import sys

    config = {"name": "cold", "system": {"type": "fem", **MIXED_SQUARE}, "integrators": ["backward_euler"],
              "duration": 0.02, "sweep": {"dt": [0.01, 0.02]}}
    path = tmp_path / "cold.yaml"
    path.write_text(json.dumps(config))
    environment = {key: value for key, value in os.environ.items() if key != "NUMBA_NUM_THREADS"}
    environment["NUMBA_CACHE_DIR"] = str(tmp_path / "numba-cache")
    done = subprocess.run([sys.executable, "-m", "simrun", str(path), "--output", str(tmp_path / "out"), "-j", "2",
                           "-q", "--no-plots"], env=environment, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))
