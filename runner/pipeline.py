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

import math
import shutil
import sys
import time
from collections import Counter
from pathlib import Path

from simrun.errors import ConfigError
from simrun.execution.executors import LANE_MODES, ExecutorOptions, checked, execute
from simrun.execution.workers import default_jobs
from simrun.experiment.config import config_file_of, load_experiment
from simrun.experiment.sweep import config_hash, expand_runs, resolved_config
from simrun.format.layout import RESULTS_NAME
from simrun.format.summary import Status
from simrun.results import Results, load
from simrun.results.lock import FIGURES_NAME, REPORT_NAME, OutputLock, check_writable, filling, write_error
from simrun.results.writer import DEFAULT_MAX_SIZE_GB, admit_size, open_writer
from simrun.version import __version__

# The remaining time is estimated once this many runs finished, or this many seconds passed with one finished:
# earlier, the first runs' times (imports, the pool starting) say little about the rest.
ESTIMATE_AFTER_RUNS = 3
ESTIMATE_AFTER_SECONDS = 5.0


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a sweep: what finished is in the file; the same call again runs the rest (or, once every run
    is in, ``simrun plot`` draws the figures: none is left half-drawn)."""

    def __init__(self, path: Path, kept: int, total: int, drawing: bool = False):
        if drawing:
            text = (f"interrupted while drawing the figures: all {total} runs are in {path}; "
                    f"`simrun plot {path}` draws the figures")
        else:
            text = f"interrupted: {kept} of {total} runs are in {path}; run the same command again to finish the rest"
        super().__init__(text)
        self.path, self.kept, self.total = path, kept, total


def run(config: str | Path | dict, *, output: str | Path | None = None, jobs: int | None = None,
        executor: str = "process", scheduler: str | None = None, force: bool = False, progress: bool = True,
        figures: bool = True, svg: bool = False, overrides: list[str] | tuple[str, ...] = (),
        max_size_gb: float = DEFAULT_MAX_SIZE_GB, command_line: str | None = None, lanes: str = "auto") -> Results:
    """Run an experiment and return its results (``simrun.results.Results``).

    config: a path to a YAML file, YAML text, or a dict of the same content.
    output: the folder for results.h5 and figures/ (default: the config's ``output``, else results/<name>).
    jobs: runs at once (default: one per core; 1 = serial). executor: "process" (this machine) or "dask"
    (``scheduler``: an existing cluster's address, else a local one). force: start over even if the
    folder holds other results, removing its old figures and report (default: resume an unchanged
    config, refuse a changed one). progress: a progress bar on a terminal, else a line per run (False:
    silent). figures: draw them (PNG; with svg, SVG too). overrides: ``key.path=value`` assignments, as ``--set``. max_size_gb:
    refuse bigger sweeps. command_line: what started the sweep, stored as provenance (the command line
    passes its own; default: this call, ``simrun.run('configs/x.yaml', ...)``). lanes: "auto" steps many small
    runs of one kind together as lanes of one array (runner/execution/lanes.py; each run's data is what it would be alone),
    "off" every run alone.

    Raises ConfigError (one line naming the field) before anything is written, and Interrupted
    (a KeyboardInterrupt) on Ctrl-C after committing what finished. The returned results also carry
    ``figure_files`` (what was drawn) and ``ran`` (status -> count of the runs this call simulated).
    """
    jobs = default_jobs() if jobs is None else jobs
    options = checked(ExecutorOptions(executor, jobs, scheduler))
    if lanes not in LANE_MODES:
        raise ConfigError(f"--lanes: unknown {lanes!r}; valid: " + ", ".join(LANE_MODES))
    experiment, config_text = load_experiment(config, list(overrides))
    if experiment.fit is not None:  # a calibration's sweep alone would silently leave out what it is for
        where = config if isinstance(config, (str, Path)) and Path(str(config)).suffix else "CONFIG"
        raise ConfigError(f"fit: this config is a calibration (it has a fit block): `simrun fit {where}` fits it "
                          "(simrun.fit from Python); to run its sweep without fitting, --set fit=null")
    runs = expand_runs(experiment)
    output = Path(output) if output is not None else experiment.output_dir
    check_writable(output)
    admit_size(runs, output, jobs, max_size_gb)
    say = _printer(progress)
    if command_line is None:
        command_line = _call_text(config, output=output, jobs=jobs, executor=executor, force=force, overrides=overrides,
                                  lanes=lanes)

    path = output / RESULTS_NAME
    ran: Counter[str] = Counter()
    try:
        output.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise write_error("output", output, error) from None
    with OutputLock(output):
        if force:
            _remove_drawn(output)
        try:
            writer = open_writer(path, config_text, config_hash(experiment), experiment.name, force,
                                 command_line=command_line, config_path=config_file_of(config),
                                 resolved_config=resolved_config(experiment))
        except OSError as error:
            raise write_error("output", path, error) from None
        with writer:
            done = writer.completed_runs()
            stale = done - {item.run_id for item in runs}
            if stale:  # the same config, runs named otherwise: written by an older simrun
                raise ConfigError(f"output: {str(path)!r} holds {len(stale)} runs this config does not name "
                                  f"(e.g. {min(stale)!r}, from an older simrun?); start over with --force")
            pending = [item for item in runs if item.run_id not in done]
            where = f"{executor}, {jobs} job{'s' if jobs > 1 else ''}" if len(pending) > 1 else "serial"
            say(f"simrun {__version__}: {experiment.name}: {len(runs)} runs -> {output} ({where})")
            if done:
                say(f"resuming: skipped {len(runs) - len(pending)} runs already in {path}; running {len(pending)}")
            view = _Progress(len(pending), progress)
            try:
                for task, outcome in execute(pending, options, lanes):
                    chunk = isinstance(task, list)  # runs stepped together as lanes: a LaneBatch
                    try:
                        writer.write_lanes(task, outcome) if chunk else writer.write_run(task, outcome)
                    except OSError as error:
                        raise write_error("output", path, error) from None
                    if chunk:
                        ran.update(str(status) for status in outcome.status)
                        view.finished_chunk(task, outcome)
                    else:
                        ran[str(outcome.status)] += 1
                        view.finished(task, outcome)
            except KeyboardInterrupt:
                raise Interrupted(path, len(writer.completed_runs()), len(runs)) from None
            finally:
                view.close()
    results = load(path)
    results.ran = dict(sorted(ran.items()))
    if figures:
        from simrun.analysis.reference import automatic_reference, reference_errors
        from simrun.figures import draw_figures

        try:
            reference = automatic_reference(results)  # a convergence study without an exact solution: DOP853's
            errors = reference_errors(results, reference, say=say) if reference else None
            with filling(output / FIGURES_NAME, "output") as folder:  # a failed drawing leaves no half figure
                written = draw_figures(results, folder, reference_errors=errors,
                                       jobs=jobs if executor == "process" else 1, svg=svg)
        except KeyboardInterrupt:
            raise Interrupted(path, len(results.runs), len(results.runs), drawing=True) from None
        results.figure_files = [output / FIGURES_NAME / drawn.name for drawn in written]
    return results


def _remove_drawn(output: Path) -> None:
    """--force: the figures and the report drawn from the old results go before the new runs start."""
    try:
        if (output / FIGURES_NAME).is_dir():
            shutil.rmtree(output / FIGURES_NAME)
        (output / REPORT_NAME).unlink(missing_ok=True)
    except OSError as error:
        raise ConfigError(f"output: cannot remove the old figures or report in {str(output)!r} "
                          f"({error.strerror or error}); remove them, or choose another --output") from None


def _call_text(config, **keywords) -> str:
    """This call as text, for the provenance: simrun.run('configs/x.yaml', output='results/x', jobs=2)."""
    source = repr(str(config)) if config_file_of(config) is not None else ("<dict>" if isinstance(config, dict) else "<YAML text>")
    defaults = {"executor": "process", "force": False, "overrides": (), "lanes": "auto"}
    shown = [f"{key}={str(value)!r}" if isinstance(value, Path) else f"{key}={value!r}" for key, value in keywords.items()
             if key not in defaults or defaults[key] != (tuple(value) if key == "overrides" else value)]
    return f"simrun.run({', '.join([source, *shown])})"


def _printer(progress: bool):
    if not progress:
        return lambda _text: None
    return lambda text: print(text, flush=True)


class _Progress:
    """What a sweep shows while it runs: a bar on a terminal, else a line per run; in both, a line for
    each run that did not end ok (with why) and, after the first few runs, the time left. Silent when
    progress is off."""

    def __init__(self, total: int, progress: bool):
        self.total, self.progress, self.done = total, progress, 0
        self.start = time.monotonic()
        self.bar = _progress_bar(total, progress)

    def finished(self, run, result) -> None:
        self.done += 1
        if not self.progress:
            return
        detail = f" ({result.message})" if result.status is not Status.OK and result.message else ""
        left = remaining_text(time.monotonic() - self.start, self.done, self.total)
        if self.bar is None:
            took = f"in {result.wall_time:.3g} s" if math.isfinite(result.wall_time) else "(its wall time not recorded)"
            print(f"[{self.done}/{self.total}] {run.run_id}: {result.status}, {result.steps} steps "
                  f"{took}{detail}{f'; {left}' if left else ''}", flush=True)
            return
        if result.status is not Status.OK:
            self.bar.write(f"{run.run_id}: {result.status}{detail}", file=sys.stderr)
        self.bar.set_postfix_str(", ".join(filter(None, [left, run.run_id])), refresh=False)
        self.bar.update()

    def finished_chunk(self, runs, batch) -> None:
        """A chunk of runs stepped together: one line (or one update of the bar) for all of them, with their statuses
        counted (a map's chunk holds thousands of runs: its runs that did not end ok are in the summary)."""
        self.done += len(runs)
        if not self.progress:
            return
        counts = Counter(str(status) for status in batch.status)
        left = remaining_text(time.monotonic() - self.start, self.done, self.total)
        text = (f"{len(runs)} runs of {runs[0].integrator_label} as lanes: "
                + ", ".join(f"{count} {status}" for status, count in sorted(counts.items()))
                + f" in {float(batch.wall_time.sum()):.3g} s")
        if self.bar is None:
            print(f"[{self.done}/{self.total}] {text}{f'; {left}' if left else ''}", flush=True)
            return
        self.bar.write(text, file=sys.stderr)
        self.bar.set_postfix_str(left or "", refresh=False)
        self.bar.update(len(runs))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def remaining_text(elapsed: float, done: int, total: int) -> str | None:
    """'about 2 min 10 s left' from the mean time per finished run so far (s); None before the first
    ESTIMATE_AFTER_RUNS runs (or ESTIMATE_AFTER_SECONDS s), and at the end."""
    if done == 0 or done >= total or (done < ESTIMATE_AFTER_RUNS and elapsed < ESTIMATE_AFTER_SECONDS):
        return None
    return f"about {_duration_text(elapsed / done * (total - done))} left"


def _duration_text(seconds: float) -> str:
    seconds = max(1, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


def _progress_bar(total: int, progress: bool):
    """A progress bar on a terminal; None (plain log lines) when not asked for or stderr is not a terminal."""
    if not progress or total == 0 or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="run", dynamic_ncols=True, file=sys.stderr,
                bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]")  # the time left: in the postfix


__all__ = ["Interrupted", "remaining_text", "run"]
