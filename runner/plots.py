"""The figures of an experiment, drawn from its results file alone (PNG and SVG).

Data flows one way: this module reads the HDF5 file written by ``simrun.store`` and nothing else,
so the figures can be redrawn from results without re-running (``simrun plot results.h5``).

Figures (each skipped when the file holds nothing it could show):
- ``energy_over_time``: E/E0 against t, one panel per dt, one line per integrator;
- ``energy_drift_vs_dt``: max |E - E0|/|E0| against dt (log-log), one line per integrator;
- ``stability_map``: integrators x dt, coloured by the log10 of the largest energy growth;
- ``newton_iterations_vs_dt``: mean Newton iterations per step against dt (implicit methods);
- ``orbits``: x-y trajectories of circular motion against the exact circle;
- ``artificial_damping``: d_method / w against h w, predicted (from the integrators, through
  ``simrun.analysis``) as lines, measured (the energy decay of each undamped linear run) as markers;
- ``spectral_radius_and_period``: rho(h w) and the relative period error, predicted, with the
  periods measured from the runs' zero crossings;
- ``convergence``: error at the end time against dt (log-log), the fitted slope of each method in the legend;
- ``work_precision``: that error against wall time;
- ``wall_time_per_step_vs_dt``: the cost of a step against dt;
- ``energy_budget``: kinetic + potential terms + the work of the physical damping, stacked over
  time; what is left of the initial energy is the integrator's own (numerical) loss or gain.

The predicted curves are computed from the integrators named in the file (``simrun.analysis``
probes their amplification matrices), never from the runs; everything else comes from the file.

Runs that share every swept parameter other than dt and the integrator's own form a *group*; with
several groups, each figure gets a panel (or a row of panels) per group, titled by its parameters.
A consistent colour per integrator label (sorted labels -> tab10/tab20) runs through all figures.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")  # files only: no display, and safe in worker processes

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402
from matplotlib.colors import TwoSlopeNorm  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402
from matplotlib.transforms import blended_transform_factory  # noqa: E402

from simrun import analysis  # noqa: E402  (predicted curves: from the integrators, not from runs)

FORMATS = ("png", "svg")
PNG_DPI = 150
# One panel of the small multiples (in); large enough for 8-pt tick labels to stay readable.
PANEL_SIZE = (3.6, 2.7)
# More dt panels than this become unreadable; show this many, spread over the range.
MAX_DT_PANELS = 12
# With several groups each group is a row; a row wider than this no longer fits a page.
MAX_DT_PANELS_PER_GROUP = 6
# Likewise at most this many groups (rows / panels) per figure.
MAX_GROUPS = 8
PANEL_COLUMNS = 4
# One panel of the figures against dt (in): one line per integrator needs more room than a small multiple.
SUMMARY_PANEL_SIZE = (5.0, 3.6)
# Signed energies (bound orbits, E0 < 0) reaching this many times |E0| get a symlog axis.
SYMLOG_RANGE = 10.0
# A y range wider than this factor is drawn on a log axis (forward Euler grows by decades).
LOG_AXIS_RANGE = 100.0
# Exact conservation (zero drift) cannot sit on a log axis: drawn at double-precision round-off.
DRIFT_FLOOR = 1e-16
# Diverged runs are off the drift scale: drawn at this fraction of the axes height, above
# the data, which a y range padded by this factor leaves room for.
TOP_EDGE, TOP_PADDING = 0.95, 30.0
# Smallest half-range (decades) of the stability map's colour scale, so that round-off-sized
# changes stay pale instead of saturating the map.
MIN_GROWTH_DECADES = 1.0
# The stability map's key (two lines of 7.5-pt text) needs this width (in).
MAP_MIN_WIDTH = 6.0
# More stability-map columns than this get slanted dt labels.
MAP_COLUMNS_UPRIGHT = 8
# Room for a legend beside the panels (in): the longest entry is about 30 characters at 8 pt.
FIGURE_LEGEND_WIDTH = 2.2
# An orbit panel (in): square, since x and y share a scale.
ORBIT_PANEL_SIZE = (3.3, 3.0)
# A diverged orbit is clipped to this many radii around the centre.
ORBIT_BOX_RADII = 3.0

DIVERGED, FAILED, NOT_CONVERGED = "diverged", "failed", "not_converged"
# A marker per integrator label in the figures against dt, so that coinciding lines stay apart
# (and colour is not the only cue); "X" is kept for failed runs.
LABEL_MARKERS = "osD^vP<>hpd*"
# Each later label's marker is drawn this much smaller (pt), so coinciding points show as rings.
MARKER_SHRINK = 0.5
LEGEND_MARKER_SIZE = 6.0


# -- reading the file ------------------------------------------------------------------------------
@dataclass(eq=False)
class RunData:
    """One run as the figures need it: its description (attributes) and its recorded series."""

    run_id: str
    index: int
    label: str  # integrator name with its non-default parameters: tells lines apart
    dt: float  # s
    status: str
    explicit: bool
    system: str
    system_params: dict
    group: str  # JSON of the swept parameters other than dt and integrator.*
    t: np.ndarray  # (samples,) s
    energy: np.ndarray  # (samples,) J
    energy_ref: float  # J: |E0|, or |KE0| + |PE0| when E0 = 0 (1 when both vanish)
    newton_iterations: np.ndarray  # (steps,)
    xy: np.ndarray | None  # (samples, 2) m, the orbit plane; circular motion only
    integrator: str = ""  # registered name
    integrator_params: dict = field(default_factory=dict)  # the method's parameters (integrator.* of params)
    order: int = 0  # declared order (attribute `order`)
    steps: int = 0
    wall_time: float = math.nan  # s, the stepping loop
    final_error: float = math.nan  # m, against the exact solution (or a reference, see draw_figures)
    coordinate: np.ndarray | None = None  # (samples,) m, the first coordinate; linear test systems only
    length_scale: float = 1.0  # m, max |x0| (1 when x0 = 0): the scale of position errors
    frequency: float | None = None  # w (rad/s) when the run is the undamped test equation, else None

    @property
    def x(self) -> float:
        """h w of the run (NaN when it is not the test equation)."""
        return self.dt * self.frequency if self.frequency else math.nan

    @functools.cached_property
    def method(self):
        """The integrator object (from its name and parameters), or None if this simrun does not know it."""
        try:
            return analysis.integrator_from_params(self.integrator, self.integrator_params)
        except Exception:  # a file written by another version: no prediction, the rest still draws
            return None

    @functools.cached_property
    def damping_fit(self) -> "analysis.DampingFit | None":
        """The measured artificial damping (energy decay) of an undamped linear run that did not stop early."""
        if self.frequency is None or self.status in (DIVERGED, FAILED) or not self.has_change:
            return None
        return analysis.measure_damping(self.t, self.energy, self.coordinate, self.frequency)

    @functools.cached_property
    def period_error(self) -> float:
        """T / T_exact - 1 measured from the zero crossings of the first coordinate (NaN where not measurable)."""
        if self.frequency is None or self.coordinate is None or self.status in (DIVERGED, FAILED):
            return math.nan
        return analysis.measure_period_error(self.t, self.coordinate, self.frequency)

    @property
    def has_series(self) -> bool:
        """At least one finite energy sample: something to draw."""
        return int(np.count_nonzero(np.isfinite(self.energy))) >= 1

    @property
    def has_change(self) -> bool:
        """At least two finite energy samples: a drift or growth can be measured."""
        return int(np.count_nonzero(np.isfinite(self.energy))) >= 2

    @property
    def energy_ratio(self) -> np.ndarray:
        """E / E_ref: E/E0 where E0 > 0; starts at -1 where E0 < 0 (a bound orbit)."""
        return self.energy / self.energy_ref

    def status_note(self) -> str:
        return {DIVERGED: " (diverged)", FAILED: " (failed)", NOT_CONVERGED: " (solver not converged)"}.get(self.status, "")


@dataclass
class Results:
    name: str
    runs: list[RunData]
    groups: list[tuple[str, list[RunData]]]  # (title, runs) in config order
    labels: list[str]  # integrator labels in config order
    colours: dict[str, tuple]
    markers: dict[str, str]
    dt_names: dict[float, str]  # dt (s) -> the shortest text that tells it from the other dts
    path: Path | None = None  # the results file (series that only one figure needs are read from it on demand)


def load_results(path: str | Path) -> Results:
    """Read every run of a results file (h5py only: no config, no simulation)."""
    path = Path(path)
    with h5py.File(path, "r") as file:
        name = _text(file.attrs.get("name", path.parent.name))
        runs = [_read_run(run_id, group) for run_id, group in file["runs"].items()] if "runs" in file else []
    runs.sort(key=lambda run: run.index)
    grouped: dict[str, list[RunData]] = {}
    for run in runs:
        grouped.setdefault(run.group, []).append(run)
    groups = [(_group_title(key), members) for key, members in grouped.items()]
    labels = list(dict.fromkeys(run.label for run in runs))
    markers = {label: LABEL_MARKERS[number % len(LABEL_MARKERS)] for number, label in enumerate(labels)}
    return Results(name, runs, groups, labels, label_colours(labels), markers, _dt_names(sorted({run.dt for run in runs})), path)


def _read_run(run_id: str, group: h5py.Group) -> RunData:
    attrs = group.attrs

    def series(key: str) -> np.ndarray:
        return np.asarray(group[key][()], dtype=float) if key in group else np.empty(0)

    params = json.loads(_text(attrs.get("params", "{}")))
    swept = {key: value for key, value in params.items() if key != "dt" and not key.startswith("integrator.")}
    energy = series("energy")
    newton = series("newton_iterations")
    system = _text(attrs.get("system", ""))
    system_params = json.loads(_text(attrs.get("system_params", "{}")))
    frequency = analysis.test_frequency(system, system_params)
    xy = coordinate = None
    length_scale = 1.0
    if "positions" in group:
        positions = np.asarray(group["positions"][()], dtype=float)
        if positions.ndim == 2 and positions.shape[0]:
            start = np.abs(positions[0][np.isfinite(positions[0])])
            length_scale = float(start.max()) if start.size and start.max() > 0 else 1.0
            if system == "circular_motion":
                xy = positions[:, :2] if positions.shape[1] >= 2 else np.empty((0, 2))
            if frequency is not None:
                coordinate = positions[:, 0]
        elif system == "circular_motion":
            xy = np.empty((0, 2))
    elif "frames" in group and group["frames"].shape[0]:
        start = np.abs(np.asarray(group["frames"][0], dtype=float))
        length_scale = float(start.max()) if start.size and start.max() > 0 else 1.0
    return RunData(
        run_id=run_id,
        index=int(attrs.get("index", 0)),
        label=_text(attrs.get("integrator_label", attrs.get("integrator", run_id))),
        dt=float(attrs.get("dt", params.get("dt", math.nan))),
        status=_text(attrs.get("status", "ok")),
        explicit=bool(attrs.get("explicit", False)),
        system=system,
        system_params=system_params,
        group=json.dumps(swept, sort_keys=True),
        t=series("t"),
        energy=energy,
        energy_ref=_energy_ref(energy, series("kinetic_energy"), series("potential_energy")),
        newton_iterations=newton,
        xy=xy,
        integrator=_text(attrs.get("integrator", "")),
        integrator_params={key.removeprefix("integrator."): value for key, value in params.items() if key.startswith("integrator.")},
        order=int(attrs.get("order", 0)),
        steps=int(attrs.get("steps", newton.size)),
        wall_time=float(attrs.get("wall_time", math.nan)),
        final_error=float(attrs.get("final_error", math.nan)),
        coordinate=coordinate,
        length_scale=length_scale,
        frequency=frequency,
    )


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _energy_ref(energy: np.ndarray, kinetic: np.ndarray, potential: np.ndarray) -> float:
    """The initial energy scale the store uses for drift: |E0|, else |KE0| + |PE0|, else 1 J."""
    if energy.size and np.isfinite(energy[0]) and energy[0] != 0:
        return abs(float(energy[0]))
    if kinetic.size and potential.size:
        scale = abs(float(kinetic[0])) + abs(float(potential[0]))
        if np.isfinite(scale) and scale > 0:
            return scale
    return 1.0


def _group_title(key: str) -> str:
    swept = json.loads(key)
    return ", ".join(f"{name} = {_format_value(value)}" for name, value in swept.items())


def _format_value(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _dt_names(dts: list[float]) -> dict[float, str]:
    """Three significant digits (logspace sweeps), more only where two time steps would read alike."""
    for digits in range(3, 18):
        names = [f"{dt:.{digits}g}" for dt in dts]
        if len(set(names)) == len(names):
            break
    return dict(zip(dts, names))


def label_colours(labels: list[str]) -> dict[str, tuple]:
    """A stable colour per integrator label: sorted labels -> tab10 (or tab20 beyond ten labels)."""
    ordered = sorted(labels)
    palette = plt.get_cmap("tab10" if len(ordered) <= 10 else "tab20")
    return {label: palette(number % palette.N) for number, label in enumerate(ordered)}


# -- the public entry point ------------------------------------------------------------------------
def draw_figures(results_path: str | Path, out_dir: str | Path, reference_errors: dict[str, float] | None = None) -> list[Path]:
    """Draw every figure the results file supports into out_dir as PNG and SVG; returns the paths written.

    reference_errors (run_id -> error at the end time, m) stand in for the stored ``final_error``
    where it is NaN (cloth: no exact solution); ``simrun.report.reference_errors`` computes them
    from a reference solution on request. Without them such runs have no convergence figure.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = load_results(results_path)
    written: list[Path] = []
    for name, figure in _render(results, reference_errors):
        try:
            written += save_figure(figure, out_dir / name)
        finally:
            plt.close(figure)
    if any(run.system == "cloth" for run in results.runs):
        from simrun.cloth_figures import draw_cloth_snapshots  # reads the file only, like this module

        with h5py.File(results_path, "r") as file:
            written += draw_cloth_snapshots(file, out_dir)
    return written


def save_figure(figure, stem: Path) -> list[Path]:
    """Write stem.png and stem.svg; the layout is computed once, for the first format (it is the costly part)."""
    written = []
    for extension in FORMATS:
        target = stem.with_name(f"{stem.name}.{extension}")  # not with_suffix: names may contain dots
        # no creation date in the metadata, so redrawing the same file gives the same SVG
        metadata = {"Date": None} if extension == "svg" else None
        figure.savefig(target, dpi=PNG_DPI, metadata=metadata)
        written.append(target)
        if figure.get_layout_engine() is not None:
            figure.set_layout_engine("none")  # the axes keep the positions the layout gave them
    return written


def render_figures(results_path: str | Path, reference_errors: dict[str, float] | None = None):
    """Yield (name, matplotlib Figure) for every figure the file supports; the caller closes each figure."""
    yield from _render(load_results(results_path), reference_errors)


def _render(results: Results, reference_errors: dict[str, float] | None):
    if not results.runs:
        return
    if reference_errors:
        results = with_reference_errors(results, reference_errors)
    for name, draw in FIGURES.items():
        figure = draw(results)
        if figure is not None:
            yield name, figure


def with_reference_errors(results: Results, errors: dict[str, float]) -> Results:
    """The results with each run's missing final_error (NaN) replaced by its error against a reference."""
    runs = [replace(run, final_error=errors[run.run_id]) if run.run_id in errors and not np.isfinite(run.final_error) else run
            for run in results.runs]
    by_id = {run.run_id: run for run in runs}
    groups = [(title, [by_id[run.run_id] for run in members]) for title, members in results.groups]
    return replace(results, runs=runs, groups=groups)


# -- 1. energy over time ---------------------------------------------------------------------------
def energy_over_time(results: Results):
    """E/E0 against t: small multiples per dt (rows per group), one line per integrator label."""
    rows, note = _dt_panels(results)
    figure, axes = _panel_grid(rows, sharex=True, legend_width=FIGURE_LEGEND_WIDTH)
    for (title, runs), ax in zip(_flatten(rows), axes):
        drawn = [run for run in runs if run.has_series]
        for run in _in_label_order(drawn, results):
            t, ratio = _finite(run.t, run.energy_ratio)
            if ratio.size == 0:
                continue
            stopped = run.status in (DIVERGED, FAILED)
            ax.plot(t, ratio, color=results.colours[run.label], lw=1.1, label=_status_label(run),
                    marker="x" if stopped else None, markevery=[ratio.size - 1], ms=7, mew=1.8)
        _no_data_entries(ax, runs, results)
        values = np.concatenate([_finite(run.t, run.energy_ratio)[1] for run in drawn] or [np.empty(0)])
        _energy_axis(ax, values)
        if values.size:  # the exact energy: E / E_ref stays at its start, +1 (or -1 for a bound orbit)
            ax.axhline(np.sign(values[0]), color="0.6", lw=0.8, ls="--", zorder=0)
        ax.set_title(title, fontsize=9)
        _status_legend(ax)
        ax.grid(True, which="major", alpha=0.3)
    _label_outer(axes, rows, "time t (s)", _energy_label(results.runs))
    handles = _label_handles(results, results.labels)
    handles += [Line2D([], [], ls="--", color="0.6", lw=0.8, label="exact (E conserved)"),
                Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="run stopped (diverged/failed)")]
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{results.name}: energy over time" + note, fontsize=11)
    return figure


def _energy_label(runs: list[RunData]) -> str:
    if all(run.energy.size and run.energy[0] > 0 for run in runs if run.has_series):
        return "energy E / E$_0$"
    if any(run.energy.size and run.energy[0] == 0 for run in runs):
        return "energy E / E$_{ref}$  (|E$_0$|, or |KE$_0$|+|PE$_0$| if E$_0$=0)"
    return "energy E / |E$_0$|"


def _energy_axis(ax, values: np.ndarray) -> None:
    """Log axis when positive values span decades, symlog when signed values do, else linear."""
    if values.size == 0:
        return
    if np.all(values > 0) and values.max() / values.min() > LOG_AXIS_RANGE:
        ax.set_yscale("log")
    elif np.any(values <= 0) and np.abs(values).max() > SYMLOG_RANGE:
        ax.set_yscale("symlog", linthresh=1.0)  # linear within the initial energy scale
    else:
        ax.ticklabel_format(axis="y", useOffset=False)


# -- 2. energy drift against dt --------------------------------------------------------------------
def energy_drift_vs_dt(results: Results):
    """max |E - E0| / |E0| against dt, log-log; one panel per group, one line per integrator label."""
    panels = _group_panels(results)
    figure, axes = _panel_grid(panels, sharey=True, panel_size=SUMMARY_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH)
    floored, marked = False, set()
    for (title, runs), ax in zip(_flatten(panels), axes):
        top = blended_transform_factory(ax.transData, ax.transAxes)  # x in data, y in axes fraction
        for number, label in enumerate(results.labels):
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            style = _label_style(results, label, number)
            shown = [run for run in mine if run.status not in (DIVERGED, FAILED) and run.has_change]
            if shown:
                dts = np.array([run.dt for run in shown])
                drifts = np.array([_max_drift(run) for run in shown])
                floored |= bool(np.any(drifts < DRIFT_FLOOR))
                drifts = np.maximum(drifts, DRIFT_FLOOR)
                ax.plot(dts, drifts, "-", lw=1.3, **style)
                marked |= _ring_not_converged(ax, dts, drifts, shown)
            for run in mine:
                if run.status == DIVERGED:  # off the scale: hollow, at the top edge
                    ax.plot(run.dt, TOP_EDGE, transform=top, clip_on=False, **{**style, "mfc": "none", "mew": 1.6})
                elif run.status == FAILED:
                    ax.plot(run.dt, TOP_EDGE, "X", color=style["color"], ms=8, transform=top, clip_on=False)
                marked.add(run.status)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.1)
        if any(run.status in (DIVERGED, FAILED) for run in runs):
            _pad_top(ax)
    handles = [Line2D([], [], ls="-", **{**_label_style(results, label, number), "ms": LEGEND_MARKER_SIZE})
               for number, label in enumerate(results.labels)]
    handles += _status_handles(marked, "(at top edge)")
    if floored:
        handles.append(Line2D([], [], ls="none", label=f"zero drift drawn at {DRIFT_FLOOR:g}"))
    _label_outer(axes, panels, "time step dt (s)", "max |E − E$_0$| / |E$_0$| over the run")
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{results.name}: relative energy drift against time step", fontsize=11)
    return figure


def _max_drift(run: RunData) -> float:
    energy = run.energy[np.isfinite(run.energy)]
    return float(np.max(np.abs(energy - energy[0])) / run.energy_ref)


def _pad_top(ax) -> None:
    """Room above the data for the markers of diverged runs, drawn at the top edge."""
    low, high = ax.get_ylim()
    ax.set_ylim(low, high * TOP_PADDING)


def _label_style(results: Results, label: str, number: int) -> dict:
    """Colour and marker of a label; later labels get smaller markers, so coinciding points stay visible."""
    size = max(4.0, 8.0 - MARKER_SHRINK * number)
    return {"color": results.colours[label], "marker": results.markers[label], "ms": size, "label": label}


def _ring_not_converged(ax, dts: np.ndarray, values: np.ndarray, runs: list[RunData]) -> set[str]:
    """A black ring around the points of runs whose solver gave up in some steps."""
    late = np.array([run.status == NOT_CONVERGED for run in runs])
    if not late.any():
        return set()
    ax.plot(dts[late], values[late], "o", ms=12, mfc="none", mec="black", mew=1.0, zorder=5)
    return {NOT_CONVERGED}


def _status_handles(marked: set[str], where: str) -> list[Line2D]:
    """Legend entries for the ways runs ended that the figure shows."""
    entries = {
        DIVERGED: dict(marker="o", mfc="none", mec="0.3", mew=1.6, ms=8, label=f"diverged, hollow {where}".strip()),
        FAILED: dict(marker="X", color="0.3", ms=8, label=f"failed {where}".strip()),
        NOT_CONVERGED: dict(marker="o", mfc="none", mec="black", ms=12, label="solver not converged in some steps"),
    }
    return [Line2D([], [], ls="none", **entries[status]) for status in entries if status in marked]


# -- 3. stability map ------------------------------------------------------------------------------
def stability_map(results: Results):
    """Integrators (rows) x dt (columns), coloured by log10 of the largest energy growth."""
    panels = [(title, runs) for title, runs in results.groups[:MAX_GROUPS]]
    signed = not all(run.energy.size and run.energy[0] > 0 and np.nanmin(run.energy) >= 0
                     for run in results.runs if run.has_series)
    tables = [_growth_table(runs, results.labels, signed) for _, runs in panels]
    values = np.concatenate([table[2].ravel() for table in tables])
    values = values[np.isfinite(values)]
    low = min(float(values.min()) if values.size else 0.0, -MIN_GROWTH_DECADES)
    high = max(float(values.max()) if values.size else 0.0, MIN_GROWTH_DECADES)
    norm = TwoSlopeNorm(vcenter=0.0, vmin=low, vmax=high)
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.93")
    widest = max(len(table[1]) for table in tables)
    size = (max(MAP_MIN_WIDTH, 1.0 + 0.75 * widest + 0.11 * max(map(len, results.labels))),
            0.9 + sum(0.45 * len(table[0]) + 0.7 for table in tables))
    figure, axes = plt.subplots(len(panels), 1, figsize=size, layout="constrained", squeeze=False)
    axes = axes.ravel()
    image, names = None, results.dt_names
    predictions = predictions_for(results) if test_equation_runs(results) else {}
    limits_drawn = False
    for (title, runs), (labels, dts, growth, statuses), ax in zip(panels, tables, axes):
        image = ax.imshow(np.ma.masked_invalid(growth), cmap=cmap, norm=norm, aspect="auto", interpolation="nearest")
        for row, column in np.ndindex(growth.shape):
            _annotate_cell(ax, row, column, growth[row, column], statuses[row][column], norm)
        limits_drawn |= _draw_predicted_limits(ax, labels, dts, runs, predictions)
        ax.set_xticks(range(len(dts)), [names[dt] for dt in dts], fontsize=8,
                      rotation=45 if len(dts) > MAP_COLUMNS_UPRIGHT else 0, ha="right" if len(dts) > MAP_COLUMNS_UPRIGHT else "center",
                      rotation_mode="anchor")
        ax.set_yticks(range(len(labels)), labels, fontsize=8)
        ax.set_xticks(np.arange(len(dts) + 1) - 0.5, minor=True)
        ax.set_yticks(np.arange(len(labels) + 1) - 0.5, minor=True)
        ax.grid(which="minor", color="white", lw=1.5)
        ax.tick_params(which="minor", length=0)
        ax.set_xlabel("time step dt (s)", fontsize=9)
        if title:
            ax.set_title(title, fontsize=9)
    what = "sign(ΔE)·log$_{10}$(1 + |ΔE| / |E$_0$|)" if signed else "log$_{10}$ (E / E$_0$)"
    colourbar = figure.colorbar(image, ax=list(axes), shrink=0.9, pad=0.02)
    colourbar.set_label(f"largest energy growth\n{what}", fontsize=8)
    colourbar.ax.tick_params(labelsize=7)
    present = {run.status for run in results.runs}
    marks = [note for status, note in ((DIVERGED, "X diverged (value at divergence)"), (FAILED, "! failed"),
                                       (NOT_CONVERGED, "* solver did not converge in some steps")) if status in present]
    if limits_drawn:
        marks.append("┃ predicted stability limit (ρ > 1 to its right)")
    key = "blue: energy lost, red: gained" + ("\n" + ",   ".join(marks) if marks else "")
    more = f"  (first {MAX_GROUPS} of {len(results.groups)} groups)" if len(results.groups) > MAX_GROUPS else ""
    figure.suptitle(f"{results.name}: stability map" + more, fontsize=11)
    figure.supxlabel(key, fontsize=7.5, color="0.25")
    return figure


def _draw_predicted_limits(ax, labels: list[str], dts: list[float], runs: list[RunData], predictions: dict) -> bool:
    """A thick bar in each row at the predicted stability limit dt = (h w)* / w, between the columns it falls between.

    A limit below the smallest dt (forward Euler: unstable at every h) sits on the left edge; no
    bar when the limit lies beyond the largest dt. Only for runs on the undamped test equation.
    """
    frequency = next((run.frequency for run in runs if run.frequency is not None), None)
    if frequency is None:
        return False
    drawn = False
    log_dts = np.log(dts)
    for row, label in enumerate(labels):
        prediction = predictions.get(label)
        if prediction is None or not np.isfinite(prediction.stability_limit):
            continue
        limit_dt = prediction.stability_limit / frequency
        if limit_dt > dts[-1]:
            continue
        if limit_dt <= dts[0]:
            position = -0.5
        else:
            position = float(np.interp(math.log(limit_dt), log_dts, np.arange(len(dts))))
        ax.plot([position, position], [row - 0.5, row + 0.5], color="black", lw=3.0, solid_capstyle="butt", zorder=6)
        drawn = True
    return drawn


def _growth_table(runs: list[RunData], labels: list[str], signed: bool):
    """(row labels, sorted dts, growth (rows x dts; NaN where no value), statuses)."""
    rows = [label for label in labels if any(run.label == label for run in runs)]
    dts = sorted({run.dt for run in runs})
    growth = np.full((len(rows), len(dts)), np.nan)
    statuses = [[""] * len(dts) for _ in rows]
    for run in runs:
        row, column = rows.index(run.label), dts.index(run.dt)
        statuses[row][column] = run.status
        if run.has_change:
            growth[row, column] = _growth(run, signed)
    return rows, dts, growth, statuses


def _growth(run: RunData, signed: bool) -> float:
    """The largest excursion of the energy from E0 over the run, in decades (see the colour bar)."""
    energy = run.energy[np.isfinite(run.energy)]
    if signed:
        change = (energy - energy[0]) / run.energy_ref
        values = np.sign(change) * np.log10(1.0 + np.abs(change))
    else:
        values = np.log10(np.maximum(energy / energy[0], np.finfo(float).tiny))
    return float(values[np.argmax(np.abs(values))])


def _annotate_cell(ax, row: int, column: int, value: float, status: str, norm) -> None:
    """The value in the cell, an X over diverged runs, '!' for failed ones, '*' where the solver gave up."""
    if status == "":
        return
    if status == FAILED and not np.isfinite(value):
        ax.text(column, row, "!", ha="center", va="center", fontsize=13, fontweight="bold", color="firebrick")
        return
    dark = np.isfinite(value) and abs(norm(value) - 0.5) > 0.3
    ink = "white" if dark else "black"
    if status == DIVERGED:
        ax.plot(column, row, marker="x", ms=26, mew=2.0, color=ink, alpha=0.45)
    if abs(value) < 0.005:
        text = "0.00"  # no sign on a change that rounds to nothing
    else:
        text = f"{value:+.2f}" if abs(value) < 10 else f"{value:+.0f}"
    text += {FAILED: " !", NOT_CONVERGED: "*"}.get(status, "")
    ax.text(column, row, text, ha="center", va="center", fontsize=8, color=ink,
            fontweight="bold" if status == DIVERGED else "normal")


# -- 4. Newton iterations against dt ---------------------------------------------------------------
def newton_iterations_vs_dt(results: Results):
    """Mean (and largest) Newton iterations per step against dt, implicit integrators only."""
    def counted(run: RunData) -> bool:
        return not run.explicit and run.newton_iterations.size > 0

    implicit = [run for run in results.runs if counted(run)]
    if not implicit:
        return None
    panels = [(title, [run for run in runs if counted(run)]) for title, runs in results.groups[:MAX_GROUPS]]
    panels = [panel for panel in panels if panel[1]]
    rows = [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    figure, axes = _panel_grid(rows, sharey=True, panel_size=SUMMARY_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH)
    marked = set()
    labels = [label for label in results.labels if any(run.label == label for run in implicit)]
    for (title, runs), ax in zip(_flatten(rows), axes):
        for number, label in enumerate(labels):
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            if not mine:
                continue
            style = _label_style(results, label, number)
            dts = np.array([run.dt for run in mine])
            mean = np.array([run.newton_iterations.mean() for run in mine])
            peak = np.array([run.newton_iterations.max() for run in mine])
            ax.plot(dts, mean, "-", lw=1.3, **style)
            ax.plot(dts, peak, ":", lw=1.0, color=style["color"])
            stopped = np.array([run.status in (DIVERGED, FAILED) for run in mine])
            if stopped.any():  # the mean over the steps before the run stopped
                ax.plot(dts[stopped], mean[stopped], ls="none", **{**style, "mfc": "white", "mew": 1.6, "label": None})
                marked |= {run.status for run in mine if run.status in (DIVERGED, FAILED)}
            marked |= _ring_not_converged(ax, dts, mean, mine)
        ax.set_xscale("log")
        ax.set_ylim(0, max(ax.get_ylim()[1], 1.0) * 1.12)
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    handles = [Line2D([], [], ls="-", **{**_label_style(results, label, number), "ms": LEGEND_MARKER_SIZE})
               for number, label in enumerate(labels)]
    handles += [Line2D([], [], ls="-", color="0.4", label="mean per step"),
                Line2D([], [], ls=":", color="0.4", label="largest in one step")]
    if marked & {DIVERGED, FAILED}:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.4", mew=1.6, ms=8,
                              label="run stopped early (diverged/failed)"))
    handles += _status_handles(marked & {NOT_CONVERGED}, "")
    _label_outer(axes, rows, "time step dt (s)", "Newton iterations per step")
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{results.name}: Newton iterations against time step", fontsize=11)
    return figure


# -- 5. orbits -------------------------------------------------------------------------------------
def orbits(results: Results):
    """x-y trajectories of circular motion per dt (rows per group), with the exact circle dashed."""
    circular = [run for run in results.runs if run.system == "circular_motion"]
    if not circular:
        return None
    groups = [(title, [run for run in runs if run.system == "circular_motion"]) for title, runs in results.groups]
    subset = replace(results, runs=circular, groups=[group for group in groups if group[1]])
    rows, note = _dt_panels(subset)
    figure, axes = _panel_grid(rows, panel_size=ORBIT_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH)
    circle = np.linspace(0.0, 2.0 * np.pi, 361)
    for (title, runs), ax in zip(_flatten(rows), axes):
        radius = float(runs[0].system_params.get("radius", 1.0))
        reach = radius
        for run in _in_label_order(runs, results):
            colour = results.colours[run.label]
            xy = run.xy if run.xy is not None else np.empty((0, 2))
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if xy.shape[0] == 0:
                ax.plot([], [], ls=":", color=colour, label=f"{run.label} (failed, no data)")
                continue
            stopped = run.status in (DIVERGED, FAILED)
            ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.0, alpha=0.9, label=_status_label(run),
                    marker="x" if stopped else None, markevery=[xy.shape[0] - 1], ms=7, mew=1.8)
            reach = max(reach, float(np.abs(xy).max()))
        ax.plot(radius * np.cos(circle), radius * np.sin(circle), "--", color="black", lw=1.0)
        ax.plot(radius, 0.0, "o", color="black", ms=4, zorder=5)
        limit = min(reach, ORBIT_BOX_RADII * radius) * 1.08
        ax.set_xlim(-limit, limit)
        ax.set_ylim(-limit, limit)
        ax.set_aspect("equal")
        clipped = reach > ORBIT_BOX_RADII * radius
        ax.set_title(title + (f"\n(clipped to ±{ORBIT_BOX_RADII:g} r)" if clipped else ""), fontsize=9)
        _status_legend(ax)
        ax.grid(True, alpha=0.3)
    handles = _label_handles(results, [label for label in results.labels if any(run.label == label for run in circular)])
    handles += [Line2D([], [], ls="--", color="black", label="exact circle"),
                Line2D([], [], ls="none", marker="o", color="black", ms=4, label="start"),
                Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="run stopped (diverged/failed)")]
    _label_outer(axes, rows, "x (m)", "y (m)")
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{results.name}: orbits" + note, fontsize=11)
    return figure


# -- 6. artificial damping: predicted curves, measured markers ---------------------------------------
# Up to this many labels share one panel; more are split into families (one panel per integrator
# with several parameter values, one for the rest), so that the curves stay apart.
SHARED_PANEL_LABELS = 6
FAMILY_COLUMNS = 3
CURVE_PANEL_SIZE = (4.4, 3.3)
# Below zero the damping axis shows growth (rho > 1, dashed) down to this fraction of its top.
GROWTH_AXIS_FRACTION = 0.3
# A predicted damping below this (|d| / w) over the whole stable range is "no artificial damping".
NO_DAMPING = 1e-9
# The relative period error axis is cut here: beyond, the curves only say "far too slow".
PERIOD_ERROR_RANGE = (-0.5, 1.5)
RHO_AXIS_TOP = 1.3


def test_equation_runs(results: Results) -> list[RunData]:
    """The runs on the undamped test equation (spring, linear circular motion): h w is defined for them."""
    return [run for run in results.runs if run.frequency is not None]


def predictions_for(results: Results, runs: list[RunData] | None = None) -> dict[str, "analysis.Prediction"]:
    """label -> predicted curves for each label whose integrator this simrun knows, over analysis.X_RANGE
    widened to cover the runs' h w."""
    runs = test_equation_runs(results) if runs is None else runs
    xs = [run.x for run in runs if np.isfinite(run.x) and run.x > 0]
    low = min([analysis.X_RANGE[0]] + [0.5 * min(xs)] if xs else [analysis.X_RANGE[0]])
    high = max([analysis.X_RANGE[1]] + [2.0 * max(xs)] if xs else [analysis.X_RANGE[1]])
    # a decade boundary keeps the grid (and so the cache key) the same for similar files
    low, high = 10.0 ** math.floor(math.log10(low)), 10.0 ** math.ceil(math.log10(high))
    methods = {}
    for run in results.runs:
        if run.label not in methods and run.method is not None:
            methods[run.label] = run.method
    return {label: analysis.predict(method, low, high) for label, method in methods.items()}


def family_panels(predictions: dict[str, "analysis.Prediction"]) -> list[tuple[str, list[str]]]:
    """(title, labels) panels: all in one, or one per integrator with several parameter values plus one for the rest."""
    labels = list(predictions)
    by_name: dict[str, list[str]] = {}
    for label in labels:
        by_name.setdefault(predictions[label].integrator.name, []).append(label)
    families = {name: members for name, members in by_name.items() if len(members) > 1}
    if len(labels) <= SHARED_PANEL_LABELS or not families:
        return [("", labels)]
    singles = [label for label in labels if predictions[label].integrator.name not in families]
    panels = [("methods", singles)] if singles else []
    for name, members in families.items():
        dumps = [predictions[label].integrator.model_dump() for label in members]
        varied = [key for key in dumps[0] if len({json.dumps(dump[key]) for dump in dumps}) > 1]
        panels.append((f"{name}: {', '.join(varied)} varied" if varied else name, members))
    return panels


def _grid_rows(panels: list, columns: int = FAMILY_COLUMNS) -> list[list]:
    return [panels[start:start + columns] for start in range(0, len(panels), columns)]


def artificial_damping(results: Results):
    """d_method / w against h w: predicted lines (all labels), measured markers (undamped linear runs)."""
    runs = test_equation_runs(results)
    predictions = predictions_for(results, runs) if runs else {}
    if not predictions:
        return None
    return damping_figure(predictions, results.colours, results.markers,
                          f"{results.name}: artificial damping, predicted and measured", runs)


def damping_figure(predictions: dict[str, "analysis.Prediction"], colours: dict, markers: dict, title: str,
                   runs: list[RunData] = ()):
    """The damping curves (one panel per family), with the measured damping of `runs` as markers."""
    rows = _grid_rows(family_panels(predictions))
    figure, axes = _panel_grid(rows, sharey=True, panel_size=CURVE_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH + 0.6)
    top, bottom, growth, marked = 0.0, 0.0, False, set()
    diverged_marks = []
    for (panel_title, labels), ax in zip(_flatten(rows), axes):
        for number, label in enumerate(labels):
            prediction, colour = predictions[label], colours[label]
            stable = prediction.rho <= 1.0 + analysis.GROWTH_TOLERANCE
            damping = prediction.damping + 0.0  # no "-0" for rho = 1
            # later labels thinner, so that coinciding curves (backward Euler and its one-Newton-step twin) both show
            width = max(1.0, 2.0 - 0.3 * number)
            ax.plot(prediction.x, np.where(stable, damping, np.nan), "-", color=colour, lw=width, zorder=3)
            if not stable.all():
                # dashed where rho > 1, joined to the solid part at the crossing
                unstable = ~stable | np.r_[~stable[1:], False]
                ax.plot(prediction.x, np.where(unstable, damping, np.nan), "--", color=colour, lw=1.1, zorder=3)
                growth = True
            if stable.any():
                top = max(top, float(np.nanmax(damping[stable])))
            for run in (run for run in runs if run.label == label):
                if run.status in (DIVERGED, FAILED):
                    diverged_marks.append((ax, run.x, colour))
                    marked.add(DIVERGED)
                    continue
                fit = run.damping_fit
                if fit is None or not np.isfinite(fit.rate):
                    continue
                value = fit.rate / run.frequency
                style = dict(color=colour, marker=markers[label], ms=max(4.0, 6.5 - 0.4 * number), ls="none", zorder=4,
                             mec="white", mew=0.6)
                if not fit.resolved:
                    style.update(mfc="white", mec=colour, mew=1.2)
                    marked.add("unresolved")
                else:
                    marked.add("measured")
                ax.plot(run.x, value, **style)
                top = max(top, value) if np.isfinite(value) else top
                bottom = min(bottom, value) if np.isfinite(value) else bottom
        ax.axhline(0.0, color="0.55", lw=0.8, zorder=1)
        ax.set_xscale("log")
        ax.set_title(panel_title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.08)
    top = max(top, 1e-3) * 1.08
    # measured values a hair below zero (round-off of energy-conserving methods) need no room for growth
    low = -GROWTH_AXIS_FRACTION * top if growth or bottom < -0.02 * top else -0.04 * top
    axes[0].set_ylim(low, top)
    for ax, x, colour in diverged_marks:
        edge = blended_transform_factory(ax.transData, ax.transAxes)
        ax.plot(x, 0.04, "x", color=colour, ms=7, mew=1.8, transform=edge, clip_on=False, zorder=5)
    _label_outer(axes, rows, "h w  (time step × natural frequency)", "d$_{method}$ / w  = −2 ln ρ / (h w)")
    handles = []
    seen: list[str] = []
    for label, prediction in predictions.items():
        stable = prediction.rho <= 1.0 + analysis.GROWTH_TOLERANCE
        twin = next((other for other in seen if predictions[other].x.shape == prediction.x.shape
                     and np.allclose(predictions[other].rho, prediction.rho, rtol=0, atol=1e-10)), None)
        seen.append(label)
        notes = []
        if stable.any() and np.nanmax(np.abs(prediction.damping[stable])) < NO_DAMPING:
            notes.append("no damping: on the axis")
        elif twin is not None:
            notes.append(f"= {twin} here")
        if prediction.stability_limit == 0.0:
            notes.append("grows at every h")
        elif np.isfinite(prediction.stability_limit):
            notes.append(f"stable for h w < {prediction.stability_limit:.3g}")
        note = f"  ({'; '.join(notes)})" if notes else ""
        handles.append(Line2D([], [], color=colours[label], marker=markers[label] if runs else None, ms=LEGEND_MARKER_SIZE,
                              lw=1.6, label=label + note))
    handles.append(Line2D([], [], ls="-", color="0.3", lw=1.6, label="predicted (amplification matrix)"))
    if growth:
        handles.append(Line2D([], [], ls="--", color="0.3", lw=1.1, label="predicted, ρ > 1: energy grows"))
    if "measured" in marked:
        handles.append(Line2D([], [], ls="none", marker="o", color="0.3", ms=6, label="measured: decay of ln E(t)"))
    if "unresolved" in marked:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.3", ms=6,
                              label="measured, not resolved by the run"))
    if DIVERGED in marked:
        handles.append(Line2D([], [], ls="none", marker="x", color="0.3", ms=7, mew=1.8, label="diverged: not fitted"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(title, fontsize=11)
    return figure


# -- 7. spectral radius and period error ------------------------------------------------------------
def spectral_radius_and_period(results: Results):
    """rho(h w) (top) and the relative period error (bottom), predicted; measured periods as markers."""
    runs = test_equation_runs(results)
    predictions = predictions_for(results, runs) if runs else {}
    if not predictions:
        return None
    return spectral_figure(predictions, results.colours, results.markers,
                           f"{results.name}: spectral radius and period error", runs)


def spectral_figure(predictions: dict[str, "analysis.Prediction"], colours: dict, markers: dict, title: str,
                    runs: list[RunData] = ()):
    panels = family_panels(predictions)
    columns = len(panels)
    if columns == 1:  # one family: the two quantities side by side
        size = (2 * CURVE_PANEL_SIZE[0] + FIGURE_LEGEND_WIDTH + 0.6, CURVE_PANEL_SIZE[1] + 0.6)
        figure, pair = plt.subplots(1, 2, figsize=size, layout="constrained", squeeze=False)
        grid = pair.reshape(2, 1)
    else:
        size = (CURVE_PANEL_SIZE[0] * columns + FIGURE_LEGEND_WIDTH + 0.6, 2 * CURVE_PANEL_SIZE[1] + 0.6)
        figure, grid = plt.subplots(2, columns, figsize=size, layout="constrained", squeeze=False, sharex="row", sharey="row")
    measured = limits = False
    for column, (panel_title, labels) in enumerate(panels):
        radius_ax, period_ax = grid[0, column], grid[1, column]
        for number, label in enumerate(labels):
            prediction, colour = predictions[label], colours[label]
            radius_ax.plot(prediction.x, prediction.rho, "-", color=colour, lw=1.5)
            limit = prediction.stability_limit
            if 0.0 < limit < prediction.x[-1]:
                radius_ax.plot(limit, 1.0, "o", color=colour, mfc="white", mew=1.4, ms=6, zorder=5)
                limits = True
            period_ax.plot(prediction.x, prediction.period_error, "-", color=colour, lw=1.5)
            for run in (run for run in runs if run.label == label):
                if np.isfinite(run.period_error):
                    period_ax.plot(run.x, run.period_error, ls="none", marker=markers[label], color=colour,
                                   ms=max(4.0, 6.5 - 0.25 * number), zorder=4)
                    measured = True
        radius_ax.axhline(1.0, color="0.55", lw=0.8, ls=":")
        period_ax.axhline(0.0, color="0.55", lw=0.8)
        period_ax.axvline(math.pi, color="0.55", lw=0.8, ls=":")
        for ax in (radius_ax, period_ax):
            ax.set_xscale("log")
            ax.grid(True, which="major", alpha=0.3)
            ax.tick_params(labelsize=8)
        radius_ax.set_title(panel_title, fontsize=9)
        radius_ax.set_xlabel("h w", fontsize=9)
        period_ax.set_xlabel("h w  (up to π: beyond, a step spans over half a period)", fontsize=8.5)
    growth = any(np.nanmax(prediction.rho) > 1.0 + analysis.GROWTH_TOLERANCE for prediction in predictions.values())
    grid[0, 0].set_ylim(0.0, RHO_AXIS_TOP if growth else 1.08)
    grid[0, 0].set_ylabel("spectral radius ρ(h w)", fontsize=9)
    # the period is defined up to h w = pi only: its row zooms onto that range
    low = min(prediction.x[0] for prediction in predictions.values())
    grid[1, 0].set_xlim(low, 1.3 * math.pi)
    grid[1, 0].set_ylim(*PERIOD_ERROR_RANGE)
    grid[1, 0].set_ylabel("relative period error T$_h$/T − 1", fontsize=9)
    grid[1, 0].text(math.pi, 0.97 * PERIOD_ERROR_RANGE[1], "h w = π ", fontsize=7, color="0.4", va="top", ha="right")
    handles = [Line2D([], [], color=colours[label], lw=1.5, marker=markers[label] if measured else None,
                      ms=LEGEND_MARKER_SIZE, label=label + _limit_note(prediction))
               for label, prediction in predictions.items()]
    if limits:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.3", mew=1.4, ms=6,
                              label="stability limit: ρ > 1 beyond"))
    if measured:
        handles.append(Line2D([], [], ls="none", marker="o", color="0.3", ms=6, label="measured period (zero crossings)"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(title, fontsize=11)
    return figure


def _limit_note(prediction: "analysis.Prediction") -> str:
    limit = prediction.stability_limit
    if limit == 0.0:
        return "  (unstable at every h)"
    if math.isinf(limit):
        return ""
    return f"  (stable for h w < {limit:.3g})"


# -- 8. convergence, work-precision, cost per step -------------------------------------------------
# An error of exactly zero cannot sit on a log axis: drawn at this floor (m).
ERROR_FLOOR = 1e-16


def _error_runs(results: Results) -> list[RunData]:
    """Runs that reached the end time with a known error (exact solution, or a reference on request)."""
    return [run for run in results.runs if run.status not in (DIVERGED, FAILED) and np.isfinite(run.final_error)]


def order_fits(results: Results) -> dict[tuple[str, str], tuple["analysis.OrderFit", list[RunData]]]:
    """(group title, label) -> (observed order fit, runs sorted by dt) for every label with errors."""
    fits = {}
    usable = set(map(id, _error_runs(results)))
    for title, runs in results.groups:
        for label in results.labels:
            mine = sorted((run for run in runs if run.label == label and id(run) in usable), key=lambda run: run.dt)
            if mine:
                fit = analysis.observed_order([run.dt for run in mine], [run.final_error for run in mine],
                                              scale=mine[0].length_scale)
                fits[(title, label)] = (fit, mine)
    return fits


def order_text(fit: "analysis.OrderFit") -> str:
    if np.isfinite(fit.order):
        return f"p = {fit.order:.2f}"
    return "exact (round-off)" if fit.exact else "p: too few points"


def convergence(results: Results):
    """Error at the end time against dt (log-log); the fitted slope (observed order) of each label in the legend."""
    fits = order_fits(results)
    if not fits:
        return None
    panels = [(title, runs) for title, runs in results.groups[:MAX_GROUPS] if any((title, label) in fits for label in results.labels)]
    rows = [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    single = len(panels) == 1
    figure, axes = _panel_grid(rows, panel_size=SUMMARY_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH + 0.4 if single else 0.0)
    handles = []
    for (title, _), ax in zip(_flatten(rows), axes):
        for number, label in enumerate(results.labels):
            if (title, label) not in fits:
                continue
            fit, mine = fits[(title, label)]
            style = _label_style(results, label, number)
            dts = np.array([run.dt for run in mine])
            errors = np.maximum([run.final_error for run in mine], ERROR_FLOOR)
            ax.plot(dts, errors, "-", lw=1.2, **{**style, "label": f"{label}: {order_text(fit)}"})
            if np.isfinite(fit.order):
                ends = dts[fit.used][[0, -1]]
                ax.plot(ends, np.exp(fit.intercept) * ends ** fit.order, "--", color="black", lw=0.9, zorder=5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        _tidy_log_axes(ax)
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.08)
        if single:
            handles = ax.get_legend_handles_labels()[0]
        else:
            ax.legend(fontsize=6.5, loc="lower right", framealpha=0.85, handlelength=1.5)
    reference = any(run.system == "cloth" for run in _error_runs(results))
    _label_outer(axes, rows, "time step dt (s)", "error at the end time (m)" + (" vs reference" if reference else ""))
    fit_handle = Line2D([], [], ls="--", color="black", lw=0.9, label=f"least-squares fit (≤ {analysis.ORDER_FIT_POINTS} smallest dt)")
    if single:
        figure.legend(handles=handles + [fit_handle], loc="outside right center", fontsize=8, frameon=False)
    else:
        axes[0].add_artist(axes[0].legend(handles=[fit_handle], fontsize=6.5, loc="upper left", framealpha=0.85))
    figure.suptitle(f"{results.name}: convergence (observed order p)", fontsize=11)
    return figure


def work_precision(results: Results):
    """Error at the end time against the wall time of the run (log-log), one line per label."""
    fits = order_fits(results)
    timed = {key: (fit, [run for run in runs if run.wall_time > 0]) for key, (fit, runs) in fits.items()}
    timed = {key: value for key, value in timed.items() if value[1]}
    if not timed:
        return None
    panels = [(title, runs) for title, runs in results.groups[:MAX_GROUPS] if any((title, label) in timed for label in results.labels)]
    rows = [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    figure, axes = _panel_grid(rows, sharey=True, panel_size=SUMMARY_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH)
    labels = []
    for (title, _), ax in zip(_flatten(rows), axes):
        for number, label in enumerate(results.labels):
            if (title, label) not in timed:
                continue
            _, mine = timed[(title, label)]
            labels.append(label)
            ax.plot([run.wall_time for run in mine], np.maximum([run.final_error for run in mine], ERROR_FLOOR),
                    "-", lw=1.2, **_label_style(results, label, number))
        ax.set_xscale("log")
        ax.set_yscale("log")
        _tidy_log_axes(ax)
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    _label_outer(axes, rows, "wall time of the run (s)", "error at the end time (m)")
    handles = [Line2D([], [], ls="-", **{**_label_style(results, label, number), "ms": LEGEND_MARKER_SIZE})
               for number, label in enumerate(results.labels) if label in labels]
    handles.append(Line2D([], [], ls="none", label="lower left is better"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{results.name}: work-precision (points: the time steps)", fontsize=11)
    return figure


def wall_time_per_step_vs_dt(results: Results):
    """Wall time per step against dt, one line per label, one panel per group (e.g. per solver)."""
    timed = [run for run in results.runs if run.steps > 0 and run.wall_time > 0]
    if not timed:
        return None
    chosen = set(map(id, timed))
    panels = [(title, [run for run in runs if id(run) in chosen]) for title, runs in results.groups[:MAX_GROUPS]]
    panels = [panel for panel in panels if panel[1]]
    rows = [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    figure, axes = _panel_grid(rows, sharey=True, panel_size=SUMMARY_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH)
    stopped_any = False
    for (title, runs), ax in zip(_flatten(rows), axes):
        for number, label in enumerate(results.labels):
            mine = sorted((run for run in runs if run.label == label), key=lambda run: run.dt)
            if not mine:
                continue
            style = _label_style(results, label, number)
            dts = np.array([run.dt for run in mine])
            cost = np.array([run.wall_time / run.steps for run in mine]) * 1e3
            ax.plot(dts, cost, "-", lw=1.2, **style)
            stopped = np.array([run.status in (DIVERGED, FAILED) for run in mine])
            if stopped.any():
                ax.plot(dts[stopped], cost[stopped], ls="none", **{**style, "mfc": "white", "mew": 1.6, "label": None})
                stopped_any = True
        ax.set_xscale("log")
        ax.set_yscale("log")
        _tidy_log_axes(ax)
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        ax.grid(True, which="minor", alpha=0.08)
    _label_outer(axes, rows, "time step dt (s)", "wall time per step (ms)")
    handles = [Line2D([], [], ls="-", **{**_label_style(results, label, number), "ms": LEGEND_MARKER_SIZE})
               for number, label in enumerate(results.labels)]
    if stopped_any:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.4", mew=1.6, ms=8,
                              label="run stopped early (diverged/failed)"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    figure.suptitle(f"{results.name}: cost per step against time step", fontsize=11)
    return figure


# -- 9. where the energy goes ----------------------------------------------------------------------
BUDGET_PANELS = 16
BUDGET_PANEL_SIZE = (3.6, 2.5)
# The stack is cut at this multiple of the budget: a method that gains energy leaves the panel.
BUDGET_AXIS_TOP = 1.6
BUDGET_TERMS = (  # dataset, legend text, colour
    ("kinetic_energy", "kinetic", "#4c72b0"),
    ("potential_energy", "potential", "#55a868"),
    ("spring_energy", "potential: springs", "#55a868"),
    ("gravity_energy", "potential: gravity", "#ccb974"),
    ("contact_energy", "potential: contact", "#8172b2"),
    ("dissipated_energy", "dissipated by physical damping", "#c44e52"),
)
NUMERICAL_LOSS_COLOUR, NUMERICAL_GAIN_COLOUR = "0.82", "#dd8452"
# A term (or a gain) smaller than this fraction of the budget throughout is left out of the legend.
BUDGET_VISIBLE = 1e-3


def energy_budget(results: Results):
    """Where the energy goes, for each label at one dt: kinetic + potential terms + physical damping work,
    stacked over time; the gap to the initial energy is the integrator's numerical loss (or gain)."""
    if results.path is None or not results.groups:
        return None
    title, runs = results.groups[0]
    dt = _budget_dt(runs)
    chosen = [run for run in _in_label_order([run for run in runs if run.dt == dt], results) if run.t.size >= 2][:BUDGET_PANELS]
    if not chosen:
        return None
    budgets = _read_budgets(results.path, chosen)
    panels = [(run.label + run.status_note(), run) for run in chosen]
    rows = [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    figure, axes = _panel_grid(rows, sharex=True, sharey=True, panel_size=BUDGET_PANEL_SIZE, legend_width=FIGURE_LEGEND_WIDTH + 0.3)
    shown: dict[str, str] = {}
    gained = False
    for (panel_title, run), ax in zip(_flatten(rows), axes):
        t, terms, budget = budgets[run.run_id]
        bottom = np.zeros_like(t)
        for key, text, colour in BUDGET_TERMS:
            if key in terms:
                ax.fill_between(t, bottom / budget, (bottom + terms[key]) / budget, color=colour, lw=0)
                bottom = bottom + terms[key]
                if np.nanmax(terms[key]) > BUDGET_VISIBLE * budget:
                    shown[text] = colour
        # what is left of the budget: the integrator's own loss (below the line) or gain (above)
        ax.fill_between(t, bottom / budget, 1.0, where=bottom <= budget, interpolate=True,
                        facecolor=NUMERICAL_LOSS_COLOUR, lw=0)
        if np.any(bottom > budget * (1.0 + BUDGET_VISIBLE)):
            # hatched over the stack: the terms above the line are there, but only through the method's gain
            ax.fill_between(t, 1.0, np.minimum(bottom / budget, BUDGET_AXIS_TOP), where=bottom > budget, interpolate=True,
                            facecolor="none", edgecolor=NUMERICAL_GAIN_COLOUR, hatch="xx", lw=0)
            gained = True
        ax.axhline(1.0, color="black", lw=0.9, ls="--")
        if t.size > 1:
            ax.set_xlim(t[0], t[-1])
        ax.set_title(panel_title, fontsize=8.5)
        ax.grid(True, alpha=0.25)
    axes[0].set_ylim(0.0, BUDGET_AXIS_TOP if gained else 1.05)
    _label_outer(axes, rows, "time t (s)", "energy / initial budget")
    handles = [Patch(facecolor=colour, label=text) for text, colour in shown.items()]
    handles.append(Patch(facecolor=NUMERICAL_LOSS_COLOUR, label="numerical loss (the integrator)"))
    if gained:
        handles.append(Patch(facecolor="none", edgecolor=NUMERICAL_GAIN_COLOUR, hatch="xx", label="numerical gain (the integrator)"))
    handles.append(Line2D([], [], ls="--", color="black", lw=0.9, label="initial energy (the budget)"))
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    where = f", {title}" if title else ""
    figure.suptitle(f"{results.name}: where the energy goes (dt = {results.dt_names[dt]} s{where})", fontsize=11)
    return figure


def _budget_dt(runs: list[RunData]) -> float:
    """The dt shown: nearest the geometric middle of the swept dts among those where every run reached the end."""
    dts = sorted({run.dt for run in runs})
    complete = [dt for dt in dts if all(run.status not in (DIVERGED, FAILED) for run in runs if run.dt == dt)] or dts
    middle = math.sqrt(dts[0] * dts[-1])
    return min(complete, key=lambda dt: abs(math.log(dt / middle)))


def _read_budgets(path: Path, runs: list[RunData]) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray], float]]:
    """run_id -> (t, energy terms (each >= 0), budget): potential terms that can be negative (gravity)
    are counted from their lowest value in the run, and the budget is E0 minus those offsets."""
    budgets = {}
    with h5py.File(path, "r") as file:
        for run in runs:
            group = file["runs"][run.run_id]
            t = np.asarray(group["t"][()], dtype=float)
            parts = ("spring_energy", "gravity_energy", "contact_energy") if "spring_energy" in group else ("potential_energy",)
            terms = {}
            for key in ("kinetic_energy", *parts, "dissipated_energy"):
                if key in group:
                    terms[key] = np.asarray(group[key][()], dtype=float)[: t.size]
            count = min([t.size] + [values.size for values in terms.values()])
            finite = np.all([np.isfinite(values[:count]) for values in terms.values()], axis=0) & np.isfinite(t[:count])
            stop = int(np.argmin(finite)) if not finite.all() else count
            t = t[:stop]
            terms = {key: values[:stop] for key, values in terms.items()}
            offset = 0.0
            for key in parts:
                if key in terms and terms[key].size and terms[key].min() < 0:
                    low = float(terms[key].min())
                    terms[key] = terms[key] - low
                    offset += low
            start = sum(float(values[0]) for key, values in terms.items() if key != "dissipated_energy") if t.size else 0.0
            budget = start if start > 0 else 1.0
            budgets[run.run_id] = (t, terms, budget)
    return budgets


FIGURES = {
    "energy_over_time": energy_over_time,
    "energy_drift_vs_dt": energy_drift_vs_dt,
    "stability_map": stability_map,
    "newton_iterations_vs_dt": newton_iterations_vs_dt,
    "orbits": orbits,
    "artificial_damping": artificial_damping,
    "spectral_radius_and_period": spectral_radius_and_period,
    "convergence": convergence,
    "work_precision": work_precision,
    "wall_time_per_step_vs_dt": wall_time_per_step_vs_dt,
    "energy_budget": energy_budget,
}


# -- layout helpers --------------------------------------------------------------------------------
def _dt_panels(results: Results) -> tuple[list[list[tuple[str, list[RunData]]]], str]:
    """Rows of (title, runs) panels, one per dt; wrapped rows for one group, a row per group otherwise."""
    groups = results.groups[:MAX_GROUPS]
    several = len(results.groups) > 1
    cap = MAX_DT_PANELS_PER_GROUP if several else MAX_DT_PANELS
    rows, notes = [], []
    for title, runs in groups:
        dts = sorted({run.dt for run in runs})
        shown = _spread(dts, cap)
        if len(shown) < len(dts):
            notes.append(f"{len(shown)} of {len(dts)} time steps shown")
        panels = [(f"dt = {results.dt_names[dt]} s" + (f"\n{title}" if several else ""), [run for run in runs if run.dt == dt])
                  for dt in shown]
        if several:
            rows.append(panels)
        else:
            rows += [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]
    if len(results.groups) > MAX_GROUPS:
        notes.append(f"first {MAX_GROUPS} of {len(results.groups)} groups")
    note = f"  ({'; '.join(dict.fromkeys(notes))})" if notes else ""
    return rows, note


def _group_panels(results: Results) -> list[list[tuple[str, list[RunData]]]]:
    panels = results.groups[:MAX_GROUPS]
    return [panels[start:start + PANEL_COLUMNS] for start in range(0, len(panels), PANEL_COLUMNS)]


def _spread(values: list[float], count: int) -> list[float]:
    """At most `count` of the sorted values, evenly spread and always including both ends."""
    if len(values) <= count:
        return list(values)
    picks = np.unique(np.round(np.linspace(0, len(values) - 1, count)).astype(int))
    return [values[pick] for pick in picks]


def _panel_grid(rows, sharex=False, sharey=False, panel_size=PANEL_SIZE, legend_width=0.0):
    """A figure with one axes per panel (rows of varying length); returns (figure, axes in panel order).

    legend_width (in) is added for a figure legend on the right, so that it does not squeeze the panels.
    """
    columns = max(len(row) for row in rows)
    size = (panel_size[0] * columns + legend_width, panel_size[1] * len(rows) + 0.6)
    figure, grid = plt.subplots(len(rows), columns, figsize=size,
                                layout="constrained", squeeze=False, sharex=sharex, sharey=sharey)
    axes = []
    for number, row in enumerate(rows):
        axes += list(grid[number, :len(row)])
        for ax in grid[number, len(row):]:
            ax.set_visible(False)
    return figure, axes


def _label_outer(axes, rows, xlabel: str, ylabel: str) -> None:
    """Axis labels on the left column and on the lowest panel of each column only."""
    columns = max(len(row) for row in rows)
    positions = [(number, column) for number, row in enumerate(rows) for column in range(len(row))]
    lowest = {column: max(number for number, c in positions if c == column) for column in range(columns)}
    for ax, (number, column) in zip(axes, positions):
        if lowest[column] == number:
            ax.set_xlabel(xlabel, fontsize=9)
            ax.xaxis.set_tick_params(labelbottom=True)  # shared x hides them above an empty slot
        if column == 0:
            ax.set_ylabel(ylabel, fontsize=9)
        ax.tick_params(labelsize=8)


def _status_label(run: RunData) -> str:
    """A legend label for runs that did not end ok; ok runs stay out of the panel legends."""
    return run.label + run.status_note() if run.status != "ok" else "_nolegend_"


def _no_data_entries(ax, runs: list[RunData], results: Results) -> None:
    for run in _in_label_order([run for run in runs if not run.has_series], results):
        ax.plot([], [], ls=":", color=results.colours[run.label], label=f"{run.label} (failed, no data)")


def _status_legend(ax) -> None:
    """A small legend in the panel naming its runs that diverged, failed or did not converge (if any)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(fontsize=7, loc="best", framealpha=0.85, handlelength=1.5)


def _label_handles(results: Results, labels: list[str]) -> list[Line2D]:
    return [Line2D([], [], color=results.colours[label], lw=1.5, label=label) for label in labels]


# A log axis spanning fewer decades than this gets ticks at 1, 2 and 5 times the powers of ten, in
# plain numbers (matplotlib would otherwise label the minor ticks in crowded scientific notation).
SHORT_LOG_DECADES = 2.0


def _tidy_log_axes(ax) -> None:
    for axis, limits in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        low, high = sorted(limits)
        if axis.get_scale() == "log" and low > 0 and high / low < 10.0 ** SHORT_LOG_DECADES:
            axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
            axis.set_minor_formatter(NullFormatter())


def _flatten(rows):
    return [panel for row in rows for panel in row]


def _in_label_order(runs: list[RunData], results: Results) -> list[RunData]:
    return sorted(runs, key=lambda run: results.labels.index(run.label))


def _finite(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    count = min(t.size, values.size)
    t, values = t[:count], values[:count]
    keep = np.isfinite(t) & np.isfinite(values)
    return t[keep], values[keep]
