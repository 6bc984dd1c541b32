"""One projected Newton iteration of backward Euler on the cloth, over one SuperLU factorisation.

The real solver (``solver_params(type="projected_newton").build()``: clamped Hessian, backtracking
line search, direct solve) minimises one incremental potential of a deformed, moving cloth for a
fixed number of iterations (tolerance 0, so none ends early); the time per iteration (assembly,
restriction to the free dofs, factorisation and solve, line search, bookkeeping) is divided by the
time of one ``splu`` of the same reduced matrix with the options the direct solver uses, measured
in the same run. Target: at most 1.3 at 64x64. The same iteration with the optional
``cholesky`` linear solver (CHOLMOD: the pattern analysed in the warm-up solve, as in a run's
first step, then refactored per iteration) against the same splu: at most 0.6 at 64x64.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg

from simrun.integrators import IncrementalPotential
from simrun.solvers import LINEAR_SOLVERS, solver_params
from simrun.solvers.linear import SPLU_ORDERING, SPLU_SPD_OPTIONS
from simrun.systems import ClothParams

from .cloth_newton import DT, deformed_state
from .timing import best_of

RESOLUTIONS = (32, 64, 128)
ITERATIONS = 4
TARGET = {"direct": {64: 1.3}, "cholesky": {64: 0.6}}


def cloth_step_problem(resolution: int):
    system = ClothParams(resolution=(resolution, resolution)).build()
    x, v = deformed_state(system)
    problem = IncrementalPotential(system, x + DT * v, DT * DT, velocity_origin=x, velocity_divisor=DT, damping_at=x)
    return system, problem, x


def repeats(resolution: int) -> int:
    return 3 if resolution <= 64 else 1


def newton_iteration(resolution: int, linear_solver: str) -> tuple[float, int]:
    """(best wall time per projected Newton iteration, iterations per solve) with ``linear_solver``."""
    _, problem, x = cloth_step_problem(resolution)
    solver = solver_params(type="projected_newton", linear_solver=linear_solver, tolerance=1e-300,
                           max_iterations=ITERATIONS).build()

    def newton():
        start = time.perf_counter()
        _, stats = solver.minimize(problem, x)
        return (time.perf_counter() - start) / max(stats.iterations, 1), stats.iterations

    newton()  # warm what every run has after its first step (restriction map, CHOLMOD's analysis)
    return min(newton() for _ in range(repeats(resolution)))


def splu_factorisation(resolution: int) -> float:
    """Best wall time of one splu of the reduced Newton matrix, with the direct solver's options."""
    system, problem, x = cloth_step_problem(resolution)
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    reduced = problem.hessian(x, project_spd=True)[free][:, free].tocsc()
    return best_of(lambda: scipy.sparse.linalg.splu(reduced, permc_spec=SPLU_ORDERING, **SPLU_SPD_OPTIONS),
                   repeats(resolution))


def rows() -> list[tuple[str, float, str, str]]:
    # splu and the direct iterations first: loading CHOLMOD holds numpy's BLAS at one thread
    # (solvers.linear.cholmod_module), which would slow the reference and flatter cholesky's ratio
    references = {resolution: splu_factorisation(resolution) for resolution in RESOLUTIONS}
    measured = {("direct", resolution): newton_iteration(resolution, "direct") for resolution in RESOLUTIONS}
    missing = LINEAR_SOLVERS["cholesky"].missing()
    if missing is None:
        measured.update({("cholesky", resolution): newton_iteration(resolution, "cholesky") for resolution in RESOLUTIONS})
    table = []
    for resolution in RESOLUTIONS:
        dof = 3 * resolution * resolution
        for linear_solver, targets in TARGET.items():
            label = f"cloth {resolution}x{resolution} ({dof} DOF): projected Newton iteration ({linear_solver}) / splu"
            target = f"<= {targets[resolution]:g}" if resolution in targets else "-"
            if (linear_solver, resolution) not in measured:
                table.append((label, float("nan"), target, missing))
                continue
            per_iteration, iterations = measured[linear_solver, resolution]
            table.append((
                label, per_iteration / references[resolution], target,
                f"iteration {per_iteration * 1e3:.1f} ms (mean of {iterations}), splu {references[resolution] * 1e3:.1f} ms",
            ))
    return table
