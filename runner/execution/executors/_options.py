"""What every executor is given besides its tasks: where they run and how many at once, as one object (checked
against the registry by ``simrun.execution.executors.checked``)."""

from __future__ import annotations

from dataclasses import dataclass



@dataclass(frozen=True)
class ExecutorOptions:
    """The executor's name (a module of this package), the jobs at once, and each executor's own options, travelling
    together from the command line (or ``simrun.run``, ``simrun.fit``) to the executor."""

    name: str = "process"
    jobs: int = 1
    scheduler: str | None = None  # dask: an existing scheduler's address (None: a local cluster of ``jobs`` workers)
