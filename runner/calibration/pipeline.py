"""simrun.fit: a calibration from config to results file and figures, callable from Python.

    results = simrun.fit("configs/calibrate_spring.yaml")
    results.fits.table[["label", "dt", "system.damping"]]

In order: load the config (an experiment with a ``fit`` block) and expand its sweep; load the observations and check
the fitted keys (every error one line, before anything is written); decide where to write (resume an unchanged
calibration, refuse other results); fit every integrator x dt of the sweep (and the exact solution, where the system
has one) on the chosen number of processes, committing each fit and the run simulated with its fitted values as
they finish; then the predicted fits (the spring's root-find), the transfer table and the figures.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from simrun.results import fits_writer
from simrun.calibration.engine import FitTask, Model, at_times, fit_one, on_steps, step_run, steps_covering
from simrun.calibration.keys import check_parameters, get_value, key_parts, system_at, system_mapping
from simrun.calibration.observations import load_observations
from simrun.calibration.predicted import predicted_values
from simrun.errors import ConfigError, WorkerLost
from simrun.execution.simulate import simulate
from simrun.execution.executors import ExecutorOptions, checked, execute_tasks
from simrun.execution.workers import default_jobs
from simrun.experiment.config import build_integrator, config_file_of, load_experiment
from simrun.experiment.sweep import config_hash, expand_runs, resolved_config
from simrun.format.layout import RESULTS_NAME
from simrun.results import Results, load
from simrun.results.lock import FIGURES_NAME, OutputLock, check_writable, filling, write_error
from simrun.results.writer import open_writer
from simrun.version import __version__

EXACT_ID = "exact"  # the fit id of the fit with the system's exact solution


def fit(config: str | Path | dict, *, output: str | Path | None = None, jobs: int | None = None, force: bool = False,
        progress: bool = True, figures: bool = True, svg: bool = False, overrides: list[str] | tuple[str, ...] = (),
        command_line: str | None = None, executor: str = "process", scheduler: str | None = None) -> Results:
    """Fit the config's parameters for every integrator x dt of its sweep; returns the results (``results.fits``).

    config: a path, YAML text or a dict, with a ``fit`` block. output: the folder (default: the config's output,
    else results/<name>). jobs: fits at once (default: one per core). executor, scheduler: where they run, as for
    ``simrun.run``. force: start over whatever the folder holds.
    figures: draw them (PNG; with svg, SVG too).
    Raises ConfigError (one line naming the field or file) before anything is written."""
    jobs = default_jobs() if jobs is None else jobs
    options = checked(ExecutorOptions(executor, jobs, scheduler))
    experiment, config_text = load_experiment(config, list(overrides))
    if experiment.fit is None:
        raise ConfigError("fit: this config has no fit block (what was observed, which parameters); add one "
                          "(docs/calibration.md), or run the experiment with `simrun run`")
    runs = expand_runs(experiment)
    config_file = config_file_of(config)  # None for YAML text or a dict
    folders = (config_file.resolve().parent,) if config_file is not None else ()
    tasks, observations = prepare(experiment, runs, folders)
    transfer_steps = _transfer_steps(experiment)
    output = Path(output) if output is not None else experiment.output_dir
    check_writable(output)
    say = (lambda text: print(text, flush=True)) if progress else (lambda text: None)
    path = output / RESULTS_NAME
    try:
        output.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise write_error("output", output, error) from None
    digest = fit_digest(experiment, observations)
    runs_by_id = {run.run_id: run for run in runs}
    with OutputLock(output):
        try:
            writer = open_writer(path, config_text, digest, experiment.name, force,
                                 command_line=command_line or f"simrun.fit({str(config)!r})",
                                 config_path=config_file, resolved_config=resolved_config(experiment))
        except OSError as error:
            raise write_error("output", path, error) from None
        with writer:
            fits_writer.begin(writer.file, experiment.fit, observations, tasks[0].keys)
            done = fits_writer.completed(writer.file)
            pending = [task for task in tasks if task.fit_id not in done]
            stale = [task.fit_id for task in pending if task.fit_id in writer.file["runs"]]
            if stale:  # a fitted run written before its fit was committed (a killed calibration)
                writer.remove_runs(stale)
            say(f"simrun {__version__}: {experiment.name}: {len(tasks)} fits of {', '.join(tasks[0].keys)} -> {output}"
                + (f" (resuming: {len(tasks) - len(pending)} done)" if done else ""))
            for number, (task, outcome, result) in enumerate(_execute(pending, runs_by_id, options), start=1):
                if result is not None:
                    writer.write_run(runs_by_id[task.fit_id].model_copy(update={"system": result[0]}), result[1])
                fits_writer.write_fit(writer.file, task, outcome)
                values = ", ".join(f"{key.removeprefix('system.')} = {value:.6g}" for key, value in zip(task.keys, outcome.values))
                say(f"[{number}/{len(pending)}] {task.label} dt = {task.dt:g}: {outcome.status}, {values} "
                    f"({outcome.simulations} simulations, {outcome.wall_time:.2g} s)")
            stored = load(path).fits
            fits_writer.write_predicted(writer.file, _predicted(experiment, tasks, stored, observations))
            fits_writer.write_transfer(writer.file, _transfer(experiment, tasks, stored, transfer_steps, list(runs_by_id.values()), options))
    results = load(path)
    if figures:
        from simrun.figures import draw_figures

        with filling(output / FIGURES_NAME, "output") as folder:
            written = draw_figures(results, folder, jobs=jobs if options.name == "process" else 1, svg=svg)
        results.figure_files = [output / FIGURES_NAME / drawn.name for drawn in written]
    return results


def fit_digest(experiment, observations) -> str:
    """What a calibration's results depend on: the config (its hash) and the observations' numbers (a changed
    observation file is a changed calibration: refused, or started over with --force, never resumed)."""
    digest = hashlib.sha256(f"{config_hash(experiment)}\nsimrun fit\n".encode())
    for array in (observations.t, observations.positions, observations.velocities):
        if array is not None:
            digest.update(np.ascontiguousarray(array, dtype=float).tobytes())
    return digest.hexdigest()


def prepare(experiment, runs, folders: tuple[Path, ...] = ()) -> tuple[list[FitTask], object]:
    """The fit tasks of the sweep (the exact solution's first, where the system has one) and the observations."""
    fit = experiment.fit
    keys = list(fit.parameters)
    swept = [key for key in keys if key in experiment.sweep]
    if swept:
        raise ConfigError(f"fit.parameters.{swept[0]}: the sweep also sets {swept[0]}; a fitted key is the fit's to "
                          "choose: remove it from the sweep")
    system_params = runs[0].system
    check_parameters(system_params, fit.parameters)
    system = system_params.build()

    def truth_of(params) -> dict[str, float]:
        mapping = system_mapping(params)
        return {key: float(get_value(mapping, key_parts(key))) for key in keys}

    observations = load_observations(fit, experiment, system, truth_of, folders)
    start = np.array([spec.start for spec in fit.parameters.values()], dtype=float)
    lower = np.array([spec.bounds[0] for spec in fit.parameters.values()], dtype=float)
    upper = np.array([spec.bounds[1] for spec in fit.parameters.values()], dtype=float)
    shared = dict(keys=keys, start=start, lower=lower, upper=upper, observations=observations, weights=fit.weights,
                  compare=fit.compare, sensitivities=fit.sensitivities, max_evaluations=fit.max_evaluations, tolerance=fit.tolerance)
    tasks = []
    if system.exact_solution(np.zeros(1)) is not None:
        tasks.append(FitTask(fit_id=EXACT_ID, index=-1, label="exact solution", integrator=None, solver=runs[0].solver,
                             dt=math.nan, duration=experiment.duration, system=system_params, **shared))
    for run in runs:
        if fit.compare == "steps":
            count = int(np.count_nonzero(on_steps(observations.t, run.dt)))
            if count <= len(keys):
                raise ConfigError(f"fit.compare: steps, but only {count} observation times are steps of dt = {run.dt:g} s "
                                  f"(fitting {len(keys)} parameters needs more): observe at multiples of every dt, or "
                                  "use compare: interpolated")
        task = FitTask(fit_id=run.run_id, index=run.index, label=run.integrator_label, integrator=run.integrator,
                       solver=run.solver, dt=run.dt, duration=run.duration, system=run.system, **shared)
        if fit.sensitivities == "exact":
            _check_exact(task)
        tasks.append(task)
    return tasks, observations


def _check_exact(task: FitTask) -> None:
    """``sensitivities: exact``: the method has forward sensitivities on this system and every parameter a derivative
    there (at the start); ConfigError naming what would need finite differences otherwise."""
    from simrun.integrators.sensitivity import exact_refusal

    model = Model(task)
    system = model.system(task.start)
    reason = exact_refusal(system, task.integrator)
    if reason is not None:
        raise ConfigError(f"fit.sensitivities: exact, but {task.label}: {reason}; use auto")
    _, columns = model.sensitivity(system, task.start)
    without = [key for column, key in enumerate(task.keys) if column not in columns]
    if without:
        raise ConfigError(f"fit.sensitivities: exact, but {', '.join(without)} does not enter the system linearly "
                          "(only finite differences follow it); use auto")


def fit_and_simulate(task: FitTask, run):
    """A worker's job: the fit, then the run simulated with its fitted values (None when the fit has none)."""
    outcome = fit_one(task)
    if run is None or not np.all(np.isfinite(outcome.values)):
        return task, outcome, None
    fitted = system_at(run.system, task.keys, outcome.values)
    return task, outcome, (fitted, simulate(run.model_copy(update={"system": fitted})))


def fit_pair(pair: tuple):
    """An executor's task of a calibration: (the fit, its run or None) -> fit_and_simulate's outcome."""
    return fit_and_simulate(*pair)


def _execute(tasks: list[FitTask], runs_by_id: dict, options: ExecutorOptions) -> Iterator[tuple]:
    """(task, outcome, (fitted system, run result) or None) as the fits finish, on the executor ``options`` names."""
    pairs = [(task, runs_by_id.get(task.fit_id)) for task in tasks]
    try:
        for _, outcome in execute_tasks(pairs, fit_pair, list(runs_by_id.values()), options):
            yield outcome
    except WorkerLost:
        raise WorkerLost("fitting") from None


def _predicted(experiment, tasks: list[FitTask], stored, observations) -> dict[str, dict[str, float]]:
    """Each method fit's predicted values (the spring's root-find), from the truth of synthetic data, else from
    the fit with the exact solution (the observed motion's own parameters)."""
    truth = dict(observations.truth)
    reference = stored.reference
    if not truth and reference is not None and reference["status"] == "converged":
        truth = {key: float(reference[key]) for key in stored.parameters}
    predicted = {}
    for task in tasks:
        if task.integrator is None or task.fit_id not in set(stored.table["fit_id"]):
            continue
        # synthetic data made by a method are that method's motion: its eigenvalue is what the fits match
        data_method = observations.truth_method if observations.truth else None
        predicted[task.fit_id] = predicted_values(task.keys, system_mapping(task.system), task.integrator, task.dt, truth,
                                                  data_method)
    return predicted


def _transfer_steps(experiment) -> list[tuple]:
    """The (integrator, dt) pairs of the transfer table (fit.transfer; default: every integrator at the smallest dt)."""
    transfer = experiment.fit.transfer
    try:
        integrators = [build_integrator(item) for item in transfer.integrators] if transfer.integrators else list(experiment.integrators)
    except ValueError as error:
        raise ConfigError(f"fit.transfer.integrators: {error}") from None
    steps = transfer.dt or [min(experiment.sweep["dt"])]
    for dt in steps:
        if dt > experiment.duration:
            raise ConfigError(f"fit.transfer.dt: {dt:g} is longer than duration {experiment.duration:g}")
    return [(integrator, float(dt)) for integrator in integrators for dt in steps]


def transfer_rows(task: FitTask, values: np.ndarray, steps: list[tuple], solver, energy_factor: float) -> list[tuple]:
    """The fit's values simulated with each (integrator, dt): rms(x - x_obs) / rms(x_obs) over the observations.
    A motion that leaves sqrt(energy_factor) times the observed amplitude (the runs' divergence bound, on an
    amplitude instead of an energy) is ``diverged``, with its error."""
    observations = task.observations
    system = system_at(task.system, task.keys, values).build()
    scale = float(np.sqrt(np.mean(np.square(observations.positions))))
    bound = math.sqrt(energy_factor) * float(np.max(np.abs(observations.positions)))
    rows = []
    for integrator, dt in steps:
        count = steps_covering(task.duration, dt, observations.t[-1])
        try:
            trajectory = step_run(system, integrator, solver.build(), dt, count, observations.dofs)
        except Exception as error:  # a transfer that cannot run is a row that says so
            rows.append((task.fit_id, integrator.label, dt, math.nan, f"failed: {type(error).__name__}"))
            continue
        if trajectory.diverged_step:
            rows.append((task.fit_id, integrator.label, dt, math.inf, "diverged"))
            continue
        x, _ = at_times(trajectory, dt, observations.t)
        error = float(np.sqrt(np.mean(np.square(x - observations.positions)))) / scale if scale > 0 else math.nan
        grew = float(np.max(np.abs(x - observations.positions))) > bound
        rows.append((task.fit_id, integrator.label, dt, error, "diverged" if grew else "ok"))
    return rows


def _transfer(experiment, tasks: list[FitTask], stored, steps: list[tuple], runs: list, options: ExecutorOptions) -> list[tuple]:
    table = stored.table.set_index("fit_id")
    factor = experiment.divergence.energy_factor
    work = []
    for task in tasks:
        if task.fit_id not in table.index:
            continue
        values = np.array([table.loc[task.fit_id, key] for key in task.keys], dtype=float)
        if np.all(np.isfinite(values)):
            work.append((task, values))
    tasks_in_order = [(index, task, values, steps, experiment.solver, factor) for index, (task, values) in enumerate(work)]
    try:
        rows_by_index = {task[0]: rows for task, rows in execute_tasks(tasks_in_order, transfer_task, runs, options)}
    except WorkerLost:
        raise WorkerLost("computing the transfer table") from None
    return [row for index in range(len(work)) for row in rows_by_index[index]]


def transfer_task(task: tuple) -> list[tuple]:
    """An executor's task of the transfer table: (its position, then transfer_rows' arguments) -> transfer_rows."""
    return transfer_rows(*task[1:])


__all__ = ["EXACT_ID", "fit", "fit_and_simulate", "prepare", "transfer_rows"]
