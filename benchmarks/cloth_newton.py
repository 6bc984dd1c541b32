"""One backward Euler Newton iteration on the cloth, split into assembly and linear solve.

Assembly: the incremental potential's value, gradient and Hessian values (M + h^2 K in the fixed
pattern). Solve: SuperLU factorisation (MMD_AT_PLUS_A) and the triangular solves. Reported as the
ratio assembly / factorisation, measured in the same process; absolute times for information.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg

from simrun.integrators import IncrementalPotential
from simrun.solvers.linear import SPLU_ORDERING
from simrun.systems import ClothParams

from .timing import best_of

RESOLUTIONS = (32, 64, 128)
DT = 1.0 / 60.0  # one animation frame


def deformed_state(system, seed: int = 0):
    """A crumpled, moving configuration, so the Hessian has compressed and stretched springs."""
    rng = np.random.default_rng(seed)
    x = system.x0 + 0.2 * system.params.size[0] / system.shape[0] * rng.standard_normal(system.dof_count)
    x[system.fixed_dofs] = system.x0[system.fixed_dofs]
    v = 0.1 * rng.standard_normal(system.dof_count)
    v[system.fixed_dofs] = 0.0
    return x, v


def measure(resolution: int) -> dict[str, float]:
    system = ClothParams(resolution=(resolution, resolution)).build()
    x, v = deformed_state(system)
    problem = IncrementalPotential(system, x + DT * v, DT * DT, velocity_origin=x, velocity_divisor=DT, damping_at=x)

    def assemble():
        problem.value(x)
        problem.gradient(x)
        return problem.hessian(x, project_spd=True)

    matrix = assemble()
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    reduced = matrix.tocsr()[free][:, free].tocsc()
    rhs = -problem.gradient(x)[free]

    def factor():
        return scipy.sparse.linalg.splu(reduced, permc_spec=SPLU_ORDERING, diag_pivot_thresh=0.0,
                                        options=dict(SymmetricMode=True))

    lu = factor()
    repeats = 5 if resolution <= 64 else 2
    return {
        "dof": system.dof_count,
        "assembly": best_of(assemble, repeats),
        "factorisation": best_of(factor, repeats),
        "solve": best_of(lambda: lu.solve(rhs), repeats),
    }


def rows() -> list[tuple[str, float, str, str]]:
    table = []
    for resolution in RESOLUTIONS:
        m = measure(resolution)
        table.append((
            f"cloth {resolution}x{resolution} ({m['dof']} DOF): assembly / splu factorisation",
            m["assembly"] / m["factorisation"], "-",
            f"assembly {m['assembly'] * 1e3:.1f} ms, factorisation {m['factorisation'] * 1e3:.1f} ms, solve {m['solve'] * 1e3:.1f} ms",
        ))
    return table
