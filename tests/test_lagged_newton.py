"""Newton with a lagged factorisation (``solver.refactor: adaptive``, solvers/lagged.py): the chord iterations
reach the same solution as Newton that refactors at every iteration (the convergence test is the same), with
fewer factorisations, across the steps of a run; bad options are one line."""

from __future__ import annotations

import dataclasses
import numpy as np
import pytest

from simrun.errors import ConfigError
from simrun.execution.simulate import simulate
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.solvers import lagged


def cloth_run(refactor: str, solver: str = "newton", steps: int = 12, extra: str = "", system: str = ""):
    config = f"""
name: lagged
system: {{type: cloth, resolution: [8, 8], pinned: [top_left, top_right]{system}}}
integrators: [backward_euler]
solver: {{type: {solver}, tolerance: 1.0e-10, max_iterations: 200, refactor: {refactor}{extra}}}
duration: {0.01 * steps}
sweep: {{dt: [0.01]}}
record: {{frames_every: 1}}
"""
    experiment, _ = load_experiment(config)
    return expand_runs(experiment)[0]


class Counted:
    """Counts the lagged factorisations made while it is active."""

    def __init__(self, monkeypatch):
        self.count = 0
        original = lagged.LaggedFactor.__init__

        def counting(factor, *arguments, **keywords):
            self.count += 1
            original(factor, *arguments, **keywords)

        monkeypatch.setattr(lagged.LaggedFactor, "__init__", counting)


@pytest.mark.parametrize("solver", ["newton", "projected_newton"])
def test_lagged_newton_reaches_the_same_solution_with_fewer_factorisations(solver, monkeypatch):
    every = simulate(cloth_run("every", solver))
    counter = Counted(monkeypatch)
    adaptive = simulate(cloth_run("adaptive", solver))
    assert every.status.value == adaptive.status.value == "ok"
    # both meet |g|_inf <= 1e-10 |g_0|_inf at every step: the same positions to within what that leaves
    difference = np.max(np.abs(every.samples["frames"] - adaptive.samples["frames"]))
    assert difference <= 1e-8, difference
    iterations = int(np.sum(adaptive.per_step["newton_iterations"]))
    newton_iterations = int(np.sum(every.per_step["newton_iterations"]))
    # Newton factorises at each of its iterations; the lagged one far less often, and its chord iterations,
    # converging linearly, are more
    assert 1 <= counter.count < newton_iterations / 2, (counter.count, newton_iterations)
    assert iterations > newton_iterations


def test_a_rate_of_almost_zero_refactors_every_iteration_but_each_steps_first(monkeypatch):
    """refactor_rate -> 0 asks for a residual cut to nothing per iteration: every iteration refactors, but the
    first of each step, which has no earlier residual of its step to judge by and takes the last step's matrix."""
    counter = Counted(monkeypatch)
    strict = simulate(cloth_run("adaptive", steps=4, extra=", refactor_rate: 1.0e-12"))
    assert strict.status.value == "ok"
    assert counter.count == int(np.sum(strict.per_step["newton_iterations"])) - (strict.steps - 1)


def test_the_lagged_factor_is_renewed_when_the_free_dofs_change():
    from simrun.solvers.dofs import FreeDofs

    matrix = np.diag([2.0, 3.0, 4.0])
    factor = lagged.LaggedFactor(matrix, FreeDofs(3, np.array([1])), spd=True)
    assert factor.fits(FreeDofs(3, np.array([1])))
    assert not factor.fits(FreeDofs(3, np.array([2])))
    assert np.allclose(factor.solve(np.array([2.0, 9.0, 8.0])), [1.0, 0.0, 2.0])


@pytest.mark.parametrize("extra, field", [(", refactor: sometimes", "solver.refactor"),
                                          (", refactor_rate: 1.5", "solver.refactor_rate")])
def test_bad_refactor_options_are_one_line(extra, field):
    text = f"""
name: bad
system: {{type: spring_mass}}
integrators: [backward_euler]
solver: {{type: newton{extra}}}
sweep: {{dt: [0.1]}}
"""
    with pytest.raises(ConfigError) as error:
        load_experiment(text)
    assert str(error.value).startswith(field) and "\n" not in str(error.value)


def test_newton_krylov_with_the_lagged_preconditioner_reaches_the_same_solution(monkeypatch):
    """refactor: preconditioner solves each iteration's current matrix by PCG preconditioned with the kept
    factorisation (to 1e-3 relative: inexact Newton directions), refactorising only when PCG needs too many
    iterations: the same solution, Newton's iteration count about, far fewer factorisations."""
    every = simulate(cloth_run("every"))
    counter = Counted(monkeypatch)
    krylov = simulate(cloth_run("preconditioner"))
    assert str(krylov.status) == "ok"
    assert np.max(np.abs(every.samples["frames"] - krylov.samples["frames"])) <= 1e-8
    newton_iterations = int(np.sum(every.per_step["newton_iterations"]))
    assert counter.count < newton_iterations / 2
    # the PCG iterations are the linear iterations: more than one per Newton iteration, not many more
    iterations = int(np.sum(krylov.per_step["newton_iterations"]))
    assert iterations <= 2 * newton_iterations
    assert iterations < int(np.sum(krylov.per_step["linear_iterations"])) <= 15 * iterations


def test_a_lagged_direction_the_line_search_cannot_use_is_replaced_by_the_current_matrixs(monkeypatch):
    """When the line search finds no decrease along the lagged direction, the step is retried along the direction
    of the matrix at the current iterate, factorised there (not along the lagged one again): in the order of events,
    every refused search is followed by a factorisation before the next search."""
    from simrun.solvers import newton

    events: list[str] = []
    state_of = {"lagged": False}
    original_search, original_lagged, original_factor = newton.line_search, newton.Newton._lagged_direction, lagged.LaggedFactor.__init__

    def refusing_the_lagged(problem, free, current, direction, *arguments, **keywords):
        advance = original_search(problem, free, current, direction, *arguments, **keywords)
        if state_of["lagged"] and events.count("refused") < 3:
            state_of["lagged"] = False
            events.append("refused")
            return dataclasses.replace(advance, ok=False)
        events.append("search")
        return advance

    def tracking(solver, problem, current, state):
        result = original_lagged(solver, problem, current, state)
        state_of["lagged"] = state.lagged
        return result

    def factorising(factor, *arguments, **keywords):
        events.append("factor")
        original_factor(factor, *arguments, **keywords)

    monkeypatch.setattr(newton, "line_search", refusing_the_lagged)
    monkeypatch.setattr(newton.Newton, "_lagged_direction", tracking)
    monkeypatch.setattr(lagged.LaggedFactor, "__init__", factorising)
    result = simulate(cloth_run("adaptive", steps=4))
    assert str(result.status) == "ok" and events.count("refused") == 3
    for number, event in enumerate(events):
        if event == "refused":
            assert events[number + 1] == "factor", events[number: number + 3]
