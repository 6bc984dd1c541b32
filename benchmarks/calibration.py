"""Calibration: what the exact forward sensitivities buy over finite differences.

One fit each, with the engine's exact Jacobian (``sensitivities: auto``) against forward finite differences
(``finite_differences``: one more simulation per parameter and Jacobian), started from the same values on the same
observations; and one simulation with its tangents against the same simulation without them (one more
factorisation per step, and the tangents' right-hand sides). Targets: a fit with exact sensitivities at most as
long as with finite differences; a tangent step at most 2.5x a plain one on a 16 x 16 cloth.
"""

from __future__ import annotations

import dataclasses
import time

from simrun.calibration.engine import Model, fit_one
from simrun.calibration.pipeline import prepare
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

SPRING = """
name: bench_spring
system: {type: spring_mass, mass: 1.0, stiffness: 100.0, damping: 0.4}
integrators: [implicit_midpoint]
solver: {type: newton, tolerance: 1.0e-12}
duration: 5.0
sweep: {dt: [0.005]}
fit:
  observed: {synthetic: {integrator: exact, dt: 0.005, noise: 1.0e-3, seed: 1}}
  parameters:
    system.stiffness: {start: 80.0, bounds: [1.0, 1.0e+4]}
    system.damping: {start: 0.1, bounds: [-50.0, 50.0]}
"""

CLOTH = """
name: bench_cloth
system: {type: cloth, resolution: [RESOLUTION, RESOLUTION], stretch_stiffness: 1000.0, shear_stiffness: 100.0,
         bend_stiffness: 1.0, damping: 0.05, pinned: [top_left, top_right]}
integrators: [backward_euler]
solver: {type: newton, tolerance: 1.0e-10, max_iterations: 50}
duration: DURATION
sweep: {dt: [0.01]}
fit:
  observed: {synthetic: {integrator: implicit_midpoint, dt: 0.002, every: 5}}
  markers: [0, 5]
  parameters:
    system.stretch_stiffness: {start: 600.0, bounds: [10.0, 1.0e+5]}
    system.damping: {start: 0.2, bounds: [0.0, 10.0]}
"""


def _task(text: str):
    experiment, _ = load_experiment(text)
    tasks, _ = prepare(experiment, expand_runs(experiment))
    return tasks[-1]  # the method's fit (the spring's first task is the exact solution's)


def _fit_ratio(name: str, text: str) -> tuple[str, float, str, str]:
    task = _task(text)
    exact = fit_one(dataclasses.replace(task, sensitivities="auto"))
    differences = fit_one(dataclasses.replace(task, sensitivities="finite_differences"))
    return (f"fit {name}: exact sensitivities / finite differences (wall)", exact.wall_time / differences.wall_time, "<= 1",
            f"exact {exact.simulations} simulations {exact.wall_time:.2f} s; differences {differences.simulations} "
            f"simulations {differences.wall_time:.2f} s")


def _tangent_ratio() -> tuple[str, float, str, str]:
    task = _task(CLOTH.replace("RESOLUTION", "16").replace("DURATION", "0.1"))
    model = Model(task)
    began = time.perf_counter()
    model.motion(task.start)
    plain = time.perf_counter() - began
    began = time.perf_counter()
    model.motion(task.start, with_jacobian=True)
    tangent = time.perf_counter() - began
    return ("cloth 16x16 backward Euler: a simulation with 2 tangents / without", tangent / plain, "<= 2.5",
            f"{1e3 * tangent / model.steps:.1f} ms against {1e3 * plain / model.steps:.1f} ms per step")


def rows() -> list[tuple[str, float, str, str]]:
    return [_fit_ratio("spring, implicit midpoint, 1000 steps", SPRING),
            _fit_ratio("cloth 6x6, backward Euler, 30 steps", CLOTH.replace("RESOLUTION", "6").replace("DURATION", "0.3")),
            _tangent_ratio()]
