"""Pictures of runs that keep frames of their vertex positions (the cloth): snapshots at a few times, a GIF on request.

A run's frames reshape to its system's declared ``frame_shape`` (rows x columns of the vertex grid)
and are drawn as a surface; spheres among the system's stored contact parameters are drawn with it.
"""

from __future__ import annotations

import numpy as np
from matplotlib import pyplot as plt
from matplotlib.animation import FuncAnimation, PillowWriter

from simrun.figures._data import FigureData, format_value
from simrun.results import Results, Status, StoredRun

SNAPSHOT_COUNT = 4
# A sweep of many such runs would drown its figure folder in snapshots: beyond this many runs,
# draw one per method and swept setting (its largest dt); `simrun animate` reaches any run.
MAX_SNAPSHOT_FIGURES = 12
GIF_FRAMES_MAX = 120  # a longer GIF only grows the file; 120 frames at 20 fps is 6 s
SNAPSHOT_DPI = 110
# One cell of the snapshot grid (in): four columns of 3D views fit the page's 1280 px at REPORT_DPI.
SNAPSHOT_CELL = (2.7, 2.4)
# The snapshot grid's title and row headings (in).
SNAPSHOT_TITLE_HEIGHT = 0.6


def frame_runs(results: Results) -> list[str]:
    """The runs with frames on a vertex grid: what snapshots and `simrun animate` can draw."""
    return [run.run_id for run in results.runs.values()
            if run.frame_shape is not None and "frames" in run.datasets and run["frame_t"].shape[0] > 0]


def snapshot_runs(results: Results) -> list[str]:
    """Every frame run, or for big sweeps one per integrator label and swept setting (its largest dt), at most
    MAX_SNAPSHOT_FIGURES of them, spread over the sweep."""
    runs = frame_runs(results)
    if len(runs) <= MAX_SNAPSHOT_FIGURES:
        return runs
    chosen: dict[tuple, tuple[float, str]] = {}
    for run_id in runs:
        run = results.runs[run_id]
        setting = tuple(sorted((key, str(value)) for key, value in run.params.items() if key != "dt"))
        key = (run.label, setting)
        if key not in chosen or run.dt > chosen[key][0]:
            chosen[key] = (run.dt, run_id)
    picks = sorted(run_id for _, run_id in chosen.values())
    if len(picks) <= MAX_SNAPSHOT_FIGURES:
        return picks
    # spread over the sweep (every method and swept value has a chance to appear), not its first settings
    return [picks[index] for index in np.unique(np.linspace(0, len(picks) - 1, MAX_SNAPSHOT_FIGURES).round().astype(int))]


def snapshots(data: FigureData) -> list[tuple[str, object]] | None:
    """One figure per frame run (see snapshot_runs): the vertex grid at SNAPSHOT_COUNT times spread over the run."""
    figures = []
    chosen, every = snapshot_runs(data.results), frame_runs(data.results)
    note = (f"\n{len(chosen)} of {len(every)} runs with frames drawn (one per method and setting at its largest dt, "
            "spread over the sweep; `simrun animate` draws any run)" if len(chosen) < len(every) else "")
    for run_id in chosen:
        run = data.results.runs[run_id]
        frames, times = run["frames"], run["frame_t"]
        picks = np.unique(np.linspace(0, frames.shape[0] - 1, SNAPSHOT_COUNT).round().astype(int))
        # a diverged run's last frame is the blow-up: frame the view on the frames before it
        shown = picks[:-1] if run.status is Status.DIVERGED and len(picks) > 1 else picks
        limits = _limits(frames[shown], _spheres(run))
        figure = plt.figure(figsize=(3.2 * len(picks), 3.6))
        for column, index in enumerate(picks):
            axes = figure.add_subplot(1, len(picks), column + 1, projection="3d")
            _draw_scene(axes, frames[index], run, limits)
            axes.set_title(f"t = {times[index]:.3g} s", fontsize=9)
        settings = "".join(f", {key} = {format_value(value)}" for key, value in run.swept.items())
        figure.suptitle(f"{run.label}{settings}, dt = {run.dt:g} s ({run.status}){note}", fontsize=10 if not note else 9)
        figure.tight_layout()
        figures.append((f"cloth_{run_id}", figure))
    return figures or None


def snapshot_grid(data: FigureData):
    """One figure of the frame runs (rows; simrun.figures.frames.snapshot_runs) at SNAPSHOT_COUNT times (columns),
    spread over the longest run and drawn at the same scale; a run that stopped earlier leaves its later cells empty."""
    run_ids = snapshot_runs(data.results)
    if not run_ids:
        return None
    runs = [data.results.runs[run_id] for run_id in run_ids]
    end = max(float(run["frame_t"][-1]) for run in runs)
    times = np.linspace(0.0, end, SNAPSHOT_COUNT)
    picks, shown = [], []
    for run in runs:
        t = np.asarray(run["frame_t"], dtype=float)
        spacing = (t[-1] - t[0]) / (len(t) - 1) if len(t) > 1 else 0.0
        row = [int(np.argmin(np.abs(t - time))) if time <= t[-1] + 0.5 * spacing + 1e-12 else None for time in times]
        picks.append(row)
        last = len(t) - 1
        # a diverged run's last frame is the blow-up: frame the view on the frames before it
        shown += [run["frames"][index] for index in row
                  if index is not None and not (run.status is Status.DIVERGED and index == last and last > 0)]
    spheres = [sphere for run in runs for sphere in _spheres(run)]
    limits = _limits(np.array(shown) if shown else runs[0]["frames"][:1], spheres)
    columns = len(times)
    width, height = SNAPSHOT_CELL
    figure = plt.figure(figsize=(columns * width, len(runs) * height + SNAPSHOT_TITLE_HEIGHT))
    title, body = figure.subfigures(2, 1, height_ratios=[SNAPSHOT_TITLE_HEIGHT, len(runs) * height])
    low, high = limits
    box = ", ".join(f"{name} {round(low[axis], 2) + 0.0:g} to {round(high[axis], 2) + 0.0:g} m" for axis, name in enumerate("xyz"))
    title.suptitle(f"{data.name}: snapshots (rows: runs; columns: times)\nevery cell the same box: {box}",
                   fontsize=10, y=0.75)
    for number, (subfigure, run, row) in enumerate(zip(body.subfigures(len(runs), 1, squeeze=False)[:, 0], runs, picks)):
        status = "" if run.status is Status.OK else f", {run.status}"
        if run.status is Status.DIVERGED and "t_diverged" in run.attrs:
            status += f" at t = {float(run.attrs['t_diverged']):.3g} s"
        subfigure.set_facecolor("#f4f6f9" if number % 2 == 0 else "white")  # rows told apart
        subfigure.text(0.01, 0.97, f"{run.label}, dt = {run.dt:g} s{status}", fontsize=9, fontweight="bold", va="top")
        subfigure.subplots_adjust(left=0.0, right=0.98, bottom=0.02, top=0.84, wspace=0.05)
        for column, index in enumerate(row):
            axes = subfigure.add_subplot(1, columns, column + 1, projection="3d")
            if index is None:
                axes.set_axis_off()
                axes.text2D(0.5, 0.5, f"run ended at t = {float(run['frame_t'][-1]):.3g} s", ha="center",
                            va="center", transform=axes.transAxes, fontsize=8, color="#5a6270")
                continue
            _draw_scene(axes, run["frames"][index], run, limits)
            axes.set_facecolor("none")
            axes.set_title(f"t = {float(run['frame_t'][index]):.3g} s", fontsize=8, pad=0)
            # one box for the whole grid, stated in its title: ticks in every cell would only crowd it
            axes.set_xlabel("")
            axes.set_ylabel("")
            axes.set_zlabel("")
            for axis in (axes.xaxis, axes.yaxis, axes.zaxis):
                axis.set_ticklabels([])
    return figure


def write_gif(results: Results, run_id: str, output, fps: int = 20):
    """An animated GIF of one frame run; returns its path."""
    run = results.runs[run_id]
    frames, times = run["frames"], run["frame_t"]
    label = f"{run.label}, dt = {run.dt:g} s"
    step = max(1, int(np.ceil(frames.shape[0] / GIF_FRAMES_MAX)))
    indices = np.r_[np.arange(0, frames.shape[0], step), frames.shape[0] - 1] if frames.shape[0] > 1 else np.array([0])
    indices = np.unique(indices)
    limits = _limits(frames[indices], _spheres(run))
    figure = plt.figure(figsize=(5, 4.5))
    axes = figure.add_subplot(projection="3d")

    def draw(number):
        axes.clear()
        _draw_scene(axes, frames[indices[number]], run, limits)
        axes.set_title(f"{label}\nt = {times[indices[number]]:.3f} s", fontsize=9)

    animation = FuncAnimation(figure, draw, frames=len(indices))
    output.parent.mkdir(parents=True, exist_ok=True)
    animation.save(output, writer=PillowWriter(fps=fps), dpi=80)
    plt.close(figure)
    return output


def _spheres(run: StoredRun) -> list[tuple[np.ndarray, float]]:
    """(centre (m), radius (m)) of each sphere among the system's stored contact parameters."""
    sphere = (run.system_params.get("contact") or {}).get("sphere")
    return [(np.array(sphere["center"], dtype=float), float(sphere["radius"]))] if sphere else []


def _draw_scene(axes, frame: np.ndarray, run: StoredRun, limits) -> None:
    grid = frame.reshape(*run.frame_shape, 3)
    axes.plot_surface(grid[..., 0], grid[..., 1], grid[..., 2], color="#4c72b0", edgecolor="#1f3552",
                      linewidth=0.2, alpha=0.9, shade=True)
    for centre, radius in _spheres(run):
        u, v = np.mgrid[0:2 * np.pi:24j, 0:np.pi:12j]
        axes.plot_wireframe(centre[0] + radius * np.cos(u) * np.sin(v), centre[1] + radius * np.sin(u) * np.sin(v),
                            centre[2] + radius * np.cos(v), color="#c44e52", linewidth=0.4)
    low, high = limits
    axes.set_xlim(low[0], high[0])
    axes.set_ylim(low[1], high[1])
    axes.set_zlim(low[2], high[2])
    axes.set_box_aspect(high - low)
    axes.set_xlabel("x (m)", fontsize=7)
    axes.set_ylabel("y (m)", fontsize=7)
    axes.set_zlabel("z (m)", fontsize=7)
    axes.tick_params(labelsize=6)


def _limits(frames: np.ndarray, spheres: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, np.ndarray]:
    finite = frames[np.isfinite(frames).all(axis=-1)]
    low, high = finite.min(axis=0), finite.max(axis=0)
    for centre, radius in spheres:
        low, high = np.minimum(low, centre - radius), np.maximum(high, centre + radius)
    span = np.maximum(high - low, 0.05 * max(float(np.max(high - low)), 1e-3))
    middle = (low + high) / 2
    return middle - span / 2, middle + span / 2
