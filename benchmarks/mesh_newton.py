"""A user's own mesh at the speed of the grid: Newton on a spot-sized surface in no useful vertex order.

The benchmark makes its mesh itself (models/make_models.py's ``spot_like_surface``: 2,930 vertices, as spot.obj,
shuffled as an export's or a scan's are), writes it as an OBJ and drops it as a mass-spring shell onto the ground
under IPC with friction (backward Euler, dt = 0.01 s, the default solver: Newton with the direct solver), starting
at dhat above the ground so that contact acts from the first step. The cost of one Newton iteration (the run's
wall time over its Newton iterations: energies, gradients, Hessians, IPC's barrier and CCD, the factorisation, the
line search) is compared with one symmetric-mode factorisation of its first Newton matrix. Target: at most 3. Partial
pivoting in the MMD ordering would factor that matrix in 180x the symmetric mode's time.
"""

from __future__ import annotations

import importlib.util
import tempfile
from pathlib import Path

import scipy.sparse
import scipy.sparse.linalg

from simrun.execution.simulate import simulate
from simrun.experiment.config import validate_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import IncrementalPotential
from simrun.solvers.linear import SPLU_PATHS

from .timing import best_of

DT = 0.01
STEPS = 3
DHAT = 1e-3
TARGET = 3.0
MAKE_MODELS = Path(__file__).resolve().parents[1] / "models" / "make_models.py"


def _surface():
    spec = importlib.util.spec_from_file_location("make_models", MAKE_MODELS)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.spot_like_surface(seed=1), module.write_obj


def _run(path: Path, lowest: float):
    raw = {"name": "mesh_newton", "integrators": ["backward_euler"], "duration": STEPS * DT, "sweep": {"dt": [DT]},
           "system": {"type": "mass_spring", "model": str(path), "stiffness": {"stretch": 2.0e3, "bend": 20.0},
                      "mass": {"total": 1.0}, "gravity": [0.0, 0.0, -9.81],
                      "initial": {"translate": [0.0, 0.0, DHAT - lowest]},
                      "contact": {"method": "ipc", "dhat": DHAT, "friction": {"mu": 0.3, "epsv": 1e-3},
                                  "colliders": [{"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, 0.0]}]}},
           "solver": {"type": "newton", "tolerance": 1e-6, "max_iterations": 100}}
    return expand_runs(validate_experiment(raw))[0]


def rows() -> list[tuple[str, float, str, str]]:
    (vertices, triangles), write_obj = _surface()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "shuffled_surface.obj"
        write_obj(path, vertices, triangles, "spot-sized surface, shuffled vertices (benchmarks/mesh_newton.py)")
        run = _run(path, float(vertices[:, 2].min()))
        result = simulate(run)  # its steps may not converge (see docs/performance.md): each iteration costs the same
        assert result.steps == STEPS and result.status != "failed", result.message
        iterations = int(result.per_step["newton_iterations"].sum())
        per_iteration = result.wall_time / iterations
        paths = {key: value for key, value in result.attrs.items() if key.startswith("factorisations_")}
        system = run.system.build()
        system.contact_form().begin_run(DT, system.x0)
        problem = IncrementalPotential(system, system.x0 + DT * system.v0, DT * DT, velocity_origin=system.x0,
                                       velocity_divisor=DT, damping_at=system.x0)
        matrix = problem.hessian(system.x0).tocsr()
        transposed = scipy.sparse.csc_matrix((matrix.data, matrix.indices, matrix.indptr), shape=matrix.shape)
        factorisation = best_of(lambda: scipy.sparse.linalg.splu(transposed, **SPLU_PATHS[0]), repeats=3)
        fill = scipy.sparse.linalg.splu(transposed, **SPLU_PATHS[0])
    detail = (f"{per_iteration * 1e3:.0f} ms per Newton iteration ({iterations} in {result.steps} steps, "
              f"{result.wall_time:.1f} s) / {factorisation * 1e3:.0f} ms per symmetric-mode factorisation "
              f"({fill.L.nnz + fill.U.nnz:,} in L + U, {matrix.shape[0]} dofs); paths {paths}")
    return [("mesh: Newton iteration / symmetric factorisation", per_iteration / factorisation, f"<= {TARGET:g}", detail)]


__all__ = ["rows"]
