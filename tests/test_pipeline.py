"""The Python API (simrun.run): the same results as the command line, configs as a path, YAML text or a dict,
resume and its refusals, errors before anything is written, executors, and the figure registry as the one
place a new figure is added.

Every run is the mass on a spring (k = 100 N/m, m = 1 kg, w = 10 rad/s): configs/quickstart.yaml shortened
to 1 s, or TINY_YAML (two runs of 10 steps). A run is deterministic, so two ways of running the same
config must write the same numbers, bit for bit; only the timing differs.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import matplotlib.pyplot as plt
import numpy as np
import pandas
import pytest
import yaml

import simrun
import simrun.figures
from simrun.cli import main
from simrun.errors import ConfigError
from simrun.figures import Figure, FigureData
from simrun.results import Results, load

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "configs" / "quickstart.yaml"
SHORT = "duration=1.0"  # the quickstart's 10 s of simulated time take ~10 s per call; 1 s keeps its 18 runs and figures
EULERS = ["forward_euler", "symplectic_euler", "backward_euler"]
# what differs between two writes of the same config: when (root) and how long (each run, its summary row)
TIMING_ROOT_ATTRIBUTES = {"created", "command_line"}  # when, and how it was asked for (argv or simrun.run)
TIMING_RUN_ATTRIBUTES = {"wall_time"}
TIMING_SUMMARY_COLUMNS = {"wall_time", "real_time_factor", "wall_time_per_frame"}  # the last two: wall time per simulated time
TINY_YAML = """\
# two runs of the spring: 10 steps each
name: tiny
system:
  type: spring_mass
  stiffness: 100.0   # w = 10 rad/s
integrators: [symplectic_euler, backward_euler]
duration: 0.1
sweep:
  dt: [0.01]
"""


# -- comparing two results files ---------------------------------------------------------------------------
def same_array(a, b) -> bool:
    """Equal shape, dtype kind and entries; NaN equal to NaN where the values are floats."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype.kind != b.dtype.kind:
        return False
    if a.dtype.names:  # a compound row or table: field by field
        return a.dtype.names == b.dtype.names and all(same_array(a[name], b[name]) for name in a.dtype.names)
    if a.dtype.kind in "fc":
        return bool(np.array_equal(a, b, equal_nan=True))
    return bool(np.array_equal(a, b))


def assert_same_attributes(a: h5py.AttributeManager, b: h5py.AttributeManager, where: str, ignore=frozenset()) -> None:
    assert set(a) == set(b), where
    for key in set(a) - set(ignore):
        assert same_array(a[key], b[key]), f"{where} attribute {key}: {a[key]!r} != {b[key]!r}"


def assert_same_results_file(first: Path, second: Path, ignore_runs: bool = False) -> None:
    """Every group, dataset and attribute equal, but the timing ones; /summary row by row without wall_time."""
    with h5py.File(first, "r") as a, h5py.File(second, "r") as b:
        names_a, names_b = [], []
        a.visit(names_a.append)
        b.visit(names_b.append)
        assert sorted(names_a) == sorted(names_b)
        assert_same_attributes(a.attrs, b.attrs, "/", TIMING_ROOT_ATTRIBUTES)
        for name in names_a:
            item_a, item_b = a[name], b[name]
            assert type(item_a) is type(item_b), name
            ignore = TIMING_RUN_ATTRIBUTES if name.startswith("runs/") and name.count("/") == 1 else frozenset()
            assert_same_attributes(item_a.attrs, item_b.attrs, name, ignore)
            if not isinstance(item_a, h5py.Dataset):
                continue
            if name == "summary":
                rows_a, rows_b = item_a[()], item_b[()]
                assert len(rows_a) == len(rows_b)
                kept = [column for column in rows_a.dtype.names if column not in TIMING_SUMMARY_COLUMNS]
                for row_a, row_b in zip(rows_a, rows_b):
                    for column in kept:
                        assert same_array(row_a[column], row_b[column]), f"summary {row_a['run_id']} {column}"
            else:
                assert same_array(item_a[()], item_b[()]), name


def assert_same_runs(first: Results, second: Results) -> None:
    """The same run ids, in order, with the same datasets (every entry equal)."""
    assert list(first.runs) == list(second.runs)
    for run_id, run in first.runs.items():
        other = second.runs[run_id]
        assert run.datasets == other.datasets, run_id
        for key in run.datasets:
            assert same_array(run[key], other[key]), f"{run_id}/{key}"


@pytest.fixture
def tiny_config(tmp_path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY_YAML)
    return path


# -- the API and the command line agree --------------------------------------------------------------------------
def test_run_and_the_command_line_write_the_same_file(tmp_path):
    """simrun.run(quickstart) and `simrun quickstart.yaml` give the same results file (timing aside).

    Both shorten the quickstart to 1 s (overrides=["duration=1.0"], on the command line --set duration=1.0):
    the same 18 runs, each a tenth as long, so the test stays fast."""
    results = simrun.run(str(QUICKSTART), output=tmp_path / "a", jobs=1, progress=False, overrides=[SHORT])
    assert main([str(QUICKSTART), "--output", str(tmp_path / "b"), "-q", "-j", "1", "--set", SHORT]) == 0
    assert_same_results_file(tmp_path / "a" / "results.h5", tmp_path / "b" / "results.h5")

    assert isinstance(results, Results) and results.path == tmp_path / "a" / "results.h5"
    assert isinstance(results.summary, pandas.DataFrame) and len(results.summary) == 18
    assert sum(results.ran.values()) == 18
    assert results.figure_files and all(path.is_file() for path in results.figure_files)
    assert {path.parent for path in results.figure_files} == {tmp_path / "a" / "figures"}
    assert sorted(path.name for path in (tmp_path / "b" / "figures").iterdir()) == sorted(
        path.name for path in results.figure_files)  # the command line drew the same figures
    groups = results.summary.groupby("integrator")
    assert sorted(groups.groups) == sorted(EULERS)
    assert all(len(rows) == 6 for _, rows in groups)  # one per dt of the sweep
    assert results.config["duration"] == 1.0


def _set_summary(file: h5py.File, column: str, value) -> None:
    table = file["summary"][()]
    table[column] = value
    file["summary"][...] = table


def _set_dataset_entry(file: h5py.File) -> None:
    file["runs/0001-backward_euler-dt=0.01/energy"][3] += 1e-12


# edits of a results file: the ones assert_same_results_file must ignore, and the ones it must see
TIMING_EDITS = {
    "created": lambda file: file.attrs.__setitem__("created", "2000-01-01T00:00:00+00:00"),
    "run wall_time": lambda file: file["runs/0000-symplectic_euler-dt=0.01"].attrs.__setitem__("wall_time", 99.0),
    "summary wall_time": lambda file: _set_summary(file, "wall_time", 99.0),
}
EDITS = {
    "dataset entry": _set_dataset_entry,
    "run attribute": lambda file: file["runs/0000-symplectic_euler-dt=0.01"].attrs.__setitem__("steps", 11),
    "root attribute": lambda file: file.attrs.__setitem__("simrun_version", "0.0.0"),
    "summary drift": lambda file: _set_summary(file, "max_rel_energy_drift", 0.5),
    "extra dataset": lambda file: file.create_dataset("runs/0000-symplectic_euler-dt=0.01/extra", data=[1.0]),
}


@pytest.fixture(scope="module")
def tiny_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("tiny")
    (folder / "tiny.yaml").write_text(TINY_YAML)
    return simrun.run(folder / "tiny.yaml", output=folder / "out", jobs=1, progress=False, figures=False).path


def edited_copy(path: Path, folder: Path, *edits) -> Path:
    copy = folder / "edited.h5"
    shutil.copy(path, copy)
    with h5py.File(copy, "a") as file:
        for edit in edits:
            edit(file)
    return copy


def test_the_file_comparison_ignores_timing_only(tmp_path, tiny_file):
    """The control of the acceptance check: the comparison is blind to timing and to nothing else."""
    assert_same_results_file(tiny_file, edited_copy(tiny_file, tmp_path, *TIMING_EDITS.values()))


@pytest.mark.parametrize("edit", EDITS)
def test_the_file_comparison_sees_every_other_difference(tmp_path, tiny_file, edit):
    with pytest.raises(AssertionError):
        assert_same_results_file(tiny_file, edited_copy(tiny_file, tmp_path, EDITS[edit]))


# -- what a config may be --------------------------------------------------------------------------------
def test_a_dict_and_yaml_text_give_the_runs_of_the_file(tmp_path, tiny_config):
    text = tiny_config.read_text()
    from_file = simrun.run(str(tiny_config), output=tmp_path / "file", jobs=1, progress=False, figures=False)
    from_text = simrun.run(text, output=tmp_path / "text", jobs=1, progress=False, figures=False)
    from_dict = simrun.run(yaml.safe_load(text), output=tmp_path / "dict", jobs=1, progress=False, figures=False)
    assert list(from_file.runs) == ["0000-symplectic_euler-dt=0.01", "0001-backward_euler-dt=0.01"]
    for other in (from_text, from_dict):
        assert_same_runs(from_file, other)
        assert other.provenance["config_hash"] == from_file.provenance["config_hash"]
        assert other.config == from_file.config
    assert from_file.runs["0000-symplectic_euler-dt=0.01"].steps == 10


# -- resume ------------------------------------------------------------------------------------------------
def test_a_second_call_resumes_and_a_changed_config_needs_force(tmp_path, tiny_config):
    output = tmp_path / "out"
    first = simrun.run(tiny_config, output=output, jobs=1, progress=False, figures=False)
    assert first.ran == {"ok": 2}
    again = simrun.run(tiny_config, output=output, jobs=1, progress=False, figures=False)
    assert again.ran == {}
    assert_same_runs(first, again)
    # the same experiment as a dict is the same config (same hash): nothing to run either
    assert simrun.run(yaml.safe_load(TINY_YAML), output=output, jobs=1, progress=False, figures=False).ran == {}

    # a run lost from the file (as after a kill) is the only one run again; the summary is in sweep order again
    with h5py.File(output / "results.h5", "a") as file:
        del file["runs/0000-symplectic_euler-dt=0.01"]
    repaired = simrun.run(tiny_config, output=output, jobs=1, progress=False, figures=False)
    assert repaired.ran == {"ok": 1}
    assert list(repaired.summary["run_id"]) == list(first.runs)
    assert_same_runs(first, repaired)

    with pytest.raises(ConfigError) as error:
        simrun.run(tiny_config, output=output, jobs=1, progress=False, figures=False, overrides=["duration=0.2"])
    assert "--force" in str(error.value) and "\n" not in str(error.value)
    assert load(output / "results.h5").config["duration"] == 0.1  # the refusal left the file alone

    forced = simrun.run(tiny_config, output=output, jobs=1, progress=False, figures=False, overrides=["duration=0.2"],
                        force=True)
    assert forced.ran == {"ok": 2}
    assert forced.config["duration"] == 0.2
    assert [run.steps for run in forced.runs.values()] == [20, 20]


# -- errors before anything is written ------------------------------------------------------------------------
@pytest.mark.parametrize("change, field", [
    ({"integrators": ["no_such_method"]}, "no_such_method"),
    ({"system": {"type": "no_such_system"}}, "no_such_system"),
    ({"sweep": {"dt": [0.5]}}, "sweep.dt"),  # longer than the duration of 0.1 s
    ({"duration": -1.0}, "duration"),
])
def test_a_bad_config_is_refused_before_anything_is_written(tmp_path, change, field):
    config = {**yaml.safe_load(TINY_YAML), **change}
    output = tmp_path / "out" / "nested"
    with pytest.raises(ConfigError) as error:
        simrun.run(config, output=output, jobs=1, progress=False)
    assert field in str(error.value) and "\n" not in str(error.value)
    assert not (tmp_path / "out").exists()


def test_jobs_must_be_positive(tmp_path, tiny_config):
    with pytest.raises(ConfigError, match="--jobs") as error:
        simrun.run(tiny_config, output=tmp_path / "out", jobs=0, progress=False)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "out").exists()


def test_the_command_line_offers_every_executor_and_only_those():
    """simrun.execution.workers.EXECUTORS (light, read by the parser) names exactly the executors' registry."""
    from simrun.execution.executors import EXECUTOR_FUNCTIONS
    from simrun.execution.workers import EXECUTORS, EXECUTOR_ALIASES

    assert set(EXECUTORS) == set(EXECUTOR_FUNCTIONS)
    assert set(EXECUTOR_ALIASES.values()) <= set(EXECUTOR_FUNCTIONS)


def test_the_command_line_default_size_limit_is_the_store_s():
    """commands/run.py states the --max-size default without importing the store (a light parser): the same number."""
    from simrun.commands.run import DEFAULT_MAX_SIZE_GB as command_line
    from simrun.results.writer import DEFAULT_MAX_SIZE_GB as store

    assert command_line == store


def test_an_unknown_executor_lists_the_valid_ones(tmp_path, tiny_config):
    with pytest.raises(ConfigError) as error:
        simrun.run(tiny_config, output=tmp_path / "out", jobs=1, executor="threads", progress=False)
    message = str(error.value)
    assert "threads" in message and "process" in message and "dask" in message and "\n" not in message
    assert not (tmp_path / "out").exists()


# -- a new figure is one registry entry ----------------------------------------------------------------------
def draw_throwaway(data: FigureData):
    """Steps against dt of every run: a small figure with labelled axes."""
    figure, axes = plt.subplots(figsize=(3, 2))
    axes.plot([run.dt for run in data.runs], [run.steps for run in data.runs], "o")
    axes.set_xlabel("dt (s)")
    axes.set_ylabel("steps")
    return figure


def test_a_registered_figure_is_plotted_listed_and_reported(tmp_path, tiny_config, monkeypatch, capsys):
    results = simrun.run(tiny_config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    figures = tmp_path / "out" / "figures"
    assert not figures.exists()
    monkeypatch.setitem(simrun.figures.FIGURES, "throwaway",
                        Figure("throwaway", draw_throwaway, "A throwaway caption.", "anything"))

    assert main(["plot", "--list"]) == 0
    assert "throwaway: needs anything" in capsys.readouterr().out.splitlines()

    assert main(["plot", str(results.path), "--svg"]) == 0
    capsys.readouterr()
    for suffix in ("png", "svg"):
        path = figures / f"throwaway.{suffix}"
        assert path.is_file() and path.stat().st_size > 1000, path

    assert main(["report", str(results.path), "--reference", "none"]) == 0
    page = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    assert '<figure id="figure-throwaway">' in page
    assert "A throwaway caption." in page


# -- executors -----------------------------------------------------------------------------------------------
def test_dask_gives_the_datasets_of_the_process_pool(tmp_path, tiny_config):
    """Dask is in the test extras: a missing install fails here rather than skipping. jobs=2 on the process
    executor is its pool (jobs=1 would be serial)."""
    on_processes = simrun.run(tiny_config, output=tmp_path / "process", jobs=2, progress=False, figures=False)
    on_dask = simrun.run(tiny_config, output=tmp_path / "dask", executor="dask", jobs=1, progress=False, figures=False)
    assert on_dask.ran == on_processes.ran == {"ok": 2}
    assert_same_runs(on_processes, on_dask)


def test_a_run_over_its_wall_time_budget_stops_not_converged_with_that_reason(tmp_path):
    """record.max_wall_time: a run that would take far longer stops at its first step past the budget, not_converged,
    its message naming the budget; what it recorded up to there is kept, and it is stepped alone (not as a lane)."""
    import simrun

    config = {"name": "budget", "system": {"type": "cloth", "resolution": [16, 16]}, "integrators": ["backward_euler"],
              "duration": 100.0, "sweep": {"dt": [0.01]}, "record": {"max_wall_time": 0.5}}
    results = simrun.run(config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    (run,) = results.runs.values()
    assert run.status == "not_converged"
    assert "over record.max_wall_time 0.5 s" in run.message and run.message.startswith("stopped at t = ")
    assert 1 <= run.steps < 10_000 and run.wall_time < 5.0
    assert run["t"][-1] == pytest.approx(run.steps * 0.01)
