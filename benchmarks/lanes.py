"""Lockstep lanes (runner/execution/lanes.py): many spring runs stepped together, against the same arithmetic written
as a bare numpy loop here, and the damping map end to end.

- 10^4 spring runs (w from 1 to 100 rad/s x 100 damping ratios in (0, 0.05]) of 10^3 steps of 0.01 s, stepped by
  ``simulate_lanes`` (the stepping loop's wall time: the integrator's own step, the batched Newton, the energy check
  of every step, a sample every 10 steps), over the bare loop on the same arrays: symplectic Euler's kick and drift;
  backward Euler as one Newton iteration and its residual test per step (the step of a linear problem). Target <= 3.
  A second reference adds to the bare loop what a run records besides its update, also inline: the damping's energy
  budget and the divergence test of every step (what simulate and the lanes do for every run's numbers).
  The runs stay stable (h w <= 1) and their energies far above the subnormal range (E >= 1e-44 E0): an energy that
  underflows costs each operation a microcode assist (about 100 cycles), in both loops, and would time the CPU's
  subnormal handling rather than the lanes. The damping map sweeps into that range; its own row measures it.
- ``simrun configs/damping_map.yaml -j 2`` in a fresh process, figures included: wall time (target < 20 s), the
  peak of the summed resident memory of simrun and its workers (target < 1 GB, sampled from /proc every 20 ms), and
  the size of the results file. ``SIMRUN_BENCH_QUICK=1`` skips it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from simrun.execution.lanes import simulate_lanes
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

RUNS_PER_AXIS, STEPS, DT = 100, 1000, 0.01
ROOT = Path(__file__).resolve().parent.parent


def _runs(integrator: str):
    config = f"""
name: bench_lanes
system: {{type: spring_mass, mass: 1.0, x0: 1.0, damping_ratio: 0.0}}
integrators: [{integrator}]
solver: {{type: newton, tolerance: 1.0e-10}}
duration: {STEPS * DT}
record: {{every: 10}}
sweep:
  dt: [{DT}]
  system.stiffness: {{logspace: [0.0, 4.0, {RUNS_PER_AXIS}]}}
  system.damping_ratio: {{linspace: [0.0005, 0.05, {RUNS_PER_AXIS}]}}
"""
    experiment, _ = load_experiment(config)
    return expand_runs(experiment)


def _arrays(runs):
    column = lambda values: np.array(values, dtype=float).reshape(-1, 1)  # noqa: E731
    systems = [run.system.build() for run in runs]
    return (column([system.params.mass for system in systems]), column([system.stiffness for system in systems]),
            column([system.damping for system in systems]))


def _bare_symplectic_euler(m, k, d) -> float:
    x, v = np.ones_like(m), np.zeros_like(m)
    start = time.perf_counter()
    for _ in range(STEPS):
        v = v + DT * ((-k * x - d * v) / m)
        x = x + DT * v
    return time.perf_counter() - start


def _bare_backward_euler(m, k, d) -> float:
    x, v = np.ones_like(m), np.zeros_like(m)
    scale, weight = DT * DT, DT
    start = time.perf_counter()
    for _ in range(STEPS):
        predictor = x + DT * v
        gradient = m * (x - predictor) + scale * (k * x)
        y = x - gradient / (scale * k + weight * d + m)
        residual = m * (y - predictor) + scale * (k * y) + weight * (d * (y - x))
        np.all(np.abs(residual) <= 1e-10 * np.abs(gradient))
        v = (y - x) / DT
        x = y
    return time.perf_counter() - start


def _bare_bookkeeping(step):
    """``step`` (a bare loop) with what a run records besides its update, inline too: the damping's energy budget
    (h v_bar d v_bar per step) and the divergence test of every step (E and |E - E0| <= bound)."""
    def loop(m, k, d) -> float:
        x, v = np.ones_like(m), np.zeros_like(m)
        dissipated = np.zeros_like(m)
        energy0 = 0.5 * (m * v * v + k * x * x)
        bound = 1e6 * energy0
        start = time.perf_counter()
        for _ in range(STEPS):
            x_new, v_new = step(m, k, d, x, v)
            mean = 0.5 * (v + v_new)
            dissipated += DT * (mean * (d * mean))
            x, v = x_new, v_new
            np.all(np.abs(0.5 * (m * v * v + k * x * x) - energy0) <= bound)
        return time.perf_counter() - start
    return loop


def _symplectic_euler_step(m, k, d, x, v):
    v = v + DT * ((-k * x - d * v) / m)
    return x + DT * v, v


def _backward_euler_step(m, k, d, x, v):
    scale, weight = DT * DT, DT
    predictor = x + DT * v
    gradient = m * (x - predictor) + scale * (k * x)
    y = x - gradient / (scale * k + weight * d + m)
    residual = m * (y - predictor) + scale * (k * y) + weight * (d * (y - x))
    np.all(np.abs(residual) <= 1e-10 * np.abs(gradient))
    return y, (y - x) / DT


def _lane_rows() -> list[tuple[str, float, str, str]]:
    rows = []
    for integrator, bare, step in (("symplectic_euler", _bare_symplectic_euler, _symplectic_euler_step),
                                   ("backward_euler", _bare_backward_euler, _backward_euler_step)):
        runs = _runs(integrator)
        reference = min(bare(*_arrays(runs)) for _ in range(3))
        stepping = min(float(simulate_lanes(runs).wall_time.sum()) for _ in range(2))
        with_bookkeeping = min(_bare_bookkeeping(step)(*_arrays(runs)) for _ in range(3))
        rows.append((f"lanes: {len(runs):,} spring runs x {STEPS} steps, {integrator} / bare numpy loop",
                     stepping / reference, "<= 3",
                     f"{1e6 * stepping / STEPS:.0f} us per step of all runs against {1e6 * reference / STEPS:.0f} us"))
        rows.append(("lanes: the same / bare loop with the run's energy budget and divergence test",
                     stepping / with_bookkeeping, "-", f"against {1e6 * with_bookkeeping / STEPS:.0f} us"))
    return rows


def _tree_rss(pid: int) -> int:
    """Bytes resident in process ``pid`` and all its descendants (the pool's fork server and workers)."""
    children: dict[int, list[int]] = {}
    sizes: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/status", encoding="ascii", errors="replace") as status:
                fields = dict(line.split(":", 1) for line in status if ":" in line)
        except OSError:
            continue
        children.setdefault(int(fields.get("PPid", "0").strip()), []).append(int(entry))
        sizes[int(entry)] = int(fields.get("VmRSS", "0 kB").split()[0]) * 1024
    total, pending = 0, [pid]
    while pending:
        current = pending.pop()
        total += sizes.get(current, 0)
        pending += children.get(current, [])
    return total


def _map_rows() -> list[tuple[str, float, str, str]]:
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "simrun", "run", str(ROOT / "configs" / "damping_map.yaml"), "-j", "2",
                   "--output", folder, "-q"]
        peak = [0]
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

        def sample() -> None:
            while process.poll() is None:
                peak[0] = max(peak[0], _tree_rss(process.pid))
                time.sleep(0.02)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        _, errors = process.communicate()
        elapsed = time.perf_counter() - start
        sampler.join()
        if process.returncode != 0:
            raise RuntimeError(f"configs/damping_map.yaml failed: {errors.strip()}")
        size = os.path.getsize(Path(folder) / "results.h5")
        runs = len(expand_runs(load_experiment(ROOT / "configs" / "damping_map.yaml")[0]))
    return [(f"damping map: simrun configs/damping_map.yaml -j 2, {runs:,} runs, figures included (s)", elapsed,
             "< 20", f"results.h5 {size / 1e6:.0f} MB"),
            ("damping map: peak resident memory of simrun and its workers (GB)", peak[0] / 1e9, "< 1",
             f"{peak[0] / 1e6:.0f} MB, sampled every 20 ms")]


def rows() -> list[tuple[str, float, str, str]]:
    return _lane_rows() + ([] if os.environ.get("SIMRUN_BENCH_QUICK") else _map_rows())


if __name__ == "__main__":
    for row in rows():
        print(row)
