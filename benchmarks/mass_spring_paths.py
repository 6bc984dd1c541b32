"""The general mass-spring path against the specialised cloth it replaced.

A 64x64 grid built as ``type: mass_spring`` (grid generator, stiffness per kind, equal masses, pinned
corners) against ``benchmarks/legacy_cloth.py``, the cloth system as it was before it became a grid
mass_spring, on the same state:
- an explicit step (symplectic Euler through simulate(), recording included), per step;
- one backward Euler Newton iteration: the incremental potential's value, gradient and SPD-projected
  Hessian, the SuperLU factorisation of the free block and the solve.
Target: at most 1.05 for both.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg

from simrun.execution.simulate import simulate
from simrun.experiment.config import DivergenceParams, RecordParams, Run
from simrun.integrators import INTEGRATORS, IncrementalPotential
from simrun.solvers import solver_params
from simrun.solvers.linear import SPLU_ORDERING
from simrun.systems import MassSpringParams

from .legacy_cloth import LegacyClothParams
from .timing import best_of

RESOLUTION = 64
STEPS = 100
EXPLICIT_DT = 1e-5  # below the stability limit of the stretch springs at 64x64
NEWTON_DT = 1.0 / 60.0
TARGET = 1.05
REPEATS = 7


def _params():
    legacy = LegacyClothParams(resolution=(RESOLUTION, RESOLUTION))
    general = MassSpringParams(model={"grid": {"resolution": [RESOLUTION, RESOLUTION]}},
                               stiffness={"stretch": legacy.stretch_stiffness, "shear": legacy.shear_stiffness,
                                          "bend": legacy.bend_stiffness},
                               mass={"total": legacy.mass, "by": "equal"}, gravity=list(legacy.gravity), pinned=["top_left", "top_right"])
    return legacy, general


def _run(params) -> Run:
    return Run(run_id="bench", index=0, system=params, integrator=INTEGRATORS["symplectic_euler"](),
               solver=solver_params(), dt=EXPLICIT_DT, duration=STEPS * EXPLICIT_DT, record=RecordParams(),
               divergence=DivergenceParams(), swept={})


def _step_time(run: Run) -> float:
    result = simulate(run)
    assert result.status == "ok" and result.steps == run.step_count, result.message
    return result.wall_time / STEPS


def _newton_iteration(system, x, v):
    problem = IncrementalPotential(system, x + NEWTON_DT * v, NEWTON_DT * NEWTON_DT, velocity_origin=x,
                                   velocity_divisor=NEWTON_DT, damping_at=x)
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)

    def iteration():
        problem.value(x)
        gradient = problem.gradient(x)
        matrix = problem.hessian(x, project_spd=True).tocsr()[free][:, free].tocsc()
        lu = scipy.sparse.linalg.splu(matrix, permc_spec=SPLU_ORDERING, diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        return lu.solve(-gradient[free])

    return iteration


def rows() -> list[tuple[str, float, str, str]]:
    legacy, general = _params()
    legacy_system, general_system = legacy.build(), general.build()
    assert np.array_equal(legacy_system.x0, general_system.x0) and np.array_equal(legacy_system.stiffness, general_system.stiffness)
    rng = np.random.default_rng(0)
    x = legacy_system.x0 + 0.2 / RESOLUTION * rng.standard_normal(legacy_system.dof_count)
    x[legacy_system.fixed_dofs] = legacy_system.x0[legacy_system.fixed_dofs]
    v = 0.1 * rng.standard_normal(legacy_system.dof_count)
    v[legacy_system.fixed_dofs] = 0.0
    iterations = {name: _newton_iteration(system, x, v) for name, system in (("legacy", legacy_system), ("general", general_system))}
    np.testing.assert_array_equal(iterations["legacy"](), iterations["general"]())  # the same arithmetic
    # interleaved, best of REPEATS each: a slow spell of this shared machine then hits both alike
    step = {"legacy": float("inf"), "general": float("inf")}
    newton = dict(step)
    runs = {"legacy": _run(legacy), "general": _run(general)}
    for _ in range(REPEATS):
        for name in ("legacy", "general"):
            step[name] = min(step[name], _step_time(runs[name]))
            newton[name] = min(newton[name], best_of(iterations[name], 1))
    size = f"{RESOLUTION}x{RESOLUTION} grid ({legacy_system.dof_count} DOF)"
    return [
        (f"mass_spring {size}, symplectic_euler step / legacy cloth step", step["general"] / step["legacy"],
         f"<= {TARGET:g}", f"{step['general'] * 1e3:.2f} ms/step, legacy {step['legacy'] * 1e3:.2f} ms/step"),
        (f"mass_spring {size}, backward Euler Newton iteration / legacy cloth", newton["general"] / newton["legacy"],
         f"<= {TARGET:g}", f"{newton['general'] * 1e3:.0f} ms, legacy {newton['legacy'] * 1e3:.0f} ms"),
    ]
