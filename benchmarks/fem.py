"""Finite elements at compiled speed: the element loops per tetrahedron, a Newton iteration against a
factorisation of its matrix, and the course code's Newton iteration on its own square.

- Element loops on a 20^3-cube box (48,000 tets), stable neo-Hookean, one thread, at a state 1 % off the rest shape:
  energy, gradient, and the Hessian with its scatter into the fixed pattern, raw and SPD-projected. Target:
  at most 2 us per tet for all of it, set by what a compiled C loop takes for a StVK Hessian and its scatter
  (docs/performance.md).
- A backward Euler step of a 12 x 12 x 12 box hanging from one face (projected Newton, the direct solver): the
  cost of one Newton iteration over one symmetric-mode SuperLU factorisation of its Newton matrix. Target: <= 1.5.
- A shell on a 64 x 64 grid (7,938 StVK membrane triangles, 11,781 discrete-shell hinges), one thread: gradient and
  SPD-projected Hessian with its scatter, over the mass-spring cloth's (clamped springs) on the same grid; per
  triangle and per hinge for information. No target: a hinge's 9 x 9 eigenproblem (the projection of
  its indefinite Hessian) is most of it.
- The course code's 2-D neo-Hookean square (solid-sim-tutorial 6_inv_free), 16 segments: its Newton iteration (its
  own functions, Python loops per element) over simrun's on the same scene. Target: >= 50. The course code is not
  part of simrun: set SIMRUN_COURSE_CODE to its 6_inv_free folder, or the row says it is skipped.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import time

import numba
import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import IncrementalPotential
from simrun.solvers.linear import SPLU_PATHS
from simrun.systems import SYSTEMS

from .timing import best_of

ELEMENT_TARGET_US, ITERATION_TARGET, COURSE_TARGET = 2.0, 1.5, 50.0
COURSE_VARIABLE = "SIMRUN_COURSE_CODE"


def _element_rows() -> list[tuple[str, float, str, str]]:
    system = SYSTEMS["fem"].model_validate({"type": "fem", "model": {"box": {"size": [1, 1, 1], "cells": [20, 20, 20]}},
                                            "material": {"model": "stable_neo_hookean"}}).build()
    x = system.x0 + 0.01 * 0.05 * np.random.default_rng(0).standard_normal(system.dof_count)
    count = len(system.elements)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        times = {name: best_of(function, repeats=3) / count * 1e6 for name, function in (
            ("energy", lambda: system.elastic_energy(x)), ("gradient", lambda: system.gradient(x)),
            ("raw", lambda: system.hessian_data(x, False)), ("projected", lambda: system.hessian_data(x, "clamp")))}
    finally:
        numba.set_num_threads(threads)
    rows = []
    for kind in ("raw", "projected"):
        total = times["energy"] + times["gradient"] + times[kind]
        rows.append((f"fem 20^3 box, {count:,} tets, 1 thread: E + grad + {kind} Hessian + scatter (us/tet)", total,
                     f"<= {ELEMENT_TARGET_US:g}",
                     f"energy {times['energy']:.2f}, gradient {times['gradient']:.2f}, Hessian {times[kind]:.2f} us/tet"))
    return rows


def _shell_row() -> tuple[str, float, str, str]:
    grid = {"resolution": [64, 64], "size": [1.0, 1.0]}
    shell = SYSTEMS["fem"].model_validate({
        "type": "fem", "model": {"grid": grid}, "thickness": 1.0e-3, "bending": {"stiffness": 1.0e-4},
        "material": {"model": "stvk", "youngs_modulus": 1.0e7, "poisson_ratio": 0.3, "density": 1.0}}).build()
    springs = SYSTEMS["cloth"].model_validate({"type": "cloth", "resolution": grid["resolution"], "size": grid["size"],
                                               "pinned": []}).build()
    noise = 0.05 / 63 * np.random.default_rng(0).standard_normal(shell.dof_count)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        times = [best_of(lambda: (system.gradient(system.x0 + noise), system.hessian_data(system.x0 + noise, "clamp")),
                         repeats=3) for system in (shell, springs)]
    finally:
        numba.set_num_threads(threads)
    triangles, hinges = len(shell.elements), len(shell.hinges)
    return (f"fem shell 64x64, {triangles:,} triangles + {hinges:,} hinges, 1 thread: grad + projected Hessian / "
            "spring cloth's", times[0] / times[1], "(information)",
            f"{times[0] * 1e3:.1f} ms against {times[1] * 1e3:.1f} ms; {times[0] / (triangles + hinges) * 1e6:.2f} us "
            "per triangle or hinge")


def _iteration_row() -> tuple[str, float, str, str]:
    raw = {"name": "fem_iteration", "integrators": ["backward_euler"], "duration": 0.02, "sweep": {"dt": [0.01]},
           "system": {"type": "fem", "model": {"box": {"size": [0.3, 0.3, 0.3], "cells": [12, 12, 12]}},
                      "material": {"model": "stable_neo_hookean", "youngs_modulus": 1e5}, "pinned": "left"},
           "solver": {"type": "projected_newton", "tolerance": 1e-8, "max_iterations": 50}}
    run = expand_runs(validate_experiment(raw))[0]
    simulate(run)  # loads the compiled kernels (numba's cache) and warms the allocator
    result = simulate(run)
    iterations = int(result.per_step["newton_iterations"].sum())
    per_iteration = result.wall_time / iterations
    system = run.system.build()
    problem = IncrementalPotential(system, system.x0 + 0.01 * system.v0, 1e-4)
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    matrix = problem.hessian(system.x0, project_spd=True).tocsr()[free][:, free]
    transposed = scipy.sparse.csc_matrix((matrix.data, matrix.indices, matrix.indptr), shape=matrix.shape)
    factorisation = best_of(lambda: scipy.sparse.linalg.splu(transposed, **SPLU_PATHS[0]), repeats=3)
    return ("fem 12^3 box, 10,368 tets: projected Newton iteration / symmetric factorisation", per_iteration / factorisation,
            f"<= {ITERATION_TARGET:g}", f"{per_iteration * 1e3:.0f} ms per iteration ({iterations} in {result.steps} steps) / "
            f"{factorisation * 1e3:.0f} ms per factorisation ({matrix.shape[0]:,} free dofs)")


def _course_row() -> tuple[str, float, str, str]:
    folder = os.environ.get(COURSE_VARIABLE)
    name = "fem course square 16 seg: course code's Newton iteration / simrun's"
    if not folder or not os.path.isdir(folder):
        return (name, float("nan"), f">= {COURSE_TARGET:g}",
                f"skipped: set {COURSE_VARIABLE} to solid-sim-tutorial's 6_inv_free folder")
    sys.path.insert(0, folder)
    import square_mesh
    import time_integrator

    segments, dt = 16, 0.01
    x, e = square_mesh.generate(1.0, segments)
    vol, IB = [0.0] * len(e), [None] * len(e)
    for i in range(len(e)):
        TB = [x[e[i][1]] - x[e[i][0]], x[e[i][2]] - x[e[i][0]]]
        vol[i] = np.linalg.det(np.transpose(TB)) / 2
        IB[i] = np.linalg.inv(np.transpose(TB))
    mu, lam = [0.5 * 1e5 / 1.4] * len(e), [1e5 * 0.4 / (1.4 * 0.2)] * len(e)
    start = x.copy()
    start[:, 0] *= 1.4
    positions = np.append(start, [[0.0, 100.0]], axis=0)
    velocities = np.zeros_like(positions)
    masses = [1000.0 / len(x)] * len(positions)
    output = io.StringIO()
    begin = time.perf_counter()
    with contextlib.redirect_stdout(output):  # it prints each iteration: counted from there
        time_integrator.step_forward(positions, e, velocities, masses, vol, IB, mu, lam, np.array([0.0, 1.0]),
                                     np.array([0.0, -100.0]), [1.0 / segments] * len(positions), 0.0,
                                     [False] * len(positions), [], [], [], [1000.0], dt, 1e-2)
    course = (time.perf_counter() - begin) / max(1, output.getvalue().count("Iteration"))
    raw = {"name": "fem_course", "integrators": ["backward_euler"], "duration": 5 * dt, "sweep": {"dt": [dt]},
           "system": {"type": "fem", "model": {"square": {"segments": segments, "size": 1.0}},
                      "material": {"model": "neo_hookean", "youngs_modulus": 1e5, "poisson_ratio": 0.4},
                      "mass": {"total": 1000.0, "by": "equal"}, "initial": {"scale": [1.4, 1.0]}},
           "solver": {"type": "projected_newton", "tolerance": 1e-2}}
    run = expand_runs(validate_experiment(raw))[0]
    simulate(run)  # the first call in a process loads the compiled kernels from numba's cache
    result = simulate(run)
    ours = result.wall_time / int(result.per_step["newton_iterations"].sum())
    return (name, course / ours, f">= {COURSE_TARGET:g}", f"{course * 1e3:.0f} ms against {ours * 1e3:.2f} ms per iteration")


def rows() -> list[tuple[str, float, str, str]]:
    return [*_element_rows(), _shell_row(), _iteration_row(), _course_row()]


__all__ = ["rows"]
