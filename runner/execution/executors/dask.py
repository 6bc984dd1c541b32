"""The Dask executor: an existing scheduler's workers, or a local cluster of single-threaded ones. A plug-in system's
or integrator's module, where it is not installed, travels with every task."""

from __future__ import annotations

import io
import logging
import pickle
import sys
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

from simrun.errors import ConfigError
from simrun.experiment.config import Run

from ._options import ExecutorOptions


def _task_key(task) -> str | None:
    """The name a sweep's task has on the Dask dashboard (None: Dask names it)."""
    if isinstance(task, list):
        return f"simrun-lanes-{task[0].run_id}"
    return f"simrun-{task.run_id}" if isinstance(task, Run) else None


def run(tasks: list, work, runs: list[Run], options: ExecutorOptions) -> Iterator[tuple]:
    """Dask: an existing scheduler at ``options.scheduler``, else a local cluster of ``options.jobs``
    single-threaded workers."""
    try:
        import cloudpickle  # dask's own dependency
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ConfigError("--executor dask: Dask is not installed; install it with  pip install 'simrun[dask]'  "
                          "(or: pip install 'dask[distributed]')") from None
    cluster, scheduler = None, options.scheduler
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            cluster = LocalCluster(n_workers=options.jobs, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=logging.ERROR)
            client = Client(cluster)
    except OSError as error:
        raise ConfigError(f"--scheduler: cannot reach the Dask scheduler at {scheduler!r}: {error}") from None
    futures = []
    try:
        shipped = _plugin_sources(runs)  # a user's own system or method: its module travels with every task
        by_future = {}
        for task in tasks:
            # the task as bytes: the scheduler deserialises what it is given, and it has no plug-in's module; the
            # worker unpickles it once the modules shipped with it are importable
            key = _task_key(task)
            future = client.submit(_work_pickled, shipped, work, cloudpickle.dumps(task), pure=False,
                                   **({"key": key} if key is not None else {}))
            futures.append(future)
            by_future[future.key] = task
        for future in as_completed(futures):
            try:
                outcome = future.result()
            except ImportError as error:  # a worker could not import (or unpickle a task that needs) a module
                raise ConfigError(f"--executor dask: a worker cannot import {error.name or error!s}: install it where "
                                  "the workers run, or make it part of the plug-in's package (simrun ships the module "
                                  "or package that defines a plug-in system or integrator, when it is not installed)"
                                  ) from None
            yield by_future[future.key], outcome
    finally:
        client.cancel(futures)
        client.close()
        if cluster is not None:
            cluster.close()


# plug-in modules a worker process wrote from its tasks, by name: each once per process
_SHIPPED: dict[str, Path] = {}


def _work_pickled(shipped: dict[str, tuple[str, bytes]], work, payload: bytes):
    """A Dask task: the modules shipped with it made importable (written to a folder of this worker process and put
    on its path, unless it has them), then ``work`` done on the pickled task."""
    for name, (filename, data) in shipped.items():
        if name in sys.modules or name in _SHIPPED:
            continue
        folder = Path(tempfile.mkdtemp(prefix="simrun-plugin-"))
        (folder / filename).write_bytes(data)
        sys.path.insert(0, str(folder / filename) if filename.endswith(".zip") else str(folder))
        _SHIPPED[name] = folder
    task = pickle.loads(payload)
    return work(task)


def _plugin_sources(runs: list[Run]) -> dict[str, tuple[str, bytes]]:
    """What a Dask worker needs to import the plug-ins of ``runs``: for each top-level module of a system's parameter
    model or system class, or of an integrator's class, that is neither simrun's nor installed (under site-packages),
    its file's name and bytes, or its package as a zip (imported from the zip)."""
    names = {cls.__module__.split(".")[0] for run in runs
             for cls in (type(run.system), run.system.system_class, type(run.integrator))}
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
