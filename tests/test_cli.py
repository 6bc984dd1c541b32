"""The command line end to end, and the one-line answer to every bad config."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from simrun.cli import main
from simrun.results import load

SPRING_CONFIG = """\
name: spring-euler
system:
  type: spring_mass
  mass: 1.0
  stiffness: 100.0
  damping: 0.0
  x0: 1.0
  v0: 0.0
integrators:
  - forward_euler
  - symplectic_euler
  - {type: backward_euler}
solver:
  type: newton
  tolerance: 1.0e-10
  max_iterations: 50
  linear_solver: direct
duration: 4.0
sweep:
  dt: [0.001, 0.01, 0.5]
record:
  every: 1
divergence:
  energy_factor: 1.0e6
"""


def write(tmp_path: Path, text: str, name: str = "config.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_run_writes_every_run_and_figure(tmp_path, capsys):
    config = write(tmp_path, SPRING_CONFIG + f"output: {tmp_path / 'out'}\n")
    assert main([str(config)]) == 0
    out = capsys.readouterr().out
    assert "results:" in out and "figures:" in out
    results = tmp_path / "out" / "results.h5"
    with h5py.File(results, "r") as file:
        assert file.attrs["simrun_version"]
        assert file.attrs["config"].startswith("name: spring-euler")
        assert len(file.attrs["config_hash"]) == 64
        assert "numpy" in json.loads(file.attrs["package_versions"])
        runs = file["runs"]
        assert len(runs) == 9
        statuses = {}
        for run_id, group in runs.items():
            attrs = group.attrs
            statuses[(attrs["integrator"], attrs["dt"])] = attrs["status"]
            for key in ("system", "integrator", "dt", "duration", "status", "steps", "wall_time", "params"):
                assert key in attrs, key
            params = json.loads(attrs["params"])
            assert params["dt"] == attrs["dt"]
            samples = group["t"].shape[0]
            for key in ("energy", "kinetic_energy", "potential_energy"):
                assert group[key].shape == (samples,)
            assert group["positions"].shape == (samples, 1) == group["velocities"].shape
            assert group["momentum"].shape == (samples, 1)
            assert group["newton_iterations"].shape == (attrs["steps"],) == group["linear_iterations"].shape
            if attrs["integrator"] != "backward_euler":
                assert not group["newton_iterations"][()].any()
        # h w = 5 at dt = 0.5: forward Euler multiplies the energy by 26 per step, symplectic Euler is past h w = 2
        assert statuses[("forward_euler", 0.5)] == "diverged"
        assert statuses[("symplectic_euler", 0.5)] == "diverged"
        assert statuses[("backward_euler", 0.5)] == "ok"
        assert "t_diverged" in runs["0002-forward_euler-dt=0.5"].attrs
    summary = load(results).summary
    assert len(summary) == 9 and set(summary["status"]) == {"ok", "diverged"}
    assert summary["mean_newton_iterations"][summary["integrator"] == "backward_euler"].min() >= 1
    figures = {path.name for path in (tmp_path / "out" / "figures").iterdir()}
    for name in ("energy_over_time", "energy_drift_vs_dt", "stability_map", "newton_iterations_vs_dt"):
        assert f"{name}.png" in figures, name
    assert not any(name.endswith(".svg") for name in figures)  # SVG on request only


def test_circular_motion_draws_orbits_and_plot_redraws_from_the_file(tmp_path):
    config = write(tmp_path, f"""\
        name: orbits
        system: {{type: circular_motion, force: gravity}}
        integrators: [forward_euler, symplectic_euler, backward_euler]
        duration: 6.3
        sweep: {{dt: [0.05, 0.1]}}
        output: {tmp_path / 'orbits'}
        """)
    assert main([str(config), "-q"]) == 0
    results = tmp_path / "orbits" / "results.h5"
    with h5py.File(results, "r") as file:
        group = file["runs"]["0000-forward_euler-dt=0.05"]
        assert group["angular_momentum"].shape[1] == 3 and group["radius"].ndim == 1
    redrawn = tmp_path / "redrawn"
    assert main(["plot", str(results), "--output", str(redrawn), "--svg"]) == 0
    assert (redrawn / "orbits.png").exists() and (redrawn / "orbits.svg").exists()


def test_sweeping_another_key_and_set_overrides(tmp_path):
    config = write(tmp_path, f"""\
        name: stiff
        system: {{type: spring_mass}}
        integrators: [backward_euler]
        duration: 1.0
        sweep:
          dt: {{logspace: [-3, -2, 2]}}
          system.stiffness: [10, 1000]
        output: {tmp_path / 'stiff'}
        """)
    assert main([str(config), "-q", "--no-plots", "--set", "system.damping=0.5", "--set", "duration=0.5"]) == 0
    with h5py.File(tmp_path / "stiff" / "results.h5", "r") as file:
        runs = list(file["runs"].values())
        assert len(runs) == 4
        assert sorted({json.loads(run.attrs["params"])["system.stiffness"] for run in runs}) == [10, 1000]
        assert sorted({run.attrs["dt"] for run in runs}) == [0.001, 0.01]
        assert all(run.attrs["duration"] == 0.5 for run in runs)
        assert all(json.loads(run.attrs["system_params"])["damping"] == 0.5 for run in runs)
        assert "damping: 0.5" in file.attrs["config"]


@pytest.mark.parametrize("text, field", [
    ("name: x\nsystem: {type: spring_mass, stifness: 3}\nintegrators: [forward_euler]\nsweep: {dt: [0.1]}\n", "system.stifness: unknown key (did you mean 'stiffness'?)"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [backward_eulr]\nsweep: {dt: [0.1]}\n", "unknown integrator 'backward_eulr' (did you mean 'backward_euler'?)"),
    ("name: x\nsystem: {type: pendulum}\nintegrators: [forward_euler]\nsweep: {dt: [0.1]}\n", "system.type: unknown system 'pendulum'; valid: spring_mass, circular_motion"),
    ("name: x\nsystem: {type: spring_mass, mass: heavy}\nintegrators: [forward_euler]\nsweep: {dt: [0.1]}\n", "system.mass: Input should be a valid number"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: [0.1, -0.01]}\n", "sweep: dt must be finite numbers > 0, got -0.01"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: [0]}\n", "sweep: dt must be finite numbers > 0"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: []}\n", "sweep.dt: an empty sweep runs nothing"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\n", "sweep: needs 'dt': a list of time steps (s), or a step_control block"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nduration: 1\nsweep: {dt: [2.0]}\n", "sweep.dt: 2 is longer than duration 1"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: [0.1]}\nsolver: {tolerance: -1}\n", "solver.tolerance: Input should be greater than 0"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: [0.1], system.stiffnes: [1, 2]}\n", "sweep: system.stiffnes: unknown key (did you mean 'stiffness'?)"),
    ("name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: [0.1]\n", "malformed YAML"),
    ("name: x\nsystem: !!python/object/apply:os.system [echo hi]\nintegrators: [forward_euler]\nsweep: {dt: [0.1]}\n", "YAML tags that build objects are not allowed"),
    ("- just\n- a list\n", "expected a mapping"),
])
def test_bad_config_is_one_line_exit_2_and_no_file(tmp_path, capsys, text, field):
    config = write(tmp_path, text + f"output: {tmp_path / 'never'}\n" if "sweep: {dt: [0.1]\n" not in text and text.startswith("name") else text)
    assert main([str(config)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: "), captured.err
    assert field in lines[0]
    assert "Traceback" not in captured.err and captured.out == ""
    assert not (tmp_path / "never").exists() and not Path("results/x").exists()


@pytest.mark.parametrize("argv, message", [
    (["missing.yaml"], "does not exist"),
    (["."], "is a folder"),
    (["CONFIG", "--set", "system.stiffness"], "--set system.stiffness: expected key.path=value"),
    (["CONFIG", "--set", "system.mass=[1"], "malformed YAML"),
    (["CONFIG", "--set", "system.mass=-1"], "system.mass: Input should be greater than 0"),
    (["plot", "nothing.h5"], "nothing.h5' does not exist"),
])
def test_bad_command_line_is_one_line_exit_2(tmp_path, capsys, argv, message):
    config = write(tmp_path, SPRING_CONFIG + f"output: {tmp_path / 'never'}\n")
    argv = [str(config) if item == "CONFIG" else item for item in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "never").exists()


def test_unwritable_output_is_refused_before_anything_runs(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    config = write(tmp_path, SPRING_CONFIG + f"output: {blocker / 'sub'}\n")
    assert main([str(config)]) == 2
    assert "output:" in capsys.readouterr().err


def test_help_and_list_through_the_console_script():
    """`simrun --help` names every subcommand; `simrun list` names every registered part."""
    from simrun.integrators import INTEGRATORS
    from simrun.systems import SYSTEMS

    executable = Path(sys.executable).parent / "simrun"
    help_text = subprocess.run([executable, "--help"], capture_output=True, text=True, check=True).stdout
    for command in ("run", "plot", "list"):
        assert command in help_text
    listing = subprocess.run([executable, "list"], capture_output=True, text=True, check=True).stdout
    for name in [*SYSTEMS, *INTEGRATORS, "newton", "direct", "stiffness", "angular_velocity"]:
        assert name in listing, name
    bare = subprocess.run([executable], capture_output=True, text=True)  # no command: the help, as an error
    assert bare.returncode == 2 and bare.stdout == "" and "usage: simrun" in bare.stderr


def test_summary_drift_matches_the_exact_energy_factor(tmp_path):
    """Backward Euler's final relative drift in the summary is (1 + x^2)^-n - 1."""
    config = write(tmp_path, f"""\
        name: drift
        system: {{type: spring_mass, stiffness: 4.0}}
        integrators: [backward_euler]
        duration: 1.0
        sweep: {{dt: [0.1]}}
        output: {tmp_path / 'drift'}
        """)
    assert main([str(config), "-q", "--no-plots"]) == 0
    row = load(tmp_path / "drift" / "results.h5").summary.iloc[0]
    assert row["final_rel_energy_drift"] == pytest.approx(1.04 ** -10 - 1.0, rel=1e-9)
    assert row["steps"] == 10 and row["status"] == "ok" and np.isfinite(row["final_error"])
