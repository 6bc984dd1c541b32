"""What a fit is fitted to: observation times and the observed dofs' positions (and velocities), from a CSV file, a
run of a simrun results file, or made on the fly (``synthetic``). Every problem with them is one line naming the
file or the config path (exit status 2), found before anything is written."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simrun.errors import ConfigError
from simrun.experiment.fit import FitParams, StoredRun, Synthetic

AXES = "xyz"
# an observation this far past the run's end (in units of its smallest step) still counts as inside it
END_TOLERANCE = 1e-9


@dataclass
class Observations:
    """Observation times t (K,) s, positions (K, q) m and velocities (K, q) m/s (None when not observed) of the
    system's dofs ``dofs`` (q,), named ``names``; ``velocity_scale`` (s) weighs velocities against positions
    (rms x / rms v of the observed motion); ``truth``: the fitted keys' values that made synthetic data."""

    t: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None
    dofs: np.ndarray
    names: list[str]
    source: str
    truth: dict[str, float] = field(default_factory=dict)
    first_line: int | None = None  # the file line of the first observation (a CSV file's), for error messages
    truth_method: tuple | None = None  # (integrator, dt) that made synthetic data; None: the exact solution, or measured

    @property
    def velocity_scale(self) -> float:
        if self.velocities is None:
            return 0.0
        spread = float(np.sqrt(np.mean(np.square(self.velocities))))
        return float(np.sqrt(np.mean(np.square(self.positions)))) / spread if spread > 0 else 1.0


def observed_dofs(system, markers: list[int] | None) -> tuple[np.ndarray, list[str]]:
    """The dofs of the marked vertices (every dof without markers) and their names (x12, y12, z12; x for one dof)."""
    dim = max(int(getattr(system, "dim", 1)), 1)
    vertices = system.dof_count // dim
    if markers is None:
        markers = list(range(vertices))
    for marker in markers:
        if marker >= vertices:
            raise ConfigError(f"fit.markers: vertex {marker} does not exist (the system has {vertices} "
                              f"{'vertex' if vertices == 1 else 'vertices'}: 0 to {vertices - 1})")
    dofs = np.array([dim * marker + axis for marker in markers for axis in range(dim)], dtype=np.intp)
    if system.dof_count == 1:
        return dofs, ["x"]
    names = [f"{AXES[axis]}{marker}" for marker in markers for axis in range(dim)]
    return dofs, names


def load_observations(fit: FitParams, experiment, system, keys_truth, folders: tuple[Path, ...] = ()) -> Observations:
    """The observations the fit block names, for ``system`` (built from the experiment); ``keys_truth``: a function
    (system params) -> the fitted keys' values, for synthetic data."""
    dofs, names = observed_dofs(system, fit.markers)
    with_velocity = fit.weights == "position_and_velocity"
    source = fit.observed
    if isinstance(source, dict):  # {synthetic: {...}}
        observations = _synthetic(source["synthetic"], experiment, dofs, names, keys_truth)
    elif isinstance(source, StoredRun):
        observations = _stored_run(source, system, dofs, names, with_velocity, folders)
    else:
        observations = _csv(source, dofs, names, with_velocity, folders)
    _check_times(observations, experiment.duration, min(experiment.sweep["dt"]))
    if with_velocity and observations.velocities is None:
        raise ConfigError(f"fit.weights: position_and_velocity, but {observations.source} holds no velocities")
    if not with_velocity:
        observations.velocities = None
    return observations


def _find(name: str, folders: tuple[Path, ...]) -> Path:
    path = Path(name).expanduser()
    candidates = [path] if path.is_absolute() else [folder / path for folder in folders] + [Path.cwd() / path]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise ConfigError(f"fit.observed: file {name!r} does not exist (looked in "
                      f"{', '.join(dict.fromkeys(str(candidate.parent) for candidate in candidates))})")


def _csv(name: str, dofs: np.ndarray, names: list[str], with_velocity: bool, folders) -> Observations:
    """t in the first column, then one column per observed dof (then, with velocities, one per dof again)."""
    import pandas

    path = _find(name, folders)
    where = f"fit.observed: {str(name)!r}"
    try:
        table = pandas.read_csv(path, skipinitialspace=True, comment="#")
    except (pandas.errors.ParserError, pandas.errors.EmptyDataError, UnicodeDecodeError, OSError) as error:
        raise ConfigError(f"{where} cannot be read as CSV: {str(error).splitlines()[0] if str(error) else type(error).__name__}") from None
    columns = list(table.columns)
    expected = dofs.size * (2 if with_velocity else 1)
    if len(columns) - 1 not in (dofs.size, 2 * dofs.size) or (with_velocity and len(columns) - 1 != expected):
        what = f"{dofs.size} positions" + (f" and {dofs.size} velocities" if with_velocity else "")
        raise ConfigError(f"{where} has {len(columns) - 1} columns after t, but the markers observe {dofs.size} "
                          f"dofs ({', '.join(names[:6])}{', ...' if len(names) > 6 else ''}): expected {what}")
    if table.shape[0] == 0:
        raise ConfigError(f"{where} has a header but no rows")
    numbers = table.apply(pandas.to_numeric, errors="coerce")
    bad = numbers.isna().to_numpy()
    if bad.any():
        row, column = map(int, np.argwhere(bad)[0])
        value = table.iat[row, column]
        what = "is empty or NaN" if numbers.isna().iat[row, column] and (pandas.isna(value) or str(value).strip().lower() == "nan") \
            else f"holds {str(value)!r}, not a number"
        raise ConfigError(f"{where} line {row + 2}, column {columns[column]!r} {what}")
    values = numbers.to_numpy(dtype=float)
    if not np.all(np.isfinite(values)):
        row, column = map(int, np.argwhere(~np.isfinite(values))[0])
        raise ConfigError(f"{where} line {row + 2}, column {columns[column]!r} is not finite")
    velocities = values[:, 1 + dofs.size:] if values.shape[1] == 1 + 2 * dofs.size else None
    return Observations(values[:, 0].copy(), values[:, 1:1 + dofs.size].copy(), velocities, dofs,
                        [str(column) for column in columns[1:1 + dofs.size]], f"{name} ({path})", first_line=2)


def _stored_run(source: StoredRun, system, dofs: np.ndarray, names: list[str], with_velocity: bool, folders) -> Observations:
    from simrun.results import load

    path = _find(source.results, folders)
    try:
        results = load(path)
    except ConfigError as error:
        raise ConfigError(f"fit.observed.results: {str(error).split(': ', 1)[-1]}") from None
    if source.run is None:
        if len(results.runs) != 1:
            raise ConfigError(f"fit.observed.run: {source.results!r} holds {len(results.runs)} runs; name one "
                              f"(e.g. {next(iter(results.runs), '?')!r})")
        run = next(iter(results.runs.values()))
    elif source.run not in results.runs:
        raise ConfigError(f"fit.observed.run: {source.results!r} has no run {source.run!r}")
    else:
        run = results.runs[source.run]
    if run.dof_count != system.dof_count:
        raise ConfigError(f"fit.observed.run: {run.run_id!r} has {run.dof_count} dofs; this experiment's system has {system.dof_count}")
    with results.opened():
        if "positions" in run:
            t, positions = run["t"], run["positions"][:, dofs]
            velocities = run["velocities"][:, dofs] if "velocities" in run else None
        elif "frames" in run:
            frames = run["frames"]
            t, positions, velocities = run["frame_t"], frames.reshape(frames.shape[0], -1)[:, dofs], None
        else:
            raise ConfigError(f"fit.observed.run: {run.run_id!r} recorded no positions")
    return Observations(np.asarray(t, dtype=float), np.asarray(positions, dtype=float),
                        None if velocities is None else np.asarray(velocities, dtype=float), dofs, names,
                        f"run {run.run_id} of {source.results}")


def _synthetic(spec: Synthetic, experiment, dofs: np.ndarray, names: list[str], keys_truth) -> Observations:
    from simrun.calibration.engine import step_run
    from simrun.calibration.keys import system_mapping
    from simrun.experiment.config import set_path, validate_system

    mapping = system_mapping(experiment.system)
    for key, value in spec.system.items():  # dotted keys reach into mappings: stiffness.stretch
        set_path(mapping, key.removeprefix("system.").split("."), value, f"fit.observed.synthetic.system.{key}")
    try:
        truth = validate_system(mapping)
    except ConfigError as error:
        raise ConfigError("fit.observed.synthetic." + str(error)) from None
    system = truth.build()
    duration = spec.duration or experiment.duration
    steps = max(1, math.floor(duration / spec.dt + 1e-9))
    if spec.integrator == "exact":
        t = spec.dt * np.arange(steps + 1)
        exact = system.exact_solution(t)
        if exact is None:
            raise ConfigError(f"fit.observed.synthetic.integrator: exact, but {truth.type} has no exact solution; "
                              "name an integrator instead (e.g. rk4 or implicit_midpoint, at a small dt)")
        positions, velocities = exact[0][:, dofs], exact[1][:, dofs]
        label = "the exact solution"
    else:
        integrator = _integrator(spec.integrator)
        trajectory = step_run(system, integrator, experiment.solver.build(), spec.dt, steps, dofs)
        if trajectory.diverged_step:
            raise ConfigError(f"fit.observed.synthetic: {integrator.label} at dt = {spec.dt:g} s diverged at step "
                              f"{trajectory.diverged_step}; choose a smaller dt or another integrator")
        t, positions, velocities = spec.dt * np.arange(steps + 1), trajectory.x, trajectory.v
        label = f"{integrator.label} at dt = {spec.dt:g} s"
    keep = slice(None, None, spec.every)
    t, positions, velocities = t[keep], positions[keep].copy(), velocities[keep].copy()
    if spec.noise > 0:
        generator = np.random.default_rng(spec.seed)
        scale = Observations(t, positions, velocities, dofs, names, "").velocity_scale
        positions += spec.noise * generator.standard_normal(positions.shape)
        velocities += (spec.noise / scale if scale > 0 else spec.noise) * generator.standard_normal(velocities.shape)
    overrides = ", ".join(f"{key} = {value}" for key, value in spec.system.items())
    source = f"synthetic: {label}" + (f", {overrides}" if overrides else "") + (f", noise {spec.noise:g} m (seed {spec.seed})" if spec.noise else "")
    method = None if spec.integrator == "exact" else (integrator, spec.dt)
    return Observations(t, positions, velocities, dofs, names, source, keys_truth(truth), truth_method=method)


def _integrator(value):
    from simrun.experiment.config import build_integrator

    try:
        return build_integrator(value)
    except ValueError as error:
        raise ConfigError(f"fit.observed.synthetic.integrator: {error}") from None


def _check_times(observations: Observations, duration: float, dt: float) -> None:
    t = observations.t
    where = f"fit.observed: {observations.source.split(' (')[0]}"
    if t.size < 2:
        raise ConfigError(f"{where}: {t.size} observation time; a fit needs at least two")
    steps = np.diff(t)
    if np.any(steps <= 0):
        number = int(np.flatnonzero(steps <= 0)[0]) + 1  # the observation that does not follow on
        place = (f"line {number + observations.first_line}" if observations.first_line is not None
                 else f"observation {number + 1}")
        raise ConfigError(f"{where}: times must increase, but t = {t[number]:g} s ({place}) follows "
                          f"t = {t[number - 1]:g} s")
    if t[0] < 0 or t[-1] > duration + END_TOLERANCE * max(dt, 1.0):
        outside = t[0] if t[0] < 0 else t[-1]
        raise ConfigError(f"{where}: t = {outside:g} s lies outside the run (0 to duration {duration:g} s)")


__all__ = ["Observations", "load_observations", "observed_dofs"]
