"""Where tasks are done: one module per executor in this package (``process``: serially or on a local process pool;
``dask``: a Dask cluster), each a function ``run(tasks, work, runs, options)`` that yields ``(task, work(task))`` as
tasks finish. ``runs`` are the runs the tasks hold (the workers must import their plug-in systems), ``options`` an
ExecutorOptions. A new executor is a new module here: the command line and EXECUTOR_FUNCTIONS find it by its name.

A sweep's task is a run (``simulate``) or a chunk of runs stepped together as lanes (``simulate_lanes``,
runner/execution/lanes.py): a RunResult for a run, a LaneBatch for a chunk; a calibration's are its fits. The caller
(one writer in the main process) commits each outcome at once. Runs are independent, so neither the order of
completion nor the chunk a run was stepped in changes any run's data.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator

from simrun.errors import ConfigError
from simrun.execution.lanes import lane_chunks, simulate_lanes
from simrun.execution.simulate import simulate
from simrun.execution.workers import EXECUTORS
from simrun.experiment.config import Run

from ._options import ExecutorOptions

__all__ = ["EXECUTORS", "EXECUTOR_FUNCTIONS", "LANE_MODES", "ExecutorOptions", "checked", "execute", "execute_tasks",
           "simulate_task"]

LANE_MODES = ("auto", "off")  # --lanes: step many small runs of one kind together (auto), or every run alone (off)


def simulate_task(task):
    """A sweep's task: a chunk of runs (a list) stepped as lanes into a LaneBatch, or one run into its RunResult."""
    return simulate_lanes(task) if isinstance(task, list) else simulate(task)


# executor name -> its module's run(tasks, work, runs, options); the names are simrun.execution.workers.EXECUTORS,
# which the command line offers before it imports this package
EXECUTOR_FUNCTIONS = {name: importlib.import_module(f"{__name__}.{name}").run for name in EXECUTORS}


def checked(options: ExecutorOptions) -> ExecutorOptions:
    """``options``, or ConfigError naming the option that is not allowed (before anything runs or is written)."""
    if options.jobs < 1:
        raise ConfigError(f"--jobs: must be >= 1, got {options.jobs}")
    if options.name not in EXECUTOR_FUNCTIONS:
        raise ConfigError(f"--executor: unknown {options.name!r}; valid: " + ", ".join(EXECUTOR_FUNCTIONS))
    return options


def execute_tasks(tasks: list, work, runs: list[Run], options: ExecutorOptions) -> Iterator[tuple]:
    """``work`` (a module-level function, so that it pickles) done on every task by the executor ``options`` names;
    yields (task, outcome) as each task finishes. No task: no executor is started (a Dask cluster costs seconds)."""
    if not tasks:
        return iter(())
    return EXECUTOR_FUNCTIONS[checked(options).name](tasks, work, runs, options)


def execute(runs: list[Run], options: ExecutorOptions = ExecutorOptions(), lanes: str = "auto") -> Iterator[tuple]:
    """Every run of a sweep; yields (task, outcome) as each task finishes: (run, RunResult), or, for the runs stepped
    together as lanes (``lanes`` auto: runner/execution/lanes.py decides which), (list of runs, LaneBatch)."""
    if lanes not in LANE_MODES:
        raise ConfigError(f"--lanes: unknown {lanes!r}; valid: " + ", ".join(LANE_MODES))
    chunks, alone = lane_chunks(runs, options.jobs) if lanes == "auto" else ([], list(runs))
    return execute_tasks([*chunks, *alone], simulate_task, runs, options)
