"""One projected Newton iteration of backward Euler on the cloth, over one SuperLU factorisation.

The real solver (``SolverParams(type="projected_newton").build()``: clamped Hessian, backtracking
line search, direct solve) minimises one incremental potential of a deformed, moving cloth for a
fixed number of iterations (tolerance 0, so none ends early); the time per iteration (assembly,
restriction to the free dofs, factorisation and solve, line search, bookkeeping) is divided by the
time of one ``splu`` of the same reduced matrix with the options the direct solver uses, measured
in the same run. Target (issue 8): at most 1.3 at 64x64.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg

from simrun.integrators import IncrementalPotential
from simrun.solvers import SolverParams
from simrun.solvers.linear import SPLU_ORDERING, SPLU_SPD_OPTIONS
from simrun.systems import ClothParams

from .cloth_newton import DT, deformed_state
from .timing import best_of

RESOLUTIONS = (32, 64, 128)
ITERATIONS = 4
TARGET = {64: 1.3}


def measure(resolution: int) -> dict[str, float]:
    system = ClothParams(resolution=(resolution, resolution)).build()
    x, v = deformed_state(system)
    problem = IncrementalPotential(system, x + DT * v, DT * DT, velocity_origin=x, velocity_divisor=DT, damping_at=x)
    solver = SolverParams(type="projected_newton", linear_solver="direct", tolerance=1e-300,
                          max_iterations=ITERATIONS).build()

    def newton():
        start = time.perf_counter()
        _, stats = solver.minimize(problem, x)
        return (time.perf_counter() - start) / max(stats.iterations, 1), stats.iterations

    newton()  # warm the caches every run has after its first step (restriction map, free dofs)
    repeats = 3 if resolution <= 64 else 1
    per_iteration, iterations = min(newton() for _ in range(repeats))

    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    reduced = problem.hessian(x, project_spd=True)[free][:, free].tocsc()
    factorisation = best_of(lambda: scipy.sparse.linalg.splu(reduced, permc_spec=SPLU_ORDERING, **SPLU_SPD_OPTIONS),
                            repeats)
    return {"dof": system.dof_count, "iteration": per_iteration, "iterations": iterations,
            "factorisation": factorisation}


def rows() -> list[tuple[str, float, str, str]]:
    table = []
    for resolution in RESOLUTIONS:
        m = measure(resolution)
        table.append((
            f"cloth {resolution}x{resolution} ({m['dof']} DOF): projected Newton iteration / splu",
            m["iteration"] / m["factorisation"],
            f"<= {TARGET[resolution]:g}" if resolution in TARGET else "-",
            f"iteration {m['iteration'] * 1e3:.1f} ms (mean of {m['iterations']}), splu {m['factorisation'] * 1e3:.1f} ms",
        ))
    return table
