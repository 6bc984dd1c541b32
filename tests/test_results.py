"""The results reader (simrun.results) on format-1 files written before the redesign and on format-2 files written now.

Format-1 files (tests/data): format1_mixed.h5 (spring k = 100 N/m, m = 1 kg, three Euler methods,
dt = 0.01 and 0.05 s), format1_circ.h5 (linear circular motion, w = 1 rad/s), format1_cloth.h5 (a 4 x 3
cloth above a sphere, two runs). The format-2 files are written by the real pipeline into tmp_path.

On the spring with k = 100 N/m, m = 1 kg (w = 10 rad/s), forward Euler multiplies the energy by
1 + (h w)^2 per step: 7.25 at dt = 0.25 s, past the divergence bound (1e6 |E0|) within 2 s.
"""

from __future__ import annotations

import datetime
import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pandas
import pytest
import yaml

import simrun
from simrun.cli import main
from simrun.errors import ConfigError, ResultsFileError
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import config_hash
from simrun.format.layout import FORMAT_VERSION, READABLE_VERSIONS
from simrun.format.summary import SUMMARY_COLUMNS, Status, drift_scale, energy_drift
from simrun.results import Results, StoredRun, load
from simrun.systems import SYSTEMS

DATA = Path(__file__).parent / "data"
FORMAT1_FILES = sorted(DATA.glob("format1_*.h5"))
# what a system declares about itself, as format 2 stores it (run attributes) and StoredRun returns it
CAPABILITY_KEYS = ("test_frequency", "length_scale", "energy_scale", "frame_shape", "planar", "dof_count")
# the ones format 1 did not store and the reader restates (energy_scale: see test_format1_energy_scale_is_a_fallback)
FORMAT1_RESTATED = ("test_frequency", "frame_shape", "planar", "dof_count", "length_scale")
EULERS = ["forward_euler", "symplectic_euler", "backward_euler"]
# forward Euler at h w = 2.5 gains a factor 7.25 per step and symplectic Euler is past h w < 2: both diverge
DIVERGING = {"name": "diverging", "system": {"type": "spring_mass", "stiffness": 100.0}, "integrators": EULERS,
             "duration": 2.0, "sweep": {"dt": [0.01, 0.05, 0.25]}}


def write_results(folder: Path, config: dict) -> Path:
    """Run config through the real pipeline (serial, no figures) into folder; return the results file."""
    results = simrun.run(config, output=folder, jobs=1, progress=False, figures=False)
    return results.path


def decoded(value):
    """An h5py value as Python: bytes as str, numpy scalars as int/float/bool."""
    if isinstance(value, bytes):
        return value.decode()
    return value.item() if isinstance(value, np.generic) else value


def same_value(a, b) -> bool:
    """Equal, with NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def run_groups_in_sweep_order(path: Path) -> list[str]:
    with h5py.File(path, "r") as file:
        return sorted(file["runs"], key=lambda run_id: int(file["runs"][run_id].attrs["index"]))


def rebuilt_system(run: StoredRun):
    """The run's system rebuilt from its stored name and parameters, through the systems' registry."""
    name = run.system
    return SYSTEMS[name].model_validate({**run.system_params, "type": name}).build()


@pytest.fixture(scope="module")
def diverging(tmp_path_factory) -> Path:
    return write_results(tmp_path_factory.mktemp("diverging"), DIVERGING)


@pytest.fixture(scope="module", params=sorted(SYSTEMS))
def format2_system(request, tmp_path_factory) -> Path:
    """A two-step format-2 file of each registered system with its default parameters."""
    name = request.param
    config = {"name": f"tiny-{name}", "system": {"type": name}, "integrators": ["backward_euler"],
              "duration": 0.02, "sweep": {"dt": [0.01]}}
    return write_results(tmp_path_factory.mktemp(f"format2-{name}"), config)


# -- format 1 ------------------------------------------------------------------------------------------
def test_the_format1_files_are_there():
    assert [path.name for path in FORMAT1_FILES] == ["format1_circ.h5", "format1_cloth.h5", "format1_mixed.h5"]


@pytest.mark.parametrize("path", FORMAT1_FILES, ids=lambda path: path.stem)
def test_format1_summary_is_the_stored_table_in_sweep_order(path):
    results = load(path)
    summary = results.summary
    assert isinstance(summary, pandas.DataFrame)
    assert list(summary.columns) == list(SUMMARY_COLUMNS)
    order = run_groups_in_sweep_order(path)
    assert list(summary["run_id"]) == order
    with h5py.File(path, "r") as file:
        stored = file["summary"][()]
        assert file.attrs["format_version"] == 1
    assert len(stored) == len(summary) == len(order)
    rows = {row["run_id"]: row for row in summary.to_dict("records")}
    for record in stored:
        row = rows[decoded(record["run_id"])]
        for column in stored.dtype.names:
            assert same_value(row[column], decoded(record[column])), (row["run_id"], column)
        # format 1 measured the error at the end: the columns format 2 added say so
        assert row["error"] == row["final_error"] or math.isnan(row["final_error"])
        assert row["error_time"] == results.runs[row["run_id"]]["t"][-1]
    # (and the error norms over the run, added later: NaN, since format 1 stored none)
    norms = {"final_velocity_error", "max_error", "max_velocity_error"}
    split = {"max_rel_energy_remainder", "final_rel_dissipated_energy"}
    assert set(SUMMARY_COLUMNS) - set(stored.dtype.names) == {"error_time", "error", "real_time_factor",
                                                              "wall_time_per_frame"} | norms | split
    assert summary[sorted(norms)].isna().all().all()
    # the energy budget's split, added later, is computed from the stored series: nothing dissipates in these files
    assert (summary["final_rel_dissipated_energy"] == 0).all()
    assert np.allclose(summary["max_rel_energy_remainder"], summary["max_rel_energy_drift"], rtol=1e-12, equal_nan=True)


def test_summary_follows_the_sweep_order_not_the_stored_order(tmp_path):
    """/summary is in the order runs finished (parallel sweeps); the DataFrame is in sweep order."""
    path = tmp_path / "reversed.h5"
    shutil.copy(DATA / "format1_mixed.h5", path)
    with h5py.File(path, "a") as file:
        stored = file["summary"][()]
        file["summary"][...] = stored[::-1]
        stored_ids = [decoded(item) for item in file["summary"]["run_id"]]
    order = run_groups_in_sweep_order(path)
    assert stored_ids == order[::-1] != order
    summary = load(path).summary
    assert list(summary["run_id"]) == order
    assert list(summary["dt"]) == [0.01, 0.05] * 3  # the rows moved with their run ids


@pytest.mark.parametrize("path", FORMAT1_FILES, ids=lambda path: path.stem)
def test_format1_runs_and_datasets_equal_the_file(path):
    results = load(path)
    assert list(results.runs) == run_groups_in_sweep_order(path)
    with h5py.File(path, "r") as file:
        for run_id, run in results.runs.items():
            group = file["runs"][run_id]
            assert set(run.datasets) == set(group)
            for key in group:
                np.testing.assert_array_equal(run[key], group[key][()], err_msg=f"{run_id}/{key}")
            assert run.status == group.attrs["status"]
            assert run.dt == group.attrs["dt"]


@pytest.mark.parametrize("path", FORMAT1_FILES, ids=lambda path: path.stem)
def test_format1_capabilities_equal_what_the_systems_declare_today(path):
    """The format-1 table in simrun.results restates each system's declarations; they must agree with the systems."""
    for run in load(path).runs.values():
        for key in CAPABILITY_KEYS:
            assert key not in run.attrs  # the restated values are what is under test, not stored ones
        declared = rebuilt_system(run).capabilities
        assert run.test_frequency == declared.test_frequency, run.run_id
        assert run.frame_shape == declared.frame_shape, run.run_id
        assert run.planar is declared.planar, run.run_id
        assert run.dof_count == declared.dof_count, run.run_id
        assert run.length_scale == pytest.approx(declared.length_scale, rel=1e-12), run.run_id


def test_format1_capabilities_tell_the_systems_apart():
    """Known values: spring w = sqrt(k/m) = 10 rad/s; linear circular motion w = 1 rad/s, planar; the
    4 x 3 cloth (resolution [nx, ny] = [4, 3]) has frames of 3 rows of 4 vertices, 36 dofs."""
    spring = next(iter(load(DATA / "format1_mixed.h5").runs.values()))
    circle = next(iter(load(DATA / "format1_circ.h5").runs.values()))
    cloth = next(iter(load(DATA / "format1_cloth.h5").runs.values()))
    assert (spring.test_frequency, spring.planar, spring.frame_shape, spring.dof_count) == (10.0, False, None, 1)
    assert (circle.test_frequency, circle.planar, circle.frame_shape, circle.dof_count) == (1.0, True, None, 2)
    assert (cloth.test_frequency, cloth.planar, cloth.frame_shape, cloth.dof_count) == (None, False, (3, 4), 36)


# system parameters the three files do not cover, each in the format-1 file of its system
FORMAT1_VARIANTS = [
    ("format1_mixed.h5", "spring_mass", {"damping": 0.5}),  # damped: not the test equation
    ("format1_mixed.h5", "spring_mass", {"stiffness": 4.0, "mass": 2.0}),  # w = sqrt(2) rad/s
    ("format1_circ.h5", "circular_motion", {"force": "gravity"}),  # Kepler: no test frequency
    ("format1_circ.h5", "circular_motion", {"dimension": 3, "angular_velocity": 2.5}),
    ("format1_cloth.h5", "cloth", {"resolution": [5, 2]}),  # 2 rows of 5 vertices
]


@pytest.mark.parametrize("file_name, system, change", FORMAT1_VARIANTS,
                         ids=lambda item: item.removesuffix(".h5") if isinstance(item, str) else None)
def test_format1_restatement_follows_the_stored_parameters(tmp_path, file_name, system, change):
    """The restated test_frequency, planar and frame_shape come from system_params alone: store other
    parameters in a copy of a format-1 file and they must still equal what that system declares."""
    params = SYSTEMS[system].model_validate({"type": system, **change})
    path = tmp_path / file_name
    shutil.copy(DATA / file_name, path)
    with h5py.File(path, "a") as file:
        for group in file["runs"].values():
            group.attrs["system_params"] = json.dumps(params.model_dump(mode="json"))
    declared = params.build().capabilities
    for run in load(path).runs.values():
        assert (run.test_frequency, run.planar, run.frame_shape) == (
            declared.test_frequency, declared.planar, declared.frame_shape)


def test_a_format1_run_of_an_unknown_system_is_refused_in_one_line(tmp_path):
    path = tmp_path / "renamed.h5"
    shutil.copy(DATA / "format1_mixed.h5", path)
    with h5py.File(path, "a") as file:
        file["runs/0000-forward_euler-dt=0.01"].attrs["system"] = "pendulum"
    run = load(path).runs["0000-forward_euler-dt=0.01"]
    with pytest.raises(ResultsFileError) as error:
        run.test_frequency
    assert "\n" not in str(error.value) and "pendulum" in str(error.value)


@pytest.mark.parametrize("path", FORMAT1_FILES, ids=lambda path: path.stem)
def test_format1_energy_scale_is_a_fallback(path):
    """Format 1 did not store an energy reference; its drifts were relative to |E0| (|KE0| + |PE0| when
    E0 = 0, 1 J when that is 0 too), which stays its reference, so that a resumed format-1 summary keeps its
    numbers. That need not equal what a system declares today (format 2 stores what it declares), so it is
    not compared with the system: it must be positive, be that fallback, and say that it is."""
    for run in load(path).runs.values():
        scale = run.energy_reference
        assert math.isfinite(scale) and scale > 0 and run.energy_scale == scale
        energy0 = abs(run["energy"][0])
        fallback = abs(run["kinetic_energy"][0]) + abs(run["potential_energy"][0])
        assert scale == (energy0 if energy0 > 0 else fallback if fallback > 0 else 1.0)
        assert "format 1" in run.energy_reference_name


# -- format 2 ------------------------------------------------------------------------------------------
def test_format2_stores_the_capabilities_the_system_declares(format2_system):
    with h5py.File(format2_system, "r") as file:
        assert file.attrs["format_version"] == FORMAT_VERSION  # 3 keeps what 2 stored
        stored = {run_id: dict(group.attrs) for run_id, group in file["runs"].items()}
    results = load(format2_system)
    assert results.format_version == FORMAT_VERSION
    assert list(results.runs) == list(stored)
    for run_id, run in results.runs.items():
        assert set(CAPABILITY_KEYS) <= set(stored[run_id])
        declared = rebuilt_system(run).capabilities
        assert run.test_frequency == declared.test_frequency
        assert run.length_scale == declared.length_scale
        assert run.energy_scale == declared.energy_scale
        assert run.frame_shape == declared.frame_shape
        assert run.planar is declared.planar
        assert run.dof_count == declared.dof_count
        # and the attributes themselves are the system's (as_attrs spells None as NaN and an empty array)
        for key, value in declared.as_attrs().items():
            np.testing.assert_array_equal(stored[run_id][key], value, err_msg=f"{run_id} {key}")


# -- refusals ------------------------------------------------------------------------------------------
def _missing(tmp_path: Path) -> Path:
    return tmp_path / "missing.h5"


def _text(tmp_path: Path) -> Path:
    path = tmp_path / "notes.h5"
    path.write_text("name: not a results file\n")
    return path


def _without_runs(tmp_path: Path) -> Path:
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as file:
        file.attrs["format_version"] = 1
        file.create_dataset("data", data=np.arange(3))
    return path


def _future_version(tmp_path: Path) -> Path:
    path = tmp_path / "future.h5"
    shutil.copy(DATA / "format1_mixed.h5", path)
    with h5py.File(path, "a") as file:
        file.attrs["format_version"] = 99
    return path


BAD_FILES = {"missing": _missing, "text": _text, "without_runs": _without_runs, "future_version": _future_version}


@pytest.mark.parametrize("kind", BAD_FILES)
def test_load_refuses_what_it_cannot_read_in_one_line(tmp_path, kind):
    path = BAD_FILES[kind](tmp_path)
    with pytest.raises(ResultsFileError) as error:
        load(path)
    assert isinstance(error.value, ConfigError)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith("results: ") and str(path) in message


def test_an_unknown_format_version_names_the_readable_ones(tmp_path):
    with pytest.raises(ResultsFileError) as error:
        load(_future_version(tmp_path))
    message = str(error.value)
    assert "99" in message
    assert {1, FORMAT_VERSION} <= set(READABLE_VERSIONS)  # the files of before the redesign, and of now
    assert "reads versions " + ", ".join(map(str, READABLE_VERSIONS)) in message


@pytest.mark.parametrize("command", ["show", "plot", "report", "animate"])
@pytest.mark.parametrize("kind", BAD_FILES)
def test_the_commands_refuse_a_bad_results_file_in_one_line(tmp_path, capsys, command, kind):
    path = BAD_FILES[kind](tmp_path)
    assert main([command, str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("simrun: error: results: ") and str(path) in lines[0]
    assert "Traceback" not in captured.err and captured.out == ""


# -- status --------------------------------------------------------------------------------------------
def test_status_values_and_which_ones_stopped():
    assert {status.value for status in Status} == {"ok", "diverged", "not_converged", "failed"}
    assert Status("ok") == "ok" and Status("ok") is Status.OK
    assert str(Status.NOT_CONVERGED) == "not_converged"
    assert {status for status in Status if status.stopped} == {Status.DIVERGED, Status.FAILED}
    with pytest.raises(ValueError):
        Status("crashed")


def test_every_status_in_a_diverging_sweep_is_a_status(diverging):
    with h5py.File(diverging, "r") as file:
        stored = {run_id: decoded(group.attrs["status"]) for run_id, group in file["runs"].items()}
        summary_statuses = {decoded(item) for item in file["summary"]["status"]}
    assert set(stored.values()) <= {status.value for status in Status}
    assert summary_statuses <= {status.value for status in Status}
    results = load(diverging)
    for run_id, run in results.runs.items():
        assert isinstance(run.status, Status) and run.status == stored[run_id]
    assert results.runs["0002-forward_euler-dt=0.25"].status is Status.DIVERGED
    assert results.runs["0008-backward_euler-dt=0.25"].status is Status.OK
    assert list(results.summary["status"]) == [stored[run_id] for run_id in results.runs]


# -- energy drift --------------------------------------------------------------------------------------
@pytest.mark.parametrize("energy, scale, expected", [
    ([2.0, 3.0, 1.0], 2.0, (0.5, -0.5)),  # |3 - 2| / 2 and (1 - 2) / 2
    ([2.0, 3.0, 1.0], 1.0, (1.0, -1.0)),
    ([-4.0, -2.0, -5.0], 4.0, (0.5, -0.25)),  # |-2 + 4| / 4, (-5 + 4) / 4
    ([1.0], 1.0, (0.0, 0.0)),
    ([2.0, np.nan, 3.0, np.inf, 1.0], 2.0, (0.5, -0.5)),  # non-finite samples are skipped
    ([2.0, 3.0, -np.inf], 2.0, (0.5, 0.5)),  # a run that diverged: the drift up to its last finite sample
])
def test_energy_drift_by_hand(energy, scale, expected):
    assert energy_drift(np.array(energy), scale) == pytest.approx(expected, rel=1e-15)


@pytest.mark.parametrize("energy", [[], [np.nan, np.inf]])
def test_energy_drift_without_finite_samples_is_nan(energy):
    max_drift, final_drift = energy_drift(np.array(energy, dtype=float), 1.0)
    assert math.isnan(max_drift) and math.isnan(final_drift)


@pytest.mark.parametrize("energy, kinetic, potential, expected", [
    ([-3.0, 1.0], [1.0, 2.0], [-4.0, -1.0], 3.0),  # |E0|
    ([0.0, 1.0], [2.0, 3.0], [-2.0, -2.0], 4.0),  # E0 = 0: |KE0| + |PE0| = 2 + 2
    ([0.0, 1.0], [0.0, 1.0], [0.0, 0.0], 1.0),  # E0 = KE0 = PE0 = 0: 1 J
])
def test_drift_scale_three_cases(energy, kinetic, potential, expected):
    assert drift_scale(np.array(energy), np.array(kinetic), np.array(potential)) == expected


@pytest.mark.parametrize("source", [*FORMAT1_FILES, "diverging"], ids=lambda source: getattr(source, "stem", source))
def test_summary_drift_is_energy_drift_of_the_stored_energy(source, request):
    path = request.getfixturevalue("diverging") if source == "diverging" else source
    results = load(path)
    summary = results.summary.set_index("run_id")
    for run_id, run in results.runs.items():
        scale = drift_scale(run["energy"], run["kinetic_energy"], run["potential_energy"])
        max_drift, final_drift = energy_drift(run["energy"], scale)
        assert summary.loc[run_id, "max_rel_energy_drift"] == pytest.approx(max_drift, rel=1e-12), run_id
        assert summary.loc[run_id, "final_rel_energy_drift"] == pytest.approx(final_drift, rel=1e-12), run_id


def test_summary_drift_matches_the_exact_energy_factor():
    """Forward Euler on the spring multiplies E by 1 + (h w)^2 per step (w = 10 rad/s): at dt = 0.05 s by
    1.25, so the largest drift over 1 s (20 steps) is 1.25**20 - 1; backward Euler divides by the same."""
    summary = load(DATA / "format1_mixed.h5").summary.set_index("run_id")
    assert summary.loc["0001-forward_euler-dt=0.05", "max_rel_energy_drift"] == pytest.approx(1.25**20 - 1, rel=1e-9)
    assert summary.loc["0005-backward_euler-dt=0.05", "final_rel_energy_drift"] == pytest.approx(1.25**-20 - 1, rel=1e-9)


# -- config and provenance -----------------------------------------------------------------------------
@pytest.mark.parametrize("source", [*FORMAT1_FILES, "diverging"], ids=lambda source: getattr(source, "stem", source))
def test_config_is_the_stored_yaml(source, request):
    path = request.getfixturevalue("diverging") if source == "diverging" else source
    with h5py.File(path, "r") as file:
        text, name = decoded(file.attrs["config"]), decoded(file.attrs["name"])
    results = load(path)
    assert isinstance(results.config, dict)
    assert results.config == yaml.safe_load(text)
    assert results.config["name"] == name == results.name


def test_provenance_of_a_file_written_now(diverging):
    provenance = load(diverging).provenance
    assert "config" not in provenance
    assert provenance["format_version"] == FORMAT_VERSION
    assert provenance["simrun_version"] == simrun.__version__
    experiment, _ = load_experiment(DIVERGING)
    assert provenance["config_hash"] == config_hash(experiment)
    created = datetime.datetime.fromisoformat(provenance["created"])
    assert abs(datetime.datetime.now(datetime.timezone.utc) - created) < datetime.timedelta(hours=1)
    versions = provenance["package_versions"]
    assert isinstance(versions, dict)
    assert versions["numpy"] == np.__version__
    assert versions["h5py"] == h5py.__version__
    assert versions["pandas"] == pandas.__version__


def test_provenance_of_a_format1_file_decodes_its_package_versions():
    with h5py.File(DATA / "format1_mixed.h5", "r") as file:
        stored = json.loads(decoded(file.attrs["package_versions"]))
        created = decoded(file.attrs["created"])
    provenance = load(DATA / "format1_mixed.h5").provenance
    assert "config" not in provenance
    assert provenance["format_version"] == 1 and provenance["created"] == created
    assert provenance["package_versions"] == stored and "numpy" in stored


# -- the deprecated table --------------------------------------------------------------------------------
def test_load_summary_still_returns_the_structured_array(diverging):
    from simrun.results import load_summary

    for path in (*FORMAT1_FILES, diverging):
        with pytest.warns(DeprecationWarning, match=r"simrun.load\(path\).summary"):
            table = load_summary(path)
        assert isinstance(table, np.ndarray) and table.dtype.names == SUMMARY_COLUMNS
        assert list(table["run_id"]) == list(load(path).summary["run_id"])
        assert all(isinstance(run_id, str) for run_id in table["run_id"])


# -- lazy reading --------------------------------------------------------------------------------------
def test_load_reads_no_run_dataset_until_one_is_asked_for(monkeypatch, diverging):
    """Count the reads of every h5py dataset: load() reads /summary at most, a run's dataset once, on first use."""
    reads: list[str] = []
    original = h5py.Dataset.__getitem__

    def counting(self, key):
        reads.append(self.name)
        return original(self, key)

    monkeypatch.setattr(h5py.Dataset, "__getitem__", counting)
    results = load(diverging)
    assert set(reads) <= {"/summary"}
    assert all(run._cache == {} for run in results.runs.values())
    run_id = "0004-symplectic_euler-dt=0.05"
    energy = results.runs[run_id]["energy"]
    assert reads.count(f"/runs/{run_id}/energy") == 1  # the counter sees the reads it must see
    results.runs[run_id]["energy"]
    assert reads.count(f"/runs/{run_id}/energy") == 1  # cached
    assert set(results.runs[run_id]._cache) == {"energy"} and energy.shape[0] > 1
    assert all(other._cache == {} for other_id, other in results.runs.items() if other_id != run_id)
    assert isinstance(results, Results)
