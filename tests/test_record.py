"""The run record is declared once (simrun.format.record): the docs list the same fields, every producer fills only
declared ones, the status rule is one rule, and the schedules and the step log behave as the loop needs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from simrun.execution.schedule import ControlledSteps, FixedSteps
from simrun.execution.step_log import StepLog
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.format.record import (FACTORISATION_PATHS, RUN_FIELDS, SOLVER_STEP_COLUMNS, STEP_COLUMNS, check_record,
                                  decide_status, run_attribute)
from simrun.format.summary import Status
from simrun.solvers import SolveStats

DOCS = Path(__file__).resolve().parents[1] / "docs" / "results-format.md"


def _table_names(heading: str) -> dict[str, str]:
    """The backticked names of the first column of the table under ``heading`` (a cell may name several, with
    commas), each with its second column."""
    text = DOCS.read_text()
    section = text[text.index(heading):]
    rows = {}
    for line in section.splitlines()[1:]:
        if line.startswith("#"):
            break
        if not line.startswith("| `"):
            continue
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        for name in re.findall(r"`([^`]+)`", cells[0]):
            rows[name] = cells[1]
    return rows


def test_the_docs_attribute_table_lists_exactly_the_declared_run_fields():
    documented = _table_names("### Attributes")
    assert set(documented) == set(RUN_FIELDS), (sorted(set(documented) - set(RUN_FIELDS)),
                                                sorted(set(RUN_FIELDS) - set(documented)))
    type_names = {int: "int", float: "float", str: "str", bool: "bool", np.ndarray: "int array"}
    for name, field in RUN_FIELDS.items():
        assert documented[name] == type_names[field.type], name


def test_the_docs_per_step_table_lists_exactly_the_declared_columns_with_their_dtypes():
    documented = _table_names("### Datasets, one row per step")
    assert set(documented) == set(STEP_COLUMNS)
    for name, column in STEP_COLUMNS.items():
        assert documented[name] == np.dtype(column.dtype).name, name


def test_the_formats_factorisation_paths_are_the_solvers():
    from simrun.solvers.linear import FACTORISATION_PATHS as SOLVER_PATHS

    assert FACTORISATION_PATHS == SOLVER_PATHS


def test_the_solver_columns_are_the_fields_of_a_solve():
    assert {column.stats_field for column in SOLVER_STEP_COLUMNS.values()} <= set(SolveStats._fields)
    assert all(column.stats_field is None for name, column in STEP_COLUMNS.items() if name not in SOLVER_STEP_COLUMNS)


def test_an_undeclared_attribute_is_refused_and_a_missing_one_reads_its_default():
    check_record({"final_error": 0.0, "safeguard_steps": 2})
    with pytest.raises(KeyError, match="not_a_field"):
        check_record({"final_error": 0.0, "not_a_field": 1})
    assert run_attribute({}, "safeguard_steps") == 0
    assert np.isnan(run_attribute({}, "final_error"))
    assert run_attribute({"final_error": 0.5}, "final_error") == 0.5
    with pytest.raises(KeyError, match="required"):
        run_attribute({}, "status")


@pytest.mark.parametrize("failed, diverged, over_budget, not_converged, accept, expected", [
    (False, False, False, 0, False, Status.OK),
    (True, True, True, 3, False, Status.FAILED),
    (False, True, True, 3, True, Status.DIVERGED),
    (False, False, True, 0, True, Status.NOT_CONVERGED),  # a wall-clock stop is not what a budget bought
    (False, False, False, 2, False, Status.NOT_CONVERGED),
    (False, False, False, 2, True, Status.OK),  # on_not_converged: accept
])
def test_the_status_rule(failed, diverged, over_budget, not_converged, accept, expected):
    assert decide_status(failed=failed, diverged=diverged, over_budget=over_budget, not_converged_steps=not_converged,
                         accept_not_converged=accept) is expected


def test_the_step_log_records_a_solve_and_grows_keeping_its_rows():
    log = StepLog([*SOLVER_STEP_COLUMNS, "dt"], 2)
    log.record(0, SolveStats(3, 7, 1, 1e-9, True, 1, 5))
    log.put(0, dt=0.25)
    log.grow_to(3)
    assert log.rows == 4
    log.record(2, SolveStats(1, 1, 0, 2e-9, False, 0, 1))
    kept = log.result(3)
    assert kept["newton_iterations"].tolist() == [3, 0, 1] and kept["linear_iterations"].tolist() == [7, 0, 1]
    assert kept["residual"].tolist() == [1e-9, 0.0, 2e-9] and kept["safeguards"].tolist() == [5, 0, 1]
    assert kept["dt"].tolist() == [0.25, 0.0, 0.0]
    assert all(kept[name].dtype == np.dtype(STEP_COLUMNS[name].dtype) for name in kept)


def _runs(text: str):
    experiment, _ = load_experiment(text, [])
    return expand_runs(experiment)


def test_fixed_steps_sample_every_stride_and_the_last_and_measure_the_error_at_its_step():
    """100 steps of 0.01 s, 11 samples: every 10th step; the error at t = 0.5 s, step 50."""
    run = _runs("name: t\nsystem: {type: spring_mass}\nintegrators: [symplectic_euler]\nduration: 1.0\nsweep: {dt: [0.01]}\n"
                "record: {max_samples: 11, error_time: 0.5}\n")[0]
    system = run.system.build()
    schedule = FixedSteps(run, system)
    sampled, errors = [], []
    state = None
    from simrun.integrators import State

    state = State(0.0, system.x0.copy(), system.v0.copy())
    while not schedule.done:
        state, _ = schedule.next_step(system, state, run.integrator.step, None, None)
        if schedule.sample_due():
            sampled.append(schedule.steps)
        if schedule.at_error_time():
            errors.append(schedule.t)
    assert schedule.steps == 100 and schedule.t == 100 * 0.01
    assert sampled == list(range(10, 101, 10))
    assert errors == [50 * 0.01]


def test_controlled_steps_land_on_the_duration_and_the_error_time_and_log_every_step():
    run = _runs("name: t\nsystem: {type: spring_mass}\nintegrators: [trbdf2]\nduration: 1.0\n"
                "step_control: {tolerance: 1.0e-6}\nrecord: {error_time: 0.3}\n")[0]
    system = run.system.build()
    schedule = ControlledSteps(run, system, run.integrator)
    log = StepLog([*SOLVER_STEP_COLUMNS, *schedule.log_columns], schedule.log_rows)
    from simrun.integrators import State

    state = run.integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    solver = run.solver.build()
    at_error = []
    while not schedule.done:
        state, stats = schedule.next_step(system, state, run.integrator.step, solver, log)
        if schedule.at_error_time():
            at_error.append(schedule.t)
    sizes = log.result(schedule.steps)["dt"]
    assert schedule.t == 1.0 and at_error == [0.3]
    assert sizes.sum() == pytest.approx(1.0, rel=1e-12) and np.all(sizes > 0)
    assert schedule.attrs()["accepted_steps"] == schedule.steps
