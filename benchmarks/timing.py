"""Timing helpers for the benchmarks: best of several repeats, since these machines are noisy."""

from __future__ import annotations

import time


def best_of(function, repeats: int = 5) -> float:
    """The shortest wall time (s) of `repeats` calls."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best
