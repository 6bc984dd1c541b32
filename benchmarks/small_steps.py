"""Cost of one step on the small systems through the real ``simulate()`` loop, default recording
(and, for the explicit steps, also with every step recorded: the most a user can ask of the recorder).

Explicit: symplectic Euler on the spring and on linear circular motion; implicit: backward Euler
with Newton (direct) on the same systems. Each is reported as the ratio of the per-step time of
``simulate()`` over a bare loop, written inline here, that does the same update in plain numpy
(no recording, no checks); absolute times per step and steps per second for information.
Targets: at most 5 us per explicit step and 30 us per implicit step.
"""

from __future__ import annotations

import numpy as np

from simrun.execution.simulate import simulate
from simrun.experiment.config import DivergenceParams, RecordParams, Run
from simrun.integrators import INTEGRATORS
from simrun.solvers import solver_params
from simrun.systems import CircularMotionParams, SpringMassParams

from .timing import best_of

STEPS = 10_000  # the default max_samples (10 000) gives stride 2: every second step recorded, every step energy-checked
DT = 1e-3
TARGET = {"symplectic_euler": 5e-6, "backward_euler": 30e-6}
REPEATS = 7


def make_run(system, integrator: str, steps: int = STEPS, record: RecordParams | None = None) -> Run:
    return Run(run_id="bench", index=0, system=system, integrator=INTEGRATORS[integrator](),
               solver=solver_params(type="newton", linear_solver="direct"), dt=DT, duration=steps * DT,
               record=record or RecordParams(), divergence=DivergenceParams(), swept={})


def bare_symplectic(k: float, m: np.ndarray, x0: np.ndarray, v0: np.ndarray, steps: int) -> None:
    """v += h (-k x)/m; x += h v: the same update as SymplecticEuler on a linear force."""
    x, v = x0.copy(), v0.copy()
    for _ in range(steps):
        v = v + DT * (-k * x) / m
        x = x + DT * v


def bare_backward(k: float, m: np.ndarray, x0: np.ndarray, v0: np.ndarray, steps: int) -> None:
    """One Newton iteration on (M + h^2 K) y = M y~ (linear force: exact), then the velocity update."""
    x, v = x0.copy(), v0.copy()
    n = x.size
    matrix = np.diag(m) + DT * DT * k * np.eye(n)
    for _ in range(steps):
        y_tilde = x + DT * v
        gradient = m * (x - y_tilde) + DT * DT * k * x
        y = x + np.linalg.solve(matrix, -gradient) if n > 1 else x - gradient / matrix[0, 0]
        v = (y - x) / DT
        x = y


def _loop_time(run: Run) -> float:
    """Wall time (s) of simulate()'s stepping loop (its RunResult.wall_time: the set-up excluded)."""
    result = simulate(run)
    assert result.status == "ok" and result.steps == run.step_count, result.message
    return result.wall_time


def rows() -> list[tuple[str, float, str, str]]:
    systems = {
        "spring": SpringMassParams(),
        "circular 2-D": CircularMotionParams(force="linear"),
    }
    table = []
    for label, params in systems.items():
        system = params.build()
        k = system.stiffness
        cases = (("symplectic_euler", bare_symplectic, None), ("symplectic_euler", bare_symplectic, 1),
                 ("backward_euler", bare_backward, None))
        for integrator, bare, every in cases:
            run = make_run(params, integrator, record=RecordParams(every=every))
            # interleaved, best of REPEATS each: a slow spell of this shared machine then hits both alike
            full = reference = float("inf")
            for _ in range(REPEATS):
                full = min(full, _loop_time(run) / STEPS)
                reference = min(reference, best_of(lambda: bare(k, system.mass, system.x0, system.v0, STEPS), 1) / STEPS)
            recording = ", every step recorded" if every == 1 else ""
            table.append((
                f"{label}, {integrator}{recording}: simulate() step / bare loop step",
                full / reference,
                f"<= {TARGET[integrator] * 1e6:.0f} us/step",
                f"{full * 1e6:.2f} us/step ({1 / full:,.0f} steps/s), bare {reference * 1e6:.2f} us/step",
            ))
    return table
