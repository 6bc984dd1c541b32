"""The summary has one typed column per swept key and method parameter (simrun.results.parameters), in
`results.summary`, `simrun show --csv` and the report's runs table; every shipped config's sweep keys get theirs."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pandas
import pytest
import yaml

from conftest import config_params
import simrun
from simrun.analysis.rows import summary_rows
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.figures import figure_data
from simrun.report.summary_table import write_csv
from simrun.report.tables import summary_section
from simrun.results.parameters import column_kind, mapping_keys, parameter_columns

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


@pytest.fixture(scope="module")
def work_precision(tmp_path_factory):
    """work_precision.yaml as shipped, shortened to run in seconds: its spring and Kepler orbit (the labelled systems
    of its sweep), two of its tolerances, five of its methods (a family of BDF orders and a scipy peer among them)."""
    config = yaml.safe_load((ROOT / "configs" / "work_precision.yaml").read_text())
    config["sweep"]["system"] = config["sweep"]["system"][:2]
    config["sweep"]["step_control.tolerance"] = [1e-3, 1e-5]
    config["integrators"] = ["dopri5", {"type": "bdf", "order": 2}, {"type": "bdf", "order": 3},
                             {"type": "rosenbrock", "scheme": "ros3p"}, {"type": "solve_ivp", "method": "RK45"}]
    config["duration"] = 0.5
    output = tmp_path_factory.mktemp("work_precision")
    return simrun.run(config, output=output, jobs=1, figures=False, progress=False)


def test_work_precision_groups_by_system_tolerance_and_method_without_run_ids(work_precision):
    summary = work_precision.summary
    assert summary["step_control.tolerance"].dtype == np.float64
    assert summary["system.label"].tolist() == ["spring"] * 5 + ["kepler"] * 5 + ["spring"] * 5 + ["kepler"] * 5
    assert str(summary["integrator.order"].dtype) == "Int64"  # only BDF has an order: NA elsewhere
    grouped = summary.groupby(["system.label", "step_control.tolerance", "integrator"])["error"].min()
    assert len(grouped) == 20 and grouped.notna().all()
    # a tighter tolerance buys a smaller error, method by method, on both systems
    for system in ("spring", "kepler"):
        loose, tight = grouped[system][1e-3], grouped[system][1e-5]
        assert (tight < loose).all(), (system, loose, tight)
    bdf = summary[summary["integrator.order"].notna()]
    assert sorted(set(bdf["integrator.order"].astype(int))) == [2, 3]
    assert summary.loc[summary["integrator"] == "rosenbrock[scheme=ros3p]", "integrator.scheme"].eq("ros3p").all()
    assert summary["integrator.scheme"].isna().sum() == 16


def test_the_csv_and_the_report_carry_the_parameter_columns(work_precision):
    with work_precision.opened():
        rows = summary_rows(figure_data(work_precision))
    stream = io.StringIO()
    write_csv(rows, stream)
    table = list(csv.DictReader(io.StringIO(stream.getvalue())))
    header = next(csv.reader(io.StringIO(stream.getvalue())))
    assert header.index("step_control.tolerance") == header.index("solver") + 1
    assert {"system.label", "integrator.order", "integrator.method"} <= set(header)
    assert [row["system.label"] for row in table[:6]] == ["spring"] * 5 + ["kepler"]
    assert {row["integrator.order"] for row in table} == {"", "2", "3"}
    assert float(table[0]["step_control.tolerance"]) == 1e-3
    html = summary_section(rows)
    # the swept keys that vary are columns of the runs table; the integrators' own are in their labels
    assert '<th class="text">system.label</th>' in html and "<th>step_control.tolerance</th>" in html
    assert "integrator.order" not in html


@pytest.mark.parametrize("config", config_params(CONFIGS))
def test_every_swept_key_of_a_shipped_config_is_a_typed_column(config):
    experiment, text = load_experiment(config)
    raw = yaml.safe_load(text)
    runs = expand_runs(experiment)
    columns = parameter_columns([run.params for run in runs], raw)
    mappings = mapping_keys(raw)
    for key, values in (raw.get("sweep") or {}).items():
        if key == "dt":
            continue  # the summary's own column
        name = f"{key}.label" if key in mappings else key
        assert name in columns, f"{config.name}: no column for sweep.{key}"
        present = [value for value in columns[name] if value is not None]
        assert present, f"{config.name}: sweep.{key} is read by no run"
        numeric = all(isinstance(value, (int, float)) and not isinstance(value, bool) for value in values)
        if numeric:
            assert column_kind(columns[name]) in ("int", "float"), f"{config.name}: {name} is not numeric"
    for run in runs:
        for key in run.params:
            if key.startswith("integrator."):
                assert key in columns


def test_a_swept_list_groups_as_a_tuple_and_a_missing_key_is_missing():
    params = [{"dt": 0.1, "system.resolution": [4, 4], "solver.linear_solver": "cg"},
              {"dt": 0.1, "system.resolution": [8, 8]}]
    columns = parameter_columns(params, {"sweep": {"system.resolution": [[4, 4], [8, 8]]}})
    assert columns == {"system.resolution": [(4, 4), (8, 8)], "solver.linear_solver": ["cg", None]}
    frame = pandas.DataFrame({"error": [1.0, 2.0], **columns})
    assert frame.groupby("system.resolution")["error"].sum().to_dict() == {(4, 4): 1.0, (8, 8): 2.0}
