"""Shared helpers: build runs from a config mapping, as a user's YAML would."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

# tetrahedralized meshes (systems/fem/tetrahedralize.py) go to a cache of this session, not the user's: set before
# any worker pool starts, so that every process of the session reads the same one
if "SIMRUN_CACHE" not in os.environ:
    os.environ["SIMRUN_CACHE"] = tempfile.mkdtemp(prefix="simrun-test-cache-")
    atexit.register(shutil.rmtree, os.environ["SIMRUN_CACHE"], True)

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest

from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.solvers import LINEAR_SOLVERS, SolveStats, solver_params

# the example plug-ins (systems and integrators) that the tests import by path
PLUGIN_FOLDER = Path(__file__).parent / "plugins"

# CI installs the optional CHOLMOD solver and sets this, so a broken install fails instead of skipping
REQUIRE_OPTIONAL_SOLVERS = os.environ.get("SIMRUN_REQUIRE_CHOLMOD") == "1"


def needs_linear_solver(name: str):
    """A mark for tests of linear solver ``name``: skip when its optional package is missing (unless
    SIMRUN_REQUIRE_CHOLMOD=1: then the test runs and fails)."""
    missing = LINEAR_SOLVERS[name].missing()
    return pytest.mark.skipif(missing is not None and not REQUIRE_OPTIONAL_SOLVERS, reason=str(missing))


# CI installs the engines extra (MuJoCo) in its second pass and sets this, so a broken install fails instead of skipping
REQUIRE_ENGINES = os.environ.get("SIMRUN_REQUIRE_ENGINES") == "1"


def needs_engine(name: str):
    """A mark for tests of an engine's integrators (``mujoco``, ``newton``): skip when its extra is missing (unless
    SIMRUN_REQUIRE_ENGINES=1: then the test runs and fails)."""
    from simrun.integrators import ENGINES

    missing = ENGINES[name].missing()
    return pytest.mark.skipif(missing is not None and not REQUIRE_ENGINES, reason=str(missing))


def config_params(paths) -> list:
    """Shipped configs as pytest params (ids: their names); a config that names an engine whose extra is missing
    (configs/engine_cards.yaml without MuJoCo) skips with that reason, unless SIMRUN_REQUIRE_ENGINES=1."""
    import yaml

    from simrun.integrators import ENGINES

    params = []
    for path in paths:
        entries = (yaml.safe_load(path.read_text()) or {}).get("integrators") or []
        names = [entry.get("type") if isinstance(entry, dict) else entry for entry in entries]
        reason = next((ENGINES[name].missing() for name in names if name in ENGINES and ENGINES[name].missing()), None)
        marks = pytest.mark.skipif(reason is not None and not REQUIRE_ENGINES, reason=str(reason))
        params.append(pytest.param(path, marks=marks, id=path.stem))
    return params


def linear_solver_params(names=None) -> list:
    """pytest params of linear solver names, each with its needs_linear_solver marks."""
    return [pytest.param(name, marks=needs_linear_solver(name), id=name) for name in (names or sorted(LINEAR_SOLVERS))]


def always_available_linear_solvers() -> set[str]:
    """The linear solvers that need no optional package."""
    return {name for name, cls in LINEAR_SOLVERS.items() if not cls.optional}


@pytest.fixture
def on_path(monkeypatch):
    """The example plug-ins importable (tests/plugins on sys.path), systems and integrators resolved afresh."""
    from simrun.integrators import plugins as integrator_plugins
    from simrun.systems import plugins as system_plugins

    monkeypatch.syspath_prepend(str(PLUGIN_FOLDER))
    for plugins in (system_plugins, integrator_plugins):
        plugins.clear_cache()
    yield
    for plugins in (system_plugins, integrator_plugins):
        plugins.clear_cache()


def assert_runs_alike(first, second) -> None:
    """Two results files hold the same runs: the same datasets, entry for entry, and the same attributes but for how
    they were run (their wall time and threads), not what they gave."""
    assert list(first.runs) == list(second.runs)
    for run_id, run in first.runs.items():
        other = second.runs[run_id]
        assert run.datasets == other.datasets
        for key in run.datasets:
            np.testing.assert_array_equal(run[key], other[key])
        assert set(run.attrs) == set(other.attrs)
        for key in set(run.attrs) - {"wall_time", "threads"}:
            one, two = np.asarray(run.attrs[key]), np.asarray(other.attrs[key])
            assert np.array_equal(one, two, equal_nan=one.dtype.kind == "f"), key


def make_runs(system: dict, integrators: list, dt: list[float], duration: float = 1.0, **extra):
    raw = {"name": "test", "system": system, "integrators": integrators, "duration": duration,
           "sweep": {"dt": dt}, **extra}
    return expand_runs(validate_experiment(raw))


def run_config_file(config: dict, folder):
    """The config written as YAML into ``folder`` and run by the command line (its own process pool, no figures): its
    first stored run, after asserting the command's exit status 0."""
    import yaml

    from simrun.cli import main
    from simrun.results.reader import load

    path = folder / f"{config['name']}.yaml"
    path.write_text(yaml.safe_dump(config))
    assert main([str(path), "--output", str(folder / "out"), "-q", "--no-plots"]) == 0
    return next(iter(load(folder / "out" / "results.h5").runs.values()))


def run_one(system: dict, integrator, dt: float, duration: float, **extra):
    (run,) = make_runs(system, [integrator], [dt], duration, **extra)
    return simulate(run)


@pytest.fixture
def run_simulation():
    return run_one


class Capture:
    """A stand-in solver that keeps the problem an integrator hands over (and solves nothing)."""

    def minimize(self, problem, start):
        self.problem, self.start = problem, start.copy()
        return start, SolveStats()


def step_problem(system, x=None, v=None, dt=0.01, integrator="backward_euler"):
    """The problem (and start) that the first step of ``integrator`` (a name) from (x, v) hands its solver (default:
    the system's initial state), after the method's ``start`` (Newmark's and generalized-alpha's initial
    acceleration); BDF2's first step is backward Euler's."""
    capture = Capture()
    x = system.x0 if x is None else x
    v = system.v0 if v is None else v
    method = INTEGRATORS[integrator]()
    method.step(system, method.start(system, State(0.0, x, v)), dt, capture)
    return capture.problem, capture.start


def agreeing_sweeps(solver, problem, start, plans, sweep, parts, count: int, tolerance: float = 1e-12):
    """``count`` VBD sweeps from start, each by the numpy sweep (solvers/vbd.py ``_sweep``, the reference) and by the
    system's compiled one from the same iterate, asserted to land on the same positions (to ``tolerance`` of the largest
    move) with the same backtracking rounds and the same residual (the largest |g_i|_inf the vertices met, to
    ``tolerance``); yields (the iterate, numpy's result, its rounds), the next from numpy's result."""
    y = start.copy()
    for _ in range(count):
        numpy_y, numpy_halvings, numpy_residual = solver._sweep(problem, y, plans)
        compiled_y, compiled_halvings, compiled_residual = solver._compiled_sweep(y, plans, sweep, parts)
        scale = np.max(np.abs(numpy_y - y))
        assert scale > 0.0
        np.testing.assert_allclose(compiled_y, numpy_y, rtol=0.0, atol=tolerance * scale)
        assert compiled_halvings == numpy_halvings
        assert numpy_residual > 0.0
        np.testing.assert_allclose(compiled_residual, numpy_residual, rtol=tolerance)
        yield y, numpy_y, numpy_halvings
        y = numpy_y


def sweeps_by_thread_count(solver, start, plans, sweep, parts, sweeps: int = 3) -> list[np.ndarray]:
    """The compiled sweep's result after ``sweeps`` sweeps from start with one numba thread and with two (where there
    are two), numba's count given back after."""
    import numba

    threads = numba.get_num_threads()
    results = []
    try:
        for count in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(count)
            y = start.copy()
            for _ in range(sweeps):
                y, _, _ = solver._compiled_sweep(y, plans, sweep, parts)
            results.append(y)
    finally:
        numba.set_num_threads(threads)
    return results


def compiled_solve_energies(monkeypatch, solver_class, problem, start, **options) -> tuple[np.ndarray, np.ndarray]:
    """(the solution, E at every iterate) of ``solver_class(**options)`` from start with its numpy sweep made to fail:
    what the compiled sweep gives the solver."""

    def numpy_sweep(*args):
        raise AssertionError("the numpy sweep ran")

    monkeypatch.setattr(solver_class, "_sweep", numpy_sweep)
    energies = []
    solver = solver_class(callback=lambda y, g: energies.append(problem.value(y)), **options)
    y, _ = solver.minimize(problem, start)
    return y, np.array(energies)


def cut_and_halved(problem, start, plans, sweeps: int = 4) -> tuple[int, int]:
    """(how many vertices' first Newton steps from start the step filter cuts, the backtracking rounds of ``sweeps``
    numpy sweeps from start): what a comparison of sweeps from start exercises."""
    from simrun.solvers import VertexBlockDescent

    solver = VertexBlockDescent()
    cut = 0
    for plan in plans:
        gradient, hessian = problem.vertex_blocks(start, plan.vertices, "clamp")
        steps = solver._newton_steps(gradient, hessian, plan)
        cut += int((problem.vertex_step_fractions(start, plan.vertices, steps) < 1.0).sum())
    halved, y = 0, start
    for _ in range(sweeps):
        y, halvings, _ = solver._sweep(problem, y, plans)
        halved += halvings
    return cut, halved


def own_step_problem(system, name: str, x, v, dt: float, warmup_steps: int = 0):
    """The problem (and start) of ``name``'s own step: after the method's ``start`` and ``warmup_steps`` Newton-solved
    steps from (x, v) (BDF2 needs one: its first step is backward Euler's), the next step's, captured."""
    integrator = INTEGRATORS[name]()
    state = integrator.start(system, State(0.0, x, v))
    newton = solver_params(type="newton", tolerance=1e-12, max_iterations=50).build()
    for _ in range(warmup_steps):
        state, stats = integrator.step(system, state, dt, newton)
        assert stats.converged
    capture = Capture()
    integrator.step(system, state, dt, capture)
    return capture.problem, capture.start


def stretched_cloth_state(system, stretch: float = 1.1, bulge: float = 0.1, speed: float = 0.3, seed: int = 3):
    """(x, v) of a cloth stretched by ``stretch`` in its plane about its centre, bulged by ``bulge`` (m) as a sine
    sheet, with random velocities of scale ``speed`` (m/s) (zero on pinned dofs): a nonlinear step's start."""
    positions = system.x0.reshape(-1, 3).copy()
    centre = positions.mean(axis=0)
    positions[:, :2] = centre[:2] + stretch * (positions[:, :2] - centre[:2])
    positions[:, 2] = bulge * np.sin(np.pi * positions[:, 0]) * np.sin(np.pi * positions[:, 1])
    v = speed * np.random.default_rng(seed).standard_normal(system.dof_count)
    v[system.fixed_dofs] = 0.0
    return positions.ravel(), v
