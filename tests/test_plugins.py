"""A user's own system joins without editing simrun: by its module path in the
config (``type: pendulum_chain:ChainParams``) or by an entry point of group ``simrun.systems``; its parameters
are validated and its errors reported like a built-in system's; it runs serially, on the process pool and
on Dask; ``simrun check-system`` runs the contract on it. The example plug-in is the one of docs/systems.md,
and it is physically right: its single pendulum swings with the small-angle period 2 pi sqrt(L/g).
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import simrun
from conftest import assert_runs_alike, make_runs
from simrun.cli import main
from simrun.errors import ConfigError
from simrun.execution.simulate import simulate
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import config_hash, expand_runs
from simrun.systems import plugins
from simrun.contracts.system import CHECKS, run_checks

PLUGIN_FOLDER = Path(__file__).parent / "plugins"
SITE = PLUGIN_FOLDER / "site"  # a fake installed distribution, simrun-demo-plugin 0.1, with entry points
EXAMPLE = PLUGIN_FOLDER / "pendulum_chain.py"
DOCS = Path(__file__).parent.parent / "docs" / "systems.md"
CHAIN = "pendulum_chain:ChainParams"
SIMRUN = Path(sys.executable).parent / "simrun"


@pytest.fixture
def installed(monkeypatch, on_path):
    """simrun-demo-plugin 0.1 installed: its entry points demo_chain (the example) and demo_missing (broken)."""
    monkeypatch.syspath_prepend(str(SITE))
    yield


def config(system: dict, output: Path, **extra) -> dict:
    return {"name": "plugin", "system": system, "integrators": ["symplectic_euler", "implicit_midpoint"],
            "duration": 0.05, "sweep": {"dt": [1e-4]}, "output": str(output), **extra}


# -- joining ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("jobs", [1, 2])
def test_a_plugin_named_by_its_path_runs_through_the_pipeline(on_path, tmp_path, jobs):
    """type: pendulum_chain:ChainParams runs serially and on the process pool (the params pickled by module
    path, the module importable in the workers); the file keeps the type as written and its parameters."""
    results = simrun.run(config({"type": CHAIN, "count": 2}, tmp_path / "out"), jobs=jobs, progress=False,
                         figures=False)
    assert results.ran == {"ok": 2}
    assert set(results.summary["status"]) == {"ok"}
    with h5py.File(results.path, "r") as file:
        for run in file["runs"].values():
            assert run.attrs["system"] == CHAIN
            assert json.loads(run.attrs["system_params"])["count"] == 2
            assert run.attrs["dof_count"] == 6


def test_a_plugin_runs_on_dask(on_path, tmp_path):
    """A local Dask cluster's workers import the plug-in too."""
    results = simrun.run(config({"type": CHAIN, "count": 1}, tmp_path / "out"), executor="dask", jobs=1,
                         progress=False, figures=False)
    assert results.ran == {"ok": 2}


CLUSTER = """
import sys
from distributed import LocalCluster

if __name__ == "__main__":
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=50)
    print(cluster.scheduler_address, flush=True)
    sys.stdin.read()  # until the test closes it
    cluster.close()
"""


def test_a_plugin_runs_on_a_dask_cluster_whose_workers_do_not_have_it(tmp_path, on_path):
    """A cluster of process workers started in a process of its own, without the plug-in's folder on its path (as
    `--scheduler tcp://...` to a cluster started elsewhere): simrun ships the module's source with every task, and
    the file is the serial run's. A plug-in that imports a module of its own that simrun does not ship (it ships the
    modules the system's classes are defined in) fails on the workers with one line naming that module, exit 2."""
    pytest.importorskip("distributed")
    script = tmp_path / "cluster.py"
    script.write_text(CLUSTER)
    process = subprocess.Popen([sys.executable, str(script)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                               cwd=tmp_path, env={key: value for key, value in os.environ.items() if key != "PYTHONPATH"})
    try:
        address = process.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        serial = simrun.run(config({"type": CHAIN, "count": 2}, tmp_path / "serial"), jobs=1, progress=False,
                            figures=False)
        on_dask = simrun.run(config({"type": CHAIN, "count": 2}, tmp_path / "dask"), executor="dask",
                             scheduler=address, progress=False, figures=False)
        helped = _plugin_with_a_helper(tmp_path / "helped")
        code = subprocess.run([str(SIMRUN), str(helped), "--executor", "dask", "--scheduler", address, "--no-plots"],
                              capture_output=True, text=True, cwd=tmp_path, timeout=300,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join([str(PLUGIN_FOLDER), str(helped.parent)])})
    finally:
        process.stdin.close()
        process.wait(timeout=60)
    assert serial.ran == on_dask.ran == {"ok": 2}
    assert_runs_alike(serial, on_dask)
    assert code.returncode == 2, code.stderr
    assert code.stderr.count("\n") == 1 and "Traceback" not in code.stderr, code.stderr
    assert code.stderr.startswith("simrun: error: --executor dask: a worker cannot import chain_gravity:"), code.stderr


def _plugin_with_a_helper(folder: Path) -> Path:
    """A config beside its plug-in ``helped_chain``, whose module imports ``chain_gravity``, a module of the user's
    beside it that no system class is defined in (so simrun does not ship it)."""
    folder.mkdir()
    (folder / "chain_gravity.py").write_text("G = 9.81\n")
    (folder / "helped_chain.py").write_text(
        "from typing import Literal\n\nimport chain_gravity  # noqa: F401\nfrom pendulum_chain import Chain, ChainParams\n\n\n"
        "class HelpedChainParams(ChainParams):\n"
        "    type: Literal['helped_chain:HelpedChainParams'] = 'helped_chain:HelpedChainParams'\n\n\n"
        "HelpedChainParams.system_class = Chain\n")
    path = folder / "helped.yaml"
    path.write_text(yaml.safe_dump(config({"type": "helped_chain:HelpedChainParams", "count": 1}, folder / "out")))
    return path


def test_the_type_is_kept_as_written_so_the_hash_is_the_files(on_path):
    """The resolved config (hash, provenance) holds the type as the user wrote it; equal configs hash equally,
    and a plug-in parameter changes the hash."""
    first, _ = load_experiment({**config({"type": CHAIN}, Path("x")), "name": "a"})
    again, _ = load_experiment({**config({"type": CHAIN, "count": 3}, Path("x")), "name": "a"})  # 3 is the default
    other, _ = load_experiment({**config({"type": CHAIN, "count": 4}, Path("x")), "name": "a"})
    assert first.system.type == CHAIN and first.model_dump(mode="json")["system"]["type"] == CHAIN
    assert config_hash(first) == config_hash(again) != config_hash(other)


def test_a_type_declared_as_a_literal_of_the_path_is_accepted(on_path):
    """type: Literal["literal_chain:LiteralChainParams"] works as type: str does; the value stays as written."""
    experiment, _ = load_experiment(config({"type": "literal_chain:LiteralChainParams", "count": 1}, Path("x")))
    assert type(experiment.system).__name__ == "LiteralChainParams"
    assert experiment.model_dump(mode="json")["system"] == {**plugins.resolve(CHAIN)(count=1).model_dump(mode="json"),
                                                            "type": "literal_chain:LiteralChainParams"}


def test_a_plugin_parameter_is_swept_and_its_errors_name_their_path(on_path, tmp_path):
    """sweep: {system.count: [1, 2]} multiplies the runs; a misspelt or invalid parameter is one line naming it."""
    experiment, _ = load_experiment(config({"type": CHAIN}, tmp_path, sweep={"dt": [1e-4], "system.count": [1, 2]}))
    runs = expand_runs(experiment)
    assert sorted({run.system.count for run in runs}) == [1, 2]
    assert {run.system.type for run in runs} == {CHAIN}
    with pytest.raises(ConfigError, match=r"^system\.cout: unknown key \(did you mean 'count'\?\); allowed: type, count"):
        load_experiment(config({"type": CHAIN, "cout": 2}, tmp_path))
    with pytest.raises(ConfigError, match=r"^sweep: system\.mass: Input should be greater than 0 \(got -1\)$"):
        expand_runs(load_experiment(config({"type": CHAIN}, tmp_path, sweep={"dt": [1e-4], "system.mass": [1, -1]}))[0])


def test_an_installed_plugin_joins_by_its_entry_point_name(installed, tmp_path):
    """simrun-demo-plugin registers demo_chain = pendulum_chain:ChainParams in group simrun.systems: the name
    runs, is kept as written, and is offered among the valid names; the built-in names come first."""
    assert plugins.installed()["demo_chain"] == CHAIN
    assert plugins.names()[:3] == ["spring_mass", "circular_motion", "cloth"] and "demo_chain" in plugins.names()
    results = simrun.run(config({"type": "demo_chain", "count": 1}, tmp_path / "out"), jobs=1, progress=False,
                         figures=False)
    assert results.ran == {"ok": 2}
    with h5py.File(results.path, "r") as file:
        assert {run.attrs["system"] for run in file["runs"].values()} == {"demo_chain"}
    with pytest.raises(ConfigError, match=r"unknown system 'demo_chian' \(did you mean 'demo_chain'\?\); valid: .*demo_chain"):
        load_experiment(config({"type": "demo_chian"}, tmp_path))


def test_a_plugin_in_the_current_folder_is_found_there(monkeypatch, tmp_path):
    """A module beside the config (the current folder) imports as with ``python -m``, though the console
    script's sys.path does not hold the current folder."""
    shutil.copy(EXAMPLE, tmp_path / "chain_here.py")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [entry for entry in sys.path if entry not in ("", ".", str(tmp_path))])
    monkeypatch.delitem(sys.modules, "chain_here", raising=False)
    plugins.clear_cache()
    experiment, _ = load_experiment(config({"type": "chain_here:ChainParams"}, tmp_path / "out"))
    assert type(experiment.system).__module__ == "chain_here"
    plugins.clear_cache()


# -- bad input -------------------------------------------------------------------------------------------------
BAD_TYPES = [
    ("nosuchmodule:X", "system.type: 'nosuchmodule:X': cannot import module 'nosuchmodule': No module named 'nosuchmodule'"),
    ("json:dumps", "system.type: 'json:dumps' names a function, not a class; give a subclass of simrun.systems.SystemParams"),
    ("math:pi", "system.type: 'math:pi' names an object of type float, not a class"),
    ("pendulum_chain:NotThere", "system.type: 'pendulum_chain:NotThere': module 'pendulum_chain' has no attribute 'NotThere'; "
                                "its SystemParams classes: ChainParams"),
    ("pendulum_chain:ChainParms", "has no attribute 'ChainParms' (did you mean 'ChainParams'?)"),
    ("broken_systems:NotAParams", "system.type: 'broken_systems:NotAParams' names the class NotAParams, which is not a "
                                  "subclass of simrun.systems.SystemParams"),
    ("broken_systems:WithoutSystemClass", "system.type: 'broken_systems:WithoutSystemClass': WithoutSystemClass has no "
                                          "system_class"),
    ("pendulum_chain:", "system.type: 'pendulum_chain:' is not a plug-in path; write package.module:ClassName"),
    ("rope", "system.type: unknown system 'rope'; valid: spring_mass, circular_motion, cloth"),
]


@pytest.mark.parametrize("name, message", BAD_TYPES, ids=[name for name, _ in BAD_TYPES])
def test_a_bad_plugin_is_one_line_exit_2_and_nothing_written(on_path, tmp_path, capsys, name, message):
    """`simrun CONFIG` with a type that does not import or names no system class: one line naming system.type
    and the problem, exit status 2, no output folder; simrun.run raises the same line."""
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(config({"type": name}, tmp_path / "never")))
    assert main([str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: ") and message in lines[0], captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert not (tmp_path / "never").exists()
    with pytest.raises(ConfigError) as error:
        simrun.run(str(path), jobs=1, progress=False)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert not (tmp_path / "never").exists()


def test_a_broken_entry_point_names_its_distribution(installed, tmp_path):
    """demo_missing = pendulum_chain:NotThere: the line names the entry point, its distribution and the problem."""
    with pytest.raises(ConfigError) as error:
        load_experiment(config({"type": "demo_missing"}, tmp_path))
    assert str(error.value) == ("system.type: 'demo_missing' (entry point of simrun-demo-plugin 0.1: simrun.systems "
                                "demo_missing = 'pendulum_chain:NotThere') -> 'pendulum_chain:NotThere': module "
                                "'pendulum_chain' has no attribute 'NotThere'; its SystemParams classes: ChainParams")


def test_a_module_that_fails_to_import_says_why(on_path, tmp_path, monkeypatch):
    """An error inside the user's module (here a missing dependency) is its type and message, on one line."""
    (tmp_path / "needs_missing.py").write_text("import numpy\nimport nosuchdependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError) as error:
        load_experiment(config({"type": "needs_missing:Params"}, tmp_path))
    assert str(error.value) == ("system.type: 'needs_missing:Params': cannot import module 'needs_missing': "
                                "No module named 'nosuchdependency'")


# -- simrun check-system -----------------------------------------------------------------------------------------
def check_system(*arguments: str, cwd: Path) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHONPATH": str(PLUGIN_FOLDER)}
    return subprocess.run([str(SIMRUN), "check-system", *arguments], capture_output=True, text=True, cwd=cwd,
                          env=environment, timeout=120)


def test_check_system_passes_the_example_plugin(tmp_path):
    """The console script, as a user runs it (PYTHONPATH names the plug-in's folder): `simrun check-system
    pendulum_chain:ChainParams` prints one PASS or SKIP line per check, no FAIL, and exits 0."""
    done = check_system(CHAIN, cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.strip().splitlines()
    reported = [line for line in lines if line[:4] in ("PASS", "FAIL", "SKIP")]
    assert [line.split()[0] for line in reported].count("FAIL") == 0
    assert len(reported) == 1 + len(CHECKS)
    assert re.search(r"^PASS  gradient +relative FD error of dP/dx \d\.\de-\d\d <= 1e-06", done.stdout, re.MULTILINE)
    assert done.stderr == ""


def test_check_system_names_the_wrong_derivative_and_a_round_off_energy_reference(on_path, capsys):
    """A 0.1 % wrong gradient fails the gradient check alone: the Hessian is not dg/dx of it, but it is the second
    derivative of the energy, and the Hessian check says so; a 0.1 % wrong Hessian (the gradient right) fails the
    Hessian check alone. An energy reference of round-off (the chain released from horizontal with E_ref = |KE0| +
    |PE0| ~ 1e-16 J) fails the energy reference and the short run, which the runner would mark diverged after one
    step. Exit status 1, every line printed."""
    assert main(["check-system", "broken_systems:WrongGradientParams"]) == 1
    out = capsys.readouterr().out
    assert {line.split()[1] for line in out.splitlines() if line.startswith("FAIL")} == {"gradient"}
    assert "relative FD error 1.0e-03 > 1e-06" in out and "(the gradient is what is wrong)" in out
    assert main(["check-system", "broken_systems:WrongHessianParams"]) == 1
    out = capsys.readouterr().out
    assert {line.split()[1] for line in out.splitlines() if line.startswith("FAIL")} == {"hessian"}
    assert "nor d2P/dx2 (relative error of the energy's second differences 1.0e-03 > 1e-05)" in out
    assert len([line for line in out.splitlines() if line[:4] in ("PASS", "FAIL", "SKIP")]) == 1 + len(CHECKS)
    assert main(["check-system", "broken_systems:RoundOffReferenceParams"]) == 1
    failed = [line for line in capsys.readouterr().out.splitlines() if line.startswith("FAIL")]
    assert [line.split()[1] for line in failed] == ["energy", "short"]
    assert "is round-off next to W0" in failed[0] and "after step 1" in failed[1]


@pytest.mark.parametrize("arguments, message", [
    (["nosuchmodule:X"], "simrun: error: system.type: 'nosuchmodule:X': cannot import module 'nosuchmodule'"),
    (["broken_systems:NotAParams"], "which is not a subclass of simrun.systems.SystemParams"),
    ([CHAIN, "--set", "count=0"], "simrun: error: system.count: Input should be greater than or equal to 1 (got 0)"),
    ([CHAIN, "--set", "cuont=2"], "simrun: error: system.cuont: unknown key (did you mean 'count'?)"),
    ([CHAIN, "--set", "count"], "simrun: error: --set count: expected field=value"),
    ([CHAIN, "--set", "type=cloth"], "simrun: error: --set type=cloth: the system is the SYSTEM argument"),
])
def test_check_system_bad_input_is_one_line_exit_2(on_path, capsys, arguments, message):
    assert main(["check-system", *arguments]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1 and message in captured.err, captured.err


def test_check_system_takes_overrides(on_path, capsys):
    """--set count=1 --set system.hardening=0 (with or without the system. prefix) builds a single linear pendulum."""
    assert main(["check-system", CHAIN, "--set", "count=1", "--set", "system.hardening=0"]) == 0
    assert "builds Chain with 4 dofs" in capsys.readouterr().out


# -- the example is the documentation's, and it is right -----------------------------------------------------------
def test_the_example_in_the_docs_is_the_tested_file():
    """The code block of docs/systems.md after its marker is tests/plugins/pendulum_chain.py, character for character."""
    text = DOCS.read_text(encoding="utf-8")
    marker = "<!-- the file tests/plugins/pendulum_chain.py; tests/test_plugins.py checks that they are equal -->"
    assert marker in text
    block = re.search(r"```python\n(.*?)```", text[text.index(marker):], re.DOTALL)
    assert block is not None and block.group(1) == EXAMPLE.read_text(encoding="utf-8")


def test_the_docs_show_the_checks_that_check_system_runs(on_path):
    """The check-system output in docs/systems.md (the block after its marker) lists the checks that run_checks
    reports for the example, in order, with their verdicts."""
    text = DOCS.read_text(encoding="utf-8")
    marker = "<!-- simrun check-system pendulum_chain:ChainParams -->"
    block = re.search(r"```text\n(.*?)```", text[text.index(marker):], re.DOTALL).group(1)
    shown = re.findall(r"^(PASS|FAIL|SKIP)  (.+?)  ", block, re.MULTILINE)
    checks = run_checks(plugins.resolve(CHAIN)())
    assert shown == [(check.status, check.name) for check in checks]


def test_the_single_pendulum_swings_with_the_small_angle_period(on_path):
    """One mass on a stiff linear spring (L = 0.25 m, stretch under gravity m g / k = 4e-4 L) released at rest from
    0.05 rad: the period between zero crossings of x is 2 pi sqrt(L/g) within 0.5 %. (The finite amplitude adds
    theta0^2/16 = 1.6e-4, the stretch 2e-4, implicit midpoint at dt = 1e-3 s (w dt)^2/12 = 3e-6.)"""
    length, gravity = 0.25, 9.81
    system = {"type": CHAIN, "count": 1, "length": length, "mass": 0.1, "stiffness": 1e4, "hardening": 0.0,
              "gravity": gravity, "angle": 0.05}
    (run,) = make_runs(system, ["implicit_midpoint"], [1e-3], duration=3.3, record={"every": 1})
    result = simulate(run)
    assert result.status == "ok", result.message
    t, x = result.samples["t"], result.samples["positions"][:, 2]  # the mass's horizontal position
    crossings = [t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i]) for i in np.flatnonzero(np.sign(x[:-1]) != np.sign(x[1:]))]
    assert len(crossings) >= 6
    period = 2.0 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)
    expected = 2.0 * math.pi * math.sqrt(length / gravity)
    assert period == pytest.approx(expected, rel=5e-3)
    # and to 2e-5 with both corrections: the static stretch lengthens the pendulum, the amplitude slows it
    stretched = length + system["mass"] * gravity / system["stiffness"]
    corrected = 2.0 * math.pi * math.sqrt(stretched / gravity) * (1.0 + system["angle"] ** 2 / 16.0)
    assert period == pytest.approx(corrected, rel=2e-5)


def test_the_chain_released_from_horizontal_is_not_diverged_after_one_step(on_path):
    """A user's report: a chain released from horizontal (E0 = 0 by construction, |PE0| ~ 1e-16 J of
    round-off) was marked diverged after one step. It swings; symplectic Euler at a stable step keeps its energy."""
    (run,) = make_runs({"type": CHAIN, "angle": math.pi / 2}, ["symplectic_euler"], [2e-5], duration=0.01)
    result = simulate(run)
    assert result.status == "ok", result.message
