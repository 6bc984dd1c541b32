"""Where runs are simulated: serially, on a local process pool, or on a Dask cluster.

Every executor takes the runs and yields ``(run, result)`` as runs finish; the caller (one writer in
the main process) commits each result at once. Runs are independent, so the order of completion
does not change any run's data.
"""

from __future__ import annotations

import concurrent.futures
import logging
from collections.abc import Iterator

from simrun.config import Run
from simrun.errors import ConfigError
from simrun.simulate import RunResult, simulate
from simrun.workers import EXECUTORS, process_pool, stop_workers

__all__ = ["EXECUTORS", "EXECUTOR_FUNCTIONS", "execute", "run_serial", "run_process_pool", "run_dask"]


def run_serial(runs: list[Run]) -> Iterator[tuple[Run, RunResult]]:
    for run in runs:
        yield run, simulate(run)


def run_process_pool(runs: list[Run], jobs: int) -> Iterator[tuple[Run, RunResult]]:
    """A local pool of `jobs` processes; pending runs are cancelled and running ones ended when the
    consumer stops early (or Ctrl-C, which the workers ignore, stops it)."""
    pool = process_pool(jobs)
    finished = False
    try:
        futures = {pool.submit(simulate, run): run for run in runs}
        for future in concurrent.futures.as_completed(futures):
            yield futures[future], future.result()
        finished = True
    finally:
        if not finished:  # Ctrl-C (the workers ignore it) or a consumer that stopped: no run in flight is waited for
            stop_workers(pool)
        # wait even when the workers were stopped: the pool's manager thread then ends before the
        # interpreter's exit hook wakes it (Python 3.11 races there and prints a traceback at exit)
        pool.shutdown(wait=True, cancel_futures=True)


def run_dask(runs: list[Run], jobs: int, scheduler: str | None) -> Iterator[tuple[Run, RunResult]]:
    """Dask: an existing scheduler at `scheduler`, else a local cluster of `jobs` single-threaded workers."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ConfigError("--executor dask: Dask is not installed; install it with  pip install 'simrun[dask]'  "
                          "(or: pip install 'dask[distributed]')") from None
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=logging.ERROR)
            client = Client(cluster)
    except OSError as error:
        raise ConfigError(f"--scheduler: cannot reach the Dask scheduler at {scheduler!r}: {error}") from None
    futures = []
    try:
        futures = client.map(simulate, runs, key=[f"simrun-{run.run_id}" for run in runs], pure=False)
        by_key = {future.key: run for future, run in zip(futures, runs)}
        for future in as_completed(futures):
            yield by_key[future.key], future.result()
    finally:
        client.cancel(futures)
        client.close()
        if cluster is not None:
            cluster.close()


def run_local(runs: list[Run], jobs: int, scheduler: str | None = None) -> Iterator[tuple[Run, RunResult]]:
    """This machine: serially for one job or one run, else a pool of ``jobs`` processes."""
    if jobs <= 1 or len(runs) <= 1:
        return run_serial(runs)
    return run_process_pool(runs, min(jobs, len(runs)))


# executor name -> function(runs, jobs, scheduler) yielding (run, result) as runs finish; the names are
# simrun.workers.EXECUTORS, which the command line offers before it imports this module
EXECUTOR_FUNCTIONS = {
    "process": run_local,
    "dask": run_dask,
}


def execute(runs: list[Run], executor: str = "process", jobs: int = 1,
            scheduler: str | None = None) -> Iterator[tuple[Run, RunResult]]:
    """Every run on the named executor; yields (run, result) as each finishes."""
    if executor not in EXECUTOR_FUNCTIONS:
        raise ConfigError(f"executor: unknown {executor!r}; valid: " + ", ".join(EXECUTOR_FUNCTIONS))
    return EXECUTOR_FUNCTIONS[executor](runs, jobs, scheduler)
