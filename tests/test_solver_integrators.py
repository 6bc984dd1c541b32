"""The solvers of graphics practice with every incremental-potential integrator.

tests/test_solvers.py checks every solver on backward Euler's step only; the other implicit methods hand the
solver an incremental potential with another scale c h^2, predictor y~ and point of evaluation (implicit
midpoint: y = x_{n+1/2}; generalized-alpha: y = x_{n+1-alpha_f}; BDF2: c = 4/9 and the history in y~), and the
rest matrix A = M + c h^2 K_r of projective dynamics and L-BFGS depends on that scale. Here each of those
problems, captured from one step of a small undamped cloth stretched so that the step is nonlinear, must be
solved to its minimiser y* (Newton at 1e-14) within the bound of a strongly convex problem,
|y - y*|_2 <= |g(y)|_2 / mu, mu the smallest eigenvalue of the Hessian at y* on the free dofs.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

from conftest import own_step_problem, stretched_cloth_state
from simrun.cli import main
from simrun.integrators import INTEGRATORS
from simrun.solvers import solver_params
from simrun.systems import ClothParams

# no spring damping (the step of the review); h^2 k / m = 0.0004 * 200 * 36 = 2.9: nonlinear
CLOTH = dict(resolution=(6, 6), mass=1.0, stretch_stiffness=200.0, shear_stiffness=50.0, bend_stiffness=5.0,
             damping=0.0, pinned=["top_left", "top_right"])
DT = 0.02
TOLERANCE = 1e-11  # relative residual: the solvers then reach y* to ~1e-12 m (measured <= 2.6e-12)
# the integrators whose steps minimise an IncrementalPotential (semi_implicit_backward_euler's problem kind is
# newton_step: one Newton step, see the last test)
INTEGRATOR_NAMES = sorted(name for name, cls in INTEGRATORS.items() if cls.problem_kind == "incremental_potential")
# steps taken (with Newton) before the captured one: BDF2's first step is backward Euler's, its second is BDF2
WARMUP_STEPS = {"bdf2": 1}
SOLVER_OPTIONS = [("projective_dynamics", {"chebyshev_rho": 0.99}), ("vbd", {"chebyshev_rho": 0.9}),
                  ("lbfgs", {"initial_hessian": "rest"}), ("lbfgs", {"initial_hessian": "step", "initial_guess": "inertial"}),
                  ("newton", {"spd_projection": "abs"}), ("newton", {"spd_projection": "adaptive"}),
                  ("newton", {"tolerance_mode": "velocity"})]


def test_the_integrators_under_test_are_the_five_of_the_review():
    assert {"backward_euler", "implicit_midpoint", "newmark", "generalized_alpha", "bdf2"} <= set(INTEGRATOR_NAMES)


def expected_scale(integrator) -> float | None:
    """c h^2 of the method's incremental potential (integrators/implicit.py, multistep.py), None if not listed."""
    if integrator.name == "generalized_alpha":
        alpha_m, alpha_f, beta, _ = integrator.coefficients
        return beta * (1.0 - alpha_f) / (1.0 - alpha_m) * DT * DT
    if integrator.name == "newmark":
        return integrator.beta * DT * DT
    c = {"backward_euler": 1.0, "implicit_midpoint": 0.25, "bdf2": 4.0 / 9.0}.get(integrator.name)
    return None if c is None else c * DT * DT


@pytest.fixture(scope="module", params=INTEGRATOR_NAMES)
def integrator_step(request):
    """The stretched (1.1 in plane, pins included) and bulged cloth with random velocities; one step of the
    integrator (after WARMUP_STEPS), its problem captured; y* by Newton at 1e-14 and mu > 0 at y*."""
    name = request.param
    system = ClothParams(**CLOTH).build()
    integrator = INTEGRATORS[name]()
    problem, start = own_step_problem(system, name, *stretched_cloth_state(system), DT, WARMUP_STEPS.get(name, 0))
    if expected_scale(integrator) is not None:  # the method's own step is captured (BDF2's, not the first BE step)
        assert problem.scale == pytest.approx(expected_scale(integrator), rel=1e-14)
    reference, stats = solver_params(type="newton", tolerance=1e-14, max_iterations=50).build().minimize(problem, start)
    assert stats.converged and stats.iterations >= 3, "the step must be nonlinear"
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    hessian = problem.hessian(reference)
    dense = hessian.toarray() if scipy.sparse.issparse(hessian) else np.asarray(hessian)
    mu = np.linalg.eigvalsh(dense[np.ix_(free, free)]).min()
    assert mu > 0, "the step must be strictly convex, so that y* is unique"  # measured 0.025-0.028
    return system, problem, start, reference, mu, free


@pytest.mark.parametrize("name, options", SOLVER_OPTIONS,
                         ids=[f"{name}-{'-'.join(map(str, options.values()))}" for name, options in SOLVER_OPTIONS])
def test_every_solver_reaches_the_minimiser_of_each_integrators_step(integrator_step, name, options):
    """|y - y*|_2 <= |g(y)|_2 / mu (2x room for the change of the Hessian between y and y*), y* to 1e-10 m
    (measured <= 2.6e-12 m), fixed dofs untouched, and the residual meets the relative test where it is one."""
    system, problem, start, reference, mu, free = integrator_step
    solver = solver_params(type=name, tolerance=TOLERANCE, max_iterations=2000, **options).build()
    assert solver.refusal(system, "incremental_potential") is None
    y, stats = solver.minimize(problem, start)
    assert stats.converged, stats
    assert np.array_equal(y[system.fixed_dofs], start[system.fixed_dofs])
    gradient = problem.gradient(y)
    if options.get("tolerance_mode", "residual") == "residual" and "initial_guess" not in options:  # relative to g(x_n)
        assert np.abs(gradient[free]).max() <= max(TOLERANCE * np.abs(problem.gradient(start)[free]).max(),
                                                   problem.residual_floor)
    assert np.linalg.norm(y - reference) <= 2.0 * np.linalg.norm(gradient[free]) / mu + 1e-13
    assert np.abs(y - reference).max() < 1e-10


@pytest.mark.parametrize("name", ["projective_dynamics", "vbd"])
def test_semi_implicit_backward_euler_refuses_the_iterative_solvers_at_config_time(tmp_path, capsys, name):
    """Baraff-Witkin takes exactly one Newton step, which PD's and VBD's iterations are not: `simrun` on such a config
    exits with status 2 and one line naming solver.type, before any run (no output folder). lbfgs is
    not refused (it keeps the base's takes_newton_step = True), so it is not listed here."""
    output = tmp_path / "never"
    config = tmp_path / "config.yaml"
    config.write_text("name: semi_implicit\n"
                      "system: {type: cloth, resolution: [6, 6], damping: 0.0, pinned: [top_left, top_right]}\n"
                      f"integrators: [semi_implicit_backward_euler]\nsolver: {{type: {name}}}\n"
                      f"duration: 0.04\nsweep: {{dt: [0.02]}}\noutput: {output}\n")
    assert main([str(config)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"simrun: error: solver.type: {name} "), captured.err
    assert "semi_implicit_backward_euler" in lines[0] and "Traceback" not in captured.err
    assert not output.exists()
