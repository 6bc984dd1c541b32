"""The local process pool's workers: where they come from and how many BLAS threads each gets.

Kept free of numpy and the simulation, so that the command line can start the workers' fork server
before it imports them itself: the two imports (~0.5 s each) then run side by side on two cores.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import multiprocessing.forkserver
import os

import threadpoolctl

EXECUTORS = ("local", "dask")
# Thread-count variables of the BLAS libraries a run may load (CHOLMOD's OpenBLAS; MKL or OpenMP builds)
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def default_jobs() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


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


def start_worker_server() -> None:
    """Start the pool's fork server now, in the background: its imports then overlap with the
    caller's own instead of delaying the first run. A no-op where workers are spawned."""
    if _worker_context().get_start_method() == "forkserver":
        multiprocessing.forkserver.ensure_running()


def _worker_context():
    """Workers forked from a clean server process: a plain fork would inherit the open results file
    (and the HDF5 lock on it); the server imports the simulation once, so each fork starts at once."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["simrun.simulate"])
    return context


def may_use_local_pool(argv: list[str]) -> bool:
    """Whether a `simrun run` command line may run on the local pool (not -j 1, not --executor dask);
    a guess from the options alone, before the full parser (which needs the heavy imports) runs."""
    guess = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    guess.add_argument("-j", "--jobs", type=int)
    guess.add_argument("--executor")
    try:
        known, _ = guess.parse_known_args(argv)
    except (argparse.ArgumentError, SystemExit):
        return False  # the real parser will report it
    return known.executor in (None, "local") and (known.jobs is None or known.jobs > 1) and default_jobs() > 1
