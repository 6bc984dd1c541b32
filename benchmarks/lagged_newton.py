"""Fewer factorisations per cloth step: Newton with the factorisation lagged across iterations and steps
(``solver.refactor: adaptive``, solvers/lagged.py), and Newton-Krylov with PCG preconditioned by that factorisation
(``refactor: preconditioner``), against Newton that factorises at every iteration, backward
Euler, dt = 0.01 s, tolerance 1e-9, on the hanging cloth (pinned at two corners) and on a cloth falling onto a
penalty sphere, N x N vertices. Each ratio is the wall time of the same steps of ``simulate()`` (the stepping
loop), adaptive over every; target <= 0.5 for the hanging 64x64 and 128x128 cloth. ``SIMRUN_BENCH_QUICK=1`` skips
the 128x128 cloth.
"""

from __future__ import annotations

import os

import numpy as np

from simrun.execution.simulate import simulate
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

STEPS = {32: 12, 64: 10, 128: 3}  # the first steps refactor most: a run amortises them
SPHERE = ", height: -0.28, contact: {sphere: {center: [0.5, 0.5, -0.6], radius: 0.3, stiffness: 1.0e+4}}"


def _run(resolution: int, refactor: str, scene: str):
    extra = "pinned: [top_left, top_right]" if scene == "hanging" else "pinned: []" + SPHERE
    config = f"""
name: bench_lagged
system: {{type: cloth, resolution: [{resolution}, {resolution}], {extra}}}
integrators: [backward_euler]
solver: {{type: newton, tolerance: 1.0e-9, max_iterations: 200, refactor: {refactor}}}
duration: {0.01 * STEPS[resolution]}
sweep: {{dt: [0.01]}}
"""
    experiment, _ = load_experiment(config)
    return simulate(expand_runs(experiment)[0])


def _rows(resolution: int, scene: str, modes: tuple[str, ...]) -> list[tuple[str, float, str, str]]:
    every = _run(resolution, "every", scene)
    rows = []
    for mode in modes:
        lagged = _run(resolution, mode, scene)
        for result in (every, lagged):
            if str(result.status) != "ok":
                raise RuntimeError(f"{scene} {resolution}x{resolution}: {result.status}: {result.message}")
        per_step = [1e3 * result.wall_time / result.steps for result in (every, lagged)]
        iterations = [float(np.mean(result.per_step["newton_iterations"])) for result in (every, lagged)]
        target = "<= 0.5" if scene == "hanging" and resolution >= 64 and mode == "adaptive" else "-"
        rows.append((f"cloth {resolution}x{resolution} {scene}, backward Euler, tol 1e-9: refactor {mode} / every (per step)",
                     per_step[1] / per_step[0], target,
                     f"{per_step[1]:.0f} ms ({iterations[1]:.1f} iterations) against {per_step[0]:.0f} ms ({iterations[0]:.1f})"))
    return rows


def rows() -> list[tuple[str, float, str, str]]:
    sizes = [32, 64] if os.environ.get("SIMRUN_BENCH_QUICK") else [32, 64, 128]
    hanging = [row for size in sizes for row in _rows(size, "hanging", ("adaptive", "preconditioner"))]
    return hanging + [row for size in (32, 64) for row in _rows(size, "sphere", ("adaptive", "preconditioner"))]
