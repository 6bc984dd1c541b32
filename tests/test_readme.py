"""The README is true: its tour runs as written, in order, in a folder holding the repository's configs,
models and example plug-in, with the installed `simrun` on the path; its `make` lines name targets the Makefile has;
and every run count a config's comment or the README states is the count its sweep expands to."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import config_params
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


def tour_commands() -> list[str]:
    """The command lines of the README's "A tour" block, without their comments."""
    text = README.read_text()
    block = re.search(r"^## A tour\n+```sh\n(.*?)^```", text, re.S | re.M)
    assert block, "README.md has no '## A tour' sh block"
    commands = []
    for line in block.group(1).splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        commands.append(re.sub(r"\s+#\s.*$", "", line).strip())
    return commands


def test_the_tour_has_the_commands_a_newcomer_needs():
    commands = tour_commands()
    assert commands[0] == "simrun configs/quickstart.yaml"
    assert any(command.startswith("simrun fit ") for command in commands)
    assert {command.split()[1] for command in commands if command.startswith("make ")} >= {"sweep", "bench"}


@pytest.mark.slow
def test_the_tour_runs_as_written(tmp_path):
    """Each `simrun` line of the tour, in order, exits 0 (a line may rely on the ones before it: plot and report read
    what the first line wrote). The `make` lines are checked with `make -n` in the repository (they run every
    config and every benchmark: CI time better spent elsewhere)."""
    for folder in ("configs", "models"):
        shutil.copytree(ROOT / folder, tmp_path / folder)
    for folder in ("plugins", "trajectories"):
        shutil.copytree(ROOT / "tests" / folder, tmp_path / "tests" / folder)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg"}
    env.pop("PYTHONPATH", None)
    for command in tour_commands():
        if command.startswith("make "):
            target = shlex.split(command)[1]
            dry = subprocess.run(["make", "-n", target], cwd=ROOT, capture_output=True, text=True, timeout=60)
            assert dry.returncode == 0, f"{command}: {dry.stderr}"
            continue
        done = subprocess.run(["bash", "-c", command], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=900)
        assert done.returncode == 0, f"{command}: exit {done.returncode}\n{done.stderr[-2000:]}"


@pytest.mark.parametrize("config", config_params(CONFIGS))
def test_a_run_count_in_a_configs_comment_is_its_sweeps(config):
    comments = " ".join(line for line in config.read_text().splitlines() if line.lstrip().startswith("#"))
    stated = {int(number.replace(",", "")) for number in re.findall(r"\b(\d[\d,]*) runs\b", comments)}
    if not stated:
        return
    experiment, _ = load_experiment(config)
    assert stated == {len(expand_runs(experiment))}, f"{config.name} says {sorted(stated)} runs"


def test_the_run_counts_the_readme_states_are_the_configs():
    """"42,000 runs" and the like in the README are the count of the config named last before them."""
    text = README.read_text()
    checked = 0
    for match in re.finditer(r"\b(\d[\d,]{3,}) (?:spring )?runs\b", text):
        named = re.findall(r"(\w+)\.yaml", text[:match.start()])
        path = ROOT / "configs" / f"{named[-1]}.yaml"
        experiment, _ = load_experiment(path)
        assert len(expand_runs(experiment)) == int(match.group(1).replace(",", "")), f"README: {path.name}, {match.group(0)}"
        checked += 1
    assert checked >= 2


def test_the_readme_and_the_docs_name_the_format_the_writer_writes():
    from simrun.format.layout import FORMAT_VERSION, READABLE_VERSIONS

    readme = re.search(r"docs/results-format\.md\)\s+\(format (\d+); files of\s+formats? ([\d, and]+) are still read",
                       README.read_text())
    assert readme, "README.md no longer names the results format beside docs/results-format.md"
    assert int(readme.group(1)) == FORMAT_VERSION
    assert sorted(int(number) for number in re.findall(r"\d+", readme.group(2))) == sorted(set(READABLE_VERSIONS) - {FORMAT_VERSION})
    page = (ROOT / "docs" / "results-format.md").read_text()
    assert re.match(rf"# The results file, format version {FORMAT_VERSION}\n", page)
    assert re.search(rf"^- \*\*{FORMAT_VERSION}\*\* \(this page\)", page, re.M)
    assert re.search(rf"^\| `format_version` \| int \| {FORMAT_VERSION} \|", page, re.M)
    for path in [README, *sorted((ROOT / "docs").glob("*.md"))]:  # no other page names another version as current
        for match in re.finditer(r"\bformat version (\d+)\b", path.read_text()):
            assert int(match.group(1)) == FORMAT_VERSION, f"{path.name}: {match.group(0)}"
