"""The subcommands' contract: every refusal is one line `simrun: error: field: ...` with exit status 2
and nothing half-written; options never swallow the results file; the run's labels, sweep, progress and
provenance say what was run.

The runs are tiny: the mass on a spring (k = 100 N/m, m = 1 kg, w = 10 rad/s) for 3 s, where forward Euler
diverges at dt = 0.3 s (h w = 3: the energy grows tenfold a step), and a 3 x 3 cloth for 0.02 s (frames for
`simrun animate`)."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import simrun
from simrun.cli import main
from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment, validate_experiment
from simrun.experiment.sweep import config_hash, expand_runs, family_labels
from simrun.format.layout import RESULTS_NAME
from simrun.pipeline import ESTIMATE_AFTER_RUNS, remaining_text

ROOT = Path(__file__).resolve().parents[1]
SPRING = """\
name: spring
system: {type: spring_mass, stiffness: 100.0}
integrators: [forward_euler, backward_euler]
duration: 3.0
sweep: {dt: [0.01, 0.3]}
"""
CLOTH = """\
name: cloth
system: {type: cloth, resolution: [3, 3]}
integrators: [symplectic_euler]
duration: 0.02
sweep: {dt: [0.01]}
"""


def write(folder: Path, text: str, name: str = "config.yaml") -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


@pytest.fixture(scope="module")
def results_file(tmp_path_factory) -> Path:
    """A spring and a cloth run in one folder each; returns the cloth's results file (frames for animate)."""
    folder = tmp_path_factory.mktemp("results")
    simrun.run(CLOTH, output=folder / "cloth", jobs=1, progress=False, figures=False)
    return folder / "cloth" / RESULTS_NAME


def files_under(folder: Path) -> set[Path]:
    return {path for path in folder.rglob("*")}


def unwritable_folder(tmp_path: Path) -> tuple[Path, Path]:
    """(a folder nobody may write in, the path an error names): mode 0o500; where permissions do not bind
    (root), a path under a regular file, which no one can create, and the file."""
    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o500)
    if os.access(folder, os.W_OK):
        folder.chmod(0o700)
        blocker = tmp_path / "file.txt"
        blocker.write_text("")
        return blocker / "out", blocker
    return folder, folder


def assert_one_line_error(capsys, *words: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: "), captured.err
    assert "Traceback" not in captured.err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


# -- 1. an output that cannot be written: refused before any work, one line, nothing left -----------------
def _argv(command: str, results: Path, target: Path, tmp_path: Path) -> list[str]:
    if command == "run":
        return [str(write(tmp_path, SPRING + f"output: {target / 'run'}\n")), "-q", "-j", "1"]
    if command == "measure":  # a trajectory of the config's spring (w = 10 rad/s): its exact motion
        t = 0.01 * np.arange(11)
        np.savez(tmp_path / "exact.npz", t=t, x=np.cos(10 * t)[:, None], v=-10 * np.sin(10 * t)[:, None])
        return ["measure", str(tmp_path / "exact.npz"), "--config", str(write(tmp_path, SPRING)), "--output",
                str(target / "measure"), "-q", "-j", "1"]
    return {
        "plot": ["plot", str(results), "--output", str(target / "figures")],
        "report": ["report", str(results), "--output", str(target / "report.html"), "--reference", "none"],
        "analyze": ["analyze", "--integrators", "backward_euler", "--output", str(target / "analysis")],
        "animate": ["animate", str(results), "--output", str(target / "cloth.gif")],
        "show": ["show", str(results), "--output", str(target / "summary.csv")],
    }[command]


COMMAND_NAMES = ["run", "plot", "report", "analyze", "animate", "show", "measure"]


@pytest.mark.parametrize("command", COMMAND_NAMES)
def test_an_unwritable_output_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, results_file, command):
    target, named = unwritable_folder(tmp_path)
    argv = _argv(command, results_file, target, tmp_path)
    before = files_under(tmp_path)
    try:
        assert main(argv) == 2
    finally:
        (tmp_path / "readonly").chmod(0o700)
    assert_one_line_error(capsys, str(named))
    assert files_under(tmp_path) == before


@pytest.mark.parametrize("command", ["run", "plot", "report", "animate", "show"])
def test_a_missing_results_file_is_one_line_exit_2(tmp_path, capsys, command):
    missing = tmp_path / "nothing" / ("config.yaml" if command == "run" else "results.h5")
    argv = [str(missing)] if command == "run" else [command, str(missing)]
    assert main(argv) == 2
    assert_one_line_error(capsys, "does not exist")
    assert files_under(tmp_path) == set()


def _writing_command(monkeypatch, write, command: str, results_file: Path, target: Path) -> list[str]:
    """``_argv`` of plot, report or animate writing under ``target``, its writer replaced by ``write(path)`` (the
    figure, report or animation file it would write)."""
    monkeypatch.setattr("simrun.figures.draw_figures", lambda results, folder, **_: write(Path(folder) / "a.png"))
    monkeypatch.setattr("simrun.report.page.write_report", lambda path, output, **_: write(Path(output)))
    monkeypatch.setattr("simrun.figures.frames.write_gif", lambda results, run_id, output, **_: write(Path(output)))
    return _argv(command, results_file, target, target.parent)


@pytest.mark.parametrize("command", ["plot", "report", "animate"])
def test_a_full_disk_while_writing_is_one_line_naming_the_path_and_leaves_nothing(tmp_path, capsys, monkeypatch,
                                                                                    results_file, command):
    """The writer fails midway (ENOSPC) after writing part of its output: one line naming the output, and neither
    the half-written file nor a temporary one is left."""
    def half_then_full(written: Path) -> None:
        written.write_bytes(b"half a file")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    target = tmp_path / "out"
    assert main(_writing_command(monkeypatch, half_then_full, command, results_file, target)) == 2
    assert_one_line_error(capsys, "--output", str(target), "No space left on device")
    assert files_under(tmp_path) == set()


@pytest.mark.parametrize("command", ["plot", "report", "animate"])
def test_ctrl_c_while_writing_is_one_line_exit_130_and_leaves_nothing(tmp_path, capsys, monkeypatch, results_file,
                                                                     command):
    """Ctrl-C midway through a figure, the report or an animation: one line, exit 130, no traceback, and neither
    the half-written file nor a temporary one is left."""
    def half_then_interrupted(written: Path) -> None:
        written.write_bytes(b"half a file")
        raise KeyboardInterrupt

    assert main(_writing_command(monkeypatch, half_then_interrupted, command, results_file, tmp_path / "out")) == 130
    captured = capsys.readouterr()
    assert captured.err == f"simrun: interrupted: nothing {command} writes is left half-written; run the same command again\n"
    assert files_under(tmp_path) == set()


def test_ctrl_c_while_the_figures_of_a_run_are_drawn_says_every_run_is_in(tmp_path, capsys, monkeypatch):
    """Every run committed, then Ctrl-C in the figures: one line that says so and how to draw them, exit 130, the
    results file whole and no figure folder."""
    def interrupted(results, folder, **_):
        (Path(folder) / "half.png").write_bytes(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr("simrun.figures.draw_figures", interrupted)
    config = tmp_path / "spring.yaml"
    config.write_text("name: spring\nsystem: {type: spring_mass}\nintegrators: [symplectic_euler]\nduration: 0.1\n"
                      "sweep: {dt: [0.01, 0.02]}\n")
    output = tmp_path / "out"
    assert main([str(config), "--output", str(output), "-j", "1", "-q"]) == 130
    line = capsys.readouterr().err
    assert line == (f"simrun: interrupted while drawing the figures: all 2 runs are in {output / 'results.h5'}; "
                    f"`simrun plot {output / 'results.h5'}` draws the figures\n")
    assert not (output / "figures").exists() and len(simrun.load(output / "results.h5").runs) == 2
    assert {str(path.relative_to(tmp_path)) for path in files_under(tmp_path)} == {
        "spring.yaml", "out", "out/results.h5", "out/.simrun.lock"}  # the lock file stays, as after any run


def test_writable_output_refuses_before_any_work(tmp_path):
    """The shared helper of the subcommands (and `show --output`): a file under a file, a folder given for a file."""
    from simrun.commands._options import writable_output
    from simrun.errors import ConfigError

    blocker = tmp_path / "file.txt"
    blocker.write_text("")
    with pytest.raises(ConfigError, match=r"^--csv: .*file.txt' is a file, not a folder"):
        writable_output(blocker / "deeper" / "summary.csv", "--csv")
    with pytest.raises(ConfigError, match=r"^--output: .* is a folder; give a file name"):
        writable_output(tmp_path, "--output")
    assert writable_output(tmp_path / "new" / "summary.csv", "--csv") == tmp_path / "new" / "summary.csv"
    assert not (tmp_path / "new").exists()  # checked, not created


# -- 3. an option's value is never the results file -------------------------------------------------------
@pytest.mark.parametrize("argv, reference", [
    (["plot", "--reference", "dop853", "r.h5"], "dop853"),
    (["plot", "r.h5"], "auto"),
    (["report", "--reference", "none", "r.h5"], "none"),
    (["report", "r.h5"], "dop853"),
])
def test_reference_takes_a_value_and_leaves_the_results_file_alone(argv, reference):
    from simrun.cli import build_parser

    args = build_parser().parse_args(argv)
    assert args.results == "r.h5" and args.reference == reference


def test_reference_without_a_value_is_a_usage_error(capsys):
    from simrun.cli import build_parser

    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["report", "r.h5", "--reference"])
    assert stop.value.code == 2 and "--reference: expected one argument" in capsys.readouterr().err


# -- 4. no command, an unknown one, a config's bare name -----------------------------------------------------
def test_no_arguments_print_the_help_to_stderr_and_exit_2(capsys):
    assert main([]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "usage: simrun" in captured.err and "COMMAND" in captured.err


@pytest.mark.parametrize("argv, suggestion", [
    (["runn", "config.yaml"], "(did you mean 'run'?)"),
    (["plott", "results.h5"], "(did you mean 'plot'?)"),
    (["quickstart"], "(did you mean 'configs/quickstart.yaml'?)"),
    (["quikstart"], "(did you mean 'configs/quickstart.yaml'?)"),
    (["zzz"], ""),
])
def test_an_unknown_command_is_named_with_a_suggestion(tmp_path, monkeypatch, capsys, argv, suggestion):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "quickstart.yaml").write_text(SPRING)
    (tmp_path / "config.yaml").write_text(SPRING)
    assert main(argv) == 2
    line = assert_one_line_error(capsys, f"unknown command {argv[0]!r}{' ' + suggestion if suggestion else ';'}")
    assert "run, fit, plot" in line
    assert not (tmp_path / "results").exists()


def test_a_path_that_looks_like_a_config_is_still_run(tmp_path, capsys):
    assert main([str(tmp_path / "missing.yml")]) == 2
    assert_one_line_error(capsys, "config: file", "does not exist")


# -- 5. simrun list -----------------------------------------------------------------------------------------
def test_list_shows_every_config_key_and_nested_model_readably(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "Params(" not in out and "ContactParams" not in out  # no Python repr
    for line in ["  name:  # required", "  duration: 10.0  # simulated time per run (s)", "  sweep:  # required",
                 "  output: null", "  solver: {type: newton}", "    max_samples: 10000", "    max_frames: 200",
                 "    energy_factor: 1000000.0", "    check_every: 1", "    contact:", "      ground:  # optional",
                 "        height: -1.0  # the last coordinate (z in 3-D, y in 2-D) of the ground (m)", "        center: [0.5, 0.5, -0.6]  # centre (m)",
                 "default type: newton"]:
        assert line in out, line
    # the listing is YAML: the config section parses, with the defaults as values
    section = out.split("\n\n")[0].split("\n", 1)[1]
    parsed = yaml.safe_load(section)
    assert parsed["duration"] == 10.0 and parsed["record"]["max_samples"] == 10000 and parsed["solver"] == {"type": "newton"}


# -- 6. labels name what a family of integrators varies ------------------------------------------------------
def test_damping_curves_labels_are_distinct_and_name_each_family_parameter():
    experiment, _ = load_experiment(ROOT / "configs" / "damping_curves.yaml")
    runs = expand_runs(experiment)
    labels = family_labels(experiment.integrators)
    assert len(set(labels)) == len(labels) == len(experiment.integrators)
    assert [label for label in labels if label.startswith("generalized_alpha")] == [
        f"generalized_alpha[rho_inf={value}]" for value in ("0", "0.25", "0.5", "0.75", "1")]
    assert [label for label in labels if label.startswith("bdf2_midpoint_mix")] == [
        f"bdf2_midpoint_mix[theta={value}]" for value in ("0", "0.25", "0.5", "0.75", "1")]
    assert "backward_euler" in labels and "newmark" in labels  # no family: labelled as everywhere
    default_member = next(run for run in runs if run.integrator.name == "generalized_alpha" and run.integrator.rho_inf == 0.5)
    assert default_member.integrator_label == "generalized_alpha[rho_inf=0.5]"
    assert default_member.run_id.split("-")[1] == "generalized_alpha[rho_inf=0.5]"


def test_labels_without_a_family_stay_as_they_were(tmp_path):
    raw = yaml.safe_load(SPRING)
    raw["integrators"] = ["generalized_alpha", {"type": "newmark", "gamma": 0.6}, "backward_euler"]
    runs = expand_runs(validate_experiment(raw))
    assert [run.integrator_label for run in runs[::2]] == [run.integrator.label for run in runs[::2]] == [
        "generalized_alpha", "newmark[gamma=0.6]", "backward_euler"]


def test_the_stored_label_is_the_family_label(tmp_path):
    raw = yaml.safe_load(SPRING)
    raw["integrators"] = [{"type": "generalized_alpha", "rho_inf": 0.0}, "generalized_alpha"]
    raw["sweep"] = {"dt": [0.01]}
    results = simrun.run(raw, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    assert sorted(run.label for run in results.runs.values()) == ["generalized_alpha[rho_inf=0.5]", "generalized_alpha[rho_inf=0]"]
    assert sorted(results.runs) == ["0000-generalized_alpha[rho_inf=0]-dt=0.01", "0001-generalized_alpha[rho_inf=0.5]-dt=0.01"]


# -- 7. --force removes the figures and the report of the old results --------------------------------------
def test_force_removes_the_old_figures_and_report_before_the_run(tmp_path, capsys):
    config = write(tmp_path, SPRING + f"output: {tmp_path / 'out'}\n")
    (tmp_path / "out" / "figures").mkdir(parents=True)
    (tmp_path / "out" / "figures" / "old.png").write_bytes(b"old")
    (tmp_path / "out" / "report.html").write_text("old")
    assert main([str(config), "-q", "--no-plots", "-j", "1"]) == 0  # no force: the new file, the old drawings stay
    assert (tmp_path / "out" / "figures" / "old.png").exists()
    bad = write(tmp_path, SPRING.replace("duration: 3.0", "duration: -1") + f"output: {tmp_path / 'out'}\n", "bad.yaml")
    assert main([str(bad), "-q", "--no-plots", "--force"]) == 2  # refused in validation: nothing removed
    assert (tmp_path / "out" / "figures" / "old.png").exists() and (tmp_path / "out" / "report.html").exists()
    assert main([str(config), "-q", "--no-plots", "--force", "-j", "1"]) == 0
    assert not (tmp_path / "out" / "figures").exists() and not (tmp_path / "out" / "report.html").exists()
    assert (tmp_path / "out" / RESULTS_NAME).exists()


# -- 9. progress: what did not end ok, and the time left --------------------------------------------------
def test_progress_lines_say_why_a_run_did_not_end_ok_and_estimate_the_time_left(tmp_path, capsys):
    raw = yaml.safe_load(SPRING)
    raw["sweep"] = {"dt": [0.001, 0.002, 0.005, 0.01, 0.3]}  # forward Euler diverges at dt = 0.3 (h w = 3)
    simrun.run(raw, output=tmp_path / "out", jobs=1, figures=False)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[")]
    assert len(lines) == 10
    diverged = next(line for line in lines if "forward_euler-dt=0.3" in line)
    assert "diverged" in diverged and "(" in diverged.split("diverged", 1)[1]  # with its reason
    assert all("left" not in line for line in lines[:ESTIMATE_AFTER_RUNS - 1])
    assert all(" left" in line for line in lines[ESTIMATE_AFTER_RUNS - 1:-1]) and "left" not in lines[-1]


def test_the_progress_bar_keeps_a_line_for_each_run_that_did_not_end_ok(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # a terminal: the bar
    raw = yaml.safe_load(SPRING)
    simrun.run(raw, output=tmp_path / "out", jobs=1, figures=False)
    captured = capsys.readouterr()
    assert not [line for line in captured.out.splitlines() if line.startswith("[")]  # the bar instead
    written = [line for line in captured.err.replace("\r", "\n").splitlines() if line.startswith("0001-forward_euler-dt=0.3")]
    assert len(written) == 1 and "diverged (" in written[0]


def test_quiet_prints_no_progress(tmp_path, capsys):
    config = write(tmp_path, SPRING + f"output: {tmp_path / 'out'}\n")
    assert main([str(config), "-q", "--no-plots", "-j", "1"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out.splitlines() == [f"results: {tmp_path / 'out' / RESULTS_NAME}  (1 diverged, 3 ok)"]


@pytest.mark.parametrize("elapsed, done, total, expected", [
    (1.0, 1, 10, None),  # too early to say
    (6.0, 1, 10, "about 54 s left"),  # one run, but 5 s passed
    (3.0, 3, 10, "about 7 s left"),
    (30.0, 3, 50, "about 7 min 50 s left"),
    (300.0, 3, 50, "about 1 h 18 min left"),
    (3600.0, 10, 100, "about 9 h 00 min left"),
    (10.0, 10, 10, None),  # done
])
def test_the_time_left_is_the_mean_time_per_run_so_far(elapsed, done, total, expected):
    assert remaining_text(elapsed, done, total) == expected


# -- 10. every error of a config, up to five -----------------------------------------------------------------
def test_a_config_with_several_errors_gets_one_line_each(tmp_path, capsys):
    config = write(tmp_path, """\
        name: x
        system: {type: spring_mass, mass: heavy, stifness: 3}
        integrators: [backward_eulr]
        duration: -1
        sweep: {dt: [0.1]}
        """)
    assert main([str(config)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert lines == [
        "simrun: error: system.mass: Input should be a valid number, unable to parse string as a number (got 'heavy')",
        "simrun: error: system.stifness: unknown key (did you mean 'stiffness'?); allowed: type, mass, stiffness, damping, damping_ratio, x0, v0",
        "simrun: error: integrators.0: unknown integrator 'backward_eulr' (did you mean 'backward_euler'?); valid: "
        + ", ".join(simrun.integrators.INTEGRATORS | simrun.integrators.ENGINES | simrun.integrators.PEERS)
        + ", or a plug-in as package.module:ClassName",
        "simrun: error: duration: Input should be greater than 0 (got -1)",
    ]
    assert captured.out == "" and not Path("results/x").exists()


def test_at_most_five_errors_are_reported(tmp_path, capsys):
    config = write(tmp_path, "nmae: x\nsystm: 1\nintegratrs: 2\nduraton: 3\nswep: 4\nrecrd: 5\noutptu: 6\n")
    assert main([str(config)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 5 and all(line.startswith("simrun: error: ") for line in lines)


def test_one_error_of_a_union_is_one_line(tmp_path, capsys):
    config = write(tmp_path, SPRING + "record: {error_time: soon}\n")
    assert main([str(config)]) == 2
    assert_one_line_error(capsys, "record.error_time: ", "'auto'", "(got 'soon')")


# -- 11. a swept solver key that a run does not use does not multiply it -----------------------------------
def test_solver_comparison_runs_each_first_order_solver_once_per_dt():
    """2 Newton-type solvers x 7 linear solvers x 3 dt + 5 solvers without a linear solve (3 first-order ones,
    projective dynamics, vbd) x 3 dt, L-BFGS twice (its swept initial_hessian) = 60 runs, not 294."""
    experiment, _ = load_experiment(ROOT / "configs" / "solver_comparison.yaml")
    runs = expand_runs(experiment)
    assert len(runs) == 2 * 7 * 3 + (5 + 1) * 3 == 60
    assert len({run.run_id for run in runs}) == 60 and [run.index for run in runs] == list(range(60))
    for run in runs:
        newton_type = run.solver.type in ("newton", "projected_newton")
        assert ("solver.linear_solver" in run.run_id) == newton_type == ("solver.linear_solver" in run.swept), run.run_id
        if not newton_type:
            assert run.solver.linear_solver == "direct"  # the first value of the sweep
    assert {(run.solver.initial_hessian, run.dt) for run in runs if run.solver.type == "lbfgs"} == {
        (initial_hessian, dt) for initial_hessian in ("scalar", "rest") for dt in experiment.sweep["dt"]}


@pytest.mark.parametrize("integrator, fallback, runs", [
    ("backward_euler", [], 2),  # lbfgs: no linear solve
    ("backward_euler", ["projected_newton"], 4),  # its fallback solves linear systems
    ("semi_implicit_backward_euler", [], 4),  # one Newton step with the linear solver, whatever the solver
    ("forward_euler", [], 1),  # explicit: no solver at all, solver.type included
])
def test_an_unused_linear_solver_key_runs_once(integrator, fallback, runs):
    raw = yaml.safe_load(SPRING)
    raw.update(integrators=[integrator], solver={"type": "lbfgs", "fallback": fallback},
               sweep={"dt": [0.01], "solver.linear_solver": ["direct", "cg"], "solver.type": ["lbfgs", "gradient_descent"]})
    if fallback:
        raw["sweep"]["solver.type"] = ["lbfgs"]
        runs //= 2
    assert len(expand_runs(validate_experiment(raw))) == runs


# -- provenance -----------------------------------------------------------------------------------------------
def test_the_results_file_records_where_how_and_what_was_run(tmp_path):
    config = write(tmp_path, SPRING + f"output: {tmp_path / 'out'}\n")
    assert main([str(config), "-q", "--no-plots", "-j", "1", "--set", "duration=0.6"]) == 0
    with h5py.File(tmp_path / "out" / RESULTS_NAME, "r") as file:
        attrs = dict(file.attrs)
    assert attrs["host"] and f"({os.cpu_count()} cores)" in attrs["cpu"]
    assert attrs["command_line"] == f"simrun {config} -q --no-plots -j 1 --set duration=0.6"
    assert attrs["config_git_commit"] == ""  # tmp_path is in no git work tree
    resolved = yaml.safe_load(attrs["resolved_config"])
    assert resolved["duration"] == 0.6 and resolved["record"]["max_samples"] == 10000  # defaults filled in
    experiment, _ = load_experiment(config, ["duration=0.6"])
    assert config_hash(validate_experiment(resolved)) == config_hash(experiment) == attrs["config_hash"]


def test_a_python_call_records_itself(tmp_path):
    simrun.run(SPRING, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    with h5py.File(tmp_path / "out" / RESULTS_NAME, "r") as file:
        assert file.attrs["command_line"] == f"simrun.run(<YAML text>, output='{tmp_path / 'out'}', jobs=1)"


@pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")
def test_the_config_s_git_commit_is_recorded_with_a_dirty_mark(tmp_path):
    repository = tmp_path / "repository"
    repository.mkdir()
    config = write(repository, SPRING + f"output: {tmp_path / 'out'}\n")

    def git(*arguments: str) -> str:
        return subprocess.run(["git", "-C", str(repository), "-c", "user.name=test", "-c", "user.email=test@example.org",
                               *arguments], capture_output=True, text=True, check=True).stdout.strip()

    git("init", "-q")
    git("add", "config.yaml")
    git("commit", "-q", "-m", "config")
    commit = git("rev-parse", "HEAD")
    simrun.run(config, jobs=1, progress=False, figures=False)
    with h5py.File(tmp_path / "out" / RESULTS_NAME, "r") as file:
        assert file.attrs["config_git_commit"] == commit
    config.write_text(config.read_text() + "# changed\n")
    simrun.run(config, jobs=1, progress=False, figures=False, force=True)
    with h5py.File(tmp_path / "out" / RESULTS_NAME, "r") as file:
        assert file.attrs["config_git_commit"] == commit + "+dirty"


def test_run_on_a_calibration_refuses_in_one_line_naming_simrun_fit(tmp_path, capsys):
    """`simrun run` (and simrun.run) on a config with a fit block would run its sweep and leave out the fit: one line
    pointing to `simrun fit` and to --set fit=null, exit 2, nothing written; with fit=null the sweep runs."""
    config = Path(__file__).resolve().parents[1] / "configs" / "calibrate_spring.yaml"
    assert main([str(config), "--output", str(tmp_path / "out")]) == 2
    assert_one_line_error(capsys, "fit: this config is a calibration", f"`simrun fit {config}`", "--set fit=null")
    assert files_under(tmp_path) == set()
    with pytest.raises(ConfigError, match="simrun fit CONFIG"):
        simrun.run(yaml.safe_load(config.read_text()), output=tmp_path / "out")
    assert main([str(config), "--output", str(tmp_path / "out"), "--set", "fit=null", "--set", "sweep.dt=[0.1]",
                 "--set", "integrators=[rk4]", "-q", "--no-plots"]) == 0


@pytest.mark.parametrize("command", ["show", "plot", "report", "animate", "resume"])
def test_a_truncated_results_file_is_one_line_saying_so(tmp_path, capsys, results_file, command):
    """The first half of a results file (a copy cut short, a write killed by a full disk): every reader says it is
    truncated, with its size against the size HDF5 recorded, and a resume into its folder says so and how to start
    over; exit 2, nothing written."""
    data = results_file.read_bytes()
    folder = tmp_path / "cut"
    folder.mkdir()
    truncated = folder / RESULTS_NAME
    truncated.write_bytes(data[: len(data) // 2])
    if command == "resume":
        config = write(tmp_path, CLOTH + f"output: {folder}\n")
        argv = [str(config), "-q", "-j", "1"]
    else:
        argv = _argv(command, truncated, tmp_path / "out", tmp_path)
    before = files_under(tmp_path)
    assert main(argv) == 2
    line = assert_one_line_error(capsys, f"is truncated: {len(data) // 2:,} of its {len(data):,} bytes",
                                 "interrupted process")
    if command == "resume":
        assert "start over with --force" in line
    assert files_under(tmp_path) - before <= {folder / ".simrun.lock"}
