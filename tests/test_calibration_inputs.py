"""`simrun fit` on bad input: every problem with the observations, the fitted keys or the fit block is one line
`simrun: error: <config path or file>: ...` on stderr, exit status 2, no traceback, and nothing in the output folder;
a fit that goes wrong (no convergence within its budget) is a result, not an error."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from simrun.cli import main

GOOD_CSV = "t,x\n" + "".join(f"{0.1 * n:.1f},{np.cos(10 * 0.1 * n):.12f}\n" for n in range(11))  # q = cos(10 t), 0..1 s


def spring_config(observed, parameters: str | None = None, extra: str = "", fit: bool = True) -> str:
    """A spring calibrated on 1 s; ``observed`` written as JSON (valid YAML); ``parameters`` replaces the block."""
    parameters = parameters if parameters is not None else textwrap.dedent("""\
        system.stiffness: {start: 80.0, bounds: [1.0, 1.0e4]}
        system.damping: {start: 0.1, bounds: [-50.0, 50.0]}""")
    text = textwrap.dedent("""\
        name: calibration_inputs
        system: {type: spring_mass, mass: 1.0, stiffness: 100.0, damping: 0.0, x0: 1.0, v0: 0.0}
        integrators: [backward_euler]
        duration: 1.0
        sweep: {dt: [0.1]}
        """)
    if fit:
        text += f"fit:\n  observed: {json.dumps(observed)}\n  parameters:\n" + textwrap.indent(parameters, "    ") + "\n" + extra
    return text


CLOTH = {"type": "cloth", "resolution": [3, 3], "pinned": ["top_left", "top_right"]}


def cloth_config(parameters: str, extra: str = "") -> str:
    return textwrap.dedent(f"""\
        name: cloth_inputs
        system: {json.dumps(CLOTH)}
        integrators: [backward_euler]
        duration: 0.1
        sweep: {{dt: [0.01]}}
        fit:
          observed: {{synthetic: {{integrator: backward_euler, dt: 0.01}}}}
          parameters:
        """) + textwrap.indent(parameters, "    ") + "\n" + extra


@pytest.fixture(scope="module")
def stored_results(tmp_path_factory) -> Path:
    """A results file of `simrun run` with one spring run (backward Euler at dt = 0.1 s)."""
    folder = tmp_path_factory.mktemp("stored")
    config = folder / "run.yaml"
    config.write_text(spring_config(None, fit=False) + f"output: {json.dumps(str(folder / 'out'))}\n")
    assert main([str(config), "-j", "1", "-q", "--no-plots"]) == 0
    return folder / "out" / "results.h5"


# (id, the CSV beside the config (None: none), config text of (csv path, results path), what the line names)
CASES = [
    ("observation file missing", None, lambda csv, h5: spring_config("missing.csv"),
     ["fit.observed", "'missing.csv' does not exist"]),
    ("non-numeric cell", "t,x\n0.0,1.0\n0.5,one\n1.0,0.5\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "line 3", "'x'", "'one'", "not a number"]),
    ("NaN cell", "t,x\n0.0,1.0\n0.5,nan\n1.0,0.5\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "line 3", "'x'", "empty or NaN"]),
    ("empty cell", "t,x\n0.0,1.0\n0.5,\n1.0,0.5\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "line 3", "'x'", "empty or NaN"]),
    ("infinite cell", "t,x\n0.0,1.0\n0.5,inf\n1.0,0.5\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "line 3", "'x'"]),
    ("header only", "t,x\n", lambda csv, h5: spring_config(csv), ["fit.observed", "observed.csv", "no rows"]),
    ("times unsorted", "t,x\n0.0,1.0\n0.6,0.5\n0.5,0.4\n1.0,0.1\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "times must increase", "t = 0.5 s (line 4) follows t = 0.6 s"]),
    ("times repeated", "t,x\n0.0,1.0\n0.5,0.5\n0.5,0.5\n1.0,0.1\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "times must increase"]),
    ("time after the run", "t,x\n0.0,1.0\n0.5,0.5\n1.5,0.1\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "t = 1.5 s lies outside the run", "duration 1 s"]),
    ("time before the run", "t,x\n-0.5,1.0\n0.5,0.5\n1.0,0.1\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "t = -0.5 s lies outside the run"]),
    ("one observation time", "t,x\n0.0,1.0\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "at least two"]),
    ("column count", "t,x,y,z\n0.0,1.0,0,0\n0.5,0.5,0,0\n1.0,0.1,0,0\n", lambda csv, h5: spring_config(csv),
     ["fit.observed", "observed.csv", "3 columns after t", "observe 1 dofs"]),
    ("velocities missing", None, lambda csv, h5: spring_config(csv, extra="  weights: position_and_velocity\n"),
     ["fit.observed", "observed.csv", "1 columns after t", "1 velocities"]),
    ("unknown key", None, lambda csv, h5: spring_config(csv, "system.stifness: {start: 80.0, bounds: [1.0, 1.0e4]}"),
     ["fit.parameters.system.stifness", "no key 'stifness'", "did you mean 'system.stiffness'?"]),
    ("key outside the system", None, lambda csv, h5: spring_config(csv, "solver.tolerance: {start: 1.0e-8}"),
     ["fit.parameters", "solver.tolerance", "system keys"]),
    ("system.type", None, lambda csv, h5: spring_config(csv, "system.type: {start: 1.0}"),
     ["fit.parameters", "system.type", "not a number"]),
    ("a list-valued key", None, lambda csv, h5: cloth_config("system.gravity: {start: 1.0}"),
     ["fit.parameters.system.gravity", "not a number"]),
    ("a string-valued key", None, lambda csv, h5: cloth_config("system.pinned.0: {start: 1.0}"),
     ["fit.parameters.system.pinned.0", "'top_left'", "not a number"]),
    ("a non-numeric start", None, lambda csv, h5: spring_config(csv, "system.stiffness: {start: stiff}"),
     ["fit.parameters.system.stiffness.start"]),
    ("bounds inverted", None, lambda csv, h5: spring_config(csv, "system.stiffness: {start: 80.0, bounds: [1.0e4, 1.0]}"),
     ["fit.parameters.system.stiffness", "inverted"]),
    ("bounds exclude the start", None, lambda csv, h5: spring_config(csv, "system.stiffness: {start: 80.0, bounds: [90.0, 1.0e4]}"),
     ["fit.parameters.system.stiffness", "start: 80 lies outside bounds [90, 10000]"]),
    ("a bound the model refuses", None, lambda csv, h5: spring_config(csv, "system.mass: {start: 1.0, bounds: [-1.0, 2.0]}"),
     ["fit.parameters.system.mass.bounds", "-1 is not a value of system.mass"]),
    ("marker out of range", None, lambda csv, h5: cloth_config("system.stretch_stiffness: {start: 8000.0}", "  markers: [4, 9]\n"),
     ["fit.markers", "vertex 9 does not exist", "0 to 8"]),
    ("negative marker", None, lambda csv, h5: cloth_config("system.stretch_stiffness: {start: 8000.0}", "  markers: [-1]\n"),
     ["fit.markers"]),
    ("a fitted key the sweep sets", None, lambda csv, h5: spring_config(csv).replace(
        "sweep: {dt: [0.1]}", "sweep: {dt: [0.1], system.stiffness: [50.0, 100.0]}"),
     ["fit.parameters.system.stiffness", "the sweep also sets"]),
    ("an unknown key of the synthetic truth", None,
     lambda csv, h5: spring_config({"synthetic": {"integrator": "exact", "dt": 0.1, "system": {"stifness": 120.0}}}),
     ["fit.observed.synthetic", "stifness"]),
    ("no fit block", None, lambda csv, h5: spring_config(csv, fit=False), ["fit:", "no fit block"]),
    ("unknown synthetic integrator", None,
     lambda csv, h5: spring_config({"synthetic": {"integrator": "backward_eular", "dt": 0.1}}),
     ["fit.observed.synthetic.integrator", "backward_euler"]),
    ("exact solution of a cloth", None, lambda csv, h5: cloth_config("system.stretch_stiffness: {start: 8000.0}").replace(
        "integrator: backward_euler", "integrator: exact"), ["fit.observed.synthetic.integrator", "no exact solution"]),
    ("results file missing", None, lambda csv, h5: spring_config({"results": str(h5.parent / "none.h5")}),
     ["fit.observed", "none.h5", "does not exist"]),
    ("a run that does not exist", None, lambda csv, h5: spring_config({"results": str(h5), "run": "0007-nothing"}),
     ["fit.observed.run", "no run '0007-nothing'"]),
    ("a stored run of another system", None, lambda csv, h5: cloth_config("system.stretch_stiffness: {start: 8000.0}").replace(
        "{synthetic: {integrator: backward_euler, dt: 0.01}}", json.dumps({"results": str(h5)})),
     ["fit.observed.run", "1 dofs", "27"]),
    # an error inside one form of `observed` is that form's, in one line (not every member of the union failing)
    ("a synthetic step <= 0", None, lambda csv, h5: spring_config({"synthetic": {"integrator": "exact", "dt": -0.05}}),
     ["fit.observed", "synthetic.dt", "greater than 0"]),
    ("an unknown key of a stored run", None, lambda csv, h5: spring_config({"results": str(h5), "extra": 1}),
     ["fit.observed", "extra: unknown key", "results, run"]),
    ("observed as a list", None, lambda csv, h5: spring_config([1, 2]),
     ["fit.observed", "expected a CSV file's path"]),
    ("exact sensitivities for a key that needs differences", None,
     lambda csv, h5: spring_config(csv, "system.x0: {start: 0.9, bounds: [0.0, 2.0]}", "  sensitivities: exact\n"),
     ["fit.sensitivities", "system.x0", "use auto"]),
]


@pytest.mark.parametrize("csv_text, make, expected", [pytest.param(*case[1:], id=case[0]) for case in CASES])
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, stored_results, csv_text, make, expected):
    csv = tmp_path / "observed.csv"
    csv.write_text(GOOD_CSV if csv_text is None else csv_text)
    config = tmp_path / "calibrate.yaml"
    config.write_text(make(str(csv), stored_results))
    output = tmp_path / "out"
    assert main(["fit", str(config), "--output", str(output), "-j", "1", "-q"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: "), captured.err
    for part in expected:
        assert part in lines[0], (part, lines[0])
    assert "Traceback" not in captured.err and captured.out == ""
    assert not output.exists()


def test_bad_input_through_the_console(tmp_path):
    """The same through `python -m simrun fit`: a missing observation file is one line and exit status 2."""
    config = tmp_path / "calibrate.yaml"
    config.write_text(spring_config("missing.csv"))
    output = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "simrun", "fit", str(config), "--output", str(output), "-j", "1", "-q"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: fit.observed: file 'missing.csv' does not exist")
    assert not output.exists()


def test_observation_file_beside_the_config_is_found(tmp_path, capsys):
    """A relative observation file is looked for beside the config (the CLI run from anywhere)."""
    folder = tmp_path / "experiment"
    folder.mkdir()
    (folder / "observed.csv").write_text(GOOD_CSV)
    config = folder / "calibrate.yaml"
    config.write_text(spring_config("observed.csv"))
    assert main(["fit", str(config), "--output", str(tmp_path / "out"), "-j", "1", "-q", "--no-plots"]) == 0
    assert "results:" in capsys.readouterr().out


def test_a_fit_that_runs_out_of_evaluations_is_a_result(tmp_path, capsys):
    """max_evaluations: 2 (far too few from k = 80 N/m when the truth is 100 N/m): the fit's status is
    not_converged with its last iterate (finite, within bounds, moved from the start), and `simrun fit` exits 0."""
    from simrun.results import load

    (tmp_path / "observed.csv").write_text(GOOD_CSV)
    config = tmp_path / "calibrate.yaml"
    config.write_text(spring_config(str(tmp_path / "observed.csv"), extra="  max_evaluations: 2\n"))
    output = tmp_path / "out"
    assert main(["fit", str(config), "--output", str(output), "-j", "1", "-q", "--no-plots"]) == 0
    assert "not_converged" in capsys.readouterr().out
    table = load(output / "results.h5").fits.table.set_index("label")
    row = table.loc["backward_euler"]
    assert row["status"] == "not_converged"
    assert "max_evaluations" in row["message"]
    values = np.array([row["system.stiffness"], row["system.damping"]])
    assert np.all(np.isfinite(values)) and 1.0 <= values[0] <= 1.0e4 and -50.0 <= values[1] <= 50.0
    assert values[0] != 80.0
    assert np.isfinite(row["residual_norm"])
