"""``--jobs 2`` against ``--jobs 1`` on a sweep of 16 independent runs of about a second each.

Both go through the real command line (``simrun.cli.main``) into a temporary folder, without
figures, twice each, interleaved; the ratio is the best serial wall time over the best parallel one (target: at least 1.8
with two jobs on a machine with two free cores). Also: the shipped configs/damping_curves.yaml
end to end, figures included, with ``--jobs 2`` (target: under 30 s); ``SIMRUN_BENCH_QUICK=1``
skips it.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import time
from pathlib import Path

from simrun.cli import main as cli

RUNS = 16
REPEATS = 2
# backward Euler with Newton on the spring: about 38 k steps, so that a run lasts about a second
CONFIG = f"""\
name: parallel_bench
system: {{type: spring_mass, stiffness: 100.0}}
integrators: [backward_euler]
solver: {{type: newton, linear_solver: direct}}
duration: 40.0
sweep:
  dt: {{linspace: [1.0e-3, 1.15e-3, {RUNS}]}}
"""
DAMPING_CURVES = Path(__file__).resolve().parent.parent / "configs" / "damping_curves.yaml"


def _timed_cli(argv: list[str]) -> float:
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = cli(argv)
    if code != 0:
        raise RuntimeError(f"simrun {' '.join(argv)} exited with {code}")
    return time.perf_counter() - start


def rows() -> list[tuple[str, float, str, str]]:
    table = []
    with tempfile.TemporaryDirectory() as folder:
        config = Path(folder) / "parallel_bench.yaml"
        config.write_text(CONFIG)
        # interleaved, best of REPEATS each: a slow spell of this shared machine hits both alike
        timings = {1: [], 2: []}
        for repeat in range(REPEATS):
            for jobs in timings:
                output = f"{folder}/jobs{jobs}-{repeat}"
                timings[jobs].append(_timed_cli([str(config), "--output", output, "-j", str(jobs), "--no-plots", "-q"]))
        serial, parallel = min(timings[1]), min(timings[2])
        table.append((
            f"sweep of {RUNS} runs through the CLI: --jobs 1 / --jobs 2 wall time",
            serial / parallel, ">= 1.8",
            f"jobs 1: {serial:.1f} s, jobs 2: {parallel:.1f} s ({os.cpu_count()} cores)",
        ))
        if os.environ.get("SIMRUN_BENCH_QUICK"):
            return table
        whole = _timed_cli([str(DAMPING_CURVES), "--output", f"{folder}/damping_curves", "-j", "2", "-q"])
        table.append((
            "configs/damping_curves.yaml end to end with figures, --jobs 2: wall time / 30 s",
            whole / 30.0, "<= 1", f"{whole:.1f} s",
        ))
    return table
