"""A whole explicit step on the cloth through ``simulate()``, over the bare force evaluation and update.

Symplectic Euler on a 64x64 cloth (pinned corners, gravity, default springs) at a stable dt, with the
default recording (energies and momenta every step, frames at their own cadence) and the energy
check. The reference, written inline here, is the vectorised spring force (one ``np.bincount``
scatter), gravity, the pins and the update v += dt M^-1 f, x += dt v, without any recording.
Target (issue 8): at most 1.5.
"""

from __future__ import annotations

import numpy as np

from simrun.config import DivergenceParams, RecordParams, Run
from simrun.integrators import INTEGRATORS
from simrun.simulate import simulate
from simrun.solvers import SolverParams
from simrun.systems import ClothParams

from .timing import best_of

RESOLUTION = 64
STEPS = 200
DT = 1e-5  # below the stability limit ~2/w_max of the stretch springs at 64x64 (w_max ~ 4e4 rad/s)
TARGET = 1.5


def bare_steps(system, steps: int) -> None:
    """The same update as SymplecticEuler on the cloth, in plain numpy."""
    x, v = system.x0.copy(), system.v0.copy()
    first, second, stiffness, rest = system.first, system.second, system.stiffness, system.rest_length
    index = np.concatenate([3 * first[:, None] + np.arange(3), 3 * second[:, None] + np.arange(3)]).ravel()
    gravity = np.tile(system.vertex_mass * system.gravity, system.vertex_count)
    fixed = system.fixed_dofs
    for _ in range(steps):
        positions = x.reshape(-1, 3)
        delta = np.take(positions, first, axis=0) - np.take(positions, second, axis=0)
        length = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        force = (stiffness * (length - rest) / length)[:, None] * delta
        total = gravity - np.bincount(index, weights=np.concatenate([force, -force]).ravel(), minlength=x.size)
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
              solver=SolverParams(), dt=DT, duration=STEPS * DT, record=RecordParams(),
              divergence=DivergenceParams(), swept={})
    full = min(_loop_time(run) for _ in range(5)) / STEPS
    bare = best_of(lambda: bare_steps(system, STEPS), 5) / STEPS
    return [(
        f"cloth {RESOLUTION}x{RESOLUTION} ({system.dof_count} DOF), symplectic_euler: simulate() step / bare step",
        full / bare, f"<= {TARGET:g}", f"{full * 1e3:.2f} ms/step, bare {bare * 1e3:.2f} ms/step",
    )]
