"""A run's budgets of work: record.max_steps and record.max_solver_iterations stop a run at the same step on every
machine (not_converged, the message naming the budget); the wall clock (record.max_wall_time, solver.time_budget)
bounds only the shipped configs whose question it is."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import simrun
from simrun.analysis.equal_error import left_out_reason

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))
# what a config whose question is the wall clock says so with
WALL_CLOCK_QUESTION = "The wall clock is this experiment's question"

SPRING = """
name: budgets
system: {type: spring_mass, mass: 1.0, stiffness: 100.0, damping: 0.0, x0: 1.0, v0: 0.0}
integrators: [backward_euler, symplectic_euler]
duration: 1.0
record: RECORD
sweep:
  dt: [0.01]
"""


def run(tmp_path, record: str, name: str):
    return simrun.run(SPRING.replace("RECORD", record), output=tmp_path / name, jobs=1, figures=False, progress=False)


def test_max_steps_stops_every_method_at_that_step(tmp_path):
    results = run(tmp_path, "{max_steps: 30}", "steps")
    for stored in results.runs.values():
        assert str(stored.status) == "not_converged" and stored.steps == 30
        assert stored.message.endswith("30 steps, record.max_steps 30")
        assert stored.series("t")[-1] == pytest.approx(0.3)
        assert left_out_reason(stored_run(stored)) == "over record.max_steps"


def test_max_solver_iterations_counts_the_solvers_iterations_only(tmp_path):
    results = run(tmp_path, "{max_solver_iterations: 20}", "iterations")
    implicit, explicit = results.runs.values()
    # backward Euler's Newton converges in one iteration on the linear spring: 20 steps use up 20 iterations
    assert str(implicit.status) == "not_converged" and implicit.steps == 20
    assert "20 solver iterations, record.max_solver_iterations 20" in implicit.message
    assert str(explicit.status) == "ok" and explicit.steps == 100  # an explicit method iterates no solver


def test_a_budget_the_run_does_not_reach_changes_nothing(tmp_path):
    free = run(tmp_path, "{}", "free").summary
    bounded = run(tmp_path, "{max_steps: 100, max_solver_iterations: 100}", "bounded").summary
    assert (bounded["status"] == "ok").all()
    assert bounded["max_rel_energy_drift"].tolist() == free["max_rel_energy_drift"].tolist()


def test_a_step_controlled_peer_counts_its_steps(tmp_path):
    config = yaml.safe_load(SPRING.replace("RECORD", "{max_steps: 5}"))
    config.update(integrators=[{"type": "solve_ivp", "method": "RK45"}], step_control={"tolerance": 1e-8})
    del config["sweep"]
    stored = next(iter(simrun.run(config, output=tmp_path / "peer", jobs=1, figures=False, progress=False).runs.values()))
    assert str(stored.status) == "not_converged" and stored.steps == 5 and "record.max_steps 5" in stored.message


def test_max_wall_time_stops_a_run_and_a_peer_at_their_first_step(tmp_path):
    """A budget of wall time shorter than any step: every run, simrun's and scipy's, stops after one step."""
    simruns = run(tmp_path, "{max_wall_time: 1.0e-9}", "wall")
    config = yaml.safe_load(SPRING.replace("RECORD", "{max_wall_time: 1.0e-9}"))
    config.update(integrators=[{"type": "solve_ivp", "method": "Radau"}], step_control={"tolerance": 1e-8})
    del config["sweep"]
    peers = simrun.run(config, output=tmp_path / "wall_peer", jobs=1, figures=False, progress=False)
    assert len(simruns.runs) == 2 and len(peers.runs) == 1
    for stored in [*simruns.runs.values(), *peers.runs.values()]:
        assert str(stored.status) == "not_converged" and stored.steps == 1
        assert stored.message.endswith("over record.max_wall_time 1e-09 s")
        assert left_out_reason(stored_run(stored)) == "over record.max_wall_time"


def stored_run(stored):
    class Run:  # what left_out_reason reads of a run
        status, error, wall_time = stored.status, stored.error, stored.wall_time
    Run.stored = stored
    return Run


@pytest.mark.parametrize("config", CONFIGS, ids=lambda path: path.stem)
def test_only_a_config_whose_question_is_the_wall_clock_is_bounded_by_it(config):
    """A shipped experiment gives the same statuses on a slow machine and a fast one: no wall-clock limit, except where
    the wall clock is the question (the real-time configs), and those say so."""
    text = config.read_text()
    settings = "\n".join(line.split("#")[0] for line in text.splitlines())  # wherever set: a section, a sweep, a mapping
    timed = "max_wall_time" in settings or "time_budget" in settings
    comment = " ".join(line.lstrip("# ").strip() for line in text.splitlines() if line.startswith("#"))
    if timed:
        assert WALL_CLOCK_QUESTION in comment, f"{config.name} is bounded by the wall clock: its comment must say why"
    else:
        assert WALL_CLOCK_QUESTION not in comment
