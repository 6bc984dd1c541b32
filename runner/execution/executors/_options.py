"""What every executor is given besides its tasks: where they run and how many at once, as one object."""

from __future__ import annotations

from dataclasses import dataclass

from simrun.errors import ConfigError
from simrun.execution.workers import EXECUTORS


@dataclass(frozen=True)
class ExecutorOptions:
    """The executor's name (a module of this package), the jobs at once, and each executor's own options, travelling
    together from the command line (or ``simrun.run``, ``simrun.fit``) to the executor."""

    name: str = "process"
    jobs: int = 1
    scheduler: str | None = None  # dask: an existing scheduler's address (None: a local cluster of ``jobs`` workers)

    def checked(self) -> "ExecutorOptions":
        """These options, or ConfigError naming the option that is not allowed."""
        if self.jobs < 1:
            raise ConfigError(f"--jobs: must be >= 1, got {self.jobs}")
        if self.name not in EXECUTORS:
            raise ConfigError(f"--executor: unknown {self.name!r}; valid: " + ", ".join(EXECUTORS))
        return self
