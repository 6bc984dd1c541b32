"""This machine's executor: the tasks one after another for one job (or one task), else on a pool of processes."""

from __future__ import annotations

import concurrent.futures
import concurrent.futures.process
from collections.abc import Iterator

from simrun.errors import WorkerLost
from simrun.execution.workers import defined_in_main, process_pool, stop_workers
from simrun.experiment.config import Run

from ._options import ExecutorOptions


def run(tasks: list, work, runs: list[Run], options: ExecutorOptions) -> Iterator[tuple]:
    """Serially for one job or one task, else a pool of ``options.jobs`` processes."""
    if options.jobs <= 1 or len(tasks) <= 1:
        return run_serial(tasks, work)
    return run_process_pool(tasks, work, runs, options)


def run_serial(tasks: list, work) -> Iterator[tuple]:
    for task in tasks:
        yield task, work(task)


def _size(task) -> int:
    return len(task) if isinstance(task, list) else 1


def run_process_pool(tasks: list, work, runs: list[Run], options: ExecutorOptions) -> Iterator[tuple]:
    """A local pool of ``options.jobs`` processes; pending tasks are cancelled and running ones ended when the
    consumer stops early (or Ctrl-C, which the workers ignore, stops it)."""
    pool = process_pool(min(options.jobs, len(tasks)), needs_main=defined_in_main(
        item for run in runs for item in (run.system, run.system.system_class)))
    finished = False
    try:
        # the biggest tasks first (chunks of lanes), so that no worker is left with a long one at the end
        ordered = sorted(tasks, key=_size, reverse=True)
        futures = {pool.submit(work, task): task for task in ordered}
        for future in concurrent.futures.as_completed(futures):
            try:
                outcome = future.result()
            except concurrent.futures.process.BrokenProcessPool:  # which task's worker died is not known: it fails them all
                raise WorkerLost("running the sweep") from None
            yield futures[future], outcome
        finished = True
    finally:
        if not finished:  # Ctrl-C (the workers ignore it) or a consumer that stopped: no task in flight is waited for
            stop_workers(pool)
        # wait even when the workers were stopped: the pool's manager thread then ends before the
        # interpreter's exit hook wakes it (Python 3.11 races there and prints a traceback at exit)
        pool.shutdown(wait=True, cancel_futures=True)
