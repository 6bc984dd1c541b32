"""`python -m benchmarks` (what `make bench` runs): every benchmark, one table of ratios.

Every figure is a ratio against a reference measured in the same process in the same run; the
absolute times are printed for information only.
"""

from __future__ import annotations

import platform

import numpy as np
import scipy

from . import cloth_newton

BENCHMARKS = (cloth_newton,)


def main() -> None:
    print(f"simrun benchmarks: python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}")
    rows = [row for benchmark in BENCHMARKS for row in benchmark.rows()]
    width = max(len(name) for name, _, _ in rows)
    print(f"{'what':<{width}}  {'ratio':>7}  absolute")
    for name, ratio, detail in rows:
        print(f"{name:<{width}}  {ratio:7.2f}  {detail}")


if __name__ == "__main__":
    main()
