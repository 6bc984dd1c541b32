"""A whole explicit step on the cloth through ``simulate()``, over the bare force evaluation and update.

Symplectic Euler on a 64x64 cloth (pinned corners, gravity, default springs) at a stable dt, with the
default recording (energies and momenta every step, frames at their own cadence) and the energy
check. The reference, written inline here, is the vectorised spring force (one sparse incidence
product for the scatter), gravity, the pins and the update v += dt M^-1 f, x += dt v, without any
recording.
Target: at most 1.5.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from simrun.execution.simulate import simulate
from simrun.experiment.config import DivergenceParams, RecordParams, Run
from simrun.integrators import INTEGRATORS
from simrun.solvers import solver_params
from simrun.systems import ClothParams

from .timing import best_of

RESOLUTION = 64
STEPS = 200
DT = 1e-5  # below the stability limit ~2/w_max of the stretch springs at 64x64 (w_max ~ 4e4 rad/s)
TARGET = 1.5
REPEATS = 9


def bare_steps(system, steps: int) -> None:
    """The same update as SymplecticEuler on the cloth, in plain numpy with the fastest primitives we
    know (the same as the product's: a flat gather of the spring ends' dofs, |delta|^2 as a product
    with (1, 1, 1), the force scatter as one sparse incidence product), so that the ratio measures
    what the simulate() loop adds, not a difference of formulations."""
    x, v = system.x0.copy(), system.v0.copy()
    first, second, stiffness, rest = system.first, system.second, system.stiffness, system.rest_length
    offsets = np.arange(3)
    first_dofs, second_dofs = (3 * first[:, None] + offsets).ravel(), (3 * second[:, None] + offsets).ravel()
    springs = np.arange(first.size)
    incidence = scipy.sparse.csr_matrix(
        (np.concatenate([np.ones(first.size), -np.ones(first.size)]),
         (np.concatenate([first, second]), np.concatenate([springs, springs]))),
        shape=(system.vertex_count, first.size))
    ones = np.ones(3)
    gravity = np.tile(system.vertex_mass * system.gravity, system.vertex_count)
    fixed = system.fixed_dofs
    for _ in range(steps):
        delta = (np.take(x, first_dofs) - np.take(x, second_dofs)).reshape(-1, 3)
        length = np.sqrt(np.square(delta) @ ones)
        force = (delta.T * (stiffness * (length - rest) / length)).T
        total = gravity - (incidence @ force).ravel()
        total[fixed] = 0.0
        v = v + DT * total / system.mass
        x = x + DT * v


def _loop_time(run: Run) -> float:
    """Wall time (s) of simulate()'s stepping loop (its RunResult.wall_time: the set-up excluded)."""
    result = simulate(run)
    assert result.status == "ok" and result.steps == run.step_count, result.message
    return result.wall_time


def rows() -> list[tuple[str, float, str, str]]:
    params = ClothParams(resolution=(RESOLUTION, RESOLUTION))
    system = params.build()
    run = Run(run_id="bench", index=0, system=params, integrator=INTEGRATORS["symplectic_euler"](),
              solver=solver_params(), dt=DT, duration=STEPS * DT, record=RecordParams(),
              divergence=DivergenceParams(), swept={})
    # interleaved, best of REPEATS each: a slow spell of this shared machine then hits both alike
    full = bare = float("inf")
    for _ in range(REPEATS):
        full = min(full, _loop_time(run) / STEPS)
        bare = min(bare, best_of(lambda: bare_steps(system, STEPS), 1) / STEPS)
    return [(
        f"cloth {RESOLUTION}x{RESOLUTION} ({system.dof_count} DOF), symplectic_euler: simulate() step / bare step",
        full / bare, f"<= {TARGET:g}", f"{full * 1e3:.2f} ms/step, bare {bare * 1e3:.2f} ms/step",
    )]
