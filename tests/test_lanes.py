"""Lanes (runner/execution/lanes.py): many runs of the spring stepped together, one row of an array per run.

What is held here: every lane's data is its run's stepped alone by ``simulate``, bit for bit (status, steps,
message, samples, per-step arrays, attributes), for every lane integrator, with and without series, with strided
samples and divergence checks, with steps that do not converge, and in chunks that mix damped and undamped springs;
which runs share lanes (``lane_key``) and how a sweep is cut into chunks (``lane_chunks``); a chunk that fails as lanes
falls back to its runs alone; the results file (``simrun.run`` with lanes auto against lanes off, serial and on a
pool, resumed after a killed chunk write, without series) reads back the same; the decay per period against its
closed forms (backward Euler's energy factor 1/(1 + (h w)^2) a step, the trapezoidal methods' 1, the exact motion's
modal energy e^(-2 zeta w t)); the amplification matrices probed as lanes against those probed one at a time; the
config errors; and the damping map figure.

The spring: m q'' + d q' + k q = 0, x0 = 1 m, v0 = 0.5 m/s, dt = 0.01 s, a few stiffnesses (w = sqrt(k/m) from 1 to
100 rad/s) and damping ratios zeta = d / (2 sqrt(k m)): 0 (undamped), 0.3, 2 (overdamped) and -1 (energy pumped in:
every method's lane diverges within 0.5 s, so lanes that stop while their neighbours go on are always exercised).
"""

from __future__ import annotations

import math
import shutil
import warnings
from collections import Counter
from pathlib import Path

import h5py
import matplotlib.pyplot as plt
import numpy as np
import pytest

import simrun
import simrun.execution.lanes
from conftest import needs_linear_solver
from simrun.analysis import oscillator as analysis
from simrun.cli import main
from simrun.errors import ConfigError
from simrun.execution.executors import ExecutorOptions, execute
from simrun.execution.lanes import LANE_INTEGRATORS, MIN_LANES, lane_chunks, lane_key, simulate_lanes
from simrun.execution.measures import DECAY_FLOOR, decay_per_period
from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.figures import render_figures
from simrun.format.layout import LANES_GROUP, RESULTS_NAME
from simrun.format.summary import SERIES_SUMMARY_KEYS, Status
from simrun.integrators import INTEGRATORS
from simrun.results import load
from simrun.systems import SpringMassParams
from simrun.systems.lanes import SpringMassLanes

STIFFNESSES = (1.0, 100.0, 1e4)  # w = 1, 10, 100 rad/s at m = 1 kg: h w = 0.01, 0.1, 1
RATIOS = (0.0, 0.3, 2.0, -1.0)  # undamped, underdamped, overdamped, pumped (diverges)
MASSES = (1.0, 0.5)
# the methods that iterate Newton (semi-implicit backward Euler takes one Newton step, which always "converges")
ITERATIVE = ("backward_euler", "implicit_midpoint", "newmark", "bdf2", "generalized_alpha")
# one Newton iteration and an unreachable absolute tolerance: stiff lanes (s k >> m, so that one step's round-off
# exceeds the residual floor 64 eps |M y~|) end their steps unconverged
ONE_ITERATION = {"type": "newton", "max_iterations": 1, "tolerance": 1e-300, "tolerance_mode": "absolute"}
# (Newmark's single iteration lands within its floor almost always: k = 10^6.5 is where it does not, by round-off)
STIFF = (1.0, 1e6, 10 ** 6.5, 1e9)
# what differs between executions: the time, and the compiled kernels' threads (every core in the main process, a
# worker's share in a pool)
TIMING_ATTRIBUTES = {"wall_time", "threads"}
TIMING_SUMMARY_COLUMNS = ["wall_time", "real_time_factor", "wall_time_per_frame"]


# -- building and comparing ----------------------------------------------------------------------------------
def spring_config(integrators, stiffnesses=STIFFNESSES, ratios=RATIOS, masses=(1.0,), duration=0.5, name="lanes",
                  **extra) -> dict:
    sweep = {"dt": [0.01], "system.stiffness": list(stiffnesses), "system.damping_ratio": list(ratios)}
    if len(masses) > 1:
        sweep["system.mass"] = list(masses)
    return {"name": name, "system": {"type": "spring_mass", "x0": 1.0, "v0": 0.5}, "integrators": list(integrators),
            "duration": duration, "sweep": sweep, **extra}


def spring_runs(integrators, **keywords):
    return expand_runs(validate_experiment(spring_config(integrators, **keywords)))


def same_value(a, b) -> bool:
    """Equal shape, dtype kind and entries, NaN equal to NaN."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype.kind != b.dtype.kind:
        return False
    return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))


def assert_same_arrays(a: dict, b: dict, where: str) -> None:
    assert set(a) == set(b), f"{where}: {sorted(set(a) ^ set(b))}"
    for key in a:
        shapes = f"{a[key].dtype}{a[key].shape} != {b[key].dtype}{b[key].shape}"
        assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, f"{where} {key}: {shapes}"
        assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind in "fc"), f"{where} {key}"


def assert_same_result(lane, alone, where: str = "") -> None:
    """A lane's RunResult is its run's alone: everything but the wall time."""
    where = where or alone.run_id
    assert lane.run_id == alone.run_id
    assert (lane.status, lane.steps, lane.message) == (alone.status, alone.steps, alone.message), where
    assert same_value(math.nan if lane.t_diverged is None else lane.t_diverged,
                      math.nan if alone.t_diverged is None else alone.t_diverged), f"{where}: t_diverged"
    assert (lane.t_diverged is None) == (alone.t_diverged is None), where
    assert_same_arrays(lane.samples, alone.samples, f"{where} samples")
    assert_same_arrays(lane.per_step, alone.per_step, f"{where} per_step")
    assert_same_arrays(lane.model, alone.model, f"{where} model")
    assert set(lane.attrs) == set(alone.attrs), f"{where}: {sorted(set(lane.attrs) ^ set(alone.attrs))}"
    for key, value in alone.attrs.items():
        assert same_value(lane.attrs[key], value), f"{where} attribute {key}: {lane.attrs[key]!r} != {value!r}"


def lanes_by_key(runs) -> list:
    """(runs, LaneBatch) per lane_key, stepped with simulate_lanes; asserts every run takes lanes and none fell back."""
    groups: dict = {}
    for run in runs:
        key = lane_key(run)
        assert key is not None, run.run_id
        groups.setdefault(key, []).append(run)
    batches = []
    for members in groups.values():
        batch = simulate_lanes(members)
        assert batch.results_alone is None, f"the chunk of {members[0].run_id} fell back to runs alone"
        batches.append((members, batch))
    return batches


def assert_lanes_are_runs_alone(runs) -> Counter:
    """Every run's lane result equals simulate(run); returns the count of (status, stopped early), and of the runs that
    stopped off the sampling cadence."""
    outcomes: Counter = Counter()
    for members, batch in lanes_by_key(runs):
        results = batch.results()
        assert len(results) == len(members)
        for run, lane in zip(members, results):
            assert_same_result(lane, simulate(run))
            outcomes[(str(lane.status), lane.steps < run.step_count)] += 1
            stride = run.record.stride(run.step_count)
            outcomes["stopped off cadence"] += lane.steps < run.step_count and lane.steps % stride != 0
    return outcomes


def assert_same_results(a, b, ignore_attrs=TIMING_ATTRIBUTES) -> None:
    """Two results files read back alike: run ids in order, attributes but the timing, datasets (dtype and values),
    the summary but its timing columns."""
    assert list(a.runs) == list(b.runs)
    with a.opened(), b.opened():  # one handle per file for all the datasets
        for run_id, run_a in a.runs.items():
            run_b = b.runs[run_id]
            attrs_a = {key: value for key, value in run_a.attrs.items() if key not in ignore_attrs}
            attrs_b = {key: value for key, value in run_b.attrs.items() if key not in ignore_attrs}
            assert set(attrs_a) == set(attrs_b), f"{run_id}: {sorted(set(attrs_a) ^ set(attrs_b))}"
            for key, value in attrs_a.items():
                assert same_value(value, attrs_b[key]), f"{run_id} attribute {key}: {value!r} != {attrs_b[key]!r}"
            assert sorted(run_a.datasets) == sorted(run_b.datasets), run_id
            assert_same_arrays({key: run_a[key] for key in run_a.datasets}, {key: run_b[key] for key in run_b.datasets},
                               run_id)
    summary_a = a.summary.drop(columns=TIMING_SUMMARY_COLUMNS)
    summary_b = b.summary.drop(columns=TIMING_SUMMARY_COLUMNS)
    assert list(summary_a["run_id"]) == list(a.runs)
    assert list(summary_a.dtypes) == list(summary_b.dtypes)
    assert summary_a.equals(summary_b)


def run_quietly(config, output, **keywords):
    return simrun.run(config, output=output, progress=False, figures=False, **keywords)


def lane_chunk_names(path: Path) -> list[str]:
    with h5py.File(path, "r") as file:
        return list(file.get(LANES_GROUP, {}))


# -- 1. every lane is its run stepped alone -------------------------------------------------------------------
CASES = {
    "series": {},
    "no_series": {"record": {"series": False}},
    # samples every 3rd step and checks every 7th, an error time that damped lanes (no test frequency) reach too; 44
    # steps, so that a lane stopped off the sampling cadence (at step 7, 14, 28 or 35) has two regular samples after it
    # (one only: LaneSeries.finish's bug, test_a_lane_stopped_off_cadence_in_the_last_stride_keeps_its_stop_sample)
    "strided": {"record": {"every": 3, "error_time": 0.23}, "divergence": {"check_every": 7}, "duration": 0.44},
    "strided_no_series": {"record": {"every": 3, "series": False},
                          "divergence": {"check_every": 5, "energy_factor": 2.0}},
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("integrator", LANE_INTEGRATORS)
def test_every_lane_is_its_run_stepped_alone(integrator, case):
    runs = spring_runs([integrator], masses=MASSES, **CASES[case])
    outcomes = assert_lanes_are_runs_alone(runs)
    # the pumped lanes (zeta = -1) stop while the others go on
    assert outcomes[("diverged", True)] >= 1, outcomes
    assert outcomes[("ok", False)] >= 1, outcomes
    if case.startswith("strided"):  # some at a check between two samples: with a sample of their own
        assert outcomes["stopped off cadence"] >= 1, outcomes


@pytest.mark.parametrize("mode, extra", [
    ("stop", {}),  # every step sampled: a stop is never off the cadence (the tests below stop off it)
    ("continue", {"record": {"series": False, "every": 4}}),
])
@pytest.mark.parametrize("integrator", ITERATIVE)
def test_lanes_whose_steps_do_not_converge_are_their_runs_alone(integrator, mode, extra):
    # no pumped lane here: the exact solution of a stiff pumped spring overflows (a warning in _final_error, older
    # than lanes: e^(w t) with w t ~ 1e4)
    runs = spring_runs([integrator], stiffnesses=STIFF, ratios=(0.0, 0.3, 2.0), masses=MASSES,
                       solver={**ONE_ITERATION, "on_not_converged": mode}, **extra)
    outcomes = assert_lanes_are_runs_alone(runs)
    # exercised: some lanes end not converged (stopped at that step under stop), others ok
    assert outcomes[("not_converged", mode == "stop")] >= 1, outcomes
    assert outcomes[("ok", False)] >= 1, outcomes


@pytest.mark.parametrize("integrator", LANE_INTEGRATORS)
def test_a_chunk_mixing_damped_and_undamped_lanes_is_its_runs_alone(integrator):
    runs = spring_runs([integrator], ratios=(0.0, 0.3, -1.0), masses=MASSES, record={"every": 2})
    kinds = {lane_key(run) for run in runs}
    assert len(kinds) == 2  # lane_key keeps damped and undamped apart; here they share one chunk all the same
    assert {key[:1] + key[2:] for key in kinds} == {next(iter(kinds))[:1] + next(iter(kinds))[2:]}
    batch = simulate_lanes(runs)
    assert batch.results_alone is None
    statuses = Counter()
    for run, lane in zip(runs, batch.results()):
        assert_same_result(lane, simulate(run))
        statuses[str(lane.status)] += 1
    assert statuses["diverged"] >= 1 and statuses["ok"] >= 1, statuses


@pytest.mark.parametrize("integrator, stiffnesses, solver", [
    ("symplectic_euler", (100.0, 1e6), {}),  # h w = 10: diverges within a few steps; the other lane goes on
    ("backward_euler", (1.0, 1e9), {"solver": {**ONE_ITERATION, "on_not_converged": "stop"}}),  # stops at step 1
])
def test_a_lane_stopped_off_cadence_in_the_last_stride_keeps_its_stop_sample(integrator, stiffnesses, solver):
    """10 steps sampled every 20th: samples at t = 0 and the last step only, so a lane that stops early gets a sample of
    its own at its stop, and the last step's regular sample must not replace it."""
    runs = spring_runs([integrator], stiffnesses=stiffnesses, ratios=(0.0,), duration=0.1, record={"every": 20},
                       **solver)
    alone = [simulate(run) for run in runs]
    assert [result.steps < run.step_count for run, result in zip(runs, alone)] == [False, True]
    batch = simulate_lanes(runs)
    assert batch.results_alone is None
    for lane, result in zip(batch.results(), alone):
        assert_same_result(lane, result)


def test_lanes_that_all_stop_off_cadence_keep_their_stop_samples():
    """Both lanes (h w = 10 and 14) diverge at the check of step 9, between the samples at steps 5 and 10."""
    runs = spring_runs(["symplectic_euler"], stiffnesses=(1e6, 2e6), ratios=(0.0,), duration=0.1, record={"every": 5},
                       divergence={"check_every": 9})
    alone = [simulate(run) for run in runs]
    assert [(result.status, result.steps) for result in alone] == [(Status.DIVERGED, 9)] * 2
    batch = simulate_lanes(runs)
    assert batch.results_alone is None
    for lane, result in zip(batch.results(), alone):
        assert_same_result(lane, result)


def test_a_damped_run_that_overflows_measures_its_decay_silently():
    # semi-implicit backward Euler, zeta = -1, k = 1e4, h = 0.01: m + h d + h^2 k = 1 - 2 + 1 = 0, q and v become -inf
    (run,) = spring_runs(["semi_implicit_backward_euler"], stiffnesses=(1e4,), ratios=(-1.0,), duration=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = simulate(run)
    assert result.status is Status.DIVERGED and math.isnan(result.attrs["decay_per_period"])


# -- 2. which runs share lanes, and the chunks ------------------------------------------------------------------
@pytest.mark.parametrize("solver", [
    {"type": "newton", "fallback": ["gradient_descent"]},
    {"type": "newton", "linear_solver": "cg"},
    {"type": "newton", "tolerance_mode": "step"},
    {"type": "newton", "initial_guess": "predictor"},
    {"type": "lbfgs"},
])
def test_a_solver_lanes_cannot_reproduce_steps_its_runs_alone(solver):
    (implicit,) = spring_runs(["backward_euler"], stiffnesses=(100.0,), ratios=(0.0,), solver=solver)
    assert lane_key(implicit) is None
    # an explicit method uses no solver: its runs take lanes whatever the solver says, with the default's key
    (explicit,) = spring_runs(["symplectic_euler"], stiffnesses=(100.0,), ratios=(0.0,), solver=solver)
    (default,) = spring_runs(["symplectic_euler"], stiffnesses=(100.0,), ratios=(0.0,))
    assert lane_key(explicit) is not None and lane_key(explicit) == lane_key(default)


@pytest.mark.parametrize("solver", [{"type": "newton"}, {"type": "projected_newton"},
                                    pytest.param({"type": "newton", "linear_solver": "cholesky", "tolerance_mode": "absolute"},
                                                 marks=needs_linear_solver("cholesky"), id="cholesky")])
def test_a_solver_lanes_reproduce_takes_lanes(solver):
    (run,) = spring_runs(["backward_euler"], stiffnesses=(100.0,), ratios=(0.0,), solver=solver)
    assert lane_key(run) is not None


def test_a_method_or_system_without_a_lane_form_steps_its_runs_alone():
    (exponential,) = spring_runs(["exponential_rosenbrock_euler"], stiffnesses=(100.0,), ratios=(0.0,))
    assert lane_key(exponential) is None
    circle = expand_runs(validate_experiment({"name": "circle", "system": {"type": "circular_motion"},
                                              "integrators": ["backward_euler", "symplectic_euler"], "duration": 0.1,
                                              "sweep": {"dt": [0.01]}}))
    assert [lane_key(run) for run in circle] == [None, None]


def test_lane_keys_tell_apart_what_must_not_share_a_chunk():
    runs = spring_runs(["backward_euler", "newmark", {"type": "newmark", "gamma": 0.6}], stiffnesses=(1.0, 100.0),
                       ratios=(0.0, 0.3))
    keys = {}
    for run in runs:
        keys.setdefault(lane_key(run), set()).add((run.integrator_label, run.system.damping_ratio != 0.0))
    assert all(len(members) == 1 for members in keys.values())  # a key per (method, damped or not)
    assert len(keys) == 6


def chunk_sweep():
    """40 undamped symplectic Euler runs (a key of >= MIN_LANES), 20 damped ones (another), 6 backward Euler runs (a key
    of too few), 40 exponential Euler runs (no lane form)."""
    many = spring_runs(["symplectic_euler", "exponential_rosenbrock_euler"],
                       stiffnesses=tuple(np.geomspace(1.0, 1e4, 20).tolist()), ratios=(0.0, 0.1, 0.2), duration=0.05)
    few = spring_runs(["backward_euler"], stiffnesses=(1.0, 10.0, 100.0), ratios=(0.0, 0.3), duration=0.05)
    runs = [run for run in many if not (run.integrator.name == "symplectic_euler" and run.system.damping_ratio == 0.2)]
    runs += few
    return runs


def reindexed(runs):
    """The runs with their index in this list (lane_chunks sorts runs alone by index)."""
    return [run.model_copy(update={"index": number}) for number, run in enumerate(runs)]


@pytest.mark.parametrize("jobs", [1, 2, 3, 8])
def test_lane_chunks_put_every_run_once_into_chunks_of_one_key_or_alone(jobs):
    runs = reindexed(chunk_sweep())
    assert MIN_LANES <= 20
    chunks, alone = lane_chunks(runs, jobs)
    ids = [run.run_id for chunk in chunks for run in chunk] + [run.run_id for run in alone]
    assert sorted(ids) == sorted(run.run_id for run in runs) and len(set(ids)) == len(ids)
    counts = Counter(lane_key(run) for run in runs)
    chunk_keys = Counter()
    for chunk in chunks:
        (key,) = {lane_key(run) for run in chunk}
        assert key is not None and counts[key] >= MIN_LANES
        assert [run.index for run in chunk] == sorted(run.index for run in chunk)
        chunk_keys[key] += 1
    assert set(chunk_keys) == {key for key, count in counts.items() if key is not None and count >= MIN_LANES}
    assert len(chunk_keys) == 2
    for key, number in chunk_keys.items():
        assert number == max(1, min(jobs, counts[key] // MIN_LANES)), (key[2], counts[key], number)
    for run in alone:
        assert lane_key(run) is None or counts[lane_key(run)] < MIN_LANES
    assert [run.index for run in alone] == sorted(run.index for run in alone)
    assert sum(1 for run in alone if run.integrator.name == "backward_euler") == 6


def test_lane_chunks_hold_at_most_chunk_bytes_of_data(monkeypatch):
    from simrun.format.size import estimate_run_bytes

    runs = reindexed(chunk_sweep())
    monkeypatch.setattr(simrun.execution.lanes, "CHUNK_BYTES", 7 * estimate_run_bytes(runs[0]))
    chunks, alone = lane_chunks(runs, 1)
    assert chunks and all(1 <= len(chunk) <= 7 for chunk in chunks)
    assert sum(len(chunk) for chunk in chunks) + len(alone) == len(runs)


def test_lanes_off_and_too_few_runs_step_every_run_alone():
    runs = reindexed(chunk_sweep())
    outcomes = list(execute(runs[:12], lanes="auto"))  # too few of any key
    assert all(not isinstance(task, list) for task, _ in outcomes)
    outcomes = list(execute(runs, lanes="off"))
    assert [task.run_id for task, _ in outcomes] == [run.run_id for run in runs]
    with pytest.raises(ConfigError, match="--lanes"):
        execute(runs, lanes="on")


def test_execute_yields_chunks_as_lane_batches_and_runs_as_results():
    runs = reindexed(chunk_sweep())
    seen = []
    for task, outcome in execute(runs, ExecutorOptions(jobs=1), lanes="auto"):
        if isinstance(task, list):
            assert [run.run_id for run in task] == outcome.run_ids and outcome.results_alone is None
            seen += [run.run_id for run in task]
        else:
            assert outcome.run_id == task.run_id
            seen.append(task.run_id)
    assert sorted(seen) == sorted(run.run_id for run in runs)


# -- 3. a chunk that fails as lanes -----------------------------------------------------------------------------
def fail_as_lanes(runs):
    raise RuntimeError("lanes broke")


def test_a_chunk_whose_stepping_raises_is_run_run_by_run(monkeypatch):
    runs = spring_runs(["backward_euler"], masses=MASSES)
    monkeypatch.setattr(simrun.execution.lanes, "_simulate_lanes", fail_as_lanes)
    batch = simulate_lanes(runs)
    assert batch.results_alone is not None
    assert batch.status == [result.status for result in batch.results_alone]
    for run, result in zip(runs, batch.results()):
        assert_same_result(result, simulate(run))


def test_a_sweep_whose_chunks_fail_as_lanes_stores_its_runs_as_runs(tmp_path, monkeypatch):
    config = spring_config(["backward_euler"], stiffnesses=tuple(np.geomspace(1.0, 1e4, 16).tolist()), ratios=(0.0,),
                           duration=0.1)
    off = run_quietly(config, tmp_path / "off", jobs=1, lanes="off")
    monkeypatch.setattr(simrun.execution.lanes, "_simulate_lanes", fail_as_lanes)
    failed = run_quietly(config, tmp_path / "failed", jobs=1, lanes="auto")  # serial: the patch is in this process
    assert lane_chunk_names(failed.path) == []
    assert failed.ran == {"ok": 16}
    assert_same_results(failed, off)


# -- 4. the results file: lanes auto reads back as lanes off ---------------------------------------------------
# 16 stiffnesses x 3 damping ratios: per lane method a key of 16 undamped runs and one of 32 damped ones (two chunks on
# two jobs); bdf2_midpoint_mix has no lane form: its runs are stored alone
E2E = spring_config(["symplectic_euler", {"type": "generalized_alpha", "rho_inf": 0.5}, "bdf2_midpoint_mix"],
                    stiffnesses=tuple(np.geomspace(1.0, 1e4, 16).tolist()), ratios=(0.0, 0.2, -0.9), duration=0.2,
                    name="lanes_e2e", record={"error_time": 0.13})
E2E_RUNS = 3 * 48


@pytest.fixture(scope="module")
def e2e(tmp_path_factory):
    """E2E run with lanes off (serial), lanes auto serially and on a pool of two."""
    folder = tmp_path_factory.mktemp("e2e")
    return {"off": run_quietly(E2E, folder / "off", jobs=1, lanes="off"),
            "auto1": run_quietly(E2E, folder / "auto1", jobs=1, lanes="auto"),
            "auto2": run_quietly(E2E, folder / "auto2", jobs=2, lanes="auto")}


@pytest.mark.parametrize("mode", ["auto1", "auto2"])
def test_a_sweep_with_lanes_stores_what_it_stores_without(e2e, mode):
    assert_same_results(e2e[mode], e2e["off"])
    assert e2e[mode].ran == e2e["off"].ran and sum(e2e["off"].ran.values()) == E2E_RUNS
    # the pumped runs of both lane methods diverge: lanes that stop are stored as the runs alone that stopped
    assert {run.integrator for run in e2e["off"].runs.values() if run.status is Status.DIVERGED} >= {
        "symplectic_euler", "generalized_alpha"}


@pytest.mark.parametrize("mode", ["auto1", "auto2"])
def test_a_lane_sweep_file_mixes_runs_and_lane_chunks(e2e, mode):
    with h5py.File(e2e[mode].path, "r") as file:
        assert int(file.attrs["format_version"]) == 3
        chunks = file[LANES_GROUP]
        in_chunks = sum(len(chunk["runs"]) for chunk in chunks.values())
        assert all(chunk.attrs["complete"] for chunk in chunks.values())
        alone = list(file["runs"])
        assert len(file["summary"]) == E2E_RUNS
        chunk_count = len(chunks)
    assert in_chunks == 2 * 48 and len(alone) == 48
    assert all("bdf2_midpoint_mix" in run_id for run_id in alone)
    # per method an undamped and a damped chunk; two jobs split the 32 damped runs of a method in two
    assert chunk_count == (4 if mode == "auto1" else 6)
    with h5py.File(e2e["off"].path, "r") as file:
        assert LANES_GROUP not in file and len(file["runs"]) == E2E_RUNS


def test_the_comparison_tells_files_apart(e2e, bare):
    """assert_same_results is not blind: files whose runs differ (series kept or not) are told apart."""
    with pytest.raises(AssertionError):
        assert_same_results(bare["off"], e2e["off"])


# -- 5. resume after a chunk's write was killed -------------------------------------------------------------------
def test_a_chunk_without_its_complete_mark_is_run_again_on_resume(e2e, tmp_path):
    output = tmp_path / "resumed"
    output.mkdir()
    shutil.copy(e2e["auto1"].path, output / RESULTS_NAME)
    with h5py.File(output / RESULTS_NAME, "a") as file:
        chunk = file[LANES_GROUP][sorted(file[LANES_GROUP])[1]]
        killed = [value.decode() if isinstance(value, bytes) else value for value in chunk["runs"]["run_id"].tolist()]
        del chunk.attrs["complete"]
    assert len(killed) >= MIN_LANES
    assert not set(killed) & set(load(output / RESULTS_NAME).runs)  # the reader skips an incomplete chunk
    resumed = run_quietly(E2E, output, jobs=1, lanes="auto")
    assert sum(resumed.ran.values()) == len(killed)
    assert_same_results(resumed, e2e["auto1"])
    with h5py.File(resumed.path, "r") as file:
        assert all(chunk.attrs.get("complete", False) for chunk in file[LANES_GROUP].values())
        assert len(file["summary"]) == E2E_RUNS
    again = run_quietly(E2E, output, jobs=1, lanes="auto")  # nothing left
    assert again.ran == {}
    assert_same_results(again, e2e["auto1"])


# -- 6. series false ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bare(tmp_path_factory):
    """E2E without series, with lanes (on two jobs) and without."""
    folder = tmp_path_factory.mktemp("bare")
    config = {**E2E, "record": {**E2E["record"], "series": False}}
    return {"auto": run_quietly(config, folder / "auto", jobs=2, lanes="auto"),
            "off": run_quietly(config, folder / "off", jobs=1, lanes="off")}


@pytest.mark.parametrize("lanes", ["auto", "off"])
def test_a_sweep_without_series_keeps_the_summary_of_one_with_series(e2e, bare, lanes):
    without, full = bare[lanes], e2e["off"]
    assert list(without.runs) == list(full.runs)
    assert all(run.datasets == () for run in without.runs.values())
    assert (lane_chunk_names(without.path) != []) == (lanes == "auto")
    summary, full_summary = (frame.drop(columns=TIMING_SUMMARY_COLUMNS) for frame in (without.summary, full.summary))
    assert summary.equals(full_summary)
    by_id = full_summary.set_index("run_id")
    for run_id, run in without.runs.items():
        with_series = full.runs[run_id].attrs
        attrs = {key: value for key, value in run.attrs.items() if key not in TIMING_ATTRIBUTES}
        # the run's attributes with series, and the summary's series numbers as attributes
        assert set(attrs) == set(with_series) - TIMING_ATTRIBUTES | set(SERIES_SUMMARY_KEYS), run_id
        for key in SERIES_SUMMARY_KEYS:
            assert same_value(attrs.pop(key), by_id.loc[run_id, key]), (run_id, key)
        for key, value in attrs.items():
            assert same_value(value, with_series[key]), (run_id, key, value, with_series[key])


def test_a_sweep_without_series_stores_the_same_with_and_without_lanes(bare):
    assert_same_results(bare["auto"], bare["off"])


# -- 7. the decay per period against theory ----------------------------------------------------------------------
HW = (0.01, 0.1, 1.0, 3.0)


def undamped_runs(integrator):
    """The undamped spring at h w = HW (dt = 0.01 s, m = 1 kg, k = (h w / dt)^2) for 1 s."""
    return spring_runs([integrator], stiffnesses=tuple((hw / 0.01) ** 2 for hw in HW), ratios=(0.0,), duration=1.0)


def measured_decays(runs) -> tuple[list[float], list[float]]:
    """(h w, decay_per_period) of each run, alone and as lanes (which must agree)."""
    alone = [simulate(run).attrs["decay_per_period"] for run in runs]
    batch = simulate_lanes(runs)
    assert batch.results_alone is None
    assert [result.attrs["decay_per_period"] for result in batch.results()] == alone
    hw = [run.dt * math.sqrt(run.system.stiffness / run.system.mass) for run in runs]
    return hw, alone


def test_backward_euler_decays_by_its_energy_factor_per_step():
    """Backward Euler on q'' + w^2 q = 0 multiplies the energy by exactly 1/(1 + (h w)^2) each step, so the amplitude
    per period 2 pi / w is (1 + (h w)^2)^(-pi / (h w))."""
    hw, decays = measured_decays(undamped_runs("backward_euler"))
    for x, decay in zip(hw, decays):
        expected = (1.0 + x * x) ** (-math.pi / x)
        assert decay == pytest.approx(expected, rel=1e-12), x


@pytest.mark.parametrize("integrator", ["implicit_midpoint", "newmark"])
def test_the_trapezoidal_methods_keep_the_amplitude(integrator):
    hw, decays = measured_decays(undamped_runs(integrator))
    assert decays == pytest.approx([1.0] * len(HW), rel=1e-12, abs=0)


def test_decay_per_period_is_the_amplitude_factor_per_period():
    # V(t)/V(0) = e^(-2 zeta w t): the amplitude sqrt(V) loses e^(-2 pi zeta) per period
    w, zeta, t = 3.0, 0.1, 2.7
    measured = decay_per_period(2.0, 2.0 * math.exp(-2.0 * zeta * w * t), t, w)
    assert measured == pytest.approx(math.exp(-2.0 * math.pi * zeta), rel=1e-14)


@pytest.mark.parametrize("zeta", [0.05, 0.3, 0.7, 0.95])
def test_the_exact_motion_loses_its_modal_energy_at_the_steady_rate(zeta):
    """V = E + d q v / 2 of the exact solution is V(0) e^(-2 zeta w t) at every t, whatever the phase; for a single
    spring and for lanes of springs alike."""
    params = SpringMassParams(stiffness=40.0, mass=2.5, damping_ratio=zeta, x0=0.7, v0=-1.3)
    spring = params.build()
    w = math.sqrt(40.0 / 2.5)
    t = np.linspace(0.0, 6.0 * 2.0 * math.pi / w, 301)
    q, p = spring.exact_solution(t)
    energy = 0.5 * (2.5 * p[:, 0] ** 2 + 40.0 * q[:, 0] ** 2)
    modal = spring.modal_energy(energy, q, p)
    expected = modal[0] * np.exp(-2.0 * zeta * w * t)
    assert np.allclose(modal, expected, rtol=1e-12, atol=0.0)
    # the lanes' form, one lane per time
    lanes = SpringMassLanes([spring] * t.size)
    q_lanes, p_lanes = lanes.exact_states(t)
    assert np.allclose(q_lanes, q[:, 0], rtol=0, atol=1e-13 * np.abs(q).max())
    lane_modal = lanes.modal_energy(energy, q_lanes[:, None], p_lanes[:, None])
    assert np.allclose(lane_modal, expected, rtol=1e-12, atol=0.0)


def test_above_critical_damping_the_modal_energy_is_the_energy():
    spring = SpringMassParams(stiffness=4.0, mass=1.0, damping_ratio=1.5).build()
    energy, x, v = np.array([3.0, 2.0]), np.array([[1.0], [0.5]]), np.array([[-2.0], [1.0]])
    assert np.array_equal(spring.modal_energy(energy, x, v), energy)
    below = SpringMassParams(stiffness=4.0, mass=1.0, damping_ratio=0.5).build()  # d = 2
    assert np.array_equal(below.modal_energy(energy, x, v), energy + 1.0 * (x[:, 0] * v[:, 0]))


def test_a_run_whose_energy_falls_below_the_floor_measures_up_to_the_floor():
    """Backward Euler at h w = 100 loses a factor 1e4 of energy per step: after 63 steps the modal energy is under
    DECAY_FLOOR V(0), and the decay is measured at the last sample above it (the value stays the closed form)."""
    (run,) = spring_runs(["backward_euler"], stiffnesses=(1e8,), ratios=(0.0,), duration=1.0)
    result = simulate(run)
    energy = result.samples["energy"]
    assert energy[-1] < DECAY_FLOOR * energy[0]
    expected = (1.0 + 1e4) ** (-math.pi / 100.0)
    assert result.attrs["decay_per_period"] == pytest.approx(expected, rel=1e-12)
    (lane,) = simulate_lanes([run]).results()
    assert_same_result(lane, result)


# -- 8. the amplification matrices probed as lanes ---------------------------------------------------------------
POINTS = [(0.1, 0.0), (1.0, 0.0), (5.0, 0.0), (0.1, 0.3), (1.0, 0.3), (5.0, 0.3), (1.0, 2.0), (0.5, -0.2)]


@pytest.mark.parametrize("integrator", LANE_INTEGRATORS)
def test_the_lane_probe_gives_each_point_s_amplification_matrix(integrator):
    method = INTEGRATORS[integrator]()
    hw, zeta = np.array([point[0] for point in POINTS]), np.array([point[1] for point in POINTS])
    matrices = analysis.amplification_matrices(method, hw, zeta)
    assert matrices.shape[0] == len(POINTS)
    for (h, z), matrix in zip(POINTS, matrices):
        spring = SpringMassParams(stiffness=h * h, mass=1.0, damping_ratio=z).build()
        one = analysis.amplification_matrix(method, 1.0, spring)
        assert matrix.shape == one.shape and np.array_equal(matrix, one), (h, z, matrix, one)


def test_backward_euler_s_probed_spectral_radius_is_the_closed_form():
    hw = np.geomspace(1e-2, 1e2, 17)
    matrices = analysis.amplification_matrices(INTEGRATORS["backward_euler"](), hw, np.zeros(hw.size))
    rho = np.max(np.abs(np.linalg.eigvals(matrices)), axis=1)
    assert np.allclose(rho, 1.0 / np.sqrt(1.0 + hw * hw), rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("integrator", sorted(set(INTEGRATORS) - set(LANE_INTEGRATORS)))
def test_a_method_without_lanes_is_probed_as_a_bank_of_springs(integrator):
    """The damping map's predicted contours of a method that does not step lanes (a plug-in's, most often): one step
    of a bank of damped springs per state slot, each point's matrix the point-by-point probe's to round-off (1e-10:
    expm_multiply and the coupled stages' solves stop at their own tolerances for the bank's larger system)."""
    method = INTEGRATORS[integrator]()
    hw, zeta = np.array([point[0] for point in POINTS]), np.array([point[1] for point in POINTS])
    matrices = analysis.amplification_matrices(method, hw, zeta)
    if matrices is None:  # carries more than a number per spring (the variable-order BDF's history)
        assert analysis.bank_matrices(method, hw, zeta) is None
        return
    for (h, z), matrix in zip(POINTS, matrices):
        spring = SpringMassParams(stiffness=h * h, mass=1.0, damping_ratio=z).build()
        one = analysis.amplification_matrix(method, 1.0, spring)
        np.testing.assert_allclose(matrix, one, rtol=1e-10, atol=1e-12, err_msg=f"h w = {h}, zeta = {z}")


# -- 9. config errors -------------------------------------------------------------------------------------------
TINY = "name: tiny\nsystem: {type: spring_mass}\nintegrators: [backward_euler]\nduration: 0.1\nsweep: {dt: [0.01]}\n"


def test_an_unknown_lanes_mode_on_the_command_line_is_a_usage_error(tmp_path, capsys):
    """argparse refuses it (exit 2) with one error line naming --lanes and the valid modes, after the usage lines, as
    every option with choices (--executor) is refused; nothing is written."""
    config = tmp_path / "config.yaml"
    config.write_text(TINY + f"output: {tmp_path / 'out'}\n")
    with pytest.raises(SystemExit) as stop:
        main(["run", str(config), "--lanes", "bogus", "-q"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line]
    assert len(errors) == 1 and "--lanes" in errors[0] and "'auto', 'off'" in errors[0], err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_an_unknown_lanes_mode_in_python_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"--lanes: unknown 'x'; valid: auto, off") as error:
        simrun.run(TINY, output=tmp_path / "out", lanes="x", progress=False, figures=False)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "out").exists()


def test_damping_and_a_damping_ratio_together_are_one_error_naming_the_system(tmp_path, capsys):
    text = TINY.replace("{type: spring_mass}", "{type: spring_mass, damping: 1.0, damping_ratio: 0.1}")
    config = tmp_path / "config.yaml"
    config.write_text(text + f"output: {tmp_path / 'out'}\n")
    assert main(["run", str(config), "-q"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simrun: error: system") and "damping_ratio" in lines[0], err
    with pytest.raises(ConfigError, match="^system") as error:
        simrun.run(text, output=tmp_path / "out", progress=False, figures=False)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "out").exists()


def test_a_damping_ratio_sets_the_damping_from_stiffness_and_mass():
    spring = SpringMassParams(stiffness=50.0, mass=2.0, damping_ratio=0.25).build()
    assert spring.damping == 2.0 * 0.25 * math.sqrt(50.0 * 2.0)
    assert spring.oscillator == pytest.approx((5.0, 0.25), rel=1e-15)
    assert SpringMassParams(stiffness=50.0, mass=2.0, damping=3.0).build().oscillator[1] == pytest.approx(
        3.0 / (2.0 * 10.0), rel=1e-15)


# -- 10. the damping map ------------------------------------------------------------------------------------------
def rendered(results) -> list[str]:
    names = []
    for _entry, name, figure in render_figures(results):
        names.append(name)
        plt.close(figure)
    return names


def test_the_damping_map_draws_a_panel_per_method_of_a_map(tmp_path):
    config = spring_config(["backward_euler", "symplectic_euler"], stiffnesses=(1.0, 100.0, 1e4, 1e5),
                           ratios=(0.0, 0.1, 0.5), duration=0.5, name="map", record={"series": False})
    results = run_quietly(config, tmp_path / "map", jobs=1)
    from simrun.figures import figure_data
    from simrun.figures.damping_map import damping_map

    figure = damping_map(figure_data(results))
    try:
        titles = sorted(ax.get_title() for ax in figure.axes if ax.get_title())
        # symplectic Euler is unstable beyond h w = 2: its three runs at h w = 3.2 diverge
        assert titles == ["backward_euler\n12 cells", "symplectic_euler\n12 cells, 3 diverged (hatched)"]
    finally:
        plt.close(figure)
    assert "damping_map" in rendered(results)
    one_ratio = {**config, "sweep": {**config["sweep"], "system.damping_ratio": [0.1]}}
    single = run_quietly(one_ratio, tmp_path / "one", jobs=1)
    assert "damping_map" not in rendered(single)


# -- found in review: each failed before its fix -------------------------------------------------------------------
def test_the_summary_of_a_lane_that_stopped_on_a_sample_counts_only_its_own_steps():
    """A lane stopped on a sampled step while others stopped later between samples (the loop then broke): the steps its
    chunk took after it must not enter its mean iterations (the per-step rows past its steps are zero)."""
    runs = spring_runs(["backward_euler"], stiffnesses=tuple(np.geomspace(1.0, 1e4, 40).tolist()), ratios=(-1.0,), duration=2.0,
                       record={"every": 10}, divergence={"check_every": 5})
    batch = simulate_lanes(runs)
    assert batch.results_alone is None
    stopped = [int(steps) for steps in batch.steps if steps < runs[0].step_count]
    assert len(set(stopped)) > 1  # lanes stopped at different steps
    for lane, run in enumerate(runs):
        alone = simulate(run)
        assert batch.summary["mean_newton_iterations"][lane] == float(np.mean(alone.per_step["newton_iterations"]))
        assert batch.summary["mean_linear_iterations"][lane] == float(np.mean(alone.per_step["linear_iterations"]))
        assert not batch.per_step["newton_iterations"][lane, alone.steps:].any()


def test_a_subclass_of_the_spring_is_not_stepped_by_the_springs_lanes():
    """A plug-in that subclasses SpringMass changes its physics: the spring's lane class would step the parent's."""
    from simrun.systems.spring_mass import SpringMass

    class CubicSpring(SpringMass):
        def acceleration(self, x, v):
            return super().acceleration(x, v) + 10.0 * x ** 3

    class CubicParams(SpringMassParams):
        pass

    CubicParams.system_class = CubicSpring
    (run,) = spring_runs(["symplectic_euler"], stiffnesses=(1.0,), ratios=(0.0,))
    assert lane_key(run) is not None
    assert lane_key(run.model_copy(update={"system": CubicParams(**run.system.model_dump())})) is None


def test_a_strongly_pumped_run_measures_an_infinite_growth_instead_of_raising():
    """decay_per_period beyond the largest float: inf, alone and in lanes (math.exp would raise OverflowError)."""
    runs = spring_runs(["rk4"], stiffnesses=(1.0, 4.0), ratios=(-300.0,), duration=0.5,
                       system={"type": "spring_mass", "x0": 1.0, "v0": 0.0})
    for run, lane in zip(runs, simulate_lanes(runs).results()):
        alone = simulate(run)
        assert alone.attrs["decay_per_period"] == math.inf
        assert_same_result(lane, alone)


def test_a_nan_error_at_the_error_time_is_stored_by_lanes_as_by_runs(tmp_path):
    """A run that reached its error time whose exact solution overflowed has error = NaN: a chunk keeps the attribute."""
    config = spring_config(["backward_euler"], stiffnesses=tuple(np.geomspace(0.8e8, 1.2e8, MIN_LANES).tolist()), ratios=(-0.5,),
                           record={"error_time": 0.5})
    alone = run_quietly(config, tmp_path / "off", lanes="off")
    together = run_quietly(config, tmp_path / "auto", lanes="auto")
    with h5py.File(tmp_path / "auto" / RESULTS_NAME, "r") as file:
        assert LANES_GROUP in file
    assert any("error" in run.attrs and math.isnan(run.attrs["error"]) for run in alone.runs.values())
    assert_same_results(alone, together)
