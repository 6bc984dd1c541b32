"""`simrun check-integrator`: a method measured against what it declares. Every built-in method passes, reached by
its plug-in path; Bathe's composite scheme (tests/plugins/bathe.py) passes with its closed-form spectral radius
checked to 1e-10 and rho_inf = 0 as Bathe & Baig report it; three planted defects each fail their own check; a method
that cannot be had is one line, exit 2, nothing written.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from simrun.cli import main
from simrun.contracts import integrator as contract
from simrun.integrators import INTEGRATORS, plugins
from simrun.plugins import class_path

PLUGIN_FOLDER = Path(__file__).parent / "plugins"


def statuses(report) -> dict[str, str]:
    return {check.name: check.status for check in report.checks}


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_every_built_in_method_passes_through_its_plugin_path(name):
    """package.module:ClassName of each built-in resolves to the built-in, and no check fails."""
    method = plugins.resolve(class_path(INTEGRATORS[name]))
    assert method is INTEGRATORS[name]
    report = contract.run_checks(method())
    failed = [str(check) for check in report.checks if check.passed is False]
    assert not failed, failed
    assert statuses(report)["order (spring)"] == "PASS" and statuses(report)["card"] == "PASS"


def test_bathe_passes_with_its_closed_form_and_no_high_frequency_radius(on_path):
    report = contract.run_checks(plugins.resolve("bathe:Bathe")())
    assert all(check.passed is True for check in report.checks), [str(check) for check in report.checks]
    card = report.card
    assert card.source == "amplification matrix" and abs(card.rho_inf) < 1e-6
    assert math.isinf(card.stability_limit)  # unconditionally stable
    for problem in ("spring", "Kepler"):
        assert abs(card.orders[problem].order - 2.0) <= contract.ORDER_TOLERANCE


def test_the_gamma_of_equal_newton_matrices_passes_too(on_path):
    report = contract.run_checks(plugins.resolve("bathe:Bathe")(gamma=2.0 - math.sqrt(2.0)))
    assert not [check for check in report.checks if check.passed is False]


@pytest.mark.parametrize("defect, check", [
    ("own_methods:ClaimsOrderTwo", "order (spring)"),
    ("own_methods:NonlinearKick", "linearity"),
    ("own_methods:LeakyMomentum", "free motion"),
])
def test_a_planted_defect_fails_its_own_check(on_path, defect, check):
    """Order 1 declared 2; a step not linear in the state; a leak of momentum: each named by its check, and the
    linear ones' other checks pass."""
    report = contract.run_checks(plugins.resolve(defect)())
    found = statuses(report)
    assert found[check] == "FAIL", [str(item) for item in report.checks]
    own = {check, "order (Kepler)"} if defect.endswith("ClaimsOrderTwo") else {check}
    assert {name for name, status in found.items() if status == "FAIL"} == own, [str(item) for item in report.checks]


def test_a_nonlinear_method_gets_a_measured_card(on_path):
    report = contract.run_checks(plugins.resolve("own_methods:NonlinearKick")())
    assert report.card.source == "measured runs"
    assert "no amplification matrix: the step is not linear in the state" in next(
        check.detail for check in report.checks if check.name == "linearity")


def test_the_command_prints_a_line_per_check_and_writes_the_card(on_path, tmp_path, capsys):
    output = tmp_path / "card"
    assert main(["check-integrator", "bathe:Bathe", "--set", "gamma=0.5", "--output", str(output)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("bathe: ") and lines[-1].startswith("all ")
    checks = [line for line in lines if line[:4] in ("PASS", "FAIL", "SKIP")]
    assert len(checks) == 8 and all(line.startswith("PASS") for line in checks), lines
    record = json.loads((output / "card.json").read_text())
    assert record["integrator_class"] == "bathe:Bathe" and len(record["integrator_source_sha256"]) == 64
    assert record["declared"]["order"] == 2 and record["rho_inf"] < 1e-6
    assert len(record["hw"]) == len(record["curves"]["0"]["spectral_radius"]) == 121
    assert (output / "card.png").stat().st_size > 10_000


def test_a_failing_method_exits_1(on_path, tmp_path, capsys):
    assert main(["check-integrator", "own_methods:LeakyMomentum", "--output", str(tmp_path / "card")]) == 1
    out = capsys.readouterr().out
    assert "FAIL  free motion" in out and out.strip().splitlines()[-1] == "1 of 8 checks failed"


@pytest.mark.parametrize("arguments, message", [
    (["nosuchmodule:X"], "METHOD nosuchmodule:X: 'nosuchmodule:X': cannot import module 'nosuchmodule'"),
    (["own_methods:NoOrder"], "NoOrder does not declare 'order'"),
    (["bathe:Bathe", "--set", "gamma=2"], "METHOD bathe:Bathe: bathe:Bathe: gamma: Input should be less than 1"),
    (["bathe:Bathe", "--set", "gamma"], "--set gamma: expected field=value"),
    (["solve_ivp"], "solve_ivp is a whole-run peer"),
])
def test_bad_input_is_one_line_exit_2_and_nothing_written(on_path, tmp_path, capsys, arguments, message):
    output = tmp_path / "never"
    assert main(["check-integrator", *arguments, "--output", str(output)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in captured.err, captured.err
    assert not output.exists()


# -- the docs' examples are the tested files, and they pass --------------------------------------------------------
DOCS = Path(__file__).parent.parent / "docs" / "integrators.md"
EXAMPLES = {"theta_method.py": "theta_method:ThetaMethod", "bathe.py": "bathe:Bathe", "ralston.py": "ralston:Ralston3"}


@pytest.mark.parametrize("file", sorted(EXAMPLES))
def test_each_example_in_the_docs_is_the_tested_file_and_passes(on_path, file):
    """The code block after each example's marker in docs/integrators.md is the file, character for character, and
    check-integrator passes it, its closed form included."""
    text = DOCS.read_text(encoding="utf-8")
    marker = f"<!-- the file tests/plugins/{file}; tests/test_check_integrator.py checks that they are equal -->"
    assert marker in text
    block = re.search(r"```python\n(.*?)```", text[text.index(marker):], re.DOTALL)
    assert block is not None and block.group(1) == (PLUGIN_FOLDER / file).read_text(encoding="utf-8")
    report = contract.run_checks(plugins.resolve(EXAMPLES[file])())
    assert {check.name: check.status for check in report.checks}["closed form"] == "PASS"
    assert not [str(check) for check in report.checks if check.passed is False]


def test_the_docs_show_the_checks_that_check_integrator_runs(on_path):
    text = DOCS.read_text(encoding="utf-8")
    marker = "<!-- simrun check-integrator bathe:Bathe -->"
    block = re.search(r"```text\n(.*?)```", text[text.index(marker):], re.DOTALL).group(1)
    shown = re.findall(r"^(PASS|FAIL|SKIP)  (.+?)  ", block, re.MULTILINE)
    report = contract.run_checks(plugins.resolve("bathe:Bathe")())
    assert shown == [(check.status, check.name) for check in report.checks]
