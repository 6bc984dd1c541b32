"""Multicolour Gauss-Seidel (solvers/multicolour.py) against its definition: forward Gauss-Seidel on the
matrix ordered by colour, P A P^T.

1. the colouring is proper (no two rows of a colour coupled) and covers every row once;
2. one compiled sweep is scipy's triangular solve of P A P^T's lower triangle;
3. a whole solve is ``gauss_seidel`` (natural order, SuperLU's triangular solves) on P A P^T and P b: the same
   iterations, the same solution to round-off; and it reaches the direct solution;
4. one thread and two give the same solution bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from conftest import step_problem, stretched_cloth_state
from simrun.solvers.dofs import free_dofs
from simrun.solvers.linear import LINEAR_SOLVERS
from simrun.solvers.multicolour import Colouring
from simrun.systems import ClothParams


def cloth_system(resolution=8):
    """The reduced Newton matrix (projected, SPD) and right-hand side of a stretched cloth's backward Euler step."""
    system = ClothParams(resolution=(resolution, resolution), mass=1.0, stretch_stiffness=1e3, shear_stiffness=1e2,
                         bend_stiffness=1.0, pinned=["top_left", "top_right"]).build()
    problem, start = step_problem(system, *stretched_cloth_state(system), 1.0 / 60.0)
    free = free_dofs(system.dof_count, system.fixed_dofs, system.sliding)
    matrix = scipy.sparse.csr_matrix(free.restrict_matrix(problem.hessian(start, project_spd=True)))
    matrix.sort_indices()
    return matrix, free.restrict(-problem.gradient(start))


def test_the_colouring_is_proper_and_covers_every_row_once():
    matrix, _ = cloth_system()
    colouring = Colouring(matrix)
    assert np.array_equal(np.sort(colouring.rows), np.arange(matrix.shape[0]))
    coupled = matrix.tocoo()
    off = coupled.row != coupled.col
    assert not np.any(colouring.colour_of[coupled.row[off]] == colouring.colour_of[coupled.col[off]])
    assert 1 < colouring.count < 40


def test_one_sweep_is_the_triangular_solve_of_the_matrix_in_colour_order():
    matrix, _ = cloth_system()
    colouring = Colouring(matrix)
    ordered = colouring.ordered(matrix)
    expected_order = scipy.sparse.csr_matrix(matrix[colouring.rows][:, colouring.rows])
    assert (ordered != expected_order).nnz == 0  # the gather is P A P^T
    residual = np.random.default_rng(0).standard_normal(matrix.shape[0])
    swept = colouring.forward(ordered, ordered.diagonal(), residual, np.empty_like(residual))
    expected = scipy.sparse.linalg.spsolve_triangular(scipy.sparse.tril(expected_order, format="csr"), residual,
                                                      lower=True)
    np.testing.assert_allclose(swept, expected, rtol=0.0, atol=1e-12 * np.abs(expected).max())


def test_a_solve_is_gauss_seidel_on_the_matrix_in_colour_order_and_reaches_the_direct_solution():
    matrix, rhs = cloth_system()
    everything = free_dofs(matrix.shape[0], [])
    solution, iterations = LINEAR_SOLVERS["multicolour_gauss_seidel"](1e-10, 20000).solve(matrix, rhs, everything, spd=True)
    order = Colouring(matrix).rows
    ordered = scipy.sparse.csr_matrix(matrix[order][:, order])
    natural, natural_iterations = LINEAR_SOLVERS["gauss_seidel"](1e-10, 20000).solve(ordered, rhs[order], everything,
                                                                                      spd=True)
    assert iterations == natural_iterations > 10
    np.testing.assert_allclose(solution[order], natural, rtol=0.0, atol=1e-9 * np.abs(natural).max())
    direct = scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs)
    np.testing.assert_allclose(solution, direct, rtol=0.0, atol=1e-8 * np.abs(direct).max())


def test_one_thread_and_two_give_the_same_solution_bit_for_bit():
    matrix, rhs = cloth_system(24)
    assert np.diff(Colouring(matrix).starts).max() > 64  # colours wide enough to be split between threads
    everything = free_dofs(matrix.shape[0], [])
    threads = numba.get_num_threads()
    results = []
    try:
        for count in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(count)
            results.append(LINEAR_SOLVERS["multicolour_gauss_seidel"](1e-6, 20000).solve(matrix, rhs, everything)[0])
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(results[0], results[-1])
