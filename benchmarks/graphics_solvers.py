"""The solvers of graphics practice against Newton, each as a ratio measured in this run.

- The cloth dropped on a penalty sphere (16x16, k = 1e5, backward Euler, dt = 0.005, tolerance 1e-9) with
  the default solver, to t = 0.4 s (through first contact): Newton iterations per step (target <= 8).
- The 10x10 hanging cloth (cloth_hang's parameters, backward Euler, dt = 0.02, 0.2 s, tolerance 1e-9):
  wall time of L-BFGS over Newton's, with the rest-shape H0 and with the step's H0 (target <= 5).
- Projective dynamics on cloth_hang's first step (12x12, dt = 0.02) to 1e-4 of its first residual: iterations with
  Chebyshev (rho = 0.99) over plain PD (target <= 0.5), and with the computed rho (auto; reported).
- Vertex block descent on the same step, to 1e-8: wall time over Newton's (no target: reported).
- XPBD on the unit spring: measured over predicted artificial damping at h w = 1, 10 substeps (target 1 +- 0.02).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from simrun.analysis import oscillator as analysis
from simrun.execution.simulate import simulate
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.solvers import SolveStats, solver_params

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
SPHERE = {"resolution": [16, 16], "damping": 0.1, "pinned": [],
          "contact": {"sphere": {"center": [0.5, 0.5, -0.6], "radius": 0.3, "stiffness": 1.0e5}}}


def _run(system_overrides: dict, solver: dict, dt: float, duration: float, integrator: str = "backward_euler"):
    experiment, _ = load_experiment(CONFIGS / "cloth_hang.yaml")
    raw = experiment.model_dump(mode="json", exclude={"output"})
    raw.update(system={**raw["system"], **system_overrides}, integrators=[integrator], solver=solver,
               duration=duration, sweep={"dt": [dt]})
    (run,) = expand_runs(load_experiment(raw)[0])
    result = simulate(run)
    assert result.status == "ok", f"{solver}: {result.status} {result.message}"
    return result


class _Capture:
    def minimize(self, problem, start):
        self.problem, self.start = problem, start.copy()
        return start, SolveStats()


def _first_step_problem():
    experiment, _ = load_experiment(CONFIGS / "cloth_hang.yaml")
    system = experiment.system.build()
    capture = _Capture()
    INTEGRATORS["backward_euler"]().step(system, State(0.0, system.x0, system.v0), 0.02, capture)
    return capture.problem, capture.start


def _iterations_to(problem, start, tolerance: float, **options) -> tuple[int, float]:
    solver = solver_params(tolerance=tolerance, max_iterations=50_000, **options).build()
    began = time.perf_counter()
    _, stats = solver.minimize(problem, start)
    assert stats.converged, (options, stats)
    return stats.iterations, time.perf_counter() - began


def rows() -> list[tuple[str, float, str, str]]:
    table = []
    sphere = _run(SPHERE, {"tolerance": 1e-9}, 0.005, 0.4)
    iterations = sphere.per_step["newton_iterations"]
    table.append(("sphere drop: newton iterations/step", float(iterations.mean()), "<= 8",
                  f"max {iterations.max()}, {np.count_nonzero(sphere.per_step['safeguards'])} steps with a safeguard"))

    small = {"resolution": [10, 10]}
    newton = _run(small, {"tolerance": 1e-9}, 0.02, 0.2)
    for initial_hessian in ("rest", "step"):
        lbfgs = _run(small, {"type": "lbfgs", "tolerance": 1e-9, "max_iterations": 5000, "initial_hessian": initial_hessian},
                     0.02, 0.2)
        table.append((f"hanging 10x10: lbfgs {initial_hessian} / newton", lbfgs.wall_time / newton.wall_time, "<= 5",
                      f"{lbfgs.per_step['newton_iterations'].mean():.0f} it/step vs {newton.per_step['newton_iterations'].mean():.1f}; "
                      f"{lbfgs.wall_time:.3f} s vs {newton.wall_time:.3f} s"))

    problem, start = _first_step_problem()
    plain, _ = _iterations_to(problem, start, 1e-4, type="projective_dynamics")
    accelerated, _ = _iterations_to(problem, start, 1e-4, type="projective_dynamics", chebyshev_rho=0.99)
    table.append(("cloth_hang step: PD chebyshev / plain iterations", accelerated / plain, "<= 0.5",
                  f"{accelerated} vs {plain} iterations to 1e-4 of the first residual"))
    computed, computed_time = _iterations_to(problem, start, 1e-4, type="projective_dynamics", chebyshev_rho="auto")
    table.append(("cloth_hang step: PD auto rho / plain iterations", computed / plain, "reported",
                  f"{computed} vs {plain} iterations ({computed_time:.3f} s with the Lanczos estimate)"))
    newton_iterations, newton_time = _iterations_to(problem, start, 1e-8, type="newton")
    vbd_iterations, vbd_time = _iterations_to(problem, start, 1e-8, type="vbd", chebyshev_rho=0.95)
    table.append(("cloth_hang step: vbd / newton wall time", vbd_time / newton_time, "reported",
                  f"{vbd_iterations} sweeps vs {newton_iterations} iterations; {vbd_time:.3f} s vs {newton_time:.4f} s"))

    spring = {"type": "spring_mass", "mass": 1.0, "stiffness": 1.0, "x0": 1.0, "v0": 0.0}
    experiment = load_experiment({"name": "xpbd", "system": spring, "integrators": [{"type": "xpbd", "substeps": 10}],
                                  "duration": 40.0, "sweep": {"dt": [1.0]}, "record": {"every": 1}})[0]
    (run,) = expand_runs(experiment)
    result = simulate(run)
    fit = analysis.measure_damping(result.samples["t"], result.samples["energy"], result.samples["positions"][:, 0], 1.0)
    _, predicted = analysis.predict(run.integrator).at(1.0)
    table.append(("xpbd[substeps=10] damping: measured / predicted", fit.rate / predicted, "1 +- 0.02",
                  f"d/w {fit.rate:.6f} vs {predicted:.6f} at h w = 1"))
    return table
