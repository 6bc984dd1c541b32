"""The figures of an experiment, drawn from its results file alone (PNG and SVG).

Data flows one way: this module reads the HDF5 file written by ``simrun.store`` and nothing else,
so the figures can be redrawn from results without re-running (``simrun plot results.h5``).

Figures (each skipped when the file holds nothing it could show):
- ``energy_over_time``: E/E0 against t, one panel per dt, one line per integrator;
- ``energy_drift_vs_dt``: max |E - E0|/|E0| against dt (log-log), one line per integrator;
- ``stability_map``: integrators x dt, coloured by the log10 of the largest energy growth;
- ``newton_iterations_vs_dt``: mean Newton iterations per step against dt (implicit methods);
- ``orbits``: x-y trajectories of circular motion against the exact circle.

Runs that share every swept parameter other than dt and the integrator's own form a *group*; with
several groups, each figure gets a panel (or a row of panels) per group, titled by its parameters.
A consistent colour per integrator label (sorted labels -> tab10/tab20) runs through all figures.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")  # files only: no display, and safe in worker processes

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402
from matplotlib.colors import TwoSlopeNorm  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.transforms import blended_transform_factory  # noqa: E402

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
    return Results(name, runs, groups, labels, label_colours(labels), markers, _dt_names(sorted({run.dt for run in runs})))


def _read_run(run_id: str, group: h5py.Group) -> RunData:
    attrs = group.attrs

    def series(key: str) -> np.ndarray:
        return np.asarray(group[key][()], dtype=float) if key in group else np.empty(0)

    params = json.loads(_text(attrs.get("params", "{}")))
    swept = {key: value for key, value in params.items() if key != "dt" and not key.startswith("integrator.")}
    energy = series("energy")
    xy = None
    if _text(attrs.get("system", "")) == "circular_motion" and "positions" in group:
        positions = np.asarray(group["positions"][()], dtype=float)
        xy = positions[:, :2] if positions.ndim == 2 and positions.shape[1] >= 2 else np.empty((0, 2))
    return RunData(
        run_id=run_id,
        index=int(attrs.get("index", 0)),
        label=_text(attrs.get("integrator_label", attrs.get("integrator", run_id))),
        dt=float(attrs.get("dt", params.get("dt", math.nan))),
        status=_text(attrs.get("status", "ok")),
        explicit=bool(attrs.get("explicit", False)),
        system=_text(attrs.get("system", "")),
        system_params=json.loads(_text(attrs.get("system_params", "{}"))),
        group=json.dumps(swept, sort_keys=True),
        t=series("t"),
        energy=energy,
        energy_ref=_energy_ref(energy, series("kinetic_energy"), series("potential_energy")),
        newton_iterations=series("newton_iterations"),
        xy=xy,
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
def draw_figures(results_path: str | Path, out_dir: str | Path) -> list[Path]:
    """Draw every figure the results file supports into out_dir as PNG and SVG; returns the paths written."""
    results = load_results(results_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if not results.runs:
        return written
    for name, draw in FIGURES.items():
        figure = draw(results)
        if figure is None:
            continue
        try:
            for extension in FORMATS:
                target = out_dir / f"{name}.{extension}"
                # no creation date in the metadata, so redrawing the same file gives the same SVG
                metadata = {"Date": None} if extension == "svg" else None
                figure.savefig(target, dpi=PNG_DPI, metadata=metadata)
                written.append(target)
        finally:
            plt.close(figure)
    if any(run.system == "cloth" for run in results.runs):
        from simrun.cloth_figures import draw_cloth_snapshots  # reads the file only, like this module

        with h5py.File(results_path, "r") as file:
            written += draw_cloth_snapshots(file, out_dir)
    return written


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
    for (title, _), (labels, dts, growth, statuses), ax in zip(panels, tables, axes):
        image = ax.imshow(np.ma.masked_invalid(growth), cmap=cmap, norm=norm, aspect="auto", interpolation="nearest")
        for row, column in np.ndindex(growth.shape):
            _annotate_cell(ax, row, column, growth[row, column], statuses[row][column], norm)
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
    key = "blue: energy lost, red: gained" + ("\n" + ",   ".join(marks) if marks else "")
    more = f"  (first {MAX_GROUPS} of {len(results.groups)} groups)" if len(results.groups) > MAX_GROUPS else ""
    figure.suptitle(f"{results.name}: stability map" + more, fontsize=11)
    figure.supxlabel(key, fontsize=7.5, color="0.25")
    return figure


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


FIGURES = {
    "energy_over_time": energy_over_time,
    "energy_drift_vs_dt": energy_drift_vs_dt,
    "stability_map": stability_map,
    "newton_iterations_vs_dt": newton_iterations_vs_dt,
    "orbits": orbits,
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


def _flatten(rows):
    return [panel for row in rows for panel in row]


def _in_label_order(runs: list[RunData], results: Results) -> list[RunData]:
    return sorted(runs, key=lambda run: results.labels.index(run.label))


def _finite(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    count = min(t.size, values.size)
    t, values = t[:count], values[:count]
    keep = np.isfinite(t) & np.isfinite(values)
    return t[keep], values[keep]
