"""Projective dynamics, its Chebyshev acceleration and L-BFGS with the rest-shape initial Hessian.

For Hookean springs, projective dynamics (PD) is y_{k+1} = y_k - A^{-1} grad E(y_k) with the constant
A = M + s K_r (+ (s/b) D) (Liu, Bouaziz & Kavan 2017, sec. 3), so the tests check it against theory:
its fixed point is the minimiser of the incremental potential (the step Newton finds, to the bound
|y - y*|_2 <= |g(y)|_2 / mu of a strongly convex problem); E never increases along plain iterations
(each local-global pair minimises an upper bound of E that touches it at y_k, Liu et al. 2013); on a linear
system A is the Hessian, so one iteration is exact; Chebyshev acceleration (Wang 2015) shortens the
iteration; and the problems PD cannot express are refused in one line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

from conftest import run_one, step_problem
import simrun.solvers.projective as projective
from simrun.experiment.config import load_experiment
from simrun.integrators import INTEGRATORS, State
from simrun.solvers import LBFGS, Newton, ProjectiveDynamics, SolverOptionError, refusal, solver_params, solver_refusal
from simrun.solvers.dofs import FreeDofs
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.systems import CircularMotionParams, ClothParams, SpringMassParams
from simrun.systems.mass_spring.params import MassSpringParams

CLOTH_HANG = Path(__file__).parent.parent / "configs" / "cloth_hang.yaml"
REFERENCE_TOLERANCE = 1e-12  # Newton's, for the reference step y*


def cloth_hang(**overrides):
    """The system of configs/cloth_hang.yaml (12x12, stretch 1e4, shear 1e3, bend 10, pinned top corners)."""
    params = load_experiment(CLOTH_HANG)[0].system
    return ClothParams(**{**params.model_dump(), **overrides}).build()


def assert_reaches_the_newton_step(system, problem, start, y, stats):
    """|y - y*|_2 <= |g(y)|_2 / mu (mu: smallest eigenvalue of the free block of the Hessian at y*, with 2x
    room for its change between y and y*), and y keeps the fixed dofs where they started."""
    reference, reference_stats = Newton(tolerance=REFERENCE_TOLERANCE, max_iterations=50).minimize(problem, start)
    assert reference_stats.converged
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    hessian = problem.hessian(reference)
    dense = hessian.toarray() if scipy.sparse.issparse(hessian) else np.asarray(hessian)
    gradient = problem.gradient(y)
    if system.sliding is None:
        mu = np.linalg.eigvalsh(dense[np.ix_(free, free)]).min()
    else:  # on the allowed directions only: Z^T H Z, Z an orthonormal basis of the range of the filter S
        basis = allowed_basis(system)
        mu = np.linalg.eigvalsh(basis.T @ dense @ basis).min()
    assert mu > 0, "the step must be strictly convex, so that y* is unique"
    assert stats.converged, stats
    assert np.linalg.norm(y - reference) <= 2.0 * np.linalg.norm(gradient) / mu + 1e-13
    assert np.array_equal(y[system.fixed_dofs], start[system.fixed_dofs])
    return reference


def allowed_basis(system) -> np.ndarray:
    """An orthonormal basis of the directions the fixed dofs and sliding filters allow: the range of S."""
    filter_matrix = np.empty((system.dof_count, system.dof_count))
    for column in range(system.dof_count):
        unit = np.zeros(system.dof_count)
        unit[column] = 1.0
        unit[system.fixed_dofs] = 0.0
        filter_matrix[:, column] = system.sliding.apply(unit)
    values, vectors = np.linalg.eigh(0.5 * (filter_matrix + filter_matrix.T))
    return vectors[:, values > 0.5]


# ------------------------------------------------------------------------------------------------
# PD reaches the backward Euler step
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dt", [0.01, 0.02])
@pytest.mark.parametrize("options, tolerance", [({}, 1e-5), ({"chebyshev_rho": 0.999, "relaxation": 0.9}, 1e-9)],
                         ids=["plain", "chebyshev"])
def test_pd_reaches_the_newton_step_of_the_hanging_cloth(dt, options, tolerance):
    """One backward Euler step of cloth_hang from a swinging state (after 3 steps): PD's fixed point is the
    minimiser of the incremental potential, which Newton finds to 1e-12."""
    system = cloth_hang()
    x, v = system.x0, system.v0
    for _ in range(3):
        problem, start = step_problem(system, x, v, dt)
        y, _ = Newton(tolerance=1e-10).minimize(problem, start)
        x, v = y, (y - x) / dt
    problem, start = step_problem(system, x, v, dt)
    y, stats = ProjectiveDynamics(tolerance=tolerance, max_iterations=40000, **options).minimize(problem, start)
    assert stats.residual <= tolerance * np.abs(problem.gradient(start)).max()
    assert stats.linear_iterations == stats.iterations  # one back-substitution per iteration
    assert_reaches_the_newton_step(system, problem, start, y, stats)


PLANE_NORMAL = [0.3, -0.5, 0.8]
LINE_DIRECTION = [1.0, 0.4, -0.7]
# a 5x4 grid with a pin, oblique and axis-aligned sliders, and damping that does not depend on x (relative:
# -k_d (v_i - v_j) per spring), which A = M + s K_r + (s/b) D then holds exactly
CONSTRAINED = {"model": {"grid": {"resolution": [5, 4], "size": [0.4, 0.3]}},
               "stiffness": {"stretch": 200.0, "shear": 50.0, "bend": 2.0}, "mass": {"total": 0.1},
               "damping": [{"model": "relative", "coefficient": 0.05}], "pinned": [15],
               "constraints": [{"vertices": [19], "normal": PLANE_NORMAL}, {"vertices": [0, 1], "direction": LINE_DIRECTION},
                               {"vertices": [10], "normal": [1.0, 0.0, 0.0]}],
               "initial": {"velocity": [0.1, 0.2, -0.3], "spin": [0.3, 0.2, 1.0]}}


@pytest.mark.parametrize("solver", [ProjectiveDynamics(tolerance=1e-9, max_iterations=5000),
                                    ProjectiveDynamics(tolerance=1e-9, max_iterations=5000, chebyshev_rho="auto"),
                                    LBFGS(tolerance=1e-9, max_iterations=500, initial_hessian="rest")],
                         ids=["pd", "pd-auto", "lbfgs-rest"])
def test_pinned_and_sliding_vertices_reach_the_constrained_newton_step(solver):
    """A backward Euler step of a damped cloth with a pin and vertices sliding on planes and lines: the
    free block of A, filtered as S A S + (I - S), gives the minimiser on the allowed directions, the one
    Newton finds; sliding vertices move along their planes and lines only."""
    system = MassSpringParams(type="mass_spring", **CONSTRAINED).build()
    assert system.sliding is not None and system.fixed_dofs.size > 0 and system.projective_form().inexact is None
    problem, start = step_problem(system, dt=0.01)
    start = problem.start_point(start)
    y, stats = solver.minimize(problem, start)
    assert_reaches_the_newton_step(system, problem, start, y, stats)
    moved = (y - start).reshape(-1, 3)
    normal = np.array(PLANE_NORMAL) / np.linalg.norm(PLANE_NORMAL)
    direction = np.array(LINE_DIRECTION) / np.linalg.norm(LINE_DIRECTION)
    assert abs(moved[19] @ normal) <= 1e-14 and moved[10, 0] == 0.0
    assert np.abs(moved[[0, 1]] - np.outer(moved[[0, 1]] @ direction, direction)).max() <= 1e-14
    assert np.abs(moved[[0, 1, 10, 19]]).max() > 1e-5, "the sliding vertices must move"


def test_the_constrained_pd_step_is_the_global_solve_on_the_allowed_directions():
    """PD's first step with pins and sliders is the global step restricted to the allowed directions Z:
    p = -Z (Z^T A Z)^{-1} Z^T g, what the filtered matrix S A S + (I - S) on the free dofs solves."""
    system = MassSpringParams(type="mass_spring", **CONSTRAINED).build()
    problem, start = step_problem(system, dt=0.01)
    start = problem.start_point(start)
    iterates = []
    ProjectiveDynamics(max_iterations=1, callback=lambda y, g: iterates.append(y.copy())).minimize(problem, start)
    basis = allowed_basis(system)
    matrix = problem.rest_hessian().toarray()
    exact = -basis @ np.linalg.solve(basis.T @ matrix @ basis, basis.T @ problem.gradient(start))
    step = iterates[1] - start
    assert np.abs(step - exact).max() <= 1e-12 * np.abs(exact).max()


# ------------------------------------------------------------------------------------------------
# Properties of the iteration
# ------------------------------------------------------------------------------------------------
def compressed_and_stretched_cloth_step():
    """A cloth squeezed to 0.6 of its width and stretched to 1.3 of its height, with noise out of its plane and
    random velocities: springs far from their rest lengths both ways."""
    system = ClothParams(resolution=(8, 8), mass=0.2, stretch_stiffness=500.0, shear_stiffness=100.0, bend_stiffness=5.0,
                         pinned=["top_left", "top_right"]).build()
    rng = np.random.default_rng(4)
    positions = system.x0.reshape(-1, 3).copy()
    centre = positions.mean(axis=0)
    positions[:, :2] = centre[:2] + np.array([0.6, 1.3]) * (positions[:, :2] - centre[:2])
    positions[:, 2] = 0.02 * rng.standard_normal(len(positions))
    v = rng.standard_normal(system.dof_count)
    v[system.fixed_dofs] = 0.0
    problem, start = step_problem(system, positions.ravel(), v, dt=0.02)
    return problem, start


@pytest.mark.parametrize("options", [{}, {"relaxation": 0.5}, {"chebyshev_rho": 0.99, "chebyshev_warmup": 3}],
                         ids=["plain", "relaxed", "chebyshev-checked"])
def test_pd_never_increases_the_incremental_potential(options):
    """E(y_{k+1}) <= E(y_k) (to the round-off of E) at every iteration: a plain local-global pair minimises an
    upper bound of E that touches it at y_k, an under-relaxed one moves to a convex combination, and an
    accelerated update that would raise E is replaced by a plain step."""
    problem, start = compressed_and_stretched_cloth_step()
    energies = []
    solver = ProjectiveDynamics(tolerance=1e-10, max_iterations=300, callback=lambda y, g: energies.append(problem.value(y)),
                                **options)
    solver.minimize(problem, start)
    energies = np.array(energies)
    assert energies.size > 100
    assert np.all(np.diff(energies) <= ENERGY_ROUNDOFF * np.abs(energies[:-1]))
    assert energies[-1] < energies[0] - 0.5 * abs(energies[0])


@pytest.mark.parametrize("solver", [ProjectiveDynamics(), LBFGS(initial_hessian="rest"), LBFGS(initial_hessian="scaled_rest")],
                         ids=["pd", "lbfgs-rest", "lbfgs-scaled-rest"])
@pytest.mark.parametrize("damping", [0.0, 0.7])
def test_a_linear_system_is_solved_in_one_iteration(solver, damping):
    """spring_mass: A = m + s k + (s/b) d is the Hessian of the (quadratic) incremental potential, so
    y_1 = y_0 - A^{-1} g(y_0) is its minimiser: one iteration, the step Newton takes."""
    system = SpringMassParams(stiffness=400.0, damping=damping, x0=0.3, v0=-2.0).build()
    problem, start = step_problem(system, dt=0.05)
    y, stats = solver.minimize(problem, start)
    reference, _ = Newton(tolerance=REFERENCE_TOLERANCE).minimize(problem, start)
    assert stats.converged and stats.iterations == 1
    assert y == pytest.approx(reference, rel=1e-13)


def test_lbfgs_rest_takes_the_pd_step_first():
    """With H_0 = A^{-1} and no secant pair yet, L-BFGS's first direction is PD's step -A^{-1} g; on the
    compressed cloth the line search accepts it whole (a PD step never raises E), so both first iterates agree."""
    problem, start = compressed_and_stretched_cloth_step()
    iterates = {}
    for name, solver in (("pd", ProjectiveDynamics(max_iterations=1)), ("lbfgs", LBFGS(max_iterations=1, initial_hessian="rest"))):
        solver.callback = lambda y, g, name=name: iterates.setdefault(name, []).append(y.copy())
        solver.minimize(problem, start)
    assert np.array_equal(iterates["pd"][0], start) and len(iterates["pd"]) == 2
    np.testing.assert_allclose(iterates["lbfgs"][1], iterates["pd"][1], rtol=0, atol=1e-14)


LBFGS_BAR = 100  # iterations per step asked of a quasi-Newton solver on the hanging cloth (the real-time target)


@pytest.mark.parametrize("initial_hessian", ["rest", "scaled_rest"])
def test_lbfgs_with_the_rest_matrix_converges_on_every_step_of_a_hanging_cloth_but_misses_the_bar(initial_hessian,
                                                                                                  record_property):
    """cloth_hang at 10x10, backward Euler, dt = 0.02 s for 0.2 s, tolerance 1e-9: every step converges, and every
    step needs more than the bar of 100 iterations (measured 593-837 for rest, 385-488 for scaled_rest,
    Newton 5-6): what docs/solvers.md quotes, so that a change that meets the bar has to say so here. The cause is
    the spectrum (test_the_rest_matrix_is_far_stiffer_than_the_hessian_across_the_hanging_cloth)."""
    system = {**load_experiment(CLOTH_HANG)[0].system.model_dump(), "resolution": [10, 10]}
    result = run_one(system, "backward_euler", 0.02, 0.2,
                     solver={"type": "lbfgs", "initial_hessian": initial_hessian, "tolerance": 1e-9, "max_iterations": 2000})
    assert result.status == "ok" and result.steps == 10
    iterations = result.per_step["newton_iterations"]
    assert np.all(result.per_step["linear_iterations"] >= iterations)  # a back-substitution per direction at least
    message = f"lbfgs {initial_hessian}: iterations per step {iterations.tolist()}"
    record_property("lbfgs_iterations", message)
    print(message)
    assert iterations.min() > LBFGS_BAR, message


def test_the_rest_matrix_is_far_stiffer_than_the_hessian_across_the_hanging_cloth():
    """The eigenvalues of A^{-1} H on the free dofs (A = M + s K_r the rest matrix, H the Hessian at the minimiser
    of cloth_hang's first backward Euler step at 10x10, dt = 0.02 s; dense generalized eigenproblem H u = lambda A u):
    all <= 1, since per spring H_e = k_e (n n^T + (1 - l0/l) (I - n n^T)) <= k_e I (the same M in both); and many
    below 0.01 (95 of 294, 121 below 0.1, the smallest 3.2e-4), the out-of-plane modes of a nearly unstretched cloth,
    where the Hessian has ~0 across its springs and A has k_e: condition ~3e3, which L-BFGS's few pairs cannot
    correct, hence its hundreds of iterations per step with H_0 = A^{-1}."""
    system = ClothParams(**{**load_experiment(CLOTH_HANG)[0].system.model_dump(), "resolution": (10, 10)}).build()
    problem, start = step_problem(system, dt=0.02)
    y, stats = Newton(tolerance=REFERENCE_TOLERANCE, max_iterations=50).minimize(problem, start)
    assert stats.converged
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    rest = problem.rest_hessian().toarray()[np.ix_(free, free)]
    hessian = problem.hessian(y)
    hessian = (hessian.toarray() if scipy.sparse.issparse(hessian) else np.asarray(hessian))[np.ix_(free, free)]
    values = scipy.linalg.eigh(hessian, rest, eigvals_only=True)
    assert values.max() <= 1.0 + 1e-12
    assert values.min() > 0.0  # the step is strictly convex
    assert values.min() < 1e-3
    assert free.size == 294
    # docs/solvers.md quotes 121 of 294 below 0.1; no eigenvalue lies within 1e-3 of 0.1 or 0.01: exact counts
    assert (np.count_nonzero(values < 0.1), np.count_nonzero(values < 0.01)) == (121, 95)


def minimal_residuals(operator: np.ndarray, residual: np.ndarray, steps: int) -> np.ndarray:
    """min |r0 + B c|_2 / |r0|_2 over c in the Krylov space K_k(B, r0), k = 1 .. steps (Arnoldi with
    reorthogonalisation, then the small least-squares problem: GMRES's minimal residual)."""
    size = residual.size
    basis = np.zeros((size, steps + 1))
    hessenberg = np.zeros((steps + 1, steps))
    norm = np.linalg.norm(residual)
    basis[:, 0] = residual / norm
    minima = np.zeros(steps)
    for k in range(steps):
        w = operator @ basis[:, k]
        for _ in range(2):  # classical Gram-Schmidt twice: orthogonal to round-off
            coefficients = basis[:, :k + 1].T @ w
            hessenberg[:k + 1, k] += coefficients
            w = w - basis[:, :k + 1] @ coefficients
        hessenberg[k + 1, k] = np.linalg.norm(w)
        basis[:, k + 1] = w / hessenberg[k + 1, k]
        target = np.zeros(k + 2)
        target[0] = -norm
        c, *_ = np.linalg.lstsq(hessenberg[:k + 2, :k + 1], target, rcond=None)
        minima[k] = np.linalg.norm(hessenberg[:k + 2, :k + 1] @ c - target) / norm
    return minima


@pytest.mark.parametrize("scale", [1.0, 0.1, 0.01])
def test_no_method_preconditioned_by_the_rest_matrix_meets_the_lbfgs_bar(scale):
    """The bar for L-BFGS with H_0 = A^{-1} (tolerance 1e-9 in at most 100 iterations on this cloth) is below
    what any method that builds its steps from gradients and A^{-1} can reach. On the step's quadratic model at
    its minimiser, k iterations of such a method (L-BFGS, any memory, any line search; PCG; Chebyshev) move y
    within y_0 + A^{-1} K_k(H A^{-1}, g_0), and the smallest residual there (right-preconditioned GMRES) is
    still 2e-5 of |g_0|_2 after 100 iterations (1e-9 only after 176). The solver's test is in the max norm,
    |r|_inf >= |r|_2 / sqrt(n), so the best reachable there is above 1e-6 of |g_0|_inf. Scaling the rest
    stiffness in A (A = M + scale s K_r) does not change this: the spread of A^{-1} H stays ~3e3."""
    system = ClothParams(**{**load_experiment(CLOTH_HANG)[0].system.model_dump(), "resolution": (10, 10)}).build()
    problem, start = step_problem(system, dt=0.02)
    y, stats = Newton(tolerance=REFERENCE_TOLERANCE, max_iterations=50).minimize(problem, start)
    assert stats.converged
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    mass = np.diag(system.mass[free])
    rest = mass + scale * (problem.rest_hessian().toarray()[np.ix_(free, free)] - mass)
    hessian = problem.hessian(y).toarray()[np.ix_(free, free)]
    gradient = problem.gradient(start)[free]
    minima = minimal_residuals(hessian @ np.linalg.inv(rest), gradient, LBFGS_BAR)
    assert np.all(np.diff(minima) <= 1e-15)  # a minimum over growing spaces never grows
    best_max_norm = minima[-1] * np.linalg.norm(gradient) / np.sqrt(free.size) / np.abs(gradient).max()
    assert best_max_norm > 1e3 * 1e-9, (scale, minima[-1])
    # the control: with the Hessian itself in place of A (Newton's step), one iteration solves the model
    assert minimal_residuals(np.eye(free.size), gradient, 1)[0] <= 1e-14


@pytest.mark.parametrize("guess", ["start", "inertial"])
@pytest.mark.parametrize("dt", [0.01, 0.02])
def test_lbfgs_with_the_step_hessian_meets_the_bar_on_the_hanging_cloth(dt, guess):
    """The same cloth with H_0 = the abs-projected Hessian at the inertial guess x_n + h v_n, factorised once per
    step, from x_n or from that guess: at most 100 iterations per step (measured 15-51), where the rest matrix
    needs 500-850. The stale H_0
    within a step is what the BFGS pairs correct; it follows the cloth's rotation, the rest shape does not."""
    system = {**load_experiment(CLOTH_HANG)[0].system.model_dump(), "resolution": [10, 10]}
    result = run_one(system, "backward_euler", dt, 0.2,
                     solver={"type": "lbfgs", "initial_hessian": "step", "initial_guess": guess,
                             "tolerance": 1e-9, "max_iterations": 100})
    assert result.status == "ok", result.message
    assert result.per_step["newton_iterations"].max() <= LBFGS_BAR


@pytest.mark.parametrize(("options", "converges"), [({}, True), ({"initial_hessian": "scalar"}, False)])
def test_lbfgs_with_its_default_options_converges_on_the_pinned_cloth(options, converges):
    """``solver: {type: lbfgs}`` with nothing else but the tolerance (1e-9) and max_iterations (500) on the 10x10
    pinned cloth, stretch 8000 N/m, backward Euler, dt = 0.02 s for 1 s: every step converges with the default H_0
    (the step's projected Hessian; measured 13-102 iterations per step), where the scalar H_0, the default before,
    runs out of iterations on some steps (measured 311 to over 500)."""
    system = {**load_experiment(CLOTH_HANG)[0].system.model_dump(), "resolution": [10, 10], "stretch_stiffness": 8000.0}
    result = run_one(system, "backward_euler", 0.02, 1.0,
                     solver={"type": "lbfgs", "tolerance": 1e-9, "max_iterations": 500, **options})
    assert result.steps == 50
    if converges:
        assert result.status == "ok", result.message
        assert result.per_step["newton_iterations"].max() < 500
    else:
        assert result.status == "not_converged"


def test_the_rest_matrix_is_factorised_once_per_run_and_again_when_it_changes(monkeypatch):
    """Steps with the same rest_key (system, s, s/b) share one factorisation; another dt changes s and
    needs a new one."""
    calls = []
    factorise = projective.factorise_spd
    monkeypatch.setattr(projective, "factorise_spd", lambda matrix: calls.append(matrix.shape) or factorise(matrix))
    system = cloth_hang(resolution=(6, 6))
    solver = ProjectiveDynamics(tolerance=1e-6, max_iterations=5000, chebyshev_rho=0.99)
    state = State(0.0, system.x0, system.v0)
    for _ in range(4):
        state, stats = INTEGRATORS["backward_euler"]().step(system, state, 0.01, solver)
        assert stats.converged
    assert calls == [(system.dof_count - system.fixed_dofs.size,) * 2]
    INTEGRATORS["backward_euler"]().step(system, state, 0.02, solver)
    assert len(calls) == 2


# ------------------------------------------------------------------------------------------------
# Chebyshev acceleration
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dt", [0.01, 0.02])
def test_chebyshev_needs_at_most_half_the_iterations_of_plain_pd(dt):
    """cloth_hang's first backward Euler step to the same relative residual 1e-4: Wang's acceleration with
    rho = 0.99 after 10 plain iterations (measured: ~7x fewer iterations), and with the computed rho (auto:
    measured 29x at dt = 0.01 s, 43x at 0.02 s; asserted >= 10x)."""
    system = cloth_hang()
    problem, start = step_problem(system, dt=dt)
    counts = {}
    for label, options in (("plain", {}), ("chebyshev", {"chebyshev_rho": 0.99}), ("auto", {"chebyshev_rho": "auto"})):
        y, stats = ProjectiveDynamics(tolerance=1e-4, max_iterations=30000, **options).minimize(problem, start)
        assert stats.converged
        counts[label] = stats.iterations
    assert counts["chebyshev"] <= 0.5 * counts["plain"], counts
    assert counts["auto"] <= 0.1 * counts["plain"], counts


def generalized_radius(problem, y, system, relaxation=1.0):
    """1 - gamma lambda_min of H v = lambda A v on the free dofs, by LAPACK on the dense matrices: the reference."""
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    dense = lambda m: (m.toarray() if scipy.sparse.issparse(m) else np.asarray(m))[np.ix_(free, free)]
    smallest = scipy.linalg.eigh(dense(problem.hessian(y)), dense(problem.rest_hessian()), eigvals_only=True)[0]
    return 1.0 - relaxation * smallest


@pytest.mark.parametrize("resolution, relaxation", [((6, 6), 1.0), ((6, 6), 0.9), ((12, 12), 1.0), ((12, 12), 0.8)])
def test_the_auto_rho_is_the_spectral_radius_of_the_linearised_pd_iteration(resolution, relaxation):
    """chebyshev_rho auto: 1 - gamma lambda_min(A^{-1} H) at the solve's start. 6x6 (102 free dofs) is solved
    densely and equals the reference to round-off; 12x12 (426) by Lanczos, whose Ritz value approaches the
    top eigenvalue of (A - H) v = mu A v from below: never above the true radius, and its gap 1 - rho at
    most twice the true one (measured: 1.7x at dt = 0.02 s)."""
    system = cloth_hang(resolution=resolution)
    problem, start = step_problem(system, dt=0.02)
    solver = ProjectiveDynamics(tolerance=1e-3, max_iterations=100000, chebyshev_rho="auto", relaxation=relaxation)
    solver.minimize(problem, start)
    computed, expected = solver._auto[1], generalized_radius(problem, start, system, relaxation)
    assert 0.99 < expected < 1.0
    if system.dof_count - system.fixed_dofs.size <= projective.AUTO_DENSE_LIMIT:
        assert computed == pytest.approx(expected, rel=0.0, abs=1e-12)
    else:
        assert computed <= expected + 1e-12
        assert 1.0 - computed <= 2.0 * (1.0 - expected), (computed, expected)


def test_the_plain_iteration_contracts_at_the_computed_radius():
    """An independent check of the radius (power iteration): plain PD steps from near the solution shrink their
    update norms |y_{k+1} - y_k| by the linearised iteration's spectral radius per step once the slowest mode
    dominates; on a 4x4 cloth (rho = 0.99104, the next mode close below it) the ratio after 2000 steps equals
    the auto rho taken at the solution to 1e-4, while the norms are still far above round-off (~1e-14)."""
    system = cloth_hang(resolution=(4, 4))
    problem, start = step_problem(system, dt=0.01)
    solution, _ = Newton(tolerance=REFERENCE_TOLERANCE, max_iterations=50).minimize(problem, start)
    offset = np.random.default_rng(3).standard_normal(system.dof_count) * 1e-3
    offset[system.fixed_dofs] = 0.0
    free = FreeDofs(system.dof_count, system.fixed_dofs)
    factor = projective.RestFactor()
    factor.prepare(problem, free, "projective_dynamics")
    rho = factor.iteration_radius(problem, solution, free, 1.0)  # what auto computes, at the solution
    y, norms = solution + offset, []
    for _ in range(2000):
        step = -factor.solve(free, problem.gradient(y))
        norms.append(np.linalg.norm(step))
        y = y + step
    assert 0.9 < rho < 1.0
    assert norms[-1] / norms[-2] == pytest.approx(rho, abs=1e-4)


# ------------------------------------------------------------------------------------------------
# Refusals: one line each
# ------------------------------------------------------------------------------------------------
def hookean_cloth(**overrides):
    return ClothParams(resolution=(4, 4), stretch_stiffness=100.0, shear_stiffness=10.0, bend_stiffness=1.0,
                       pinned=["top_left"], **overrides).build()


REFUSED = {
    "squared_length springs": (lambda: MassSpringParams(type="mass_spring", model={"grid": {"resolution": [3, 3]}},
                                                       spring_law="squared_length").build(), "backward_euler", "not Hookean"),
    "contact": (lambda: hookean_cloth(contact={"ground": {"height": -0.5}}), "backward_euler", "contact"),
    "segment problem": (hookean_cloth, "average_vector_field", "samples the force along the step"),
    "no rest stiffness": (lambda: CircularMotionParams(force="gravity").build(), "backward_euler", "gravitational law"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_pd_refuses_what_it_cannot_express_in_one_line(case):
    build, integrator, words = REFUSED[case]
    system = build()
    problem, start = step_problem(system, dt=0.01, integrator=integrator)
    with pytest.raises(ValueError) as error:
        ProjectiveDynamics().minimize(problem, start)
    message = str(error.value)
    assert "\n" not in message and words in message and message.startswith("projective_dynamics")
    assert message == ProjectiveDynamics().refusal(system, "incremental_potential" if problem.projective else "segment_potential")
    assert message == solver_refusal(ProjectiveDynamics(), system, problem.projective)


def test_lbfgs_rest_refuses_a_system_without_rest_stiffness_in_one_line():
    """circular_motion with the gravity law has no rest stiffness; the scalar H_0 needs none."""
    system = CircularMotionParams(force="gravity").build()
    problem, start = step_problem(system, dt=0.1)
    for initial_hessian in ("rest", "scaled_rest"):
        with pytest.raises(ValueError) as error:
            LBFGS(initial_hessian=initial_hessian).minimize(problem, start)
        message = str(error.value)
        assert "\n" not in message and "rest stiffness" in message and message.endswith("has none")
        assert message.startswith(f"lbfgs with initial_hessian {initial_hessian}")
        assert solver_refusal(LBFGS(initial_hessian=initial_hessian), system, True).startswith(f"lbfgs with initial_hessian {initial_hessian}")
    assert solver_refusal(LBFGS(), system, True) is None and LBFGS().minimize(problem, start)[1].converged


def test_what_pd_accepts_is_not_refused():
    for system in (hookean_cloth(), SpringMassParams(damping=0.2).build(), CircularMotionParams(force="linear").build()):
        assert ProjectiveDynamics().refusal(system, "incremental_potential") is None
        assert refusal("lbfgs with initial_hessian rest", ("rest_stiffness",), system, False) is None


# ------------------------------------------------------------------------------------------------
# The config
# ------------------------------------------------------------------------------------------------
def test_the_config_builds_pd_and_refuses_what_it_does_not_take():
    solver = solver_params(type="projective_dynamics", chebyshev_rho=0.9).build()
    assert type(solver) is ProjectiveDynamics and (solver.chebyshev_rho, solver.chebyshev_warmup, solver.relaxation) == (0.9, 10, 1.0)
    assert solver_params(type="projective_dynamics", chebyshev_rho="auto").build().chebyshev_rho == "auto"
    assert solver_params(type="projective_dynamics").model_dump()["chebyshev_rho"] == 0.0  # plain PD by default
    for options, field in (({"history": 4}, "history"), ({"chebyshev_rho": 1.0}, "chebyshev_rho"),
                           ({"chebyshev_rho": "fast"}, "chebyshev_rho"), ({"chebyshev_warmup": 0}, "chebyshev_warmup"),
                           ({"relaxation": 1.5}, "relaxation")):
        with pytest.raises(SolverOptionError) as error:
            solver_params(type="projective_dynamics", **options)
        assert str(error.value).startswith(f"{field}: ") and "\n" not in str(error.value)
    assert ProjectiveDynamics.requires == ("projective",)
    assert solver_params(type="lbfgs", initial_hessian="rest").build().requires == ("rest_stiffness",)
    assert solver_params(type="lbfgs").build().requires == ()


def test_pd_with_spring_damping_is_exact_and_refactorises_per_step(monkeypatch):
    """Spring damping's D(x) is taken once per step (at damping_at), so the step's incremental potential still has
    PD's form with A = M + s K_r + (s/b) D(x_n): PD reaches Newton's step, with one factorisation per step (the
    rest_key changes with D), where undamped or constant damping needs one per run."""
    calls = []
    factorise = projective.factorise_spd
    monkeypatch.setattr(projective, "factorise_spd", lambda matrix: calls.append(matrix.shape) or factorise(matrix))
    system = hookean_cloth(damping=0.3)
    assert system.projective_form().inexact is None
    solver = ProjectiveDynamics(tolerance=1e-10, max_iterations=20000, chebyshev_rho=0.99)
    state = State(0.0, system.x0, system.v0)
    for step in range(3):
        problem, start = step_problem(system, state.x, state.v, dt=0.01)
        reference, _ = Newton(tolerance=1e-14).minimize(problem, start)
        y, stats = solver.minimize(problem, start)
        assert stats.converged
        assert np.abs(y - reference).max() < 1e-8
        state, _ = INTEGRATORS["backward_euler"]().step(system, state, 0.01, Newton(tolerance=1e-14))
    assert len(calls) == 3


class _Clock:
    """A stand-in for the time module whose perf_counter advances by ``tick`` seconds per call."""

    def __init__(self, tick: float):
        self.now, self.tick = 0.0, tick

    def perf_counter(self) -> float:
        self.now += self.tick
        return self.now


@pytest.mark.parametrize("solver_type", ["projective_dynamics", "lbfgs", "vbd"])
def test_a_time_budget_stops_the_solve_before_an_iteration_that_would_overrun_it(monkeypatch, solver_type):
    """time_budget: the solve reads the clock at its start, after its start's work and after every iteration, and
    stops unconverged before an iteration that would end past the budget, the next taken as long as the last. With a
    clock that advances 1 ms per reading and a budget of 5.5 ms: the start at 1 ms (deadline 6.5 ms), iterations from
    2 ms, iteration k ending at 2 + k ms, each 1 ms long. After the 4th (6 ms) a 5th would end at 7 ms: 4 iterations,
    ended within the budget. Without the budget the same solve converges, in more iterations."""
    import simrun.solvers.base as base
    system = cloth_hang(resolution=(6, 6))
    problem, start = step_problem(system, dt=0.02)
    monkeypatch.setattr(base, "time", _Clock(1e-3))
    _, budgeted = solver_params(type=solver_type, tolerance=1e-8, max_iterations=100000, time_budget=5.5e-3).build().minimize(problem, start)
    assert (budgeted.iterations, budgeted.converged) == (4, False)
    _, unlimited = solver_params(type=solver_type, tolerance=1e-8, max_iterations=100000).build().minimize(problem, start)
    assert unlimited.converged and unlimited.iterations > 4


def test_newton_the_reference_takes_no_time_budget():
    """A sweep of solver.type with a time budget keeps Newton converged (the reference): Newton refuses the key."""
    with pytest.raises(SolverOptionError, match="newton does not use 'time_budget'"):
        solver_params(type="newton", time_budget=0.01)


@pytest.mark.parametrize("relaxation", [1.0, 0.7])
def test_where_the_hessian_is_the_rest_matrix_the_radius_is_one_minus_gamma(relaxation):
    """A problem whose Hessian equals A (a linear one, as Hookean springs of zero rest length would give): PD's
    iteration matrix is (1 - gamma) I, so rho = 1 - gamma exactly; on the Lanczos path too (426 free dofs), where
    ARPACK cannot start from A - H = 0."""
    system = cloth_hang()
    problem, start = step_problem(system, dt=0.02)
    problem.hessian = lambda y, project_spd=False: problem.rest_hessian()
    free = FreeDofs(system.dof_count, system.fixed_dofs)
    assert free.count > projective.AUTO_DENSE_LIMIT
    factor = projective.RestFactor()
    factor.prepare(problem, free, "projective_dynamics")
    assert factor.iteration_radius(problem, start, free, relaxation) == pytest.approx(1.0 - relaxation, abs=1e-15)


def test_a_time_budget_and_a_fallback_are_refused_together():
    """A budgeted solve ends when its time is spent; a fallback would then run past the budget on every step."""
    for options in ({"type": "projective_dynamics", "time_budget": 0.002, "fallback": ["newton"]},
                    {"type": "newton", "fallback": [{"type": "lbfgs", "time_budget": 0.002}]}):
        with pytest.raises(SolverOptionError, match="give time_budget or fallback, not both"):
            solver_params(**options)
