"""The compiled real-time solver kernels against a compiled C loop of the same algorithm.

Vertex block descent on the 64 x 64 hanging cloth of configs/realtime_solvers.yaml (stretch 1e4, shear 1e3, bend 10
N/m, two corners pinned), the problem of a backward Euler step at the frame rate (dt = 1/60 s) from rest: one sweep
over its colours, each vertex's Newton step on its 3 x 3 block (springs with the transverse factor clamped, inertia,
gravity), the determinant floor and the per-vertex backtracking on the change of E. simrun's sweep is the kernel the
solver calls (systems/mass_spring/vbd_kernels.py), timed at 1 and at 2 threads; the peer is the same sweep written
here in C (vbd_c_loops.py), compiled with the system's compiler (``cc -O2``), single-threaded, on the same arrays. The
two must agree (max |difference| of the swept positions below 1e-12 m) for the times to be compared. Without a C
compiler the C rows are skipped with one line. Targets: at most 0.3 us per vertex on one core, at most 2x the C loop,
two threads at least 1.6x one.

The same on a tetrahedral solid: one sweep of configs/realtime_fem.yaml's stable neo-Hookean beam (12,288 tets) at its
first frame, against the same sweep in C; target at most 2 us per vertex iteration on one core.

The peer on its own scene, where the ``newton`` package (NVIDIA's Newton on Warp, ``make install-peers``) is installed:
its VBD cloth example (newton.examples cloth_hanging: 64 x 32 cells of 0.1 m, StVK triangles, bending, ground and
self-contact, 10 substeps of 10 iterations per 1/60 s frame) on the CPU device, time per vertex iteration, against
simrun's VBD solve on a mass-spring cloth of the same mesh (65 x 33 vertices, pinned along one side) at the same
substep, per vertex iteration (the whole solve: sweeps and convergence tests). The energies differ (springs against
triangles and self-contact): the row says what a vertex iteration costs each, not that they compute the same.

XPBD on the same cloth: one iteration (every colour group's projection once, at the substep of 10 per frame) from the
first substep's prediction, per spring constraint; target at most 0.2 us.
"""

from __future__ import annotations

import ctypes
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import yaml

from simrun.experiment.config import load_experiment
from simrun.integrators import INTEGRATORS, State
from simrun.integrators.xpbd import spring_projection
from simrun.solvers import Newton, SolveStats
from simrun.solvers.dofs import free_dofs
from simrun.solvers.vbd import MAX_HALVINGS, IncrementalParts, VertexBlockDescent, colour_plans

from .vbd_c_loops import CLOTH_SOURCE, FEM_SOURCE, compiled

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
RESOLUTION = 64
SWEEPS = 40  # per timing; the best of REPEATS
REPEATS = 5
FEM_PER_VERTEX_TARGET = 2.0  # us per vertex iteration of a 10,000-tet soft body, one core (the real-time target)
PER_VERTEX_TARGET, C_RATIO_TARGET, THREADS_TARGET, XPBD_TARGET = 0.3, 2.0, 1.6, 0.2
DETERMINANT_FLOOR = 1e-20

class _Capture:
    def minimize(self, problem, start):
        self.problem, self.start = problem, start.copy()
        return start, SolveStats()


def _problem(config_name: str, **system_changes):
    """(the system of a shipped config's ``system``, changed as given; the first backward Euler step's problem at
    1/60 s; its start)."""
    shipped = yaml.safe_load((CONFIGS / config_name).read_text())["system"]
    return _problem_of({**shipped, **system_changes})


def _problem_of(system_config: dict):
    """``_problem`` of a system's config."""
    config = {"name": "bench_vbd", "system": system_config, "integrators": ["backward_euler"],
              "sweep": {"dt": [1.0 / 60.0]}}
    system = load_experiment(config)[0].system.build()
    capture = _Capture()
    INTEGRATORS["backward_euler"]().step(system, State(0.0, system.x0, system.v0), 1.0 / 60.0, capture)
    return system, capture.problem, capture.start


def _best(sweep_once) -> float:
    sweep_once()  # compiled and warm
    best = np.inf
    for _ in range(REPEATS):
        began = time.perf_counter()
        for _ in range(SWEEPS):
            sweep_once()
        best = min(best, (time.perf_counter() - began) / SWEEPS)
    return best


def _timed_sweeps(system, problem, start):
    """(the compiled sweep, the problem's parts, the colour plans, the vertices they move, one sweep in place as a
    function of y, {threads: the best time of a sweep}) at 1 and, where there are 2, 2 threads."""
    import numba

    sweep, parts = system.vertex_form().sweep(), IncrementalParts.of(problem)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding),
                         system.dim)
    rounds = np.zeros(max(plan.vertices.size for plan in plans), dtype=np.int64)
    gradient_norms = np.zeros(rounds.size)

    def sweep_once(y):
        for plan in plans:
            sweep.sweep(y, plan.vertices, plan.constrained, plan.all_projectors, parts, "clamp", DETERMINANT_FLOOR,
                        MAX_HALVINGS, rounds[:plan.vertices.size], gradient_norms[:plan.vertices.size])

    available = numba.config.NUMBA_NUM_THREADS
    times = {}
    for threads in sorted({1, min(2, available)}):
        numba.set_num_threads(threads)
        y = start.copy()
        times[threads] = _best(lambda: sweep_once(y))
    numba.set_num_threads(available)
    return sweep, parts, plans, sum(plan.vertices.size for plan in plans), sweep_once, times


def rows() -> list[tuple[str, float, str, str]]:
    system, problem, start = _problem("realtime_solvers.yaml", resolution=[RESOLUTION, RESOLUTION])
    sweep, parts, plans, vertices, simrun_sweep, times = _timed_sweeps(system, problem, start)
    one = times[1]
    table = [(f"vbd sweep cloth {RESOLUTION}x{RESOLUTION}, 1 thread: us per vertex", one / vertices * 1e6,
              f"<= {PER_VERTEX_TARGET:g}", f"{one * 1e3:.2f} ms per sweep, {vertices} vertices, {len(plans)} colours")]
    if 2 in times:
        table.append((f"vbd sweep cloth {RESOLUTION}x{RESOLUTION}: 1 thread / 2 threads", one / times[2],
                      f">= {THREADS_TARGET:g}", f"{times[2] * 1e3:.2f} ms per sweep at 2 threads"))
    table.append(_xpbd_row(system))
    table.extend(_collider_rows())
    table.extend(_fem_rows())
    table.extend(_shell_rows())
    table.extend(_newton_rows())
    library = compiled(CLOTH_SOURCE)
    if library is None:
        print("vbd against a C loop: skipped, no C compiler (cc or gcc) on the path")
        return table
    order = np.concatenate([plan.vertices for plan in plans]).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum([plan.vertices.size for plan in plans])]).astype(np.int64)
    if any(plan.constrained.any() for plan in plans) or parts.damping_weight != 0.0 or sweep.law != 0:
        raise AssertionError("the C loop takes pins only, Hookean springs and no damping")
    deltas, lengths = np.empty(3 * sweep.max_degree), np.empty(sweep.max_degree)
    arrays = [np.ascontiguousarray(array, dtype=np.int64) for array in (sweep.indptr, sweep.other, sweep.springs)]
    gravity = np.ascontiguousarray(sweep.gravity_force.ravel())
    library.sweep.restype = None
    library.sweep.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                              ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                              ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double, ctypes.c_int,
                              ctypes.c_void_p, ctypes.c_void_p]

    def c_sweep(z):
        library.sweep(z.ctypes.data, starts.ctypes.data, len(plans), order.ctypes.data, parts.y_tilde.ctypes.data,
                      parts.mass.ctypes.data, parts.scale, arrays[0].ctypes.data, arrays[1].ctypes.data,
                      arrays[2].ctypes.data, sweep.stiffness.ctypes.data, sweep.rest_length.ctypes.data,
                      gravity.ctypes.data, DETERMINANT_FLOOR, MAX_HALVINGS, deltas.ctypes.data, lengths.ctypes.data)

    table.append(_against_c(f"vbd sweep cloth {RESOLUTION}x{RESOLUTION}", simrun_sweep, c_sweep, start, one, vertices))
    return table


def _collider_rows() -> list[tuple[str, float, str, str]]:
    """The same cloth's sweep with a sphere under its middle (r = 0.3 m), penalty (k = 1e4 N/m, the cloth's middle 5 cm
    inside) and IPC (dhat = 1 cm, 5 mm below): compiled (contact/point_kernels.py in the sweep), 1 thread, and the
    numpy sweep it replaced / the compiled one. The numpy sweep is timed over 4 sweeps, not 40 (it is several times slower)."""
    import numba

    table = []
    for method, contact in (("penalty", {"sphere": {"center": [0.5, 0.5, -0.25], "radius": 0.3, "stiffness": 1.0e4}}),
                            ("ipc", {"method": "ipc", "dhat": 0.01,
                                     "sphere": {"center": [0.5, 0.5, -0.305], "radius": 0.3}})):
        system, problem, start = _problem("realtime_solvers.yaml", resolution=[RESOLUTION, RESOLUTION],
                                          contact=contact)
        _, _, plans, vertices, _, times = _timed_sweeps(system, problem, start)
        solver, y = VertexBlockDescent(), start.copy()
        available = numba.config.NUMBA_NUM_THREADS
        numba.set_num_threads(1)
        numpy_time = np.inf
        for _ in range(REPEATS):
            began = time.perf_counter()
            for _ in range(4):
                y = solver._sweep(problem, y, plans)[0]
            numpy_time = min(numpy_time, (time.perf_counter() - began) / 4)
        numba.set_num_threads(available)
        touching = system.contact.active_count(y)
        table.append((f"vbd sweep cloth {RESOLUTION}x{RESOLUTION} on a sphere ({method}), 1 thread: us per vertex",
                      times[1] / vertices * 1e6, "information",
                      f"{touching} vertices in contact; the numpy sweep: {numpy_time / vertices * 1e6:.2f} us per vertex "
                      f"({numpy_time / times[1]:.1f}x)"))
    return table


def _fem_rows() -> list[tuple[str, float, str, str]]:
    """VBD's sweep of realtime_fem.yaml's beam (12,288 stable neo-Hookean tets) at its first frame, 1 and 2 threads,
    and against the same sweep in C (vbd_c_loops.py ``fem_sweep``) on the same arrays."""
    system, problem, start = _problem("realtime_fem.yaml")
    sweep, parts, plans, vertices, simrun_sweep, times = _timed_sweeps(system, problem, start)
    one = times[1]
    table = [(f"vbd sweep fem beam ({len(system.elements)} tets), 1 thread: us per vertex", one / vertices * 1e6,
              f"<= {FEM_PER_VERTEX_TARGET:g}", f"{one * 1e3:.2f} ms per sweep, {vertices} vertices, {len(plans)} colours")]
    if 2 in times:
        table.append(("vbd sweep fem beam: 1 thread / 2 threads", one / times[2], f">= {THREADS_TARGET:g}",
                      f"{times[2] * 1e3:.2f} ms per sweep at 2 threads"))
    library = compiled(FEM_SOURCE)
    if library is None:
        print("vbd fem against a C loop: skipped, no C compiler (cc or gcc) on the path")
        return table
    if (system.material != "stable_neo_hookean" or any(plan.constrained.any() for plan in plans)
            or parts.damping_weight != 0.0 or sweep.colliders[0].size or not (sweep.lam > 0.0).all()):
        raise AssertionError("the C loop takes the stable neo-Hookean energy with lambda > 0 (K needs no projection), "
                             "pins only, no damping and no colliders")
    order = np.concatenate([plan.vertices for plan in plans]).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum([plan.vertices.size for plan in plans])]).astype(np.int64)
    scratch = [np.empty((sweep.max_degree, 3)), np.empty((sweep.max_degree, 3)), np.empty(sweep.max_degree),
               np.empty(sweep.max_degree)]
    arrays = [np.ascontiguousarray(array) for array in (sweep.indptr, sweep.elements, sweep.shape_gradients,
                                                        sweep.volumes, sweep.mu, sweep.lam, sweep.alpha)]
    gravity = np.ascontiguousarray(sweep.gravity_force.ravel())
    library.fem_sweep.restype = None
    library.fem_sweep.argtypes = ([ctypes.c_void_p] * 2 + [ctypes.c_long] + [ctypes.c_void_p] * 3 + [ctypes.c_double]
                                  + [ctypes.c_void_p] * 8 + [ctypes.c_double] * 2 + [ctypes.c_int]
                                  + [ctypes.c_void_p] * 4)

    def c_sweep(z):
        library.fem_sweep(z.ctypes.data, starts.ctypes.data, len(plans), order.ctypes.data, parts.y_tilde.ctypes.data,
                          parts.mass.ctypes.data, parts.scale, *(array.ctypes.data for array in arrays),
                          gravity.ctypes.data, sweep.kept_volume, DETERMINANT_FLOOR, MAX_HALVINGS,
                          *(array.ctypes.data for array in scratch))

    table.append(_against_c("vbd sweep fem beam", simrun_sweep, c_sweep, start, one, vertices))
    return table


def _against_c(name: str, simrun_sweep, c_sweep, start, one: float, vertices: int) -> tuple[str, float, str, str]:
    """The row of simrun's sweep (one sweep in place, taking ``one`` s on one thread) against the C loop's: both from
    start, their positions first checked to agree within 1e-12 m."""
    import numba

    simrun_y, c_y = start.copy(), start.copy()
    available = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(1)
    simrun_sweep(simrun_y)
    numba.set_num_threads(available)
    c_sweep(c_y)
    difference = float(np.max(np.abs(simrun_y - c_y)))
    if difference > 1e-12:
        raise AssertionError(f"{name}: simrun's sweep and the C loop differ by {difference:.2e} m")
    z = start.copy()
    c_time = _best(lambda: c_sweep(z))
    return (f"{name}: simrun 1 thread / C loop", one / c_time, f"<= {C_RATIO_TARGET:g}",
            f"C {c_time / vertices * 1e6:.3f} us per vertex ({c_time * 1e3:.2f} ms), swept positions within "
            f"{difference:.1e} m")


def _shell_rows() -> list[tuple[str, float, str, str]]:
    """VBD's sweep of cloth_fem.yaml's St. Venant-Kirchhoff shell (its membrane triangles and discrete-shell hinges,
    shell_vbd_kernels.py) on the 64 x 64 grid, over the sphere it falls on, at its first frame, 1 and 2 threads."""
    shipped = yaml.safe_load((CONFIGS / "cloth_fem.yaml").read_text())["sweep"]["system"]
    shell = {key: value for key, value in next(system for system in shipped if system["label"] == "stvk_shell").items()
             if key != "label"}
    shell["model"] = {"grid": {**shell["model"]["grid"], "resolution": [RESOLUTION, RESOLUTION]}}
    system, problem, start = _problem_of(shell)
    _, _, plans, vertices, _, times = _timed_sweeps(system, problem, start)
    one = times[1]
    name = f"vbd sweep shell {RESOLUTION}x{RESOLUTION} ({len(system.elements)} triangles, {len(system.hinges)} hinges)"
    table = [(f"{name}, 1 thread: us per vertex", one / vertices * 1e6, "information",
              f"{one * 1e3:.2f} ms per sweep, {vertices} vertices, {len(plans)} colours")]
    if 2 in times:
        table.append(("vbd sweep shell: 1 thread / 2 threads", one / times[2], "information",
                      f"{times[2] * 1e3:.2f} ms per sweep at 2 threads"))
    return table


def _newton_rows() -> list[tuple[str, float, str, str]]:
    try:
        import warp

        warp.config.log_level = warp.LOG_WARNING  # before newton initialises Warp: no line per kernel module loaded
        import newton
        import newton.viewer
        from newton.examples.cloth.example_cloth_hanging import Example
    except ImportError:
        print("vbd against newton: skipped, the newton package is not installed (make install-peers)")
        return []
    warp.set_device("cpu")
    width, height, frames = 64, 32, 5
    example = Example(newton.viewer.ViewerNull(), SimpleNamespace(solver="vbd", width=width, height=height))
    example.step()  # its kernels compiled
    began = time.perf_counter()
    for _ in range(frames):
        example.step()
    warp.synchronize()
    seconds = time.perf_counter() - began
    particles = example.model.particle_count
    newton_cost = seconds / (frames * example.sim_substeps * example.iterations * particles)
    cloth = {"type": "cloth", "resolution": [width + 1, height + 1], "size": [0.1 * width, 0.1 * height],
             "mass": 0.1 * particles, "stretch_stiffness": 1.0e3, "shear_stiffness": 1.0e2, "bend_stiffness": 10.0,
             "damping": 0.0, "gravity": [0.0, 0.0, -9.81], "pinned": ["left"]}
    system = load_experiment({"name": "bench_vbd_peer", "system": cloth, "integrators": ["backward_euler"],
                              "sweep": {"dt": [example.sim_dt]}})[0].system.build()
    # a substep of the cloth in motion (0.2 s of swinging, by Newton), so that 10 iterations do not converge
    method, state = INTEGRATORS["backward_euler"](), State(0.0, system.x0, system.v0)
    newton_solver = Newton(tolerance=1e-9, max_iterations=50)
    for _ in range(12):
        state, _ = method.step(system, state, 1.0 / 60.0, newton_solver)
    capture = _Capture()
    method.step(system, state, example.sim_dt, capture)
    solver = VertexBlockDescent(tolerance=1e-300, max_iterations=example.iterations)
    _, stats = solver.minimize(capture.problem, capture.start)  # compiled and warm
    repeats = 20
    began = time.perf_counter()
    for _ in range(repeats):
        solver.minimize(capture.problem, capture.start)
    simrun_cost = (time.perf_counter() - began) / (repeats * stats.iterations * system.vertex_count)
    return [(f"vbd cloth {width}x{height} cells: newton (cpu) / simrun, per vertex iteration", newton_cost / simrun_cost,
             "information", f"newton {newton.__version__} {newton_cost * 1e6:.2f} us (triangles, bending, self-contact), "
             f"simrun {simrun_cost * 1e6:.2f} us (springs, {stats.iterations} iterations), {particles} vertices")]


def _xpbd_row(system) -> tuple[str, float, str, str]:
    """One XPBD iteration over every group, one thread, per spring constraint (the rows' distance constraints)."""
    import numba

    projection = spring_projection(system)
    h = 1.0 / 60.0 / 10.0
    scaled = projection.scaled(h)
    acceleration = projection.acceleration(system, system.x0, system.v0)  # the substep's prediction x_n + h v
    displacement = h * (system.v0 + (0.0 if acceleration is None else h * acceleration))
    multipliers = [group.zero_multipliers() for group in projection.groups]
    constraints = sum(group.first.size for group in projection.groups)

    def iteration():
        for group, (stiffness_h2, damping_h), multiplier in zip(projection.groups, scaled, multipliers):
            group.project(system.x0, displacement, multiplier, stiffness_h2, damping_h)

    available = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(1)
    seconds = _best(iteration)
    numba.set_num_threads(available)
    return (f"xpbd iteration cloth {RESOLUTION}x{RESOLUTION}, 1 thread: us per constraint", seconds / constraints * 1e6,
            f"<= {XPBD_TARGET:g}", f"{seconds * 1e3:.2f} ms per iteration, {constraints} springs in "
            f"{len(projection.groups)} groups")


__all__ = ["rows"]
