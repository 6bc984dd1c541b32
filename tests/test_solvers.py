"""The solvers against theory.

One backward Euler step of a small cloth (6x6, pinned corners, a stretched and bulged start so the
step is nonlinear, the incremental potential strictly convex) is the common test problem: every
nonlinear solver with every linear solver it uses must reach the minimiser y* to its tolerance.
The error bound is that of a strongly convex problem, |y - y*|_2 <= |g(y)|_2 / mu with mu the
smallest eigenvalue of the Hessian on the free dofs. Linear solvers are checked against their
convergence theory (CG: at most k iterations for k distinct eigenvalues; Jacobi and Gauss-Seidel:
log(tol) / log(rho) iterations for the spectral radius rho of their iteration matrix; MPCG: PCG on
the reduced system, Ascher & Boxerman 2003). Tests are parametrised over SOLVERS and LINEAR_SOLVERS.
"""

from __future__ import annotations

import inspect
import textwrap
import typing
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
import yaml

from conftest import always_available_linear_solvers, linear_solver_params, needs_linear_solver, run_one, step_problem
from simrun.cli import main
from simrun.experiment.config import ConfigError, _fields_at, load_experiment, validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.results import load
from simrun.solvers import (LINEAR_SOLVERS, SOLVERS, SOLVER_PARAMS, FallbackChain, Newton, NonlinearSolver,
                            SolverOptionError, SolverParams, solver_params)
from simrun.solvers.dofs import free_dofs
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.solvers.newton import EIGEN_FLOOR, project_eigen
from simrun.systems import CircularMotionParams, ClothParams

CORNERS = ["top_left", "top_right", "bottom_left", "bottom_right"]
# h^2 k / m = 0.0004 * 200 * 36 = 2.9: nonlinear, yet the Jacobi iteration converges (rho ~ 0.93)
CLOTH = dict(resolution=(6, 6), mass=1.0, stretch_stiffness=200.0, shear_stiffness=50.0, bend_stiffness=5.0,
             damping=0.5, pinned=CORNERS)
DT = 0.02
TOLERANCE = 1e-8


def backward_euler_problem(system, x, v, dt):
    return step_problem(system, x, v, dt)


def stretched_cloth_step(stretch=1.1, bulge=0.1, dt=DT, **overrides):
    """The cloth stretched in its plane (pins included) and bulged, with random velocities: one BE step."""
    system = ClothParams(**{**CLOTH, **overrides}).build()
    positions = system.x0.reshape(-1, 3).copy()
    centre = positions.mean(axis=0)
    positions[:, :2] = centre[:2] + stretch * (positions[:, :2] - centre[:2])
    positions[:, 2] = bulge * np.sin(np.pi * positions[:, 0]) * np.sin(np.pi * positions[:, 1])
    v = 0.3 * np.random.default_rng(3).standard_normal(system.dof_count)
    v[system.fixed_dofs] = 0.0
    problem, start = backward_euler_problem(system, positions.ravel(), v, dt)
    return system, problem, start


def compressed_cloth_step():
    """A poor start: the cloth squeezed to half its size with a little noise out of plane, at rest."""
    system = ClothParams(**{**CLOTH, "mass": 0.1}).build()
    positions = system.x0.reshape(-1, 3).copy()
    centre = positions.mean(axis=0)
    positions[:, :2] = centre[:2] + 0.5 * (positions[:, :2] - centre[:2])
    positions[:, 2] = 0.01 * np.random.default_rng(0).standard_normal(len(positions))
    problem, start = backward_euler_problem(system, positions.ravel(), np.zeros(system.dof_count), 0.05)
    return system, problem, start


def free_block(matrix, fixed):
    dense = matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix)
    free = np.setdiff1d(np.arange(dense.shape[0]), fixed)
    return dense[np.ix_(free, free)], free


@pytest.fixture(scope="module")
def cloth_step():
    system, problem, start = stretched_cloth_step()
    reference, stats = solver_params(type="projected_newton", tolerance=1e-14).build().minimize(problem, start)
    assert stats.converged and stats.iterations >= 3, "the step must be nonlinear"
    hessian, free = free_block(problem.hessian(reference), system.fixed_dofs)
    mu = np.linalg.eigvalsh(hessian).min()
    assert mu > 0, "the test problem must be strictly convex, so that y* is unique"
    return system, problem, start, reference, mu, free


def combinations():
    """Every nonlinear solver with every linear solver it uses, and the line-search/projection variants."""
    cases = [(name, {"linear_solver": linear}) for name, cls in SOLVERS.items()
             for linear in (LINEAR_SOLVERS if cls.uses_linear_solver else ["direct"])]
    cases += [("projected_newton", {"spd_projection": "none"}), ("projected_newton", {"spd_projection": "eigen"}),
              ("newton", {"tolerance_mode": "step"}), ("projected_newton", {"tolerance_mode": "step"})]
    cases += [(name, {"line_search": "armijo"}) for name in ("projected_newton", "lbfgs", "gradient_descent", "jacobi_chebyshev")]
    cases += [("newton", {"spd_projection": "abs"}), ("newton", {"spd_projection": "adaptive"}),
              ("newton", {"tolerance_mode": "velocity"}), ("newton", {"initial_guess": "inertial"}),
              ("newton", {"initial_guess": "predictor"}), ("projected_newton", {"spd_projection": "abs"}),
              ("projective_dynamics", {"chebyshev_rho": 0.99}), ("vbd", {"chebyshev_rho": 0.9}),
              ("lbfgs", {"initial_hessian": "scalar"}), ("lbfgs", {"initial_hessian": "rest"})]
    return [pytest.param(name, options, id=f"{name}-{'-'.join(map(str, options.values()))}",
                         marks=needs_linear_solver(options.get("linear_solver", "direct")))
            for name, options in cases]


@pytest.mark.parametrize("name, options", combinations())
def test_every_solver_reaches_the_minimiser_of_a_cloth_step(cloth_step, name, options):
    """|y - y*|_2 <= |g(y)|_2 / mu (strong convexity), and the residual meets the shared convergence test."""
    system, problem, start, reference, mu, free = cloth_step
    params = solver_params(type=name, tolerance=TOLERANCE, max_iterations=500, linear_max_iterations=5000, **options)
    solver = params.build()
    if solver.refusal(system, "incremental_potential"):  # a solver that cannot take this cloth (none today) is refused
        pytest.skip(solver.refusal(system, "incremental_potential"))
    if name in ("projective_dynamics", "vbd") and not options.get("chebyshev_rho"):
        solver.max_iterations = 20000  # plain PD and VBD converge linearly, slowly at this tolerance
    y, stats = solver.minimize(problem, start)
    assert stats.converged, stats
    assert np.array_equal(y[system.fixed_dofs], start[system.fixed_dofs])
    gradient = problem.gradient(y)
    assert stats.residual == pytest.approx(np.abs(gradient).max(), rel=1e-12, abs=1e-300)
    if options.get("tolerance_mode") not in ("step", "velocity"):  # relative to where the solve started (vbd: its own guess)
        first = solver.starting_point(problem, start)
        assert stats.residual <= max(TOLERANCE * np.abs(problem.gradient(first)).max(), problem.residual_floor)
    bound = np.linalg.norm(gradient[free]) / mu
    assert np.linalg.norm(y - reference) <= 2.0 * bound + 1e-13
    assert np.abs(y - reference).max() < 1e-6
    if SOLVERS[name].uses_linear_solver:
        assert stats.linear_iterations >= stats.iterations  # a direct solve counts one, iterative ones more
        if LINEAR_SOLVERS[params.linear_solver].iterative:
            assert stats.linear_iterations > stats.iterations
    elif name == "projective_dynamics" or getattr(solver, "initial_hessian", "scalar") != "scalar":
        assert stats.linear_iterations >= stats.iterations  # a back-substitution with its own factor per direction
    else:
        assert stats.linear_iterations == 0


def newton_decrement(problem, fixed, y, gradient):
    """lambda(y) = sqrt(g^T H^{-1} g) on the free dofs: the residual in the affine-invariant norm."""
    hessian, free = free_block(problem.hessian(y), fixed)
    return float(np.sqrt(gradient[free] @ np.linalg.solve(hessian, gradient[free])))


def test_newton_converges_quadratically_near_the_solution():
    """lambda_{k+1} <= C lambda_k^2 (Newton decrement; Boyd & Vandenberghe sec. 9.5.3): the observed
    order log(lambda_{k+1}/lambda_k) / log(lambda_k/lambda_{k-1}) approaches 2, and the ratio
    lambda_{k+1} / lambda_k^2 stays bounded, until round-off."""
    system, problem, start = stretched_cloth_step()
    history = []
    solver = Newton(tolerance=1e-15, max_iterations=30, callback=lambda y, g: history.append((y.copy(), g.copy())))
    _, stats = solver.minimize(problem, start)
    assert stats.converged
    decrements = np.array([newton_decrement(problem, system.fixed_dofs, y, g) for y, g in history])
    above_roundoff = decrements[decrements > 1e-12 * decrements[0]]
    assert above_roundoff.size >= 4
    orders = np.log(above_roundoff[2:] / above_roundoff[1:-1]) / np.log(above_roundoff[1:-1] / above_roundoff[:-2])
    assert orders[-1] >= 1.8
    constants = above_roundoff[1:] / above_roundoff[:-1] ** 2
    assert constants.max() < 100.0
    # the max-norm residual the runner records drops by > 1e3 in the last iteration before round-off
    residuals = np.array([np.abs(g).max() for _, g in history])
    assert residuals[-2] < 1e-3 * residuals[-3]


@pytest.mark.parametrize("name", ["projected_newton", "lbfgs", "gradient_descent", "jacobi_chebyshev"])
@pytest.mark.parametrize("line_search", ["backtracking", "armijo"])
def test_line_search_solvers_never_increase_the_incremental_potential(name, line_search):
    """From a squeezed cloth plain Newton overshoots (its energy rises); the line-search solvers'
    energies never rise beyond the round-off of E along their iterations."""
    system, problem, start = compressed_cloth_step()
    newton_energies = []
    Newton(tolerance=1e-10, max_iterations=10, line_search="none", callback=lambda y, g: newton_energies.append(problem.value(y))).minimize(problem, start)
    assert np.max(np.diff(newton_energies)) > 0.1 * newton_energies[0], "the start must make plain Newton overshoot"
    energies = []
    solver = solver_params(type=name, line_search=line_search, max_iterations=30).build()
    solver.callback = lambda y, g: energies.append(problem.value(y))
    solver.minimize(problem, start)
    energies = np.array(energies)
    assert energies.size > 5
    assert np.all(np.diff(energies) <= ENERGY_ROUNDOFF * np.abs(energies[:-1]))
    assert energies[-1] < 0.5 * energies[0]


# ------------------------------------------------------------------------------------------------
# Linear solvers
# ------------------------------------------------------------------------------------------------
def diagonally_dominant_spd(n, seed, density=0.05, margin=1.2):
    """Random sparse symmetric matrix made strictly diagonally dominant with a positive diagonal: SPD by Gershgorin."""
    rng = np.random.default_rng(seed)
    random = scipy.sparse.random(n, n, density=density, random_state=rng, data_rvs=lambda k: rng.uniform(-1, 1, k))
    symmetric = (random + random.T).tolil()
    symmetric.setdiag(0.0)
    symmetric = symmetric.tocsr()
    diagonal = margin * np.abs(symmetric).sum(axis=1).A1 + 0.1
    return (symmetric + scipy.sparse.diags(diagonal)).tocsr()


def cloth_matrix(pinned=CORNERS):
    system, problem, start = stretched_cloth_step(pinned=pinned)
    return system, problem.hessian(start, project_spd=True)


@pytest.mark.parametrize("name", linear_solver_params())
@pytest.mark.parametrize("matrix_kind", ["random_sparse", "random_dense", "cloth"])
def test_each_linear_solver_solves_an_spd_system_to_its_tolerance(name, matrix_kind):
    """|b - A p|_2 <= tolerance |b|_2 on the free dofs, p = 0 on the fixed ones; a direct solve counts one."""
    rng = np.random.default_rng(11)
    if matrix_kind == "cloth":
        system, matrix = cloth_matrix()
        fixed = system.fixed_dofs
    else:
        matrix = diagonally_dominant_spd(150, seed=5)
        matrix = matrix.toarray() if matrix_kind == "random_dense" else matrix
        fixed = np.array([0, 7, 8, 149])
    n = matrix.shape[0]
    free = free_dofs(n, fixed)
    rhs = rng.standard_normal(n)
    tolerance = 1e-10
    solution, iterations = LINEAR_SOLVERS[name](tolerance, 5000).solve(matrix, rhs, free, spd=True)
    assert np.all(solution[fixed] == 0.0)
    reduced = free.restrict_matrix(matrix)
    residual = free.restrict(rhs) - reduced @ free.restrict(solution)
    assert np.linalg.norm(residual) <= tolerance * np.linalg.norm(free.restrict(rhs))
    assert iterations > 1 if LINEAR_SOLVERS[name].iterative else iterations == 1


def spectral_radius(iteration_matrix):
    return float(np.abs(np.linalg.eigvals(iteration_matrix)).max())


@pytest.mark.parametrize("name", ["jacobi", "gauss_seidel"])
@pytest.mark.parametrize("seed", range(3))
def test_stationary_iterations_converge_at_their_spectral_radius(name, seed):
    """On a diagonally dominant matrix the residual shrinks like rho^k, rho the spectral radius of
    I - D^{-1} A (Jacobi) or I - (D + L)^{-1} A (Gauss-Seidel): about log(tol)/log(rho) iterations."""
    matrix = diagonally_dominant_spd(120, seed=seed)
    dense = matrix.toarray()
    splitting = np.diag(np.diag(dense)) if name == "jacobi" else np.tril(dense)
    rho = spectral_radius(np.eye(120) - np.linalg.solve(splitting, dense))
    assert rho < 1
    tolerance = 1e-10
    rhs = np.random.default_rng(seed).standard_normal(120)
    solution, iterations = LINEAR_SOLVERS[name](tolerance, 1000).solve(matrix, rhs, free_dofs(120, []))
    assert np.linalg.norm(rhs - matrix @ solution) <= tolerance * np.linalg.norm(rhs)
    predicted = np.log(tolerance) / np.log(rho)
    assert abs(iterations - predicted) <= 0.25 * predicted + 3


def test_jacobi_reports_divergence_instead_of_returning_garbage():
    """A matrix whose Jacobi iteration matrix has spectral radius > 1 (SPD but not diagonally dominant)."""
    matrix = np.array([[1.0, 0.9, 0.9], [0.9, 1.0, 0.9], [0.9, 0.9, 1.0]])  # SPD; I - D^-1 A has eigenvalue -1.8
    with pytest.raises(np.linalg.LinAlgError, match="diverges"):
        LINEAR_SOLVERS["jacobi"](1e-10, 1000).solve(matrix, np.ones(3), free_dofs(3, []))
    solution, _ = LINEAR_SOLVERS["gauss_seidel"](1e-10, 1000).solve(matrix, np.ones(3), free_dofs(3, []))
    assert np.allclose(matrix @ solution, 1.0)  # Gauss-Seidel converges on every SPD matrix


@pytest.mark.parametrize("k", [2, 4, 7])
def test_cg_needs_at_most_k_iterations_for_k_distinct_eigenvalues(k):
    """The CG residual is a degree-k polynomial in A applied to b; the one vanishing on the k eigenvalues
    makes it zero, so CG ends after at most k iterations (to round-off)."""
    rng = np.random.default_rng(k)
    n = 120
    basis, _ = np.linalg.qr(rng.standard_normal((n, n)))
    values = np.linspace(1.0, 20.0, k)
    eigenvalues = np.concatenate([values, rng.choice(values, n - k)])
    matrix = (basis * eigenvalues) @ basis.T
    rhs = rng.standard_normal(n)
    solution, iterations = LINEAR_SOLVERS["cg"](1e-10, 1000).solve(matrix, rhs, free_dofs(n, []))
    assert iterations <= k
    assert np.linalg.norm(rhs - matrix @ solution) <= 1e-10 * np.linalg.norm(rhs)


def test_mpcg_with_pinned_vertices_matches_the_direct_solve_of_the_reduced_system():
    """Baraff & Witkin's filtered PCG from the start p_0 = 0 on the constrained dofs is PCG on the
    reduced system (Ascher & Boxerman 2003): the same solution (to cond(A) * tol) and the same
    iteration count as Jacobi-PCG on the free rows and columns, and exactly zero on the pins."""
    pinned = [*CORNERS, 14, 21]  # the corners and two interior vertices
    system, matrix = cloth_matrix(pinned=pinned)
    fixed = system.fixed_dofs
    assert fixed.size == 18
    free = free_dofs(system.dof_count, fixed)
    rhs = np.random.default_rng(2).standard_normal(system.dof_count)  # nonzero on the pinned dofs too
    tolerance = 1e-10
    filtered, iterations = LINEAR_SOLVERS["mpcg"](tolerance, 1000).solve(matrix, rhs, free)
    direct, _ = LINEAR_SOLVERS["direct"]().solve(matrix, rhs, free, spd=True)
    reduced = free.restrict_matrix(matrix).toarray()
    condition = np.linalg.cond(reduced)
    assert np.all(filtered[fixed] == 0.0) and np.all(direct[fixed] == 0.0)
    assert np.linalg.norm(filtered - direct) <= condition * tolerance * np.linalg.norm(direct)
    _, pcg_iterations = LINEAR_SOLVERS["pcg"](tolerance, 1000).solve(matrix, rhs, free)
    assert abs(iterations - pcg_iterations) <= 1


def test_restriction_to_free_dofs_is_cached():
    """One FreeDofs per fixed_dofs; its CSR restriction map is built once per sparsity pattern."""
    system, matrix = cloth_matrix()
    free = free_dofs(system.dof_count, system.fixed_dofs)
    assert free_dofs(system.dof_count, system.fixed_dofs.copy()) is free
    first = free.restrict_matrix(matrix)
    pattern = free._pattern
    again = free.restrict_matrix(matrix.copy())  # same pattern, other arrays: the map is reused
    assert free._pattern is pattern
    expected = matrix.tocsr()[free.mask][:, free.mask]
    assert abs(first - expected).max() == 0 and abs(again - expected).max() == 0


def test_eigen_projection_clamps_the_free_block_only():
    """Whole-matrix eigenvalue clamping on a dense problem: eigenvalues >= EIGEN_FLOOR max|eigenvalue|,
    unchanged where already SPD; the Kepler Hessian has a negative radial eigenvalue."""
    system = CircularMotionParams(force="gravity").build()
    hessian = system.hessian(np.array([0.7, 0.4]))
    assert np.linalg.eigvalsh(hessian).min() < 0
    projected = project_eigen(hessian, np.zeros(0, dtype=np.intp))
    eigenvalues = np.linalg.eigvalsh(projected)
    assert eigenvalues.min() >= EIGEN_FLOOR * np.abs(eigenvalues).max() * (1 - 1e-9)
    spd = np.array([[2.0, 0.5], [0.5, 1.0]])
    assert np.allclose(project_eigen(spd, np.zeros(0, dtype=np.intp)), spd)


# ------------------------------------------------------------------------------------------------
# Through the runner: counts per step, not_converged, fallbacks, sweeps, the shipped config
# ------------------------------------------------------------------------------------------------
SMALL_CLOTH = {"type": "cloth", "resolution": [5, 5], "mass": 0.5, "stretch_stiffness": 300.0, "shear_stiffness": 30.0,
               "bend_stiffness": 1.0, "pinned": ["top_left", "top_right"]}


def test_iteration_counts_are_recorded_per_step_and_summarised(tmp_path):
    """Per step: nonlinear, linear (summed over the step) and line-search counts and the residual; the
    summary's means are those of the per-step series."""
    result = run_one(SMALL_CLOTH, "backward_euler", 0.02, 0.2,
                     solver={"type": "projected_newton", "linear_solver": "pcg", "tolerance": 1e-8})
    assert result.status == "ok"
    newton, linear = result.per_step["newton_iterations"], result.per_step["linear_iterations"]
    assert newton.shape == (10,) and np.all(newton >= 2)
    assert np.all(linear > newton)  # several CG iterations per Newton iteration
    assert np.all(result.per_step["residual"] > 0) and np.all(result.per_step["solver_index"] == 0)
    config = tmp_path / "config.yaml"
    config.write_text(textwrap.dedent(f"""\
        name: counts
        system: {{type: cloth, resolution: [5, 5], mass: 0.5, stretch_stiffness: 300.0, shear_stiffness: 30.0,
                 bend_stiffness: 1.0, pinned: [top_left, top_right]}}
        integrators: [backward_euler]
        solver: {{type: projected_newton, linear_solver: pcg, tolerance: 1.0e-8}}
        duration: 0.2
        sweep: {{dt: [0.02]}}
        output: {tmp_path / 'out'}
        """))
    assert main(["run", str(config), "--no-plots", "-q", "-j", "1"]) == 0
    (_, row), = load(tmp_path / "out" / "results.h5").summary.iterrows()
    assert row["mean_newton_iterations"] == pytest.approx(newton.mean())
    assert row["mean_linear_iterations"] == pytest.approx(linear.mean())


def test_tiny_max_iterations_gives_not_converged_with_the_counts_intact():
    result = run_one(SMALL_CLOTH, "backward_euler", 0.02, 0.2,
                     solver={"type": "projected_newton", "linear_solver": "cg", "max_iterations": 1, "tolerance": 1e-12})
    assert result.status == "not_converged" and result.steps == 10
    assert np.all(result.per_step["newton_iterations"] == 1)
    # CG's counts survive (one on the first step: the flat cloth's z block is M, CG's first iterate solves it)
    assert np.all(result.per_step["linear_iterations"] >= 1) and result.per_step["linear_iterations"].sum() > 100
    assert result.attrs["not_converged_steps"] == 10


def test_a_fallback_chain_records_which_solver_rescued_each_step():
    """Gradient descent with 5 iterations cannot solve a stiff cloth step to 1e-8; projected Newton,
    restarting from gradient descent's best iterate, can: solver_index 1, counts summed."""
    alone = run_one(SMALL_CLOTH, "backward_euler", 0.02, 0.1,
                    solver={"type": "gradient_descent", "max_iterations": 5, "tolerance": 1e-8})
    assert alone.status == "not_converged"
    chained = run_one(SMALL_CLOTH, "backward_euler", 0.02, 0.1,
                      solver={"type": "gradient_descent", "max_iterations": 5, "tolerance": 1e-8,
                              "fallback": ["projected_newton"]})
    assert chained.status == "ok"
    index = chained.per_step["solver_index"]
    rescued = index == 1
    assert rescued.any()
    assert np.all(chained.per_step["newton_iterations"][rescued] > 5)  # 5 of gradient descent + Newton's
    assert np.all(chained.per_step["linear_iterations"][rescued] >= 1)
    assert np.all(chained.per_step["linear_iterations"][~rescued] == 0)


def test_solver_parameters_sweep_like_any_other_key():
    raw = {"name": "sweep", "system": SMALL_CLOTH, "integrators": ["backward_euler"], "duration": 0.1,
           "sweep": {"dt": [0.05], "solver.type": sorted(SOLVERS), "solver.linear_solver": ["direct", "mpcg"]}}
    runs = expand_runs(validate_experiment(raw))
    assert {(run.solver.type, run.solver.linear_solver) for run in runs} == {
        (name, linear) for name in SOLVERS
        for linear in (("direct", "mpcg") if SOLVERS[name].uses_linear_solver else ("direct",))}
    raw["sweep"]["solver.type"] = ["newton", "bfgs"]
    with pytest.raises(ConfigError, match="solver.type"):
        expand_runs(validate_experiment(raw))


@pytest.mark.parametrize("solver, message", [
    ({"type": "lbfgs", "tolerance_mode": "step"}, "step needs Newton-type solvers"),
    ({"type": "newton", "tolerance_mode": "step", "fallback": ["gradient_descent"]}, "step needs Newton-type solvers"),
    ({"type": "newton", "fallback": ["lbfgs", "newton"]}, "appear once"),
    ({"type": "newton", "fallback": ["bfgs"]}, "solver.fallback"),
    ({"type": "jacobi_chebyshev", "chebyshev_rho": 1.0}, "solver.chebyshev_rho"),
    ({"type": "newton", "fallback": [{"type": "lbfgs", "tolerance": 1e-3}]},
     "solver.fallback.0.tolerance: a fallback takes tolerance from the main solver; its entry takes: type, line_search, history"),
    ({"type": "newton", "fallback": [{"type": "lbfgs", "histroy": 4}]}, "solver.fallback.0.histroy: lbfgs does not use 'histroy' \\(did you mean 'history'\\?\\)"),
    ({"type": "newton", "fallback": [{"type": "lbfgs", "history": 0}]}, "solver.fallback.0.history: Input should be greater than or equal to 1"),
    ({"type": "newton", "fallback": [{"history": 4}]}, "solver.fallback.0: a mapping needs 'type'"),
    ({"type": "newton", "fallback": [{"type": "bfgs"}]}, "solver.fallback.0.type: unknown solver 'bfgs'"),
    ({"type": "bfgs"}, "solver.type: unknown solver 'bfgs' \\(did you mean 'lbfgs'\\?\\); valid: " + ", ".join(SOLVERS)),
    ({"type": "newton", "tolerence": 1e-3}, "solver.tolerence: newton does not use 'tolerence' \\(did you mean 'tolerance'\\?\\)"),
])
def test_inconsistent_solver_configs_are_rejected(solver, message):
    raw = {"name": "bad", "system": SMALL_CLOTH, "integrators": ["backward_euler"], "sweep": {"dt": [0.1]}, "solver": solver}
    with pytest.raises(ConfigError, match=message):
        validate_experiment(raw)


def test_the_shipped_solver_comparison_sweeps_solvers_and_linear_solvers():
    experiment, _ = load_experiment(Path(__file__).parent.parent / "configs" / "solver_comparison.yaml")
    runs = expand_runs(experiment)
    assert {run.solver.type for run in runs} == set(SOLVERS)
    # the optional solvers stay out of a shipped config, which must run on every installation
    assert {run.solver.linear_solver for run in runs} == always_available_linear_solvers()
    assert len({run.dt for run in runs}) >= 2
    assert experiment.system.type == "cloth"


@pytest.mark.parametrize("name, options", combinations())
def test_every_solver_solves_a_dense_kepler_step(name, options):
    """The dense path (2x2 Hessians, LAPACK, whole-matrix eigen clamp): a backward Euler step of the
    Kepler orbit at dt = 0.3 s from x_n (M + h^2 K is SPD there; from dt ~ 0.7 s the incremental
    potential is unbounded below at the centre and descent methods rightly fall in), compared with
    a tight Newton solve."""
    system = CircularMotionParams(force="gravity").build()
    problem, start = backward_euler_problem(system, system.x0, system.v0, 0.3)
    reference, stats = Newton(tolerance=1e-15).minimize(problem, start)
    assert stats.converged and stats.iterations >= 3
    solver = solver_params(type=name, tolerance=1e-10, max_iterations=500, **options).build()
    if solver.refusal(system, "incremental_potential"):  # projective dynamics: the gravitational law is no spring
        pytest.skip(solver.refusal(system, "incremental_potential"))
    y, stats = solver.minimize(problem, start)
    assert stats.converged, stats
    assert np.abs(y - reference).max() < 1e-8


def test_a_fallback_restarts_from_the_best_iterate_with_the_original_threshold(cloth_step):
    """The fallback starts where the failed attempt had its smallest |g|_inf and must reach
    tolerance * |g(start)|_inf, not tolerance times the residual at its own start."""
    from simrun.solvers import GradientDescent, ProjectedNewton

    system, problem, start, reference, mu, free = cloth_step
    tried, rescuing = [], []
    main_solver = GradientDescent(tolerance=TOLERANCE, max_iterations=4,
                                  callback=lambda y, g: tried.append((np.abs(g).max(), y.copy())))
    fallback = ProjectedNewton(tolerance=TOLERANCE, callback=lambda y, g: rescuing.append((np.abs(g).max(), y.copy())))
    y, stats = FallbackChain([main_solver, fallback]).minimize(problem, start)
    best_residual, best = min(tried, key=lambda item: item[0])
    assert best_residual < tried[0][0]
    assert np.array_equal(rescuing[0][1], best)
    assert stats.converged and stats.solver_index == 1 and stats.iterations == 4 + len(rescuing) - 1
    assert stats.residual <= TOLERANCE * np.abs(problem.gradient(start)).max()
    assert np.abs(y - reference).max() < 1e-6
    first = main_solver.solve(problem, start)
    assert first.test.threshold == TOLERANCE * np.abs(problem.gradient(start)).max()
    assert fallback.solve(problem, first.best, test=first.test).test is first.test


def test_eigen_projection_leaves_the_fixed_rows_alone():
    matrix = np.array([[5.0, 1.0, 0.0], [1.0, -2.0, 0.5], [0.0, 0.5, 1.0]])
    projected = project_eigen(matrix, np.array([0]))
    assert np.array_equal(projected[0], matrix[0]) and np.array_equal(projected[:, 0], matrix[:, 0])
    block = np.linalg.eigvalsh(projected[1:, 1:])
    assert block.min() >= EIGEN_FLOOR * np.abs(np.linalg.eigvalsh(matrix[1:, 1:])).max() * (1 - 1e-9)


# ------------------------------------------------------------------------------------------------
# The solver models: each solver's options are its constructor's arguments, and nothing else
# ------------------------------------------------------------------------------------------------
# The defaults of the one flat SolverParams that the per-solver models replaced: a config that sets
# nothing must solve as before, except where a default was changed on purpose (NEW_DEFAULTS).
FORMER_DEFAULTS = {"tolerance": 1e-10, "tolerance_mode": "residual", "max_iterations": 50, "line_search": "backtracking",
                   "spd_projection": "clamp", "history": 8, "chebyshev_rho": 0.99, "relaxation": 0.9,
                   "linear_solver": "direct", "linear_tolerance": 1e-10, "linear_max_iterations": 1000, "mpcg_start": "zero", "fallback": [],
                   "on_not_converged": "continue", "initial_guess": "start", "initial_hessian": "scalar",
                   "chebyshev_warmup": 10, "determinant_floor": 1e-20,
                   # Newton's lagged factorisation, off by default (a factorisation at every iteration)
                   "refactor": "every", "refactor_rate": 0.5,
                   # a frame's wall-time budget for the real-time solvers, off by default (not newton's: the reference)
                   "time_budget": None,
                   # the compiled kernels' threads, by default the run's worker's cores
                   "threads": None}
# newton has a line search (backtracking) and safeguards; its own matrix stays the raw Hessian;
# the new solvers' own defaults (plain PD and VBD: no Chebyshev; VBD starts from the paper's guess);
# L-BFGS's H_0 is the step's projected Hessian (the scalar one needed thousands of iterations on a cloth)
NEW_DEFAULTS = {"newton": {"spd_projection": "none"}, "projective_dynamics": {"chebyshev_rho": 0.0, "relaxation": 1.0},
                "vbd": {"initial_guess": "adaptive", "chebyshev_rho": 0.0}, "lbfgs": {"initial_hessian": "step"}}


def constructor_parameters(cls) -> set[str]:
    """The keyword arguments a solver class takes: its own, and NonlinearSolver's (passed on through **options)."""
    names = set()
    for function in (cls.__init__, NonlinearSolver.__init__):
        names |= {name for name, parameter in inspect.signature(function).parameters.items()
                  if name != "self" and parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)}
    return names


def option_value(option: str):
    """A valid value of a solver option: its default in a model that has it."""
    return next(model.model_fields[option].default for model in SOLVER_PARAMS.values() if option in model.model_fields)


def other_value(info):
    """A valid value of an own option other than its default: another choice, half the float, one more; for an
    optional number off by default (time_budget), a positive one."""
    if info.default is None:
        return 0.01
    choices = typing.get_args(info.annotation)
    if choices:
        return next(choice for choice in choices if choice != info.default)
    return info.default / 2 if isinstance(info.default, float) else info.default + 1


def foreign_options() -> list:
    """(solver, an own option of another solver that it does not take), for every solver."""
    own = sorted({option for model in SOLVER_PARAMS.values() for option in model.own_fields()})
    return [pytest.param(name, option, id=f"{name}-{option}") for name, model in SOLVER_PARAMS.items()
            for option in own if option not in model.model_fields]


def solver_config(solver: dict) -> dict:
    return {"name": "solver", "system": {"type": "spring_mass"}, "integrators": ["backward_euler"],
            "solver": solver, "sweep": {"dt": [0.1]}}


def refused_by_the_command_line(tmp_path, capsys, solver: dict) -> str:
    """Run a config with this solver section: exit 2, one line on stderr, nothing written; returns the line."""
    output = tmp_path / "out"
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump({**solver_config(solver), "output": str(output)}, sort_keys=False))
    assert main(["run", str(config), "--no-plots", "-q", "-j", "1"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and captured.out == "", captured.err
    assert not output.exists()
    return lines[0]


def test_every_solver_has_a_parameter_model_under_its_name():
    assert list(SOLVER_PARAMS) == list(SOLVERS)
    for name, model in SOLVER_PARAMS.items():
        assert issubclass(model, SolverParams) and model.solver_name() == name


@pytest.mark.parametrize("name", list(SOLVER_PARAMS))
def test_a_solver_model_holds_exactly_the_arguments_of_its_constructor(name):
    """Its own fields are the constructor's arguments beyond NonlinearSolver's, and NonlinearSolver's time_budget
    where the model offers it (the real-time solvers; not the Newton family, whose runs stay the converged
    reference); build() passes every field but type, fallback, on_not_converged and threads, with the linear solver built
    from the linear_* fields."""
    model = SOLVER_PARAMS[name]
    budgeted = {"time_budget"} & set(model.model_fields)
    assert budgeted == ({"time_budget"} if name not in ("newton", "projected_newton") else set())
    assert set(model.own_fields()) == constructor_parameters(SOLVERS[name]) - constructor_parameters(NonlinearSolver) | budgeted
    arguments = model(linear_solver="cg", linear_tolerance=1e-4, linear_max_iterations=9).constructor_arguments()
    assert set(arguments) == constructor_parameters(SOLVERS[name]) - {"callback"} - ({"time_budget"} - budgeted)
    linear = arguments["linear_solver"]
    assert type(linear) is LINEAR_SOLVERS["cg"] and (linear.tolerance, linear.max_iterations) == (1e-4, 9)
    assert type(model().build()) is SOLVERS[name]


@pytest.mark.parametrize("name", list(SOLVER_PARAMS))
def test_every_default_is_the_former_one_and_the_dump_holds_every_field(name):
    params = solver_params(type=name)
    assert type(params) is SOLVER_PARAMS[name]
    dump = params.model_dump(mode="json")
    assert list(dump) == list(SOLVER_PARAMS[name].model_fields)
    expected = {**FORMER_DEFAULTS, **NEW_DEFAULTS.get(name, {})}
    assert dump == {"type": name, **{key: expected[key] for key in dump if key != "type"}}
    assert solver_params(**dump) == params


@pytest.mark.parametrize("name, option", foreign_options())
def test_an_option_the_solver_does_not_use_is_refused_in_one_line(tmp_path, capsys, name, option):
    line = refused_by_the_command_line(tmp_path, capsys, {"type": name, option: option_value(option)})
    takes = ", ".join(key for key in SOLVER_PARAMS[name].model_fields if key != "type")
    assert line == f"simrun: error: solver.{option}: {name} does not use {option!r}; it takes: {takes}"


def test_newton_refuses_history(tmp_path, capsys):
    assert refused_by_the_command_line(tmp_path, capsys, {"type": "newton", "history": 8}) == (
        "simrun: error: solver.history: newton does not use 'history'; it takes: tolerance, tolerance_mode, initial_guess, "
        "max_iterations, linear_solver, linear_tolerance, linear_max_iterations, mpcg_start, fallback, on_not_converged, "
        "threads, line_search, refactor, refactor_rate, spd_projection")
    with pytest.raises(SolverOptionError, match="^history: newton does not use 'history'; it takes: tolerance, "):
        solver_params(type="newton", history=8)  # from Python, the same line


def test_the_shared_base_is_not_built_directly():
    with pytest.raises(ValueError, match="solver_params"):
        SolverParams(type="lbfgs", history=4)


def fallback_options() -> list:
    """(main solver, fallback, an own option of the fallback that the main solver does not take)."""
    return [pytest.param(main_name, name, option, id=f"{main_name}-{name}-{option}")
            for main_name, main_model in SOLVER_PARAMS.items() for name, model in SOLVER_PARAMS.items()
            if name != main_name for option in model.own_fields() if option not in main_model.model_fields]


@pytest.mark.parametrize("main_name, name, option", fallback_options())
def test_a_fallbacks_option_at_the_top_level_is_refused_with_the_entry_to_write(main_name, name, option):
    value = option_value(option)
    with pytest.raises(ConfigError) as error:
        validate_experiment(solver_config({"type": main_name, "fallback": [name], option: value}))
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"solver.{option}: {main_name} does not use {option!r}; it takes: ")
    assert message.endswith(f"; to set it for the fallback {name}, give it in its entry: "
                            f"fallback: [{{type: {name}, {option}: {value}}}]")


@pytest.mark.parametrize("name", list(SOLVER_PARAMS))
def test_a_fallback_entry_gives_its_own_options_and_takes_the_shared_ones_from_the_main_solver(name):
    """As a name: its own defaults; as a mapping: the options given; either way tolerance and the rest
    of the shared options are the main solver's."""
    main_name = next(other for other in SOLVER_PARAMS if other != name)
    # every own option but time_budget, which a chain refuses (test_projective.py: with a fallback, refused)
    own = {key: other_value(info) for key, info in SOLVER_PARAMS[name].own_fields().items() if key != "time_budget"}
    shared = {"tolerance": 1e-6, "max_iterations": 7, "linear_solver": "cg", "linear_tolerance": 1e-4}
    for entry, options in ((name, {}), ({"type": name}, {}), ({"type": name, **own}, own)):
        params = validate_experiment(solver_config({"type": main_name, **shared, "fallback": [entry]})).solver
        assert params.fallback == [{"type": name, **{**SOLVER_PARAMS[name]().model_dump(include=set(SOLVER_PARAMS[name].own_fields())),
                                                     **options}}]
        main_params, fallback = params.chain()
        assert main_params is params and type(fallback) is SOLVER_PARAMS[name]
        # every shared option is the main solver's, even one whose default this solver changes (vbd's initial_guess)
        main_shared = {key: getattr(main_params, key) for key in SolverParams.model_fields if key not in ("type", "fallback")}
        assert fallback.model_dump() == {**SOLVER_PARAMS[name]().model_dump(), **main_shared, **shared, **options}
        chain = params.build()
        assert isinstance(chain, FallbackChain) and [type(solver) for solver in chain.solvers] == [SOLVERS[main_name], SOLVERS[name]]
        for solver in chain.solvers:
            assert (solver.tolerance, solver.max_iterations) == (1e-6, 7)
            assert type(solver.linear_solver) is LINEAR_SOLVERS["cg"] and solver.linear_solver.tolerance == 1e-4


def test_a_fallback_chain_is_built_with_each_solvers_own_options():
    """The built solvers' attributes: the main solver's line search stays its own (lbfgs, a name, keeps
    the default one), Jacobi-Chebyshev's rho and relaxation come from its entry."""
    params = validate_experiment(solver_config({
        "type": "projected_newton", "line_search": "armijo", "tolerance": 1e-6, "max_iterations": 7,
        "fallback": ["lbfgs", {"type": "jacobi_chebyshev", "chebyshev_rho": 0.5, "relaxation": 0.25, "spd_projection": "none"},
                     {"type": "gradient_descent", "line_search": "none"}]})).solver
    chain = params.build()
    assert [solver.name for solver in chain.solvers] == ["projected_newton", "lbfgs", "jacobi_chebyshev", "gradient_descent"]
    main_solver, lbfgs, jacobi, descent = chain.solvers
    assert all((solver.tolerance, solver.max_iterations) == (1e-6, 7) for solver in chain.solvers)
    assert (main_solver.line_search, main_solver.spd_projection) == ("armijo", "clamp")
    assert (lbfgs.line_search, lbfgs.history) == ("backtracking", 8)
    assert (jacobi.line_search, jacobi.rho, jacobi.relaxation, jacobi.spd_projection) == ("backtracking", 0.5, 0.25, "none")
    assert descent.line_search == "none"
    assert params.model_dump(mode="json")["fallback"] == [
        {"type": "lbfgs", "line_search": "backtracking", "history": 8, "initial_hessian": "step", "time_budget": None},
        {"type": "jacobi_chebyshev", "line_search": "backtracking", "chebyshev_rho": 0.5, "relaxation": 0.25, "spd_projection": "none",
         "time_budget": None},
        {"type": "gradient_descent", "line_search": "none", "time_budget": None}]


def test_runs_keep_the_solvers_own_options_through_the_sweep():
    """expand_runs re-validates a dump of the experiment: the dump must hold the solver's own options."""
    experiment = validate_experiment({**solver_config({"type": "lbfgs", "history": 4, "fallback": [{"type": "jacobi_chebyshev", "relaxation": 0.5}]}),
                                      "sweep": {"dt": [0.1], "solver.max_iterations": [5, 6]}})
    runs = expand_runs(experiment)
    assert [(run.solver.max_iterations, run.solver.history, run.solver.fallback[0]["relaxation"]) for run in runs] == [(5, 4, 0.5), (6, 4, 0.5)]
    assert validate_experiment(solver_config({})).solver == solver_params(type="newton")


def test_unknown_keys_are_matched_against_the_chosen_solvers_options():
    assert _fields_at(["solver"], {"solver": {"type": "lbfgs"}}) == SOLVER_PARAMS["lbfgs"].model_fields
    assert _fields_at(["solver"], {"solver": {}}) == SOLVER_PARAMS["newton"].model_fields


def test_a_chain_takes_the_one_newton_step_with_the_next_solver_when_the_linear_solve_fails():
    """Semi-implicit methods take one Newton step; MPCG breaks down on an indefinite matrix (a compressed
    spring), so the chain takes the step with the next solver's matrix (projected Newton's SPD one) and says so."""
    from simrun.solvers.fallback import FallbackChain
    from simrun.solvers.newton import Newton, ProjectedNewton

    class Indefinite:
        fixed_dofs = np.zeros(0, dtype=np.intp)
        residual_floor = 0.0

        def gradient(self, y):
            return np.array([1.0, 1.0]) + np.array([-1.0, 2.0]) * y

        def hessian(self, y, project_spd=False):
            return np.diag([1.0, 2.0]) if project_spd else np.diag([-1.0, 2.0])

    chain = FallbackChain([Newton(linear_solver="mpcg"), ProjectedNewton(linear_solver="mpcg")])
    y, stats = chain.newton_step(Indefinite(), np.zeros(2))
    assert stats.solver_index == 1
    np.testing.assert_allclose(y, [-1.0, -0.5], rtol=1e-12)  # the projected matrix's step
    with pytest.raises(np.linalg.LinAlgError):
        FallbackChain([Newton(linear_solver="mpcg")]).newton_step(Indefinite(), np.zeros(2))


class _CountingMatrix(np.ndarray):
    """A dense matrix that counts its products with a vector (one per iteration of a stationary method)."""

    products = 0

    def __matmul__(self, other):
        _CountingMatrix.products += 1
        return np.asarray(self) @ other


def _jacobi_matrix(radius: float, size: int = 40) -> np.ndarray:
    """An SPD matrix of unit diagonal whose Jacobi iteration matrix I - A has spectral radius ``radius``: A = (1 - c) I
    + c 1 1^T with c = radius / (size - 1) has the eigenvalues 1 + radius (along 1) and 1 - c, so I - A has -radius
    and c."""
    c = radius / (size - 1)
    return (1.0 - c) * np.eye(size) + c * np.ones((size, size))


@pytest.mark.parametrize("radius, outcome", [(1.002, "diverges"), (0.9995, "cannot reach"), (0.6, None)])
def test_a_stationary_iteration_that_cannot_converge_stops_within_a_few_windows(radius, outcome):
    """Point Jacobi on SPD matrices whose iteration matrix I - D^-1 A has spectral radius 1.002 (it diverges, but its
    residual passes 1e8 |b| only after ~9,000 iterations), 0.9995 (it converges, in ~40,000 iterations: hopeless in
    a budget of 2,000) and 0.6: the first two raise LinAlgError saying which within 100 iterations, the third
    converges to its tolerance as before."""
    from simrun.solvers.linear import Jacobi

    matrix = _jacobi_matrix(radius)
    measured = float(np.max(np.abs(np.linalg.eigvalsh(np.eye(40) - matrix))))
    assert np.all(np.linalg.eigvalsh(matrix) > 0.0)  # SPD, so that only the iteration's radius can fail it
    assert measured == pytest.approx(radius)
    rhs = np.random.default_rng(4).standard_normal(40)
    solver = Jacobi(tolerance=1e-10, max_iterations=2000)
    _CountingMatrix.products = 0
    counting = matrix.view(_CountingMatrix)
    if outcome is None:
        solution, iterations = solver._solve(counting, rhs, spd=True)
        assert np.linalg.norm(rhs - matrix @ solution) <= 1e-10 * np.linalg.norm(rhs) and iterations < 200
        return
    with pytest.raises(np.linalg.LinAlgError, match=outcome):
        solver._solve(counting, rhs, spd=True)
    assert _CountingMatrix.products <= 100


def test_lbfgs_two_loop_recursion_runs_on_one_blas_thread_and_gives_the_threads_back(monkeypatch):
    """The recursion's ddot and daxpy on long vectors make OpenBLAS wake its other threads for each (slower on two
    cores: docs/performance.md, "Threads and BLAS"): they run on one BLAS thread, and the solve leaves the thread counts as it found them."""
    import threadpoolctl

    from simrun.solvers import descent

    def blas_threads():
        return [library["num_threads"] for library in threadpoolctl.threadpool_info() if library["user_api"] == "blas"]

    seen = []
    original = descent.ddot

    def counting_ddot(*args, **options):
        seen.append(max(blas_threads()))
        return original(*args, **options)

    monkeypatch.setattr(descent, "ddot", counting_ddot)
    system = ClothParams(resolution=(6, 6), stretch_stiffness=300.0, pinned=["top_left", "top_right"]).build()
    problem, start = step_problem(system, dt=0.02)
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        SOLVERS["lbfgs"](tolerance=1e-12, max_iterations=12, history=4).minimize(problem, start)
        after = blas_threads()
    assert len(seen) > 20 and set(seen) == {1}
    assert after == before
