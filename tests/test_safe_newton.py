"""Newton that does not blow up, and the lectures' stopping rules, against theory.

- The safeguards fire on a constructed indefinite problem (a double well, whose raw Newton direction
  climbs) and never on a strictly convex one; each fired safeguard is a bit of SolveStats.safeguards.
- The clamp and abs projections give positive semi-definite matrices; abs mirrors eigenvalues.
- tolerance_mode velocity stops at |p|_inf / b <= tolerance with the step applied; absolute at |g| <= tolerance.
- The initial guesses are the points their definitions give.
- A run's status: diverged wins over not_converged; the first step of each is recorded.
- The cloth dropped on a penalty sphere (16x16, k = 1e5, backward Euler, dt = 0.005, tolerance 1e-9) ends
  ok with the default solver, at most 8 Newton iterations per step on average.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from conftest import run_one, step_problem
from simrun.solvers import solver_params
from simrun.solvers.newton import SAFEGUARDS, project_eigen
from simrun.systems import ClothParams, SpringMassParams


class DoubleWell:
    """E(y) = (y0^2 - 1)^2 + 1/2 y1^2: its Hessian 12 y0^2 - 4 is negative for |y0| < 1/sqrt(3)."""

    fixed_dofs = np.zeros(0, dtype=np.intp)
    residual_floor = 0.0

    def value(self, y):
        return float((y[0] ** 2 - 1.0) ** 2 + 0.5 * y[1] ** 2)

    def gradient(self, y):
        return np.array([4.0 * y[0] * (y[0] ** 2 - 1.0), y[1]])

    def hessian(self, y, project_spd=False):
        curvature = 12.0 * y[0] ** 2 - 4.0
        if project_spd:
            curvature = abs(curvature) if project_spd == "abs" else max(curvature, 0.0)
        return np.diag([curvature, 1.0])


class ConvexQuartic:
    """E(y) = 1/2 y^T A y - b^T y + 1/4 sum y^4, A SPD: strictly convex, Newton's direction always descends."""

    fixed_dofs = np.zeros(0, dtype=np.intp)
    residual_floor = 0.0
    matrix = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]])
    rhs = np.array([1.0, -2.0, 3.0])

    def value(self, y):
        return float(0.5 * y @ self.matrix @ y - self.rhs @ y + 0.25 * np.sum(y ** 4))

    def gradient(self, y):
        return self.matrix @ y - self.rhs + y ** 3

    def hessian(self, y, project_spd=False):
        return self.matrix + np.diag(3.0 * y ** 2)


def test_the_raw_newton_direction_of_the_double_well_climbs():
    """The premise: at y0 = 0.1 the raw direction p = -g/H has g p > 0 (H < 0 there)."""
    problem, y = DoubleWell(), np.array([0.1, 0.0])
    direction = -np.linalg.solve(problem.hessian(y), problem.gradient(y))
    assert problem.gradient(y) @ direction > 0


@pytest.mark.parametrize("projection", ["none", "adaptive"])
def test_safeguards_fire_on_an_indefinite_problem_and_reach_a_minimum(projection):
    problem = DoubleWell()
    y, stats = solver_params(type="newton", tolerance=1e-12, spd_projection=projection).build().minimize(problem, np.array([0.1, 0.0]))
    assert stats.converged
    assert np.allclose(y, [1.0, 0.0], atol=1e-10)  # the minimum on the side of the start (abs flips the climb)
    assert stats.safeguards & SAFEGUARDS["projected"]


def test_plain_newton_without_a_line_search_goes_uphill_on_the_double_well():
    """The contrast: full steps of the raw Newton direction end at the local maximum y0 = 0."""
    problem = DoubleWell()
    y, stats = solver_params(type="newton", tolerance=1e-12, line_search="none").build().minimize(problem, np.array([0.1, 0.0]))
    assert abs(y[0]) < 1e-8 and stats.safeguards == 0  # a stationary point, but the maximum of the well


@pytest.mark.parametrize("projection", ["none", "clamp", "abs", "adaptive", "eigen"])
def test_no_safeguard_fires_on_a_convex_problem(projection):
    """Far from the minimiser the line search may cut a step (bit line_search), but no direction needs
    the projected or regularised matrix; from near the minimiser no safeguard fires at all."""
    problem = ConvexQuartic()
    solver = solver_params(type="newton", tolerance=1e-13, spd_projection=projection).build()
    y, stats = solver.minimize(problem, np.zeros(3))
    assert stats.converged and stats.safeguards & (SAFEGUARDS["projected"] | SAFEGUARDS["regularized"]) == 0
    assert np.max(np.abs(problem.gradient(y))) < 1e-11
    _, near = solver.minimize(problem, y + 0.01)
    assert near.converged and near.safeguards == 0


def test_regularization_fires_where_even_the_projected_matrix_cannot_be_solved():
    """A problem whose 'projected' Hessian is singular: modified Newton adds multiples of the diagonal."""

    class Singular(DoubleWell):
        def hessian(self, y, project_spd=False):
            return np.zeros((2, 2)) if project_spd else super().hessian(y)

    y, stats = solver_params(type="newton", tolerance=1e-10).build().minimize(Singular(), np.array([0.1, 0.0]))
    assert stats.safeguards & SAFEGUARDS["regularized"]
    assert stats.converged and np.allclose(np.abs(y), [1.0, 0.0], atol=1e-8)  # one of the two minima


def compressed_cloth():
    system = ClothParams(resolution=(6, 6), mass=0.1, stretch_stiffness=200.0, shear_stiffness=50.0,
                         bend_stiffness=5.0, pinned=[]).build()
    positions = system.x0.reshape(-1, 3).copy()
    positions[:, :2] *= 0.5  # every stretch spring compressed to half its rest length
    positions[:, 2] = 0.01 * np.random.default_rng(1).standard_normal(len(positions))
    return system, positions.ravel()


@pytest.mark.parametrize("projection", [True, "abs"])
def test_the_projections_of_a_compressed_cloth_are_positive_semidefinite(projection):
    system, x = compressed_cloth()
    raw = system.hessian(x).toarray()
    assert np.linalg.eigvalsh(raw).min() < -1.0, "the compressed cloth's Hessian must be indefinite"
    projected = system.hessian(x, project_spd=projection).toarray()
    assert np.allclose(projected, projected.T)
    assert np.linalg.eigvalsh(projected).min() >= -1e-9 * np.abs(raw).max()


def test_abs_mirrors_each_spring_blocks_negative_eigenvalue():
    """A single Hookean spring compressed to L = l0/2: transverse eigenvalue k (1 - l0/L) = -k, mirrored to +k."""
    system, x = compressed_cloth()
    geometry = system._geometry_at(x)
    law = system.law
    raw, mirrored = law.blocks(system, geometry, False), law.blocks(system, geometry, "abs")
    raw_eigenvalues, mirrored_eigenvalues = np.linalg.eigvalsh(raw), np.linalg.eigvalsh(mirrored)
    assert np.allclose(np.sort(np.abs(raw_eigenvalues), axis=1), np.sort(mirrored_eigenvalues, axis=1))


def test_the_dense_abs_projection_mirrors_the_eigenvalues():
    rng = np.random.default_rng(3)
    basis, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    eigenvalues = np.array([-3.0, -0.5, 2.0, 7.0])
    matrix = (basis * eigenvalues) @ basis.T
    mirrored = project_eigen(matrix, np.zeros(0, dtype=np.intp), mirror=True)
    assert np.allclose(np.sort(scipy.linalg.eigvalsh(mirrored)), np.sort(np.abs(eigenvalues)))
    clamped = project_eigen(matrix, np.zeros(0, dtype=np.intp))
    assert np.allclose(np.sort(scipy.linalg.eigvalsh(clamped))[2:], [2.0, 7.0])
    assert np.all(scipy.linalg.eigvalsh(clamped)[:2] <= 1e-6)


def captured_problem(method, system, x, v, dt):
    return step_problem(system, x, v, dt, integrator=method)


def test_velocity_mode_applies_the_step_that_meets_it():
    """On the linear spring the first Newton step is exact: |p|/h is then far above 1e-2 m/s, the second
    direction is zero, so the solve stops after applying the first one (the lectures' loop); the step
    that met the test is applied, so the answer is the backward Euler solution itself."""
    system = SpringMassParams(stiffness=100.0, x0=1.0, v0=0.5).build()
    dt = 0.1
    problem, start = captured_problem("backward_euler", system, system.x0, system.v0, dt)
    exact = (system.x0 + dt * system.v0) / (1.0 + dt * dt * 100.0)
    y, stats = solver_params(tolerance=1e-2, tolerance_mode="velocity").build().minimize(problem, start)
    assert stats.converged and np.allclose(y, exact, rtol=0, atol=1e-15)


def test_velocity_mode_stops_once_the_step_is_below_tolerance_times_b():
    """Stretched cloth, backward Euler: the solve ends at the first direction with |p|_inf <= tol h, and that
    direction is applied: the returned y is within |p| of the last iterate and much closer to y*."""
    system = ClothParams(resolution=(6, 6), mass=1.0, stretch_stiffness=200.0, shear_stiffness=50.0,
                         bend_stiffness=5.0, pinned=["top_left", "top_right"]).build()
    x = system.x0.reshape(-1, 3).copy()
    x[:, 0] *= 1.1
    x[:, 2] = 0.1 * np.sin(np.pi * x[:, 0])
    dt, tolerance = 0.02, 1e-3
    problem, start = captured_problem("backward_euler", system, x.ravel(), np.zeros(system.dof_count), dt)
    reference, _ = solver_params(tolerance=1e-14).build().minimize(problem, start)
    iterates = []
    solver = solver_params(tolerance=tolerance, tolerance_mode="velocity").build()
    solver.callback = lambda y, g: iterates.append(y.copy())
    y, stats = solver.minimize(problem, start)
    assert stats.converged and len(iterates) == stats.iterations + 1
    last_step = np.max(np.abs(iterates[-1] - iterates[-2]))
    assert last_step <= tolerance * dt  # the test met by the applied step
    assert np.max(np.abs(iterates[-2] - iterates[-3])) > tolerance * dt  # ... and not by the one before
    assert np.max(np.abs(y - reference)) < 1e-2 * last_step  # Newton's quadratic convergence: the applied step was the error


def test_absolute_mode_stops_at_the_residual_in_its_own_units():
    system = SpringMassParams(stiffness=100.0).build()
    problem, start = captured_problem("backward_euler", system, system.x0, system.v0, 0.1)
    solver = solver_params(tolerance=1e-6, tolerance_mode="absolute").build()
    residuals = []
    solver.callback = lambda y, g: residuals.append(np.max(np.abs(g)))
    solver.minimize(problem, start)
    assert residuals[-1] <= 1e-6 and residuals[0] > 1e-6


@pytest.mark.parametrize("method, fraction", [("backward_euler", 1.0), ("implicit_midpoint", 0.5), ("bdf2", 1.0)])
def test_initial_guesses_are_what_their_definitions_give(method, fraction):
    system = ClothParams(resolution=(4, 4), pinned=[]).build()
    rng = np.random.default_rng(5)
    x, v, dt = system.x0 + 0.01 * rng.standard_normal(system.dof_count), rng.standard_normal(system.dof_count), 0.01
    problem, start = captured_problem(method, system, x, v, dt)
    assert np.array_equal(problem.initial_guess("start"), x)
    assert np.allclose(problem.initial_guess("inertial"), x + fraction * dt * v, rtol=0, atol=1e-15)
    assert np.array_equal(problem.initial_guess("predictor"), problem.y_tilde)



@pytest.mark.parametrize("guess", ["start", "inertial", "predictor"])
def test_semi_implicit_backward_euler_takes_its_one_newton_step_from_the_configured_guess(guess):
    """semi_implicit_backward_euler is one Newton step on backward Euler's incremental potential: from x_n
    (Baraff & Witkin, ``start``) or from the solver's initial_guess. On a stretched, moving cloth the step
    equals y0 - H(y0)^-1 g(y0) computed by hand from that guess, and the guesses give different steps."""
    from simrun.integrators import INTEGRATORS, State
    system = ClothParams(resolution=(4, 4), pinned=[]).build()
    rng = np.random.default_rng(7)
    x, v, dt = 1.05 * system.x0 + 0.01 * rng.standard_normal(system.dof_count), rng.standard_normal(system.dof_count), 0.01
    problem, _ = captured_problem("backward_euler", system, x, v, dt)
    start = problem.initial_guess(guess)
    hessian = problem.hessian(start)
    dense = hessian.toarray() if hasattr(hessian, "toarray") else np.asarray(hessian)
    expected = start - scipy.linalg.solve(dense, problem.gradient(start))
    state, stats = INTEGRATORS["semi_implicit_backward_euler"]().step(
        system, State(0.0, x, v), dt, solver_params(initial_guess=guess).build())
    assert stats.iterations == 1
    assert np.allclose(state.x, expected, rtol=0, atol=1e-12)
    if guess != "start":
        from_x_n, _ = INTEGRATORS["semi_implicit_backward_euler"]().step(system, State(0.0, x, v), dt, solver_params().build())
        assert np.abs(from_x_n.x - state.x).max() > 1e-9  # a nonlinear step: where it is linearised matters

def test_the_adaptive_guess_of_a_free_fall_is_the_backward_euler_step():
    """A cloth at rest shape in free fall: no spring force, so a = g and backward Euler's y* = x + h v + h^2 g,
    exactly the adaptive guess y~ + h^2 a~: the solve from it needs no iteration."""
    system = ClothParams(resolution=(5, 5), pinned=[], gravity=(0.0, 0.0, -9.81)).build()
    dt, v = 0.01, np.tile([0.0, 0.0, -0.3], 25)
    problem, start = captured_problem("backward_euler", system, system.x0, v, dt)
    guess = problem.initial_guess("adaptive")
    assert np.allclose(guess, system.x0 + dt * v + dt * dt * np.tile([0.0, 0.0, -9.81], 25), rtol=0, atol=1e-15)
    _, stats = solver_params(tolerance=1e-10, initial_guess="adaptive").build().minimize(problem, start)
    assert stats.iterations == 0 and stats.converged
    _, from_start = solver_params(tolerance=1e-10).build().minimize(problem, start)
    assert from_start.iterations >= 1


def test_a_run_that_diverges_while_stopping_on_not_converged_is_diverged():
    """Backward Euler's Kepler orbit spirals in; near the centre, where the incremental potential is unbounded
    below, the line-search Newton follows it into the singularity: a step that does not converge and leaves the
    energy bound at once. With on_not_converged: stop the run ends there, and it is diverged (the energy left
    the bound), with that step recorded as both the first not converged and the diverged one."""
    result = run_one({"type": "circular_motion", "force": "gravity"}, "backward_euler", 0.05, 5.0,
                     solver={"on_not_converged": "stop"})
    assert result.status == "diverged", result.message
    assert result.attrs["diverged_step"] == result.steps
    assert result.attrs["first_not_converged_step"] == result.steps and result.attrs["not_converged_steps"] == 1
    result = run_one({"type": "circular_motion", "force": "gravity"}, "backward_euler", 0.1, 1.0,
                     solver={"type": "gradient_descent", "tolerance": 1e-15, "max_iterations": 1, "on_not_converged": "continue"})
    assert result.status == "not_converged"
    assert result.attrs["first_not_converged_step"] == 1 and result.attrs["diverged_step"] == 0


def test_accepting_a_budget_keeps_the_run_ok_and_counts_the_steps():
    result = run_one({"type": "circular_motion", "force": "gravity"}, "backward_euler", 0.1, 1.0,
                     solver={"type": "gradient_descent", "tolerance": 1e-15, "max_iterations": 1, "on_not_converged": "accept"})
    assert result.status == "ok" and result.attrs["not_converged_steps"] == 10
    assert result.attrs["first_not_converged_step"] == 1


def test_the_cloth_dropped_on_a_penalty_sphere_ends_ok_with_few_newton_iterations():
    """The held-out scene of Newton's safeguards (docs/solvers.md, "Newton that does not blow up"), to just after first contact (t = 0.25 s) and through it: default solver."""
    system = {"type": "cloth", "resolution": [16, 16], "size": [1.0, 1.0], "mass": 1.0, "stretch_stiffness": 1.0e4,
              "shear_stiffness": 1.0e3, "bend_stiffness": 10.0, "damping": 0.1, "gravity": [0.0, 0.0, -9.81],
              "pinned": [], "contact": {"sphere": {"center": [0.5, 0.5, -0.6], "radius": 0.3, "stiffness": 1.0e5}}}
    result = run_one(system, "backward_euler", 0.005, 0.4, solver={"tolerance": 1e-9})
    assert result.status == "ok", result.message
    iterations = result.per_step["newton_iterations"]
    assert iterations.mean() <= 8.0
    assert result.per_step["safeguards"].any(), "first contact must need a safeguard (the raw Hessian is indefinite there)"
