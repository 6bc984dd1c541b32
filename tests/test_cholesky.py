"""The optional `cholesky` linear solver (CHOLMOD through scikit-sparse).

What must hold: it solves the same systems as `direct` to round-off; the symbolic analysis runs once
per sparsity pattern (once per run on the cloth) and every further solve only refactors; an
indefinite matrix still gets the right solution (LU); dense matrices work; and without the package
a config that asks for it is refused before anything runs, with one line that says how to install
it. The last test runs everywhere; the others need the package (skipped without it, failed in CI,
which sets SIMRUN_REQUIRE_CHOLMOD=1).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from conftest import needs_linear_solver, run_one
from simrun.execution.workers import BLAS_THREAD_VARIABLES
from simrun.solvers import LINEAR_SOLVERS
from simrun.solvers.dofs import free_dofs
from simrun.systems import ClothParams

needs_cholmod = needs_linear_solver("cholesky")
CLOTH = dict(resolution=(8, 8), mass=1.0, stretch_stiffness=1e3, shear_stiffness=1e2, bend_stiffness=1.0,
             damping=0.2, pinned=["top_left", "top_right"])


def cholesky_solver():
    return LINEAR_SOLVERS["cholesky"]()


def cloth_newton_matrix(seed: int = 0, resolution=(8, 8)):
    """M + h^2 K (projected) of a crumpled cloth: the matrix of a backward Euler Newton iteration."""
    system = ClothParams(**{**CLOTH, "resolution": resolution}).build()
    rng = np.random.default_rng(seed)
    x = system.x0 + 0.02 * rng.standard_normal(system.dof_count)
    system.gradient(x)
    stiffness = system.hessian(x, project_spd=True)
    matrix = (scipy.sparse.diags(system.mass) + 1e-4 * stiffness).tocsr()
    return system, matrix, rng.standard_normal(system.dof_count)


class CountingCholmod:
    """Stands in for the sksparse.cholmod module: counts analyses and numeric factorisations."""

    def __init__(self, module):
        self.module = module
        self.CholmodNotPositiveDefiniteError = module.CholmodNotPositiveDefiniteError
        self.analyses = 0
        self.factorisations = 0

    def analyze(self, matrix):
        self.analyses += 1
        return CountingFactor(self, self.module.analyze(matrix))


class CountingFactor:
    def __init__(self, counter, factor):
        self.counter, self.factor = counter, factor

    def cholesky_inplace(self, matrix):
        self.counter.factorisations += 1
        return self.factor.cholesky_inplace(matrix)

    def solve_A(self, rhs):
        return self.factor.solve_A(rhs)


@pytest.mark.parametrize("pinned", [[], ["top_left", "top_right"]])
@needs_cholmod
def test_cholesky_matches_the_direct_solve_on_a_cloth_newton_matrix(pinned):
    system, matrix, rhs = cloth_newton_matrix()
    free = free_dofs(system.dof_count, system.fixed_dofs if pinned else [])
    solution, iterations = cholesky_solver().solve(matrix, rhs, free, spd=True)
    reference, _ = LINEAR_SOLVERS["direct"]().solve(matrix, rhs, free, spd=True)
    assert iterations == 1
    assert np.all(solution[free.fixed] == 0.0)
    reduced = free.restrict_matrix(matrix)
    residual = free.restrict(rhs) - reduced @ free.restrict(solution)
    assert np.linalg.norm(residual) <= 1e-12 * np.linalg.norm(free.restrict(rhs))
    assert np.abs(solution - reference).max() <= 1e-12 * np.abs(reference).max()


@needs_cholmod
def test_the_pattern_is_analysed_once_and_refactored_per_solve():
    """Three matrices of one pattern with other values: one analysis, three factorisations, all exact;
    a matrix of another pattern (other pins) is analysed anew."""
    solver = cholesky_solver()
    counting = solver._cholmod = CountingCholmod(solver._cholmod)
    for seed in range(3):
        system, matrix, rhs = cloth_newton_matrix(seed)
        free = free_dofs(system.dof_count, system.fixed_dofs)
        solution, _ = solver.solve(matrix, rhs, free, spd=True)
        expected = scipy.sparse.linalg.spsolve(free.restrict_matrix(matrix).tocsc(), free.restrict(rhs))
        assert np.allclose(free.restrict(solution), expected, rtol=1e-11, atol=0)
    assert (counting.analyses, counting.factorisations) == (1, 3)
    solution, _ = solver.solve(matrix, rhs, free_dofs(system.dof_count, []), spd=True)
    assert np.allclose(solution, scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs), rtol=1e-11, atol=0)
    assert (counting.analyses, counting.factorisations) == (2, 4)


@needs_cholmod
def test_a_cloth_run_analyses_once_and_matches_the_direct_run(monkeypatch):
    """Backward Euler with Newton on a damped hanging cloth: the same trajectory as `direct` (to the
    Newton tolerance), and one analysis for the whole run however many iterations it takes."""
    import sksparse.cholmod

    counting = CountingCholmod(sksparse.cholmod)
    monkeypatch.setattr("simrun.solvers.linear.cholmod_module", lambda: counting)
    options = dict(system={"type": "cloth", **CLOTH}, integrator="backward_euler", dt=0.01, duration=0.2)
    direct = run_one(**options, solver={"type": "newton", "tolerance": 1e-10, "linear_solver": "direct"})
    cholesky = run_one(**options, solver={"type": "newton", "tolerance": 1e-10, "linear_solver": "cholesky"})
    assert direct.status == cholesky.status == "ok"
    assert np.abs(cholesky.samples["frames"] - direct.samples["frames"]).max() < 1e-9
    assert np.array_equal(cholesky.per_step["newton_iterations"], direct.per_step["newton_iterations"])
    assert counting.analyses == 1
    assert counting.factorisations == int(cholesky.per_step["linear_iterations"].sum()) > 20


@needs_cholmod
@pytest.mark.parametrize("resolution", [(8, 8), (24, 24)], ids=["simplicial-LDLt", "supernodal-LLt"])
def test_an_indefinite_matrix_is_solved_exactly(resolution):
    """Plain Newton may hand over an indefinite Hessian (spd=False). CHOLMOD's supernodal LL^T (large
    matrices) refuses it and the LU solves; its simplicial LDL^T (small ones) factors it. Either way
    the solution is exact, also on the second solve with the same pattern."""
    system, matrix, rhs = cloth_newton_matrix(resolution=resolution)
    shift = matrix.diagonal().mean()  # pushes part of the spectrum below zero
    indefinite = (matrix - shift * scipy.sparse.identity(matrix.shape[0])).tocsr()
    free = free_dofs(system.dof_count, [])
    solver = cholesky_solver()
    counting = solver._cholmod = CountingCholmod(solver._cholmod)
    for _ in range(2):
        solution, iterations = solver.solve(indefinite, rhs, free, spd=False)
        assert iterations == 1
        assert np.linalg.norm(indefinite @ solution - rhs) <= 1e-9 * np.linalg.norm(rhs)
    # the definite matrix of the same pattern afterwards: exact, and the analysis was kept
    solution, _ = solver.solve(matrix, rhs, free, spd=True)
    assert np.linalg.norm(matrix @ solution - rhs) <= 1e-12 * np.linalg.norm(rhs)
    assert (counting.analyses, counting.factorisations) == (1, 3)


@needs_cholmod
def test_a_non_symmetric_matrix_falling_back_to_lu_is_not_transposed():
    """The LU fallback solves A p = b, not A^T p = b (the CSR arrays read as CSC are A^T):
    [[0, 1], [2, 0]] p = (2, 3) gives p = (1.5, 2)."""
    matrix = scipy.sparse.csr_matrix(np.array([[0.0, 1.0], [2.0, 0.0]]))
    solution, _ = cholesky_solver().solve(matrix, np.array([2.0, 3.0]), free_dofs(2, []), spd=False)
    assert np.allclose(solution, [1.5, 2.0], rtol=1e-15, atol=0)


@needs_cholmod
@pytest.mark.parametrize("first_pivot", [0.0, 1e-20], ids=["zero-pivot", "tiny-pivot"])
def test_a_failed_ldlt_falls_back_to_lu(first_pivot):
    """[[p, 1], [1, 0]]: with p = 0 CHOLMOD refuses the LDL^T; with p = 1e-20 it factors it and the
    solve loses everything to cancellation (it returns (0, 2)), which the residual test catches. The
    LU solves both exactly: x = (3, 2 - 3 p)."""
    matrix = scipy.sparse.csr_matrix(np.array([[first_pivot, 1.0], [1.0, 0.0]]))
    solution, _ = cholesky_solver().solve(matrix, np.array([2.0, 3.0]), free_dofs(2, []), spd=False)
    assert np.allclose(solution, [3.0, 2.0 - 3.0 * first_pivot], rtol=1e-15, atol=0)


@needs_cholmod
def test_dense_systems_take_the_lapack_path():
    """The small systems' Newton matrices are dense 1x1 to 3x3 arrays: solved exactly, one iteration."""
    kepler = run_one({"type": "circular_motion", "force": "gravity"}, "implicit_midpoint", 0.05, 2.0,
                     solver={"type": "newton", "linear_solver": "cholesky"})
    reference = run_one({"type": "circular_motion", "force": "gravity"}, "implicit_midpoint", 0.05, 2.0,
                        solver={"type": "newton", "linear_solver": "direct"})
    assert kepler.status == "ok"
    assert np.array_equal(kepler.samples["positions"], reference.samples["positions"])


def test_a_missing_cholmod_is_refused_before_anything_runs(tmp_path):
    """Without scikit-sparse (hidden here from a fresh interpreter), `linear_solver: cholesky` is one
    error line naming the field and the way to install it, exit status 2, and no output folder."""
    config = tmp_path / "cholesky.yaml"
    config.write_text(textwrap.dedent("""\
        name: cholesky
        system: {type: cloth, resolution: [4, 4]}
        integrators: [backward_euler]
        solver: {type: newton, linear_solver: cholesky}
        duration: 0.05
        sweep: {dt: [0.01]}
        """))
    hide = "import sys; sys.modules['sksparse'] = None; from simrun.cli import main; sys.exit(main(sys.argv[1:]))"
    result = subprocess.run([sys.executable, "-c", hide, str(config), "--output", str(tmp_path / "out")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert lines[0].startswith("simrun: error: solver.linear_solver: cholesky needs CHOLMOD")
    assert "libsuitesparse-dev" in lines[0] and ".[cholmod]" in lines[0]
    assert not (tmp_path / "out").exists()
    built = subprocess.run([sys.executable, "-c", "import sys; sys.modules['sksparse'] = None\n"
                            "from simrun.solvers import LINEAR_SOLVERS; LINEAR_SOLVERS['cholesky']()"],
                           capture_output=True, text=True, timeout=60)  # the solver itself says the same
    assert built.returncode != 0 and "ImportError: cholesky needs CHOLMOD" in built.stderr


@needs_cholmod
def test_loading_cholmod_holds_the_earlier_blas_libraries_at_one_thread():
    """numpy's bundled OpenBLAS (loaded first) gets one thread, so that its spinning idle threads
    leave the cores to CHOLMOD's BLAS, which keeps its default thread count (one per core)."""
    script = ("import json, numpy, threadpoolctl\n"
              "from simrun.solvers.linear import cholmod_module\n"
              "before = [lib['filepath'] for lib in threadpoolctl.threadpool_info() if lib['user_api'] == 'blas']\n"
              "cholmod_module()\n"
              "print(json.dumps([before, threadpoolctl.threadpool_info()]))\n")
    environment = {key: value for key, value in os.environ.items() if key not in BLAS_THREAD_VARIABLES}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                            env=environment, check=True)
    before, after = json.loads(result.stdout)
    blas = {lib["filepath"]: lib["num_threads"] for lib in after if lib["user_api"] == "blas"}
    assert before and all(blas[path] == 1 for path in before)
    cholmod_blas = set(blas) - set(before)
    assert cholmod_blas, "CHOLMOD's BLAS should be a library of its own"
    assert all(blas[path] == len(os.sched_getaffinity(0)) for path in cholmod_blas)
