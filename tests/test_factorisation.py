"""Sparse direct solves keep the symmetric fill-reducing ordering: the paths of solvers/linear.py's
``sparse_lu``, what a run records of them, and the cost of a mesh whose vertices come in no useful order.

A Newton matrix M + h^2 K is symmetric, so SuperLU in symmetric mode (diagonal pivots in the MMD ordering of
A + A^T) factors it with the fill of a Cholesky factor. Partial pivoting, where the matrix is not known to be SPD,
moves pivots off the diagonal and destroys that ordering: on an unstructured mesh it filled L + U twenty times
over. The direct solver now pivots only where a pivot needs it, and says which path each factorisation took.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from conftest import run_one
from simrun.solvers import LINEAR_SOLVERS
from simrun.solvers.dofs import FreeDofs
from simrun.solvers.linear import FACTORISATION_PATHS, INDEFINITE_RESIDUAL, SPLU_PATHS, FactorisationLog, sparse_lu
from simrun.systems.mass_spring.generators import model_source
from simrun.systems.mass_spring.params import MassSpringParams


def _as_transposed(matrix) -> scipy.sparse.csc_matrix:
    matrix = scipy.sparse.csr_matrix(matrix)
    return scipy.sparse.csc_matrix((matrix.data, matrix.indices, matrix.indptr), shape=matrix.shape)


def _relative_residual(matrix, solution, rhs) -> float:
    return float(np.linalg.norm(rhs - matrix @ solution) / np.linalg.norm(rhs))


def _laplacian(n: int) -> scipy.sparse.csr_matrix:
    """The 1-D Dirichlet Laplacian plus identity: SPD, tridiagonal."""
    return scipy.sparse.diags([-np.ones(n - 1), 3.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")


@pytest.mark.parametrize("spd", [True, False])
def test_a_definite_matrix_takes_the_symmetric_path(spd):
    matrix, rhs = _laplacian(40), np.linspace(1.0, 2.0, 40)
    log = FactorisationLog()
    _, solution = sparse_lu(_as_transposed(matrix), spd, rhs, log)
    assert _relative_residual(matrix, solution, rhs) <= 1e-14
    assert log.as_dict() == {"symmetric": 1, "threshold": 0, "colamd": 0} and log.take_step() == 1 and log.take_step() == 0


def _indefinite_tridiagonal(n: int, diagonal: float) -> scipy.sparse.csr_matrix:
    """tridiag(1, diagonal, 1): symmetric, indefinite, nonsingular for even n; every diagonal pivot tiny or zero."""
    return scipy.sparse.diags([np.ones(n - 1), diagonal * np.ones(n), np.ones(n - 1)], [-1, 0, 1], format="csr")


def test_tiny_pivots_are_caught_by_the_residual_and_pivoted_in_the_same_ordering():
    """Diagonal pivots of 1e-12 factor without a zero pivot but lose digits to their growth (relative residual
    1e-5 in symmetric mode): the residual test sends the matrix on, and threshold pivoting solves it to round-off."""
    matrix, rhs = _indefinite_tridiagonal(10, 1e-12), np.arange(1.0, 11.0)
    without_pivots = scipy.sparse.linalg.splu(_as_transposed(matrix), **SPLU_PATHS[0]).solve(rhs, trans="T")
    assert _relative_residual(matrix, without_pivots, rhs) > INDEFINITE_RESIDUAL
    log = FactorisationLog()
    _, solution = sparse_lu(_as_transposed(matrix), False, rhs, log)
    assert _relative_residual(matrix, solution, rhs) <= 1e-15
    assert log.as_dict() == {"symmetric": 0, "threshold": 1, "colamd": 0} and log.take_step() == 2


def test_an_exactly_zero_diagonal_is_pivoted_by_symmetric_mode_itself():
    """SuperLU's symmetric mode takes an off-diagonal pivot where the diagonal one is exactly zero: the symmetric
    path solves tridiag(1, 0, 1) to round-off and nothing more is tried."""
    matrix, rhs = _indefinite_tridiagonal(10, 0.0), np.arange(1.0, 11.0)
    log = FactorisationLog()
    _, solution = sparse_lu(_as_transposed(matrix), False, rhs, log)
    assert _relative_residual(matrix, solution, rhs) <= 1e-15 and log.counts == [1, 0, 0]


def test_colamd_is_the_last_resort_and_a_singular_matrix_raises(monkeypatch):
    """When both symmetric-mode paths fail, COLAMD with partial pivoting factors the matrix; an exactly singular
    matrix fails on every path and raises, which ends the Newton solve as not converged (LINEAR_FAILURES)."""
    splu = scipy.sparse.linalg.splu

    def no_symmetric_mode(matrix, **options):
        if options.get("options", {}).get("SymmetricMode"):
            raise RuntimeError("Factor is exactly singular")
        return splu(matrix, **options)

    matrix, rhs = _laplacian(10), np.ones(10)
    monkeypatch.setattr(scipy.sparse.linalg, "splu", no_symmetric_mode)
    log = FactorisationLog()
    _, solution = sparse_lu(_as_transposed(matrix), True, rhs, log)
    assert _relative_residual(matrix, solution, rhs) <= 1e-14 and log.as_dict()["colamd"] == 1
    monkeypatch.setattr(scipy.sparse.linalg, "splu", splu)
    singular = scipy.sparse.csr_matrix(np.array([[1.0, 1.0], [1.0, 1.0]]))
    with pytest.raises(RuntimeError):
        sparse_lu(_as_transposed(singular), False, np.ones(2))


def test_the_direct_solver_counts_its_paths_into_its_log():
    solver = LINEAR_SOLVERS["direct"]()
    solver.log = FactorisationLog()
    matrix = _laplacian(30)
    solution, iterations = solver.solve(matrix, np.ones(30), FreeDofs(30, np.array([0, 29])), spd=False)
    assert iterations == 1 and solution[0] == solution[29] == 0.0
    assert solver.log.counts == [1, 0, 0]


CLOTH = {"type": "mass_spring", "model": {"grid": {"resolution": [10, 10], "size": [1.0, 1.0]}},
         "stiffness": {"stretch": 8000.0, "shear": 800.0, "bend": 10.0}, "pinned": [0, 9]}


def test_a_run_records_the_path_of_each_step_and_counts_them():
    """A Newton run on the cloth (raw Hessian, not known to be SPD): one factorisation per Newton iteration, every
    one on the symmetric path; factorisation_path per step is 1 on every step that factored."""
    result = run_one(CLOTH, "backward_euler", 0.02, 0.2, solver={"type": "newton", "tolerance": 1e-9})
    assert result.status == "ok"
    counts = {path: result.attrs[f"factorisations_{path}"] for path in FACTORISATION_PATHS}
    assert counts["symmetric"] == int(result.per_step["linear_iterations"].sum()) > 0
    assert counts["threshold"] == counts["colamd"] == 0
    assert np.array_equal(result.per_step["factorisation_path"], (result.per_step["linear_iterations"] > 0).astype(np.int8))


def test_an_iterative_linear_solver_or_a_small_system_records_no_path():
    assert "factorisation_path" not in run_one(CLOTH, "backward_euler", 0.02, 0.06,
                                               solver={"type": "newton", "linear_solver": "cg"}).per_step
    spring = run_one({"type": "spring_mass"}, "backward_euler", 0.01, 0.05)
    assert "factorisation_path" not in spring.per_step and "factorisations_symmetric" not in spring.attrs


def _newton_matrix(model, dt: float = 0.01):
    """M + dt^2 H at a crumpled state of the mass-spring model ``model`` (free of pins), and its system."""
    system = MassSpringParams(type="mass_spring", model=model, stiffness={"stretch": 8000.0, "shear": 800.0, "bend": 10.0},
                              gravity=[0.0, 0.0, -9.81]).build()
    x = system.x0 + 0.01 * np.sin(np.arange(system.dof_count))
    mass = scipy.sparse.diags(np.repeat(system.vertex_masses, system.dim))
    return (mass + dt * dt * system.hessian(x)).tocsr()


def test_a_shuffled_grid_factors_with_the_fill_of_the_ordered_one(tmp_path):
    """The 24 x 24 grid cloth, its vertices shuffled (the order of a scanned or exported mesh): the direct solver's
    factor of its Newton matrix holds at most 1.5x the entries of the ordered grid's (measured 0.99x: MMD finds an
    ordering as good), where partial pivoting in that ordering fills 4.3x as many (the cost of a factorisation
    grows faster than its fill; make bench times both on a 2,930-vertex mesh)."""
    grid = model_source({"grid": {"resolution": [24, 24], "size": [1.0, 1.0]}}).build()
    order = np.random.default_rng(7).permutation(len(grid.vertices))
    position = np.argsort(order)  # new index of each old vertex
    shuffled = tmp_path / "shuffled.npz"
    np.savez(shuffled, vertices=grid.vertices[order], springs=position[grid.springs], kinds=grid.kinds,
             kind_names=np.array(grid.kind_names), triangles=position[grid.triangles])
    fills = {}
    for name, model in (("ordered", {"grid": {"resolution": [24, 24], "size": [1.0, 1.0]}}), ("shuffled", str(shuffled))):
        matrix = _newton_matrix(model)
        factor, solution = sparse_lu(_as_transposed(matrix), False, np.ones(matrix.shape[0]))
        assert _relative_residual(matrix, solution, np.ones(matrix.shape[0])) <= INDEFINITE_RESIDUAL
        fills[name] = factor.L.nnz + factor.U.nnz
        if name == "shuffled":
            pivoting = scipy.sparse.linalg.splu(_as_transposed(matrix), permc_spec="MMD_AT_PLUS_A")
            fills["pivoting"] = pivoting.L.nnz + pivoting.U.nnz
    assert fills["shuffled"] <= 1.5 * fills["ordered"], fills
    assert fills["pivoting"] > 1.5 * fills["shuffled"], fills  # what partial pivoting in the MMD ordering costs
