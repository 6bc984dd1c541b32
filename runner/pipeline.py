"""simrun.run: one experiment from config to results file and figures, callable from Python.

    results = simrun.run("configs/quickstart.yaml", output="/tmp/quickstart")
    results.summary.groupby("integrator")["max_rel_energy_drift"].max()

It does what ``simrun CONFIG.yaml`` does, in this order: load and validate the config (every run of
the sweep before any starts), decide where to write (resume an unchanged config, refuse a changed
one unless forced, lock the folder, admit the size), simulate the runs on the chosen executor while
one writer commits each finished run, then draw the figures from the file. The command line's
``run`` is a thin call of ``run``.
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

from simrun import __version__
from simrun.config import config_hash, expand_runs, load_experiment
from simrun.errors import ConfigError
from simrun.executors import EXECUTOR_FUNCTIONS, execute
from simrun.lock import OutputLock
from simrun.results import RESULTS_NAME, Results, Status, load
from simrun.store import DEFAULT_MAX_SIZE_GB, admit_size, check_writable, open_writer
from simrun.workers import default_jobs


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a sweep: what finished is in the file; the same call again runs the rest."""

    def __init__(self, path: Path, kept: int, total: int):
        super().__init__(f"interrupted: {kept} of {total} runs are in {path}; run the same command again to finish the rest")
        self.path, self.kept, self.total = path, kept, total


def run(config: str | Path | dict, *, output: str | Path | None = None, jobs: int | None = None,
        executor: str = "process", scheduler: str | None = None, force: bool = False, progress: bool = True,
        figures: bool = True, overrides: list[str] | tuple[str, ...] = (),
        max_size_gb: float = DEFAULT_MAX_SIZE_GB) -> Results:
    """Run an experiment and return its results (``simrun.results.Results``).

    config: a path to a YAML file, YAML text, or a dict of the same content.
    output: the folder for results.h5 and figures/ (default: the config's ``output``, else results/<name>).
    jobs: runs at once (default: one per core; 1 = serial). executor: "process" (this machine) or "dask"
    (``scheduler``: an existing cluster's address, else a local one). force: start over even if the
    folder holds other results (default: resume an unchanged config, refuse a changed one).
    progress: a progress bar on a terminal, else a line per run (False: silent). figures: draw them.
    overrides: ``key.path=value`` assignments, as ``--set``. max_size_gb: refuse bigger sweeps.

    Raises ConfigError (one line naming the field) before anything is written, and Interrupted
    (a KeyboardInterrupt) on Ctrl-C after committing what finished. The returned results also carry
    ``figure_files`` (what was drawn) and ``ran`` (status -> count of the runs this call simulated).
    """
    jobs = default_jobs() if jobs is None else jobs
    if jobs < 1:
        raise ConfigError(f"--jobs: must be >= 1, got {jobs}")
    if executor not in EXECUTOR_FUNCTIONS:
        raise ConfigError(f"--executor: unknown {executor!r}; valid: " + ", ".join(EXECUTOR_FUNCTIONS))
    experiment, config_text = load_experiment(config, list(overrides))
    runs = expand_runs(experiment)
    output = Path(output) if output is not None else experiment.output_dir
    check_writable(output)
    admit_size(runs, output, jobs, max_size_gb)
    say = _printer(progress)

    output.mkdir(parents=True, exist_ok=True)
    path = output / RESULTS_NAME
    ran: Counter[str] = Counter()
    with OutputLock(output):
        with open_writer(path, config_text, config_hash(experiment), experiment.name, force) as writer:
            done = writer.completed_runs()
            pending = [item for item in runs if item.run_id not in done]
            where = f"{executor}, {jobs} job{'s' if jobs > 1 else ''}" if len(pending) > 1 else "serial"
            say(f"simrun {__version__}: {experiment.name}: {len(runs)} runs -> {output} ({where})")
            if done:
                say(f"resuming: skipped {len(runs) - len(pending)} runs already in {path}; running {len(pending)}")
            bar = _progress_bar(len(pending), progress)
            try:
                for number, (item, result) in enumerate(execute(pending, executor, jobs, scheduler), 1):
                    writer.write_run(item, result)
                    ran[str(result.status)] += 1
                    if bar is not None:
                        bar.set_postfix_str(item.run_id, refresh=False)
                        bar.update()
                    else:
                        detail = f" ({result.message})" if result.status is not Status.OK and result.message else ""
                        say(f"[{number}/{len(pending)}] {item.run_id}: {result.status}, {result.steps} steps "
                            f"in {result.wall_time:.3g} s{detail}")
            except KeyboardInterrupt:
                raise Interrupted(path, len(writer.completed_runs()), len(runs)) from None
            finally:
                if bar is not None:
                    bar.close()
    results = load(path)
    results.ran = dict(sorted(ran.items()))
    if figures:
        from simrun.figures import draw_figures

        results.figure_files = draw_figures(results, output / "figures")
    return results


def _printer(progress: bool):
    if not progress:
        return lambda _text: None
    return lambda text: print(text, flush=True)


def _progress_bar(total: int, progress: bool):
    """A progress bar on a terminal; None (plain log lines) when not asked for or stderr is not a terminal."""
    if not progress or total == 0 or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="run", dynamic_ncols=True, file=sys.stderr)


__all__ = ["Interrupted", "run"]
