"""Where runs are simulated: serially, on a local process pool, or on a Dask cluster.

Every executor takes tasks, a run (``simulate``) or a chunk of runs stepped together as lanes (``simulate_lanes``,
runner/execution/lanes.py), and yields ``(task, outcome)`` as tasks finish: a RunResult for a run, a LaneBatch for a chunk. The
caller (one writer in the main process) commits each outcome at once. Runs are independent, so neither the order of
completion nor the chunk a run was stepped in changes any run's data.
"""

from __future__ import annotations

import concurrent.futures
import concurrent.futures.process
import io
import logging
import pickle
import sys
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

from simrun.errors import ConfigError, WorkerLost
from simrun.execution.lanes import lane_chunks, simulate_lanes
from simrun.execution.simulate import simulate
from simrun.execution.workers import EXECUTORS, defined_in_main, process_pool, stop_workers
from simrun.experiment.config import Run

__all__ = ["EXECUTORS", "EXECUTOR_FUNCTIONS", "LANE_MODES", "execute", "run_serial", "run_process_pool", "run_dask"]

LANE_MODES = ("auto", "off")  # --lanes: step many small runs of one kind together (auto), or every run alone (off)


def _work(task):
    """The function that simulates a task: simulate_lanes for a chunk (a list of runs), simulate for a run."""
    return simulate_lanes if isinstance(task, list) else simulate


def _size(task) -> int:
    return len(task) if isinstance(task, list) else 1


def run_serial(tasks: list) -> Iterator[tuple]:
    for task in tasks:
        yield task, _work(task)(task)


def run_process_pool(tasks: list, jobs: int) -> Iterator[tuple]:
    """A local pool of `jobs` processes; pending tasks are cancelled and running ones ended when the
    consumer stops early (or Ctrl-C, which the workers ignore, stops it)."""
    runs = [run for task in tasks for run in (task if isinstance(task, list) else [task])]
    pool = process_pool(jobs, needs_main=defined_in_main(item for run in runs
                                                         for item in (run.system, run.system.system_class)))
    finished = False
    try:
        # the biggest tasks first (chunks of lanes), so that no worker is left with a long one at the end
        ordered = sorted(tasks, key=_size, reverse=True)
        futures = {pool.submit(_work(task), task): task for task in ordered}
        for future in concurrent.futures.as_completed(futures):
            try:
                outcome = future.result()
            except concurrent.futures.process.BrokenProcessPool:  # which run's worker died is not known: it fails them all
                raise WorkerLost("running the sweep") from None
            yield futures[future], outcome
        finished = True
    finally:
        if not finished:  # Ctrl-C (the workers ignore it) or a consumer that stopped: no run in flight is waited for
            stop_workers(pool)
        # wait even when the workers were stopped: the pool's manager thread then ends before the
        # interpreter's exit hook wakes it (Python 3.11 races there and prints a traceback at exit)
        pool.shutdown(wait=True, cancel_futures=True)


def run_dask(tasks: list, jobs: int, scheduler: str | None) -> Iterator[tuple]:
    """Dask: an existing scheduler at `scheduler`, else a local cluster of `jobs` single-threaded workers."""
    try:
        import cloudpickle  # dask's own dependency
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
        shipped = _plugin_sources(tasks)  # a user's own system: its module travels with every task
        by_key = {}
        for task in tasks:
            key = f"simrun-lanes-{task[0].run_id}" if isinstance(task, list) else f"simrun-{task.run_id}"
            # the task as bytes: the scheduler deserialises what it is given, and it has no plug-in's module; the
            # worker unpickles it once the modules shipped with it are importable
            future = client.submit(_work_pickled, shipped, cloudpickle.dumps(task), key=key, pure=False)
            futures.append(future)
            by_key[future.key] = task
        for future in as_completed(futures):
            try:
                outcome = future.result()
            except ImportError as error:  # a worker could not import (or unpickle a task that needs) a module
                raise ConfigError(f"--executor dask: a worker cannot import {error.name or error!s}: install it where "
                                  "the workers run, or make it part of the plug-in's package (simrun ships the module "
                                  "or package that defines a plug-in system, when it is not installed)") from None
            yield by_key[future.key], outcome
    finally:
        client.cancel(futures)
        client.close()
        if cluster is not None:
            cluster.close()


# plug-in modules a worker process wrote from its tasks, by name: each once per process
_SHIPPED: dict[str, Path] = {}


def _work_pickled(shipped: dict[str, tuple[str, bytes]], payload: bytes):
    """A Dask task: the modules shipped with it made importable (written to a folder of this worker process and put
    on its path, unless it has them), then the pickled task simulated (``_work``)."""
    for name, (filename, data) in shipped.items():
        if name in sys.modules or name in _SHIPPED:
            continue
        folder = Path(tempfile.mkdtemp(prefix="simrun-plugin-"))
        (folder / filename).write_bytes(data)
        sys.path.insert(0, str(folder / filename) if filename.endswith(".zip") else str(folder))
        _SHIPPED[name] = folder
    task = pickle.loads(payload)
    return _work(task)(task)


def _plugin_sources(tasks: list) -> dict[str, tuple[str, bytes]]:
    """What a Dask worker needs to import the plug-in systems of ``tasks``: for each top-level module of a system's
    parameter model or system class that is neither simrun's nor installed (under site-packages), its file's name and
    bytes, or its package as a zip (imported from the zip)."""
    runs = [run for task in tasks for run in (task if isinstance(task, list) else [task])]
    names = {cls.__module__.split(".")[0] for run in runs for cls in (type(run.system), run.system.system_class)}
    sources = {}
    for name in sorted(names - {"simrun"}):
        module = sys.modules.get(name)
        source = Path(getattr(module, "__file__", None) or "")
        if not source.is_file() or any(part in ("site-packages", "dist-packages") for part in source.parts):
            continue  # installed (or built in): the workers must have it installed too
        if source.name != "__init__.py":
            sources[name] = (source.name, source.read_bytes())
            continue
        bundle = io.BytesIO()
        with zipfile.ZipFile(bundle, "w") as archive:
            for member in sorted(source.parent.rglob("*.py")):
                archive.write(member, Path(name) / member.relative_to(source.parent))
        sources[name] = (f"{name}.zip", bundle.getvalue())
    return sources


def run_local(tasks: list, jobs: int, scheduler: str | None = None) -> Iterator[tuple]:
    """This machine: serially for one job or one task, else a pool of ``jobs`` processes."""
    if jobs <= 1 or len(tasks) <= 1:
        return run_serial(tasks)
    return run_process_pool(tasks, min(jobs, len(tasks)))


# executor name -> function(tasks, jobs, scheduler) yielding (task, outcome) as tasks finish; the names are
# simrun.execution.workers.EXECUTORS, which the command line offers before it imports this module
EXECUTOR_FUNCTIONS = {
    "process": run_local,
    "dask": run_dask,
}


def execute(runs: list[Run], executor: str = "process", jobs: int = 1, scheduler: str | None = None,
            lanes: str = "auto") -> Iterator[tuple]:
    """Every run on the named executor; yields (task, outcome) as each task finishes: (run, RunResult), or, for the
    runs stepped together as lanes (``lanes`` auto: runner/execution/lanes.py decides which), (list of runs, LaneBatch)."""
    if executor not in EXECUTOR_FUNCTIONS:
        raise ConfigError(f"executor: unknown {executor!r}; valid: " + ", ".join(EXECUTOR_FUNCTIONS))
    if lanes not in LANE_MODES:
        raise ConfigError(f"--lanes: unknown {lanes!r}; valid: " + ", ".join(LANE_MODES))
    chunks, alone = lane_chunks(runs, jobs) if lanes == "auto" else ([], list(runs))
    return EXECUTOR_FUNCTIONS[executor]([*chunks, *alone], jobs, scheduler)
