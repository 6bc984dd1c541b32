"""Scale and reliability: executors agree, kill -9 loses only runs in flight, one writer per folder,
Ctrl-C keeps what finished, and every bad input gets one line and exit status 2."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import threadpoolctl
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simrun.cli import main
from simrun.execution.workers import (BLAS_THREAD_VARIABLES, _limit_blas_threads, default_jobs, may_use_local_pool,
                                      process_pool)
from simrun.experiment.config import ConfigError, parse_yaml, validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.results import fits_writer
from simrun.results.lock import OutputLock

SIMRUN = [sys.executable, "-m", "simrun.cli"]


def write_config(tmp_path: Path, body: str, output: Path, name: str = "config.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(body) + f"output: {output}\n")
    return path


SWEEP = """\
    name: sweep
    system: {type: spring_mass, stiffness: 50.0, damping: 0.3}
    integrators: [forward_euler, symplectic_euler, backward_euler, {type: generalized_alpha, rho_inf: 0.3}]
    duration: 2.0
    sweep:
      dt: [0.002, 0.01, 0.3]
      system.stiffness: [50.0, 400.0]
    """


def run_data(path: Path) -> dict[str, dict]:
    """Every run's datasets and attributes, minus what legitimately differs between executions: the wall time, and
    the threads of the compiled kernels (a run in the main process has every core, a pool's worker its share)."""
    data = {}
    with h5py.File(path, "r") as file:
        for run_id, group in file["runs"].items():
            attrs = {key: value for key, value in group.attrs.items() if key not in ("wall_time", "threads")}
            data[run_id] = {"attrs": attrs, **{key: group[key][()] for key in group}}
    return data


def assert_same_runs(first: dict, second: dict) -> None:
    assert first.keys() == second.keys()
    for run_id in first:
        assert first[run_id].keys() == second[run_id].keys(), run_id
        for key, value in first[run_id].items():
            if key == "attrs":
                assert {k: str(v) for k, v in value.items()} == {k: str(v) for k, v in second[run_id][key].items()}
            else:
                np.testing.assert_array_equal(value, second[run_id][key], err_msg=f"{run_id}/{key}")


def test_process_pool_and_dask_give_the_serial_results(tmp_path):
    files = {}
    for label, extra in {"serial": ["-j", "1"], "pool": ["-j", "2"], "dask": ["--executor", "dask", "-j", "2"]}.items():
        config = write_config(tmp_path, SWEEP, tmp_path / label, f"{label}.yaml")
        assert main([str(config), "-q", "--no-plots", *extra]) == 0
        files[label] = tmp_path / label / "results.h5"
    serial = run_data(files["serial"])
    assert len(serial) == 24
    assert_same_runs(serial, run_data(files["pool"]))
    assert_same_runs(serial, run_data(files["dask"]))


def _blas_thread_settings() -> dict:
    return {variable: os.environ.get(variable) for variable in BLAS_THREAD_VARIABLES}


def _worker_blas() -> tuple[dict, list[int]]:
    """In a worker: the thread variables, and the thread counts of the BLAS libraries loaded."""
    return _blas_thread_settings(), [lib["num_threads"] for lib in threadpoolctl.threadpool_info()
                                     if lib["user_api"] == "blas"]


@pytest.mark.skipif(any(variable in os.environ for variable in BLAS_THREAD_VARIABLES),
                    reason="the environment sets BLAS thread counts, which the workers keep")
def test_pool_workers_share_the_cores_for_blas():
    """-j N gives each worker cores // N BLAS threads: numpy's BLAS, loaded already, at once; CHOLMOD's
    OpenBLAS, loaded later, through the variables (it would otherwise start one thread per core in
    every worker)."""
    jobs = 2
    with process_pool(jobs) as pool:
        settings, loaded = pool.submit(_worker_blas).result()
    share = max(1, default_jobs() // jobs)
    assert settings == {variable: str(share) for variable in BLAS_THREAD_VARIABLES}
    assert loaded and all(threads == share for threads in loaded)


def test_a_blas_thread_count_the_user_set_is_kept(monkeypatch):
    """One variable set by the user: the worker changes none of them (OpenBLAS would read a forced
    OPENBLAS_NUM_THREADS before the user's OMP_NUM_THREADS)."""
    for variable in BLAS_THREAD_VARIABLES:
        monkeypatch.setenv(variable, "0")  # recorded, so that monkeypatch restores the original state
        monkeypatch.delenv(variable)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    _limit_blas_threads(1)
    assert _blas_thread_settings() == {"OPENBLAS_NUM_THREADS": None, "OMP_NUM_THREADS": "3", "MKL_NUM_THREADS": None}


@pytest.mark.parametrize("jobs, executor, started", [("2", "local", True), ("1", "local", False), ("2", "dask", False)])
def test_the_command_line_starts_the_worker_server_before_its_imports_only_for_the_pool(monkeypatch, tmp_path,
                                                                                      jobs, executor, started):
    calls = []
    monkeypatch.setattr("simrun.cli.start_worker_server", lambda: calls.append(True))
    code = main(["run", str(tmp_path / "missing.yaml"), "-j", jobs, "--executor", executor])
    assert code == 2  # the missing config ends the command after the decision
    assert calls == ([True] if started and default_jobs() > 1 else [])


@pytest.mark.parametrize("options, expected", [
    ([], True), (["-j", "2"], True), (["--jobs=3"], True), (["-j", "1"], False), (["-j1"], False),
    (["--jobs", "1"], False), (["--executor", "dask"], False), (["--executor=local", "-j", "2"], True),
    (["-j", "two"], False),  # left to the real parser, which names the option
])
def test_the_worker_server_starts_early_only_when_the_pool_may_be_used(options, expected):
    argv = ["run", "configs/quickstart.yaml", "--no-plots", *options]
    assert may_use_local_pool(argv) == (expected and default_jobs() > 1)


def test_python_dash_m_simrun_is_the_command():
    result = subprocess.run([sys.executable, "-m", "simrun", "--version"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stdout.strip().startswith("simrun ")


def test_a_resumed_sweeps_final_line_counts_the_file_then_this_invocation(tmp_path, capsys):
    """After a resume the final line gives every run in the file by status, then what this invocation ran; its
    progress (and time left) counts only the runs it has to run."""
    config = write_config(tmp_path, SWEEP, tmp_path / "out")
    assert main([str(config), "-q", "--no-plots", "-j", "1", "--lanes", "off"]) == 0
    first = capsys.readouterr().out
    with h5py.File(tmp_path / "out" / "results.h5", "r+") as file:
        statuses = {run_id: group.attrs["status"] for run_id, group in file["runs"].items()}
        redone = sorted(statuses)[:3]
        for run_id in redone:  # as a killed write leaves them: run again on resume
            file["runs"][run_id].attrs["complete"] = False
    counts = {status: list(statuses.values()).count(status) for status in set(statuses.values())}
    whole = ", ".join(f"{count} {status}" for status, count in sorted(counts.items()))
    assert f"({whole})" in first  # the first invocation ran them all: the file's counts alone
    assert main([str(config), "--no-plots", "-j", "1", "--lanes", "off"]) == 0
    out = capsys.readouterr().out
    again = {status: [statuses[run_id] for run_id in redone].count(status) for status in set(statuses[r] for r in redone)}
    ran = ", ".join(f"{count} {status}" for status, count in sorted(again.items()))
    assert f"(24 runs in the file: {whole}; this invocation ran {ran})" in out
    assert "[3/3]" in out and "[4/" not in out and "/24]" not in out


def test_unchanged_config_resumes_and_changed_config_is_refused(tmp_path, capsys):
    config = write_config(tmp_path, SWEEP, tmp_path / "out")
    assert main([str(config), "-q", "--no-plots", "-j", "1"]) == 0
    capsys.readouterr()
    assert main([str(config), "--no-plots", "-j", "1"]) == 0
    out = capsys.readouterr().out
    assert "skipped 24 runs" in out and "nothing left to run" in out
    changed = write_config(tmp_path, SWEEP.replace("damping: 0.3", "damping: 0.4"), tmp_path / "out", "changed.yaml")
    assert main([str(changed), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "different config" in err and "--force" in err and "--output" in err
    assert main([str(changed), "-q", "--no-plots", "--force", "-j", "1"]) == 0
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        assert "damping: 0.4" in file.attrs["config"] and len(file["runs"]) == 24


SLOW_SWEEP = """\
    name: slow
    system: {type: circular_motion, force: gravity}
    integrators: [backward_euler]
    duration: 40.0
    sweep:
      dt: [0.002, 0.0021, 0.0022, 0.0023, 0.0024, 0.0025, 0.0026, 0.0027, 0.0028, 0.0029, 0.003, 0.0031]
    """


def as_from_a_terminal() -> None:
    """In the child before it starts: Ctrl-C's signal as a shell leaves it, handled by default and not blocked. A pytest
    worker may have it ignored or blocked by what ran in it before (a child inherits both), and simrun would then
    never see the Ctrl-C these tests send."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _group_ends(group: int, timeout: float) -> bool:
    """Whether every process of process group ``group`` ends within ``timeout`` s (killed if not)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.1)
    os.killpg(group, signal.SIGKILL)  # leave no orphans behind, even when the test fails
    return False


def test_kill_9_keeps_every_finished_run_and_the_rerun_resumes(tmp_path):
    """A real subprocess killed with SIGKILL mid-sweep: the file opens, holds only complete runs, and the
    same command runs exactly the missing ones. Neither the killed sweep's processes (its resource tracker, which
    unlinks the pool's semaphores once simrun is gone) nor the resumed one print a warning."""
    config = write_config(tmp_path, SLOW_SWEEP, tmp_path / "out")
    # a session of its own: its process group then holds simrun, the pool's fork server, workers and resource tracker
    process = subprocess.Popen([*SIMRUN, str(config), "--no-plots", "-j", "2"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=as_from_a_terminal)
    finished = 0
    deadline = time.monotonic() + 120
    for line in process.stdout:  # each "[k/N]" line is printed after its run was committed
        if line.startswith("["):
            finished += 1
        if finished == 3 or time.monotonic() > deadline:
            break
    process.kill()
    process.wait()
    assert finished == 3
    # the workers and their fork server end with simrun (they would otherwise wait forever)
    assert _group_ends(process.pid, timeout=20), "pool processes outlived the killed simrun"
    killed_err = process.stderr.read()
    assert "resource_tracker" not in killed_err and "leaked" not in killed_err, killed_err
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        kept = {run_id for run_id, group in file["runs"].items() if group.attrs.get("complete")}
        assert len(kept) >= 3
        assert len(file["summary"]) == len(kept)
        for run_id in kept:
            group = file["runs"][run_id]
            assert group["t"][-1] == pytest.approx(40.0, rel=1e-3) and group.attrs["status"] == "ok"
    again = subprocess.run([*SIMRUN, str(config), "--no-plots", "-j", "2"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert again.stderr == "", again.stderr
    assert f"skipped {len(kept)} runs" in again.stdout and f"running {12 - len(kept)}" in again.stdout
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        assert len(file["runs"]) == 12 and len(file["summary"]) == 12


def test_an_interrupted_write_is_dropped_on_resume(tmp_path):
    """A group without its `complete` mark (a write cut off midway) is removed and run again."""
    config = write_config(tmp_path, SWEEP, tmp_path / "out")
    assert main([str(config), "-q", "--no-plots", "-j", "1"]) == 0
    path = tmp_path / "out" / "results.h5"
    with h5py.File(path, "a") as file:
        victim = sorted(file["runs"])[5]
        del file["runs"][victim].attrs["complete"]
        del file["runs"][victim]["energy"]
    assert main([str(config), "-q", "--no-plots", "-j", "1"]) == 0
    with h5py.File(path, "r") as file:
        assert "energy" in file["runs"][victim] and len(file["summary"]) == 24


def test_a_second_writer_is_refused(tmp_path, capsys):
    config = write_config(tmp_path, SWEEP, tmp_path / "out")
    (tmp_path / "out").mkdir()
    with OutputLock(tmp_path / "out"):
        assert main([str(config), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another simrun" in err and str(os.getpid()) in err
    assert not (tmp_path / "out" / "results.h5").exists()
    assert main([str(config), "-q", "--no-plots", "-j", "1"]) == 0  # the lock went with its holder


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_ctrl_c_keeps_what_finished_and_exits_130(tmp_path, jobs):
    config = write_config(tmp_path, SLOW_SWEEP, tmp_path / "out")
    process = subprocess.Popen([*SIMRUN, str(config), "--no-plots", "-j", jobs], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=as_from_a_terminal)
    for line in process.stdout:
        if line.startswith("[2/"):
            break
    os.killpg(process.pid, signal.SIGINT)  # the terminal sends SIGINT to the whole process group
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        assert len(file["runs"]) >= 2
        assert all(group.attrs.get("complete") for group in file["runs"].values())


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_ctrl_c_in_a_calibration_keeps_the_finished_fits_and_the_rerun_resumes(tmp_path, jobs):
    """SIGINT to `simrun fit` (calibrate_spring.yaml, 10 fits of a few seconds each) after its second fit: exit 130,
    one line and no traceback; the file holds every fit that was reported, each with its fitted run (the fit with
    the exact solution has none); the same
    command resumes from them."""
    config = Path(__file__).resolve().parents[1] / "configs" / "calibrate_spring.yaml"
    argv = [*SIMRUN, "fit", str(config), "--output", str(tmp_path / "fit"), "--no-plots", "-j", jobs,
            "--set", "integrators=[backward_euler,implicit_midpoint,rk4]", "--set", "sweep.dt=[0.002,0.0025,0.003]"]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=as_from_a_terminal)
    reported = 0
    for line in process.stdout:
        reported += line.startswith("[")
        if reported == 2:
            break
    os.killpg(process.pid, signal.SIGINT)
    rest, err = process.communicate(timeout=60)
    reported += sum(line.startswith("[") for line in rest.splitlines())
    assert process.returncode == 130, err
    assert err == ("simrun: interrupted: the finished fits are in the results file; run the same command again to "
                   "finish the rest\n"), err
    assert _group_ends(process.pid, timeout=20)
    with h5py.File(tmp_path / "fit" / "results.h5", "r") as file:
        done = fits_writer.completed(file)
        assert len(done) == reported and 2 <= reported < 10
        assert done - {"exact"} <= {run_id for run_id, group in file["runs"].items() if group.attrs.get("complete")}
    again = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=as_from_a_terminal)
    header = again.stdout.readline()
    os.killpg(again.pid, signal.SIGKILL)
    again.wait()
    assert "10 fits of system.stiffness, system.damping" in header and f"(resuming: {reported} done)" in header, header


def test_ctrl_c_on_the_process_pool_ends_the_workers_quietly(tmp_path):
    """SIGINT to the process group of `python -m simrun CONFIG -j 2` (what a terminal's Ctrl-C does) while
    both workers are mid-run: the workers ignore it and the main process stops them, so stderr holds the one
    message and no worker's traceback, the status is 130, and no process of the group outlives simrun."""
    # the last run is four times as long as the others: after two runs, one worker runs it and one waits for work
    sweep = SLOW_SWEEP.replace("[0.002, 0.0021, 0.0022, 0.0023, 0.0024, 0.0025, 0.0026, 0.0027, 0.0028, 0.0029, 0.003, 0.0031]",
                               "[0.002, 0.0021, 0.0005]")
    config = write_config(tmp_path, sweep, tmp_path / "out")
    process = subprocess.Popen([sys.executable, "-m", "simrun", str(config), "--no-plots", "-j", "2"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=as_from_a_terminal)
    for line in process.stdout:
        if line.startswith("[2/"):
            break
    time.sleep(0.3)
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert err.strip().splitlines() == [line for line in err.strip().splitlines() if line.startswith("simrun: interrupted")]
    assert _group_ends(process.pid, timeout=20), "pool processes outlived the interrupted simrun"


def test_memory_and_file_of_a_long_run_stay_bounded(tmp_path):
    """10^6 steps with default recording: at most 10^4 samples, small file, bounded resident memory."""
    config = write_config(tmp_path, """\
        name: long
        system: {type: spring_mass}
        integrators: [symplectic_euler]
        duration: 1000.0
        sweep: {dt: [0.001]}
        """, tmp_path / "out")
    # the peak of this process's own address space (VmHWM, Linux): ru_maxrss survives the exec and can report
    # the peak of the pytest worker it was forked from, which grows with the tests that ran before
    script = ("import resource, sys; from simrun.cli import main; code = main(sys.argv[1:]); "
              "status = open('/proc/self/status').read() if sys.platform == 'linux' else ''; "
              "peak = [line.split()[1] for line in status.splitlines() if line.startswith('VmHWM:')]; "
              "print(peak[0] if peak else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss); sys.exit(code)")
    done = subprocess.run([sys.executable, "-c", script, str(config), "-q", "--no-plots", "-j", "1"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    peak_kb = int(done.stdout.strip().splitlines()[-1])
    assert peak_kb < 300 * 1024
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        group = next(iter(file["runs"].values()))
        assert group["t"].shape[0] <= 10_000 and group.attrs["steps"] == 1_000_000
    assert (tmp_path / "out" / "results.h5").stat().st_size < 50e6


# -- every bad input: one line naming the field, exit 2, no traceback, no output ----------------------
BASE = "name: x\nsystem: {type: spring_mass}\nintegrators: [forward_euler]\nsweep: {dt: [0.1]}\n"
BAD_INPUTS = [
    (BASE.replace("stiffness", "x") + "duration: .nan\n", "duration: Input should be a finite number"),
    (BASE + "duration: .inf\n", "duration: Input should be a finite number"),
    (BASE.replace("{type: spring_mass}", "{type: spring_mass, mass: .nan}"), "system.mass: Input should be a finite number"),
    (BASE.replace("[0.1]", "[.nan]"), "sweep: dt must be finite numbers > 0"),
    (BASE.replace("[forward_euler]", "[{type: generalized_alpha, rho_inf: 1.5}]"), "generalized_alpha: rho_inf: Input should be less than or equal to 1"),
    (BASE.replace("[forward_euler]", "[{type: bdf2_midpoint_mix, theta: -0.1}]"), "bdf2_midpoint_mix: theta: Input should be greater than or equal to 0"),
    (BASE.replace("[forward_euler]", "[{type: backward_euler, rho_inf: 0.5}]"), "backward_euler: rho_inf: unknown key"),
    (BASE.replace("[forward_euler]", "[]"), "integrators: List should have at least 1 item"),
    (BASE.replace("[forward_euler]", "[42]"), "expected an integrator name or a mapping"),
    (BASE.replace("{type: spring_mass}", "{type: cloth, resolution: [1, 8]}"), "system.resolution.0: Input should be greater than or equal to 2"),
    (BASE.replace("{type: spring_mass}", "{type: cloth, resolution: [4, 4], pinned: [16]}"), "pinned: vertex 16 does not exist"),
    (BASE.replace("{type: spring_mass}", "{type: cloth, pinned: [middle]}"), "system.pinned.0"),
    (BASE.replace("{type: spring_mass}", "{type: circular_motion, force: magnetic}"), "system.force: Input should be 'linear' or 'gravity'"),
    (BASE.replace("{type: spring_mass}", "{}"), "system.type: missing"),
    (BASE + "solver: {type: magic}\n", "solver.type: unknown solver 'magic'; valid: newton"),
    (BASE + "record: {every: 0}\n", "record.every: Input should be greater than or equal to 1"),
    (BASE + "divergence: {energy_factor: 0.5}\n", "divergence.energy_factor: Input should be greater than 1"),
    (BASE + "nmae: typo\n", "nmae: unknown key (did you mean 'name'?)"),
    (BASE.replace("name: x", "name: ../escape"), "name: String should match pattern"),
    (BASE.replace("{dt: [0.1]}", "{dt: {logspace: [-3, -1]}}"), "logspace takes three finite numbers"),
    (BASE.replace("{dt: [0.1]}", "{dt: {geomspace: [1, 2, 3]}}"), "expected a list, {logspace"),
    (BASE.replace("{dt: [0.1]}", "{dt: [0.1], solver.tolerance: [1e-8, 2.0]}"), "sweep: solver.tolerance: in residual mode the tolerance is a fraction of the first residual: it must be < 1"),
    (BASE.replace("{dt: [0.1]}", "{dt: [0.1], name: [a, b]}"), "sweep.name: cannot sweep 'name'"),
    (BASE.replace("{dt: [0.1]}", "{dt: {logspace: [-6, -1, 2000]}, system.stiffness: {linspace: [1, 100, 2000]}}"), "runs exceed the limit"),
    ("name: x\nsystem: {type: spring_mass\n", "line 3, column 1: malformed YAML"),
    ("name: x\nsystem: !!python/name:os.system\n", "YAML tags that build objects are not allowed"),
    ("", "expected a mapping"),
]


@pytest.mark.parametrize("text, message", BAD_INPUTS)
def test_bad_input_matrix(tmp_path, capsys, text, message):
    path = tmp_path / "config.yaml"
    path.write_text(text + (f"output: {tmp_path / 'never'}\n" if text.startswith("name") and "{type: spring_mass\n" not in text else ""))
    assert main([str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert not (tmp_path / "never").exists()


@pytest.mark.parametrize("argv, message", [
    (["--set", "nosuchsection.key=1"], "nosuchsection: unknown key"),
    (["--set", "system.stiffnes=1"], "system.stiffnes: unknown key (did you mean 'stiffness'?)"),
    (["--set", "sweep.dt=[]"], "an empty sweep runs nothing"),
    (["--set", "=3"], "expected key.path=value"),
    (["--jobs", "0"], "--jobs: must be >= 1"),
    (["--max-size", "0.000001"], "the results would take about"),
    (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:9"], "cannot reach the Dask scheduler"),
])
def test_bad_command_line_options(tmp_path, capsys, argv, message):
    config = write_config(tmp_path, SWEEP, tmp_path / "never")
    assert main([str(config), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_a_sweep_estimated_beyond_the_disk_is_refused_before_it_starts(tmp_path, capsys):
    config = write_config(tmp_path, """\
        name: huge
        system: {type: cloth, resolution: [200, 200]}
        integrators: [symplectic_euler]
        duration: 100.0
        sweep: {dt: [1.0e-5]}
        record: {frames_every: 1}
        """, tmp_path / "never")
    assert main([str(config)]) == 2
    err = capsys.readouterr().err
    assert "GB" in err and "the frames dominate" in err and "record.frames_every" in err
    assert not (tmp_path / "never").exists()


def _estimate(raw: dict) -> int:
    from simrun.format.size import estimate_run_bytes

    return sum(estimate_run_bytes(run) for run in expand_runs(validate_experiment(raw)))


HUGE_SPRING = {"name": "x", "system": {"type": "spring_mass"}, "integrators": ["symplectic_euler"],
               "duration": 1.0e5, "sweep": {"dt": [1.0e-4]}}
HUGE_CLOTH = {"name": "x", "system": {"type": "cloth", "resolution": [100, 100]}, "integrators": ["symplectic_euler"],
              "duration": 10.0, "sweep": {"dt": [1.0e-4]}}


@pytest.mark.parametrize("raw, advice, change", [
    # 10^9 steps, 10^4 samples: the per-step arrays
    (HUGE_SPRING, "shorten duration or use a larger dt", {"duration": 1.0e3}),
    (HUGE_SPRING, "shorten duration or use a larger dt", {"sweep": {"dt": [1.0e-2]}}),
    # every step recorded: the samples (112 bytes a step against 21)
    ({**HUGE_SPRING, "record": {"every": 1}}, "use a larger record.every", {"record": {"every": 100}}),
    ({**HUGE_SPRING, "record": {"every": 1}}, "drop it and keep at most record.max_samples", {"record": {}}),
    # a frame of 10^4 vertices every step: the frames
    ({**HUGE_CLOTH, "record": {"frames_every": 1}}, "use a larger record.frames_every", {"record": {"frames_every": 100}}),
    ({**HUGE_CLOTH, "record": {"frames_every": 1}}, "keep at most record.max_frames", {"record": {"max_frames": 200}}),
    ({**HUGE_CLOTH, "duration": 1000.0, "sweep": {"dt": [1.0e-2]}, "record": {"max_frames": 100_000}},
     "lower record.max_frames", {"record": {"max_frames": 200}}),
])
def test_the_size_refusal_advises_what_lowers_the_estimate(tmp_path, capsys, raw, advice, change):
    """The refusal names what dominates the estimate; doing what it says shrinks the estimate severalfold (to
    what the other parts take)."""
    before = _estimate(raw)
    config = write_config(tmp_path, yaml.safe_dump(raw), tmp_path / "never")
    limit_gb = before / 2e9
    assert main([str(config), "--max-size", str(limit_gb), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and advice in err, err
    assert _estimate({**raw, **change}) < before / 4


# -- a property: any YAML document is accepted or refused with a ConfigError, never a traceback ------
yaml_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                         st.text(max_size=12))
yaml_values = st.recursive(yaml_scalars, lambda children: st.one_of(
    st.lists(children, max_size=4), st.dictionaries(st.text(max_size=10), children, max_size=4)), max_leaves=12)
keys = st.sampled_from(["name", "system", "integrators", "solver", "duration", "sweep", "record", "divergence",
                        "output", "type", "dt", "stiffness", "mass", "rho_inf", "every", "resolution", "pinned"])
documents = st.dictionaries(keys, yaml_values, max_size=7)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_random_documents_are_accepted_or_refused_cleanly(document):
    text = yaml.safe_dump(document)
    try:
        experiment = validate_experiment(parse_yaml(text))
        expand_runs(experiment)
    except ConfigError as error:  # up to five errors, one line each
        lines = str(error).split("\n")
        assert 1 <= len(lines) <= 5 and all(lines)


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=200))
def test_random_text_is_parsed_or_refused_cleanly(text):
    try:
        validate_experiment(parse_yaml(text))
    except ConfigError as error:  # up to five errors, one line each
        lines = str(error).split("\n")
        assert 1 <= len(lines) <= 5 and all(lines)


KILLED_CHAIN = '''
import multiprocessing
import os
import signal

from pendulum_chain import Chain, ChainParams


class KilledChain(Chain):
    """The example chain; with count 2, a worker that builds it is killed (as the kernel kills one out of memory)."""

    def __init__(self, p):
        if p.count == 2 and multiprocessing.parent_process() is not None:
            os.kill(os.getpid(), signal.SIGKILL)
        super().__init__(p)


class KilledChainParams(ChainParams):
    type: str = "killed_chain:KilledChainParams"


KilledChainParams.system_class = KilledChain
'''


def test_a_worker_killed_mid_sweep_is_one_line_and_the_finished_runs_stay(tmp_path, monkeypatch, capsys):
    """A pool worker killed by a signal (the kernel's OOM killer) while it builds a run: one line saying so and what
    to do, exit 2, no traceback (the pool fails every pending run alike, so which run it was is not known); every run the file holds is complete, and the lock went with the sweep."""
    (tmp_path / "killed_chain.py").write_text(KILLED_CHAIN)
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "plugins"))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), str(Path(__file__).parent / "plugins")]))
    config = write_config(tmp_path, """\
        name: killed
        system: {type: "killed_chain:KilledChainParams"}
        integrators: [symplectic_euler]
        duration: 0.05
        sweep: {dt: [1.0e-4], system.count: [1, 3, 2]}
        """, tmp_path / "out")
    assert main([str(config), "--no-plots", "-j", "2", "-q", "--lanes", "off"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("simrun: error: a worker process ended abruptly while running the sweep (killed by the system"), err
    assert "run the same command again" in err
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        assert all(group.attrs.get("complete") for group in file["runs"].values())
    with OutputLock(tmp_path / "out"):  # free again
        pass
