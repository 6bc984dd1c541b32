"""Vertex block descent's compiled colour sweep (systems/mass_spring/vbd_kernels.py) against the numpy sweep
it replaces for mass-spring systems (solvers/vbd.py ``_sweep``, kept as the reference here):

1. one sweep from the same iterate lands on the same positions (to 1e-12 of the largest move) and takes the same
   backtracking rounds, for each spring law and projection, with spring damping, pins, sliding planes and lines, in
   2-D and 3-D, from a stretched start (full Newton steps) and a compressed one (indefinite springs, halvings);
2. the same sweep with one thread and with two is the same, bit for bit;
3. the solver takes the compiled sweep wherever the system offers it, and E never increases along its iterations.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from conftest import (agreeing_sweeps, compiled_solve_energies, step_problem, stretched_cloth_state,
                      sweeps_by_thread_count)
from simrun.solvers import VertexBlockDescent
from simrun.solvers.dofs import free_dofs
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.solvers.vbd import IncrementalParts, colour_plans
from simrun.systems import ClothParams
from simrun.systems.mass_spring.params import MassSpringParams


def damped_constrained(law: str):
    """A 4 x 4 grid with spring damping, a pin, a sliding plane (oblique) and a sliding line, spinning."""
    return MassSpringParams(
        model={"grid": {"resolution": [4, 4], "size": [0.3, 0.3]}}, spring_law=law,
        stiffness={"stretch": 60.0, "shear": 10.0, "bend": 1.0}, mass={"total": 0.2},
        damping=[{"model": "spring", "coefficient": 0.02}], pinned=[12],
        constraints=[{"vertices": [0], "normal": [0.3, -0.5, 0.8]}, {"vertices": [5], "direction": [1.0, 2.0, -0.5]}],
        initial={"spin": [0.2, 0.5, 1.0]}).build()


def square_2d(law: str):
    """The course's 2-D square (4 segments), pinned at one corner, with drag-free spring damping."""
    return MassSpringParams(model={"square": {"segments": 4, "size": 1.0}}, spring_law=law, stiffness=500.0,
                            mass={"per_vertex": 0.1}, gravity=[0.0, -9.81], pinned=[0],
                            damping=[{"model": "spring", "coefficient": 0.05}], initial={"velocity": [0.3, -0.2]}).build()


def compressed(system):
    """The system squeezed to 60 % about its centre with a little noise: springs compressed, raw blocks indefinite."""
    positions = system.x0.reshape(-1, system.dim).copy()
    centre = positions.mean(axis=0)
    positions = centre + 0.6 * (positions - centre)
    positions += 0.01 * np.random.default_rng(1).standard_normal(positions.shape)
    return positions.ravel(), np.zeros(system.dof_count)


def _cases():
    """(build, start state, dt, backtracks: the numpy sweep halves some steps within four sweeps, clamped)."""
    for law in ("hookean", "squared_length"):
        backtracks = law == "squared_length"  # the Hookean blocks, projected and with inertia, take full steps here
        yield pytest.param(lambda law=law: damped_constrained(law), None, 0.02, False, id=f"grid-{law}")
        yield pytest.param(lambda law=law: damped_constrained(law), compressed, 0.05, backtracks,
                           id=f"grid-{law}-compressed")
        yield pytest.param(lambda law=law: square_2d(law), compressed, 0.05, False, id=f"square2d-{law}-compressed")
    cloth = ClothParams(resolution=(6, 6), mass=1.0, stretch_stiffness=200.0, shear_stiffness=50.0, bend_stiffness=5.0,
                        damping=0.5, pinned=["top_left", "top_right"])
    yield pytest.param(cloth.build, stretched_cloth_state, 0.02, False, id="cloth-stretched")


def sweeps(build, start_state, dt, projection):
    system = build()
    x, v = (system.x0, system.v0) if start_state is None else start_state(system)
    problem, start = step_problem(system, x, v, dt)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding),
                         system.dim)
    solver = VertexBlockDescent(spd_projection=projection)
    return system, problem, start, plans, solver


@pytest.mark.parametrize("projection", ["clamp", "abs"])
@pytest.mark.parametrize("build, start_state, dt, backtracks", list(_cases()))
def test_the_compiled_sweep_is_the_numpy_sweep(build, start_state, dt, backtracks, projection):
    system, problem, start, plans, solver = sweeps(build, start_state, dt, projection)
    sweep = system.vertex_form().sweep()
    assert sweep is not None
    parts = IncrementalParts.of(problem)
    assert (parts.damping_weight > 0.0) == (problem.damping is not None)
    # a few sweeps: the later ones start where the constrained and damped terms matter
    halvings_seen = sum(halvings for _, _, halvings in agreeing_sweeps(solver, problem, start, plans, sweep, parts, 4))
    if backtracks and projection == "clamp":  # mirrored, the blocks took full steps from this start too
        assert halvings_seen > 0, "this start must exercise the backtracking"


def test_one_thread_and_two_give_the_same_sweep_bit_for_bit():
    system = ClothParams(resolution=(24, 24), mass=1.0, stretch_stiffness=1e4, shear_stiffness=1e3, bend_stiffness=10.0,
                         damping=0.2, pinned=["top_left", "top_right"]).build()
    problem, start = step_problem(system, *stretched_cloth_state(system), 1.0 / 60.0)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding), 3)
    assert max(plan.vertices.size for plan in plans) > 64, "a colour must span several chunks"
    solver, sweep, parts = VertexBlockDescent(), system.vertex_form().sweep(), IncrementalParts.of(problem)
    results = sweeps_by_thread_count(solver, start, plans, sweep, parts)
    assert np.array_equal(results[0], results[-1])


def test_the_solver_takes_the_compiled_sweep_and_the_energy_never_increases(monkeypatch):
    """The compressed grid (squared-length springs, damping, constraints): every iteration goes through the compiled
    sweep, never the numpy one, and E(y_k) does not increase beyond its round-off."""
    system = damped_constrained("squared_length")
    problem, start = step_problem(system, *compressed(system), 0.05)

    _, energies = compiled_solve_energies(monkeypatch, VertexBlockDescent, problem, start, tolerance=1e-10,
                                          max_iterations=80)
    assert energies.size > 10
    assert np.all(np.diff(energies) <= ENERGY_ROUNDOFF * np.abs(energies[:-1]))
    assert energies[-1] < energies[0]


def _threaded_run(threads: int):
    from simrun.execution.simulate import simulate
    from simrun.experiment.config import load_experiment
    from simrun.experiment.sweep import expand_runs

    config = {"name": "threads", "system": {"type": "cloth", "resolution": [20, 20], "stretch_stiffness": 1e4,
                                            "shear_stiffness": 1e3, "bend_stiffness": 10.0, "damping": 0.0},
              "integrators": ["backward_euler"], "duration": 0.1, "sweep": {"dt": [1.0 / 60.0]},
              "solver": {"type": "vbd", "tolerance": 1e-300, "max_iterations": 20, "on_not_converged": "accept",
                         "threads": threads},
              "record": {"frames_every": 1}}
    return simulate(expand_runs(load_experiment(config)[0])[0])


def test_a_run_records_its_threads_and_does_not_depend_on_them():
    one, two = _threaded_run(1), _threaded_run(2)
    assert one.status == two.status == "ok"
    assert one.attrs["threads"] == 1 and two.attrs["threads"] == min(2, numba.config.NUMBA_NUM_THREADS)
    assert np.array_equal(one.samples["frames"], two.samples["frames"])


def test_threads_above_the_cores_are_capped_with_a_warning_and_below_one_refused():
    import os

    from simrun.errors import ConfigError
    from simrun.experiment.config import load_experiment
    from simrun.solvers import solver_params
    from simrun.solvers.params import ThreadsWarning

    cores = os.cpu_count() or 1
    with pytest.warns(ThreadsWarning, match=f"solver.threads: {cores + 7} is more than this machine's {cores} cores"):
        params = solver_params(type="vbd", threads=cores + 7)
    assert params.threads == cores
    with pytest.raises(ConfigError, match="solver.threads"):
        load_experiment({"name": "bad", "system": {"type": "cloth", "resolution": [3, 3]}, "integrators": ["backward_euler"],
                         "solver": {"type": "vbd", "threads": 0}, "sweep": {"dt": [0.01]}})


@pytest.mark.parametrize("method, solver, one_thread", [
    ("backward_euler", "vbd", True),
    ({"type": "xpbd", "substeps": 2}, "newton", True),
    ("backward_euler", "newton", False),
    ("backward_euler", {"type": "vbd", "fallback": ["newton"]}, False),
])
def test_a_run_on_numbas_threads_holds_blas_at_one_and_gives_the_threads_back(monkeypatch, method, solver, one_thread):
    """OpenBLAS's threads, woken by a long vector's ddot, spin against the compiled sweeps' and projections' threads
    (docs/performance.md): a vbd or xpbd run holds BLAS at one thread throughout, a run whose solver may factorise
    (newton, or a chain that falls back to it) keeps the threads it has, and each leaves them as it found them."""
    import threadpoolctl

    from simrun.execution.simulate import simulate
    from simrun.experiment.config import load_experiment
    from simrun.experiment.sweep import expand_runs
    from simrun.integrators import INTEGRATORS

    def blas_threads():
        return max(library["num_threads"] for library in threadpoolctl.threadpool_info() if library["user_api"] == "blas")

    seen = []
    kind = INTEGRATORS[method if isinstance(method, str) else method["type"]]
    original = kind.step

    def watched_step(self, *args):
        seen.append(blas_threads())
        return original(self, *args)

    monkeypatch.setattr(kind, "step", watched_step)
    solver = {"type": solver} if isinstance(solver, str) else solver
    config = {"name": "blas", "system": {"type": "cloth", "resolution": [4, 4], "pinned": ["top_left", "top_right"]},
              "integrators": [method], "duration": 0.03, "sweep": {"dt": [0.01]},
              "solver": {**solver, "max_iterations": 5, "on_not_converged": "accept"}}
    (run,) = expand_runs(load_experiment(config)[0])
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        assert simulate(run).status == "ok"
        after = blas_threads()
    assert len(seen) == 3 and set(seen) == ({1} if one_thread else {before})
    assert after == before
