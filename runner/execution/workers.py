"""The local process pool's workers: where they come from and how many BLAS threads each gets.

Kept free of numpy and the simulation, so that the command line can start the workers' fork server
before it imports them itself: the two imports then run side by side on two cores.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import multiprocessing
import multiprocessing.context
import multiprocessing.forkserver
import multiprocessing.spawn
import os
import pkgutil
import select
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

import threadpoolctl



def _executor_names() -> tuple[str, ...]:
    """The executors: one module each in execution/executors/, named as ``--executor`` names it, found without
    importing any (the command line offers them before it imports the stepping code); the default first."""
    folder = Path(__file__).resolve().parent / "executors"
    names = sorted(module.name for module in pkgutil.iter_modules([str(folder)]) if not module.name.startswith("_"))
    return tuple(sorted(names, key=lambda name: name != "process"))


EXECUTORS = _executor_names()
# what the command line also accepts: `--executor local` (the name before the pipeline API) is the process pool
EXECUTOR_ALIASES = {"local": "process"}
# The warning multiprocessing's resource tracker gives when it unlinks the semaphores of a pool whose process died
# without closing them (kill -9 of simrun): the tracker is there to clean them up, and does; the warning is for
# whoever wrote the pool, not for the user of a killed sweep. The tracker is a new interpreter that takes this
# process's -W options (multiprocessing.util._args_from_interpreter_flags), so the filter is given there.
TRACKER_WARNING_FILTER = "ignore:resource_tracker:UserWarning:multiprocessing.resource_tracker"
# Thread-count variables of the BLAS libraries a run may load (CHOLMOD's OpenBLAS; MKL or OpenMP builds)
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def default_jobs() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def process_pool(jobs: int, needs_main: bool = False) -> concurrent.futures.ProcessPoolExecutor:
    """`jobs` worker processes, each with cores / jobs BLAS threads, each ending with this process. ``needs_main``:
    the tasks hold classes of the caller's main module (a plug-in system defined in the script that runs simrun), so
    the workers import it, as multiprocessing does (the script then needs its `if __name__ == "__main__":`)."""
    threads = max(1, default_jobs() // jobs)
    return concurrent.futures.ProcessPoolExecutor(max_workers=jobs, mp_context=_worker_context(needs_main),
                                                  initializer=_start_worker, initargs=(threads, os.getpid()))


def defined_in_main(objects) -> bool:
    """Whether any of these objects (a run's system parameters, its system class) is defined in ``__main__``."""
    return any(getattr(item if isinstance(item, type) else type(item), "__module__", "") == "__main__"
               for item in objects)


def _start_worker(threads: int, owner: int) -> None:
    # Ctrl-C reaches the whole process group: the main process handles it (it commits what finished and
    # stops the workers); a worker that took it too would die with a traceback of its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # what loading a model mended was said once, when the config was validated: not again by every worker
    from simrun.systems.vertex.errors import ModelWarning

    warnings.simplefilter("ignore", ModelWarning)
    _limit_blas_threads(threads)
    _limit_compiled_threads(threads)
    _exit_with(owner)


def stop_workers(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """End the pool's workers now, in the middle of their runs (they ignore Ctrl-C): the sweep was
    interrupted, and a shutdown would wait for every run in flight to finish."""
    terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def _exit_with(owner: int) -> None:
    """End this worker when process ``owner`` (the simrun that made the pool) ends, however it ends.

    After a kill -9 of simrun nothing else would: a worker's parent is the fork server, which
    outlives simrun while the workers hold its liveness pipe, and a worker blocked on its result
    pipe waits forever. A daemon thread waits on a pidfd of the owner (no polling)."""
    def wait_for_owner() -> None:
        try:
            descriptor = os.pidfd_open(owner)
        except (AttributeError, OSError):  # no pidfd (not Linux >= 5.3): poll once a second
            while _alive(owner):
                time.sleep(1.0)
        else:
            select.select([descriptor], [], [])  # readable once the owner has ended
        os._exit(1)

    threading.Thread(target=wait_for_owner, name="simrun-exit-with-owner", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _limit_blas_threads(threads: int) -> None:
    """Give each worker its share of the cores for BLAS: multithreaded BLAS in two workers on two
    cores would run four threads, each waiting on the others. The libraries already loaded (numpy's)
    are limited now; the ones loaded later (CHOLMOD's, with the first `cholesky` solver) read these
    variables when they load. A user who set any of them chose the thread counts: nothing is changed."""
    if any(variable in os.environ for variable in BLAS_THREAD_VARIABLES):
        return
    threadpoolctl.threadpool_limits(limits=threads, user_api="blas")
    for variable in BLAS_THREAD_VARIABLES:
        os.environ[variable] = str(threads)


def _limit_compiled_threads(threads: int) -> None:
    """The same share of the cores for the compiled element loops (numba's prange, systems/fem/kernels.py): two
    workers of two OpenMP threads each on two cores spin against each other, a small run's Newton iteration hundreds of
    times slower than alone. A user who set NUMBA_NUM_THREADS chose the count."""
    if "NUMBA_NUM_THREADS" in os.environ:
        return
    global _COMPILED_SHARE
    _COMPILED_SHARE = threads
    numba = sys.modules.get("numba")
    if numba is None:  # not imported yet: numba reads the count when it is
        os.environ["NUMBA_NUM_THREADS"] = str(threads)
        return
    # imported already (the fork server's preload): its pool takes the count from here on. The variable is left
    # alone: once the pool runs, every compilation re-reads it, and a value other than the pool's size is an error
    # (a cold cache compiles in the worker: a fresh install's first parallel FEM run failed there)
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


# the threads of the compiled loops this process may use: its share of the cores in a sweep's worker, None in the main
# process (every core numba has)
_COMPILED_SHARE: int | None = None


def compiled_threads(requested: int | None) -> int:
    """Set and return the threads of this run's compiled kernels (numba's prange): ``requested`` (solver.threads)
    within the process's share of the cores, else the share."""
    import numba

    share = min(_COMPILED_SHARE or numba.config.NUMBA_NUM_THREADS, numba.config.NUMBA_NUM_THREADS)
    count = share if requested is None else min(requested, share)
    numba.set_num_threads(count)
    return count


def start_worker_server() -> None:
    """Start the pool's fork server now, in the background: its imports then overlap with the
    caller's own instead of delaying the first run. A no-op where workers are spawned."""
    if _worker_context().get_start_method() == "forkserver":
        multiprocessing.forkserver.ensure_running()


def _worker_context(needs_main: bool = False):
    """Workers forked from a clean server process: a plain fork would inherit the open results file
    (and the HDF5 lock on it); the server imports the simulation once, so each fork starts at once. The workers do
    not run the caller's script again (``_main_left_out``) unless the tasks need what it defines."""
    _quiet_resource_tracker()
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn") if needs_main else _SPAWN_CONTEXT
    context = multiprocessing.get_context("forkserver") if needs_main else _FORKSERVER_CONTEXT
    # what the workers run: the simulation, and the figures (drawn in workers after the runs, and by `simrun plot`)
    context.set_forkserver_preload(["simrun.execution.simulate", "simrun.execution.lanes", "simrun.figures"])
    return context


# A new process of multiprocessing's spawn and forkserver methods first imports the main module of its parent, to
# find what was defined there: it runs the caller's script again, as __mp_main__, so that a script calling simrun.run
# at its top level, without `if __name__ == "__main__":`, would start a pool inside each worker (which Python
# refuses: BrokenProcessPool). simrun's tasks are simrun's classes and the plug-ins' (pickled by module path), never
# the script's, so its workers start without it. (A notebook's main module has no file and was never imported.)
MAIN_KEYS = ("init_main_from_path", "init_main_from_name")


@contextlib.contextmanager
def _main_left_out():
    """multiprocessing's preparation data for a new process, without the parent's main module, while it starts."""
    prepared = multiprocessing.spawn.get_preparation_data

    def without_main(name):
        data = prepared(name)
        for key in MAIN_KEYS:
            data.pop(key, None)
        return data

    multiprocessing.spawn.get_preparation_data = without_main
    try:
        yield
    finally:
        multiprocessing.spawn.get_preparation_data = prepared


class _ForkServerWorker(multiprocessing.context.ForkServerProcess):
    @staticmethod
    def _Popen(process_obj):
        with _main_left_out():
            return multiprocessing.context.ForkServerProcess._Popen(process_obj)


class _SpawnWorker(multiprocessing.context.SpawnProcess):
    @staticmethod
    def _Popen(process_obj):
        with _main_left_out():
            return multiprocessing.context.SpawnProcess._Popen(process_obj)


class _ForkServerContext(multiprocessing.context.ForkServerContext):
    Process = _ForkServerWorker


class _SpawnContext(multiprocessing.context.SpawnContext):
    Process = _SpawnWorker


_FORKSERVER_CONTEXT = _ForkServerContext() if "forkserver" in multiprocessing.get_all_start_methods() else None
_SPAWN_CONTEXT = _SpawnContext()


def _quiet_resource_tracker() -> None:
    """Before the pool's resource tracker starts (with the fork server or the pool): it is to clean up after a
    killed sweep without a warning (TRACKER_WARNING_FILTER). Its other messages are kept."""
    if TRACKER_WARNING_FILTER not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_WARNING_FILTER)


def may_use_local_pool(argv: list[str]) -> bool:
    """Whether a `simrun run` command line may run on the local pool (not -j 1, not --executor dask);
    a guess from the options alone, before the full parser (which needs the heavy imports) runs.
    A wrong yes (--help, a sweep with one pending run, combined short options such as -qj1) costs
    one idle server process and its imports on another core, nothing of the caller's time."""
    guess = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    guess.add_argument("-j", "--jobs", type=int)
    guess.add_argument("--executor")
    try:
        known, _ = guess.parse_known_args(argv)
    except (argparse.ArgumentError, SystemExit):
        return False  # the real parser will report it
    return known.executor in (None, "local", "process") and (known.jobs is None or known.jobs > 1) and default_jobs() > 1
