"""`python -m benchmarks` (what `make bench` runs): every benchmark, one table of ratios.

Every figure is a ratio against a reference measured in the same process in the same run; the
target column is the bound on that ratio (or on the absolute time it names), and the absolute
times are printed for information. ``SIMRUN_BENCH_QUICK=1`` skips the end-to-end runs of damping_curves and of the
damping map.
"""

from __future__ import annotations

import platform

import numpy as np
import scipy

from . import (calibration, cloth_explicit, cloth_iteration, cloth_newton, contact, dirk, fem, graphics_solvers,
               lagged_newton, lanes, mass_spring_paths, mesh_newton, parallel_sweep, realtime_kernels, small_steps,
               work_precision)

# cloth_iteration last: its cholesky part loads CHOLMOD, which holds numpy's BLAS at one thread
BENCHMARKS = (small_steps, lanes, cloth_newton, lagged_newton, cloth_explicit, mass_spring_paths, mesh_newton, fem, dirk,
              work_precision,
              graphics_solvers, realtime_kernels, contact, calibration, parallel_sweep, cloth_iteration)


# the table's columns, wide enough for every row's name and target, so that each row is printed as it is measured
NAME_WIDTH, TARGET_WIDTH = 68, 14


def main() -> None:
    print(f"simrun benchmarks: python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}; "
          f"{len(BENCHMARKS)} benchmarks, each row printed once measured", flush=True)
    print(f"{'what':<{NAME_WIDTH}}  {'ratio':>7}  {'target':<{TARGET_WIDTH}}  absolute", flush=True)
    for benchmark in BENCHMARKS:
        for name, ratio, target, detail in benchmark.rows():
            print(f"{name:<{NAME_WIDTH}}  {ratio:7.2f}  {target:<{TARGET_WIDTH}}  {detail}", flush=True)


if __name__ == "__main__":
    main()
