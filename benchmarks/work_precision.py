"""At equal error on the 16 x 16 cloth of configs/work_precision.yaml: simrun's Radau IIA against scipy's
Radau, and simrun's cheapest method against scipy's best.

The cloth (stretch 1e3 N/m, hanging from two corners, swinging down from flat) over 1 s; every method step-controlled
at tolerances 1e-6, 1e-7 and 1e-8 (rtol = atol, rms norm), its error max |x - x_ref| at 1 s against scipy's DOP853 at
rtol 1e-10 (a method and tolerance no compared run uses), its wall time (the stepping loop; scipy's solve_ivp whole)
read at the error 1e-6 m off its own work-precision curve (runner/analysis/equal_error.py: log-log between the runs
that bracket it, never extrapolated). Targets: scipy's Radau (with the sparse Jacobian) over simrun's radau_iia at
least 2; scipy's best over simrun's cheapest at least 5. numpy's BLAS is held at one thread for both sides: SuperLU's
small dense kernels in two threads on a loaded machine make a factorisation's time vary from call to call
(docs/performance.md, "Threads and BLAS").

The second target cannot be met on this cloth (docs/performance.md): it is not stiff at these tolerances, so the
cheapest method of each side is explicit (simrun's dopri5, scipy's DOP853), and both evaluate one function, the
system's own acceleration, which the peer hands scipy (nearly the same cost per evaluation). At equal cost per
evaluation the ratio is that of the evaluations at equal error, and an eighth-order pair needs fewer than any fifth-
order one: 3,854 against 7,520 near 5e-6 m.
"""

from __future__ import annotations

import math

import numpy as np
import threadpoolctl

from simrun.analysis.equal_error import cost_at_error
from simrun.analysis.reference import reference_positions
from simrun.execution.simulate import simulate
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

TOLERANCES = (1e-6, 1e-7, 1e-8)
ERROR = 1e-6  # m: the equal error of the comparison (1e-6 of the cloth's 1 m)
RADAU_TARGET, CHEAPEST_TARGET = 2.0, 5.0
# the methods compared: those that could be the cheapest here. Measured on 2026-12-04 at tolerances 1e-5 to 1e-7, the
# others took 3 to 100 times as long as these at 100 times their error: simrun's trbdf2, ros3p, rodas3 and BDF3
# (ros3p 24 s and rodas3 22 s at tolerance 1e-6, 1e-4 m off; trbdf2 over 60 s at 1e-7), and scipy's LSODA (14 s at
# 1e-6, 1e-4 m off). BDF of order 5 and scipy's BDF stay as the implicit multistep methods of each side.
SIMRUN = ("dopri5", "radau_iia", "{type: bdf, order: 5}")
SCIPY = ("Radau", "BDF", "RK45", "DOP853")
CLOTH = """
system: {type: cloth, resolution: [16, 16], size: [1.0, 1.0], mass: 1.0, stretch_stiffness: 1.0e3,
         shear_stiffness: 1.0e2, bend_stiffness: 1.0, damping: 0.0, gravity: [0.0, 0.0, -9.81], pinned: [0, 15]}
"""


def _runs(integrators: list[str], duration: float = 1.0):
    config = f"""
name: bench_work_precision
{CLOTH}
integrators: [{", ".join(integrators)}]
solver: {{type: newton, tolerance: 1.0e-10, max_iterations: 50}}
duration: {duration}
step_control: {{tolerance: 1.0e-6, norm: rms}}
record: {{max_wall_time: 60}}
sweep: {{step_control.tolerance: [{", ".join(f"{tolerance:g}" for tolerance in TOLERANCES)}]}}
"""
    experiment, _ = load_experiment(config)
    return expand_runs(experiment)


def _measured(reference: np.ndarray) -> dict[str, tuple[list[float], list[float], list[int]]]:
    """label -> (errors m, wall times s, accepted steps) over the tolerances; a run that did not end ok is left out."""
    integrators = list(SIMRUN) + [f"{{type: solve_ivp, method: {method}}}" for method in SCIPY]
    simulate(_runs(["radau_iia", "dopri5"], duration=0.01)[0])  # warm-up: the first run pays for imports
    curves: dict[str, tuple[list[float], list[float], list[int]]] = {}
    for run in _runs(integrators):
        result = simulate(run)
        if str(result.status) != "ok":
            continue
        label = run.integrator.label
        errors, walls, steps = curves.setdefault(label, ([], [], []))
        errors.append(float(np.max(np.abs(result.samples["error_positions"] - reference))))
        walls.append(result.wall_time)
        steps.append(int(result.attrs.get("accepted_steps", result.steps)))
    return curves


def _at_error(curve) -> float:
    errors, walls, _ = curve
    return float(cost_at_error(errors, walls, [ERROR])[0])


def rows() -> list[tuple[str, float, str, str]]:
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
        system = _runs(["dopri5"])[0].system.build()
        reference = reference_positions(system, [1.0])[1.0]
        curves = _measured(reference)
    times = {label: _at_error(curve) for label, curve in curves.items()}

    def detail(label: str) -> str:
        errors, walls, steps = curves.get(label, ([], [], []))
        points = ", ".join(f"{error:.1e} m in {wall:.2f} s ({count} steps)" for error, wall, count in zip(errors, walls, steps))
        return f"{label}: {times.get(label, math.nan):.2f} s at {ERROR:g} m [{points}]"

    ratio = times.get("solve_ivp", math.nan) / times.get("radau_iia", math.nan)
    result = [(f"cloth 16x16, error {ERROR:g} m: scipy Radau / simrun radau_iia, wall time", ratio, f">= {RADAU_TARGET:g}",
               f"{detail('radau_iia')}; {detail('solve_ivp')}")]
    reached = {label: time for label, time in times.items() if math.isfinite(time)}
    simrun = {label: time for label, time in reached.items() if not label.startswith("solve_ivp")}
    scipy = {label: time for label, time in reached.items() if label.startswith("solve_ivp")}
    if simrun and scipy:
        cheapest, best = min(simrun, key=simrun.get), min(scipy, key=scipy.get)
        result.append((f"cloth 16x16, error {ERROR:g} m: scipy's best / simrun's cheapest", scipy[best] / simrun[cheapest],
                       f">= {CHEAPEST_TARGET:g}", f"{detail(cheapest)}; {detail(best)}; not reaching {ERROR:g} m "
                       f"inside their tolerances: {', '.join(sorted(set(curves) - set(reached))) or 'none'}"))
    return result


__all__ = ["rows"]
