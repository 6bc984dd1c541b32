"""A DIRK stage against a backward Euler step: each stage of sdirk2 is an incremental potential of backward
Euler's form, so at the same Newton iteration count it should cost the same. Measured on the hanging 32 x 32 and
64 x 64 cloth, dt = 0.01 s, Newton (direct, factorising every iteration) to 1e-9, as the wall time of ``simulate()``'s
stepping loop per Newton iteration: sdirk2's over backward Euler's. Target: at most 1.2.
"""

from __future__ import annotations

import numpy as np

from simrun.execution.simulate import simulate
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

STEPS = {32: 12, 64: 8}
TARGET = 1.2


def _run(resolution: int, integrator: str):
    config = f"""
name: bench_dirk
system: {{type: cloth, resolution: [{resolution}, {resolution}], pinned: [top_left, top_right]}}
integrators: [{integrator}]
solver: {{type: newton, tolerance: 1.0e-9, max_iterations: 100}}
duration: {0.01 * STEPS[resolution]}
sweep: {{dt: [0.01]}}
"""
    experiment, _ = load_experiment(config)
    run = expand_runs(experiment)[0]
    simulate(run)  # warm-up: the first run of a process pays for imports and allocations
    result = simulate(run)
    if str(result.status) != "ok":
        raise RuntimeError(f"{integrator} {resolution}x{resolution}: {result.status}: {result.message}")
    return result.wall_time, int(np.sum(result.per_step["newton_iterations"]))


def rows() -> list[tuple[str, float, str, str]]:
    rows = []
    for resolution in STEPS:
        (euler_time, euler_iterations), (dirk_time, dirk_iterations) = (_run(resolution, name)
                                                                        for name in ("backward_euler", "sdirk2"))
        ratio = (dirk_time / dirk_iterations) / (euler_time / euler_iterations)
        rows.append((f"cloth {resolution}x{resolution} hanging: sdirk2 / backward Euler, per Newton iteration", ratio,
                     f"<= {TARGET:g}", f"{1e3 * dirk_time / dirk_iterations:.1f} ms ({dirk_iterations} iterations) "
                     f"against {1e3 * euler_time / euler_iterations:.1f} ms ({euler_iterations})"))
    return rows


__all__ = ["rows"]
