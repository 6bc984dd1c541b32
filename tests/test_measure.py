"""`simrun measure`: trajectories computed by any code, measured on the config's system as simrun's own runs are.

The trajectories come from tests/trajectories/verlet.py, velocity Verlet in plain numpy. On the spring its measured
artificial damping is zero and its period error leapfrog's closed form h w / phi - 1 (cos phi = 1 - (h w)^2 / 2) to
1e-6; on a cloth its energies, drift and frames are those of simrun's own leapfrog at the same step to round-off. Bad
input is one line naming the field, exit status 2, and nothing written.
"""

from __future__ import annotations

import importlib.util
import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from simrun.analysis.runs import run_set
from simrun.cli import main
from simrun.findings import findings
from simrun.results import load

EXAMPLE = Path(__file__).parent / "trajectories"


def example_script():
    spec = importlib.util.spec_from_file_location("verlet_example", EXAMPLE / "verlet.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """The example's files (spring.npz, cloth.npz, cloth_model.npz) and its configs, in one folder."""
    folder = tmp_path_factory.mktemp("trajectories")
    script = example_script()
    script.spring(folder)
    script.cloth(folder)
    for config in EXAMPLE.glob("*.yaml"):
        shutil.copy(config, folder)
    return folder


def measure(*arguments) -> int:
    return main(["measure", *map(str, arguments), "-j", "1", "-q"])


def by_label(path: Path) -> dict:
    return {run.label: run for run in run_set(load(path)).runs}


@pytest.mark.parametrize("h", [0.05, 0.1, 0.3])
def test_the_numpy_verlet_spring_measures_leapfrogs_damping_and_period(tmp_path, h):
    """d/w = 0 and T_h/T - 1 = h w / phi - 1 to 1e-6, the measured card of symplectic Euler and leapfrog (whose x
    sequence velocity Verlet's is)."""
    example_script().spring(tmp_path, h=h, periods=40)
    shutil.copy(EXAMPLE / "spring.yaml", tmp_path)
    assert measure(tmp_path / "spring.npz", "--config", tmp_path / "spring.yaml", "--name", "numpy_verlet",
                   "--output", tmp_path / "out", "--no-plots", "--set", f"duration={40 * 2 * math.pi}") == 0
    run = by_label(tmp_path / "out" / "results.h5")["recorded:numpy_verlet"]
    assert run.status == "ok" and run.hw == pytest.approx(h, rel=1e-12)
    phi = 2.0 * math.asin(h / 2.0)
    assert abs(run.damping_fit.rate) < 1e-6 and run.damping_fit.resolved
    assert run.period_error == pytest.approx(h / phi - 1.0, abs=1e-6)


def test_beside_simruns_own_leapfrog_every_number_is_the_same(written, tmp_path):
    """--with-runs: the recorded spring and simrun's leapfrog give the same energies, error and measured card."""
    assert measure(written / "spring.npz", "--config", written / "spring.yaml", "--name", "numpy_verlet",
                   "--with-runs", "--output", tmp_path / "spring") == 0
    runs = by_label(tmp_path / "spring" / "results.h5")
    recorded, own = runs["recorded:numpy_verlet"], runs["leapfrog"]
    assert recorded.run_id.startswith("0000-recorded:numpy_verlet-dt=0.1")
    np.testing.assert_allclose(recorded.energy, own.energy, rtol=1e-12)
    assert recorded.error == pytest.approx(own.error, rel=1e-9)
    assert recorded.period_error == pytest.approx(own.period_error, abs=1e-12)
    assert recorded.stored.attrs["integrator"] == "recorded" and recorded.stored.wall_time > 0  # the file's wall_time
    metadata = json.loads(recorded.stored.attrs["trajectory_metadata"])
    assert metadata["method"] == "velocity Verlet (numpy)"
    figures = {path.name for path in (tmp_path / "spring" / "figures").iterdir()}
    assert {"artificial_damping.png", "spectral_radius_and_period.png", "energy_budget.png"} <= figures
    told = [finding.sentence for finding in findings(run_set(load(tmp_path / "spring" / "results.h5")))]
    assert any(text.startswith("Measured only") and "recorded:numpy_verlet at h w = 0.1: d/w" in text for text in told)


def test_the_numpy_verlet_cloth_is_simruns_leapfrog_to_round_off(written, tmp_path):
    """A 6 x 6 Hookean cloth under gravity, its model read from the file the script wrote: energies, frames and the
    drift equal simrun's own leapfrog at the same step."""
    assert measure(written / "cloth.npz", "--config", written / "cloth.yaml", "--name", "numpy_verlet",
                   "--with-runs", "--output", tmp_path / "cloth", "--no-plots") == 0
    results = load(tmp_path / "cloth" / "results.h5")
    runs = by_label(results.path)
    recorded, own = runs["recorded:numpy_verlet"], runs["leapfrog"]
    assert recorded.status == own.status == "ok" and recorded.steps == own.steps == 500
    scale = np.max(np.abs(own.energy))
    np.testing.assert_allclose(recorded.energy, own.energy, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(recorded.stored.series("frames"), own.stored.series("frames"), rtol=0, atol=1e-12)
    summary = results.summary.set_index("integrator")
    assert summary.loc["recorded:numpy_verlet", "max_rel_energy_drift"] == pytest.approx(
        summary.loc["leapfrog", "max_rel_energy_drift"], rel=1e-9)


def test_without_velocities_they_are_central_differences_and_every_number_says_so(written, tmp_path):
    """No v: the label carries [v=central_differences], the parameter too; the energies are within O(h^2)."""
    with np.load(written / "spring.npz") as file:
        t, x, v = file["t"], file["x"], file["v"]
    np.savez(tmp_path / "positions.npz", t=t, x=x)
    assert measure(tmp_path / "positions.npz", written / "spring.npz", "--config", written / "spring.yaml",
                   "--output", tmp_path / "out", "--no-plots") == 0
    results = load(tmp_path / "out" / "results.h5")
    runs = by_label(results.path)
    differenced, recorded = runs["recorded:positions[v=central_differences]"], runs["recorded:spring"]
    assert differenced.integrator_params["velocities"] == "central_differences"
    assert list(results.summary["integrator.velocities"]) == ["central_differences", "recorded"]
    h = t[1] - t[0]
    assert np.max(np.abs(differenced.energy - recorded.energy)) < h ** 2 * np.max(recorded.energy)
    assert abs(differenced.damping_fit.rate) < 1e-6  # the energy of x's differences keeps no drift either


def test_an_hdf5_trajectory_with_uneven_steps_and_its_metadata(written, tmp_path):
    """HDF5: t, x, v datasets and root attributes; uneven steps are sampled at even times; dt is the mean step."""
    t = np.cumsum(np.r_[0.0, np.tile([0.01, 0.02], 200)])
    x, v = np.cos(t)[:, None], -np.sin(t)[:, None]  # the exact motion, on the config's spring (w = 1)
    with h5py.File(tmp_path / "exact.h5", "w") as file:
        file["t"], file["x"], file["v"] = t, x, v
        file.attrs["code"] = "closed form"
        file.attrs["wall_time"] = 2.5
    assert measure(tmp_path / "exact.h5", "--config", written / "spring.yaml", "--output", tmp_path / "out",
                   "--no-plots") == 0
    run = by_label(tmp_path / "out" / "results.h5")["recorded:exact"]
    assert run.dt == pytest.approx(t[-1] / (t.size - 1), rel=1e-12) and run.steps == t.size - 1
    assert run.wall_time == 2.5 and json.loads(run.stored.attrs["trajectory_metadata"])["code"] == "closed form"
    assert run.stored.attrs["duration"] == pytest.approx(t[-1])
    assert run.error < 1e-12  # the exact motion, measured against the exact solution
    assert np.max(np.abs(run.energy - 0.5)) < 1e-12


def test_a_trajectory_that_blows_up_is_a_diverged_run(written, tmp_path):
    """Forward Euler in numpy at h w = 0.5 over 200 periods: the energy leaves the bound; the run says where."""
    h, steps = 0.5, 2500
    x, v = np.empty(steps + 1), np.empty(steps + 1)
    x[0], v[0] = 1.0, 0.0
    for n in range(steps):
        x[n + 1], v[n + 1] = x[n] + h * v[n], v[n] - h * x[n]
    with np.errstate(over="ignore"):
        keep = np.isfinite(x) & np.isfinite(v)
    np.savez(tmp_path / "euler.npz", t=h * np.arange(steps + 1)[keep], x=x[keep, None], v=v[keep, None])
    assert measure(tmp_path / "euler.npz", "--config", written / "spring.yaml", "--output", tmp_path / "out",
                   "--no-plots", "--set", "duration=1250") == 0
    run = by_label(tmp_path / "out" / "results.h5")["recorded:euler"]
    assert run.status == "diverged" and 0 < run.stored.attrs["t_diverged"] < 1250
    assert "left the bound" in run.stored.message


def test_the_same_call_again_resumes_and_a_changed_file_is_a_changed_config(written, tmp_path, capsys):
    """The file's sha256 is part of the config: unchanged, nothing is run again; changed, the resume is refused."""
    trajectory = tmp_path / "spring.npz"
    shutil.copy(written / "spring.npz", trajectory)
    arguments = [trajectory, "--config", written / "spring.yaml", "--output", tmp_path / "out", "--no-plots"]
    assert measure(*arguments) == 0
    assert measure(*arguments) == 0
    assert "nothing left to run" in capsys.readouterr().out
    with np.load(trajectory) as file:
        arrays = dict(file)
    arrays["x"] = arrays["x"] * (1 + 1e-9)
    np.savez(trajectory, **arrays)
    assert measure(*arguments) == 2
    assert "holds the results of a different config" in capsys.readouterr().err


def bad_trajectory(folder: Path, kind: str) -> Path:
    t = 0.1 * np.arange(11)
    x, v = np.cos(t)[:, None], -np.sin(t)[:, None]
    arrays = {"t": t, "x": x, "v": v}
    if kind == "dofs":
        arrays["x"] = np.column_stack([x, x])
        arrays["v"] = np.column_stack([v, v])
    elif kind == "not increasing":
        arrays["t"] = t[[0, 1, 2, 3, 5, 4, 6, 7, 8, 9, 10]]
    elif kind == "nan":
        arrays["x"] = x.copy()
        arrays["x"][4, 0] = np.nan
    elif kind == "late start":
        arrays["t"] = t + 1.0
    elif kind == "no x":
        del arrays["x"]
    elif kind == "rows":
        arrays["x"] = x[:-1]
    elif kind == "another start":
        arrays["x"] = x + 0.5
    path = folder / "bad.npz"
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("kind, message", [
    ("dofs", "trajectory.x has 2 columns, and the config's system has 1 dofs"),
    ("not increasing", "trajectory.t: not increasing at index 5 (t = 0.5 s, then 0.4 s)"),
    ("nan", "trajectory.x: holds nan at index (4, 0)"),
    ("late start", "trajectory.t: starts at 1 s"),
    ("no x", "trajectory.x: missing from bad.npz"),
    ("rows", "trajectory.x: expected shape (11, dof_count)"),
    ("another start", "trajectory.x[0] lies 0.5 m from the system's initial positions"),
])
def test_a_bad_trajectory_is_one_line_exit_2_and_nothing_written(written, tmp_path, capsys, kind, message):
    path = bad_trajectory(tmp_path, kind)
    assert measure(path, "--config", written / "spring.yaml", "--output", tmp_path / "out") == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("arguments, message", [
    (["missing.npz"], "TRAJECTORY: file 'missing.npz' not found"),
    (["{spring}", "--name", "a", "--name", "b"], "--name: 2 labels for 1 trajectories"),
    (["{spring}", "--name", "has space"], "--name: 'has space' is not a label"),
    (["{config}"], "is not a trajectory file; allowed: .npz, .h5, .hdf5"),
    (["{spring}", "--set", "sweep.system.stiffness=[1, 4]"], "sweep.system.stiffness: recorded:spring was computed for one system"),
    (["{spring}", "--set", "duration=0.05"], "trajectory.t: its first step ends at 0.1 s, past the config's duration 0.05 s"),
])
def test_bad_arguments_are_one_line_exit_2_and_nothing_written(written, tmp_path, capsys, arguments, message):
    arguments = [argument.format(spring=written / "spring.npz", config=written / "spring.yaml") for argument in arguments]
    assert measure(*arguments, "--config", written / "spring.yaml", "--output", tmp_path / "out") == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error
    assert not (tmp_path / "out").exists()


def test_a_system_that_cannot_evaluate_its_energy_is_named(on_path, tmp_path, capsys):
    """A plug-in system of forces only: the trajectory cannot be measured, and the line says what is missing."""
    config = tmp_path / "chain.yaml"
    config.write_text("name: chain\nsystem: {type: 'broken_systems:WithoutEnergyParams', count: 1}\n"
                      "integrators: [leapfrog]\nduration: 1.0\nsweep: {dt: [0.01]}\n")
    t = 0.01 * np.arange(11)
    x = np.tile([0.0, 0.0, 1.0 * math.sin(0.3), -1.0 * math.cos(0.3)], (11, 1))
    np.savez(tmp_path / "chain.npz", t=t, x=x, v=np.zeros_like(x))
    assert measure(tmp_path / "chain.npz", "--config", config, "--output", tmp_path / "out") == 2
    error = capsys.readouterr().err
    assert "the system cannot evaluate its energy (WithoutEnergyChain.potential_energy)" in error, error
    assert not (tmp_path / "out").exists()


def test_trajectories_in_a_config_are_runs_like_any_other(written, tmp_path):
    """The config's own integrators: entry: one run per trajectory whatever the dt sweep; a process pool gives the
    same bytes as serial."""
    config = {"name": "in_config", "system": {"type": "spring_mass", "stiffness": 1.0},
              "integrators": [{"type": "recorded", "trajectory": str(written / "spring.npz"), "source": "verlet"},
                              "symplectic_euler"],
              "duration": 20.0, "sweep": {"dt": [0.1, 0.05]}}
    import simrun

    serial = simrun.run(config, output=tmp_path / "serial", jobs=1, progress=False, figures=False)
    pooled = simrun.run(config, output=tmp_path / "pooled", jobs=2, progress=False, figures=False)
    assert len(serial.runs) == 3
    assert sorted(serial.summary["integrator"]) == ["recorded:verlet", "symplectic_euler", "symplectic_euler"]
    for run_id, run in serial.runs.items():
        np.testing.assert_array_equal(run.series("energy"), pooled.runs[run_id].series("energy"))
    recorded = next(run for run in serial.runs.values() if run.label == "recorded:verlet")
    assert recorded.attrs["duration"] == pytest.approx(20.0, abs=0.1) and recorded.attrs["dt"] == pytest.approx(0.1)


def test_a_trajectory_kept_without_series_keeps_the_summarys_numbers(written, tmp_path):
    """record.series: false (a map) keeps a recorded run's summary numbers as its own run's are, with no datasets."""
    assert measure(written / "spring.npz", "--config", written / "spring.yaml", "--with-runs", "--no-plots",
                   "--output", tmp_path / "out", "--set", "record.series=false") == 0
    results = load(tmp_path / "out" / "results.h5")
    summary = results.summary.set_index("integrator")
    assert summary.loc["recorded:spring", "max_rel_energy_drift"] == pytest.approx(
        summary.loc["leapfrog", "max_rel_energy_drift"], rel=1e-12)
    assert all(not run.datasets for run in results.runs.values())
