"""Where runs are simulated: serially, on a local process pool, or on a Dask cluster.

Every executor takes the runs and yields ``(run, result)`` as runs finish; the caller (one writer in
the main process) commits each result at once. Runs are independent, so the order of completion
does not change any run's data.
"""

from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import os
from collections.abc import Iterator

import threadpoolctl

from simrun.config import ConfigError, Run
from simrun.simulate import RunResult, simulate

EXECUTORS = ("local", "dask")


def default_jobs() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def run_serial(runs: list[Run]) -> Iterator[tuple[Run, RunResult]]:
    for run in runs:
        yield run, simulate(run)


# Thread-count variables of the BLAS libraries a run may load (CHOLMOD's OpenBLAS; MKL or OpenMP builds)
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_process_pool(runs: list[Run], jobs: int) -> Iterator[tuple[Run, RunResult]]:
    """A local pool of `jobs` processes; pending runs are cancelled when the consumer stops early."""
    pool = process_pool(jobs)
    finished = False
    try:
        futures = {pool.submit(simulate, run): run for run in runs}
        for future in concurrent.futures.as_completed(futures):
            yield futures[future], future.result()
        finished = True
    finally:
        pool.shutdown(wait=finished, cancel_futures=True)


def process_pool(jobs: int) -> concurrent.futures.ProcessPoolExecutor:
    """`jobs` worker processes, each with cores / jobs BLAS threads."""
    threads = max(1, default_jobs() // jobs)
    return concurrent.futures.ProcessPoolExecutor(max_workers=jobs, mp_context=_worker_context(),
                                                  initializer=_limit_blas_threads, initargs=(threads,))


def _limit_blas_threads(threads: int) -> None:
    """Give each worker its share of the cores for BLAS: multithreaded BLAS in two workers on two
    cores would run four threads, each waiting on the others. The libraries already loaded (numpy's)
    are limited now; the ones loaded later (CHOLMOD's, with the first `cholesky` solver) read these
    variables when they load. A count the user set is left alone."""
    if not any(variable in os.environ for variable in BLAS_THREAD_VARIABLES):
        threadpoolctl.threadpool_limits(limits=threads, user_api="blas")
    for variable in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(variable, str(threads))


def _worker_context():
    """Workers forked from a clean server process: a plain fork would inherit the open results file
    (and the HDF5 lock on it); the server imports the simulation once, so each fork starts at once."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["simrun.simulate"])
    return context


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


def execute(runs: list[Run], executor: str = "local", jobs: int = 1,
            scheduler: str | None = None) -> Iterator[tuple[Run, RunResult]]:
    if executor == "dask":
        return run_dask(runs, jobs, scheduler)
    if jobs <= 1 or len(runs) <= 1:
        return run_serial(runs)
    return run_process_pool(runs, min(jobs, len(runs)))
