"""Pictures of cloth runs, drawn from the results file alone: snapshots at a few times, and a GIF on request."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.animation import FuncAnimation, PillowWriter  # noqa: E402

SNAPSHOT_COUNT = 4
# A sweep of many cloth runs would drown its figure folder in snapshots: beyond this many runs,
# draw one per method and swept setting (its largest dt); `simrun animate` reaches any run.
MAX_SNAPSHOT_FIGURES = 12
GIF_FRAMES_MAX = 120  # a longer GIF only grows the file; 120 frames at 20 fps is 6 s


def cloth_runs(file: h5py.File) -> list[str]:
    return [run_id for run_id, group in file["runs"].items()
            if group.attrs.get("system") == "cloth" and "frames" in group and group["frames"].shape[0] > 0]


def _grid(group: h5py.Group) -> tuple[int, int, dict]:
    params = json.loads(group.attrs["system_params"])
    nx, ny = params["resolution"]
    return nx, ny, params


def _draw_scene(axes, frame: np.ndarray, nx: int, ny: int, params: dict, limits) -> None:
    grid = frame.reshape(ny, nx, 3)
    axes.plot_surface(grid[..., 0], grid[..., 1], grid[..., 2], color="#4c72b0", edgecolor="#1f3552",
                      linewidth=0.2, alpha=0.9, shade=True)
    sphere = (params.get("contact") or {}).get("sphere")
    if sphere:
        u, v = np.mgrid[0:2 * np.pi:24j, 0:np.pi:12j]
        c, r = np.array(sphere["center"]), sphere["radius"]
        axes.plot_wireframe(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                            c[2] + r * np.cos(v), color="#c44e52", linewidth=0.4)
    low, high = limits
    axes.set_xlim(low[0], high[0])
    axes.set_ylim(low[1], high[1])
    axes.set_zlim(low[2], high[2])
    axes.set_box_aspect(high - low)
    axes.set_xlabel("x (m)", fontsize=7)
    axes.set_ylabel("y (m)", fontsize=7)
    axes.set_zlabel("z (m)", fontsize=7)
    axes.tick_params(labelsize=6)


def _limits(frames: np.ndarray, params: dict) -> tuple[np.ndarray, np.ndarray]:
    finite = frames[np.isfinite(frames).all(axis=-1)]
    low, high = finite.min(axis=0), finite.max(axis=0)
    sphere = (params.get("contact") or {}).get("sphere")
    if sphere:
        c, r = np.array(sphere["center"]), sphere["radius"]
        low, high = np.minimum(low, c - r), np.maximum(high, c + r)
    span = np.maximum(high - low, 0.05 * max(float(np.max(high - low)), 1e-3))
    middle = (low + high) / 2
    return middle - span / 2, middle + span / 2


def snapshot_runs(file: h5py.File) -> list[str]:
    """Every cloth run, or for big sweeps one per integrator label and swept setting: the largest dt."""
    runs = cloth_runs(file)
    if len(runs) <= MAX_SNAPSHOT_FIGURES:
        return runs
    chosen: dict[tuple, tuple[float, str]] = {}
    for run_id in runs:
        attrs = file["runs"][run_id].attrs
        params = json.loads(attrs["params"])
        setting = tuple(sorted((key, str(value)) for key, value in params.items() if key != "dt"))
        key = (str(attrs["integrator_label"]), setting)
        if key not in chosen or attrs["dt"] > chosen[key][0]:
            chosen[key] = (float(attrs["dt"]), run_id)
    return sorted(run_id for _, run_id in chosen.values())[:MAX_SNAPSHOT_FIGURES]


def draw_cloth_snapshots(file: h5py.File, out_dir: Path) -> list[Path]:
    """One figure per cloth run (see snapshot_runs): the cloth at SNAPSHOT_COUNT times spread over the run."""
    written = []
    for run_id in snapshot_runs(file):
        group = file["runs"][run_id]
        nx, ny, params = _grid(group)
        frames = group["frames"][()]
        times = group["frame_t"][()]
        picks = np.unique(np.linspace(0, frames.shape[0] - 1, SNAPSHOT_COUNT).round().astype(int))
        status = group.attrs["status"]
        # a diverged run's last frame is the blow-up: frame the view on the frames before it
        shown = picks[:-1] if status == "diverged" and len(picks) > 1 else picks
        limits = _limits(frames[shown], params)
        figure = plt.figure(figsize=(3.2 * len(picks), 3.6))
        for column, index in enumerate(picks):
            axes = figure.add_subplot(1, len(picks), column + 1, projection="3d")
            _draw_scene(axes, frames[index], nx, ny, params, limits)
            axes.set_title(f"t = {times[index]:.3g} s", fontsize=9)
        figure.suptitle(f"{group.attrs['integrator_label']}, dt = {group.attrs['dt']:g} s ({status})", fontsize=10)
        figure.tight_layout()
        for suffix in ("png", "svg"):
            path = out_dir / f"cloth_{run_id}.{suffix}"  # not with_suffix: run ids contain dots
            figure.savefig(path, dpi=110)
            written.append(path)
        plt.close(figure)
    return written


def write_gif(results_path: Path, run_id: str, output: Path, fps: int = 20) -> Path:
    """An animated GIF of one cloth run's frames."""
    with h5py.File(results_path, "r") as file:
        if run_id not in file["runs"]:
            raise KeyError(run_id)
        group = file["runs"][run_id]
        nx, ny, params = _grid(group)
        frames = group["frames"][()]
        times = group["frame_t"][()]
        label = f"{group.attrs['integrator_label']}, dt = {group.attrs['dt']:g} s"
    step = max(1, int(np.ceil(frames.shape[0] / GIF_FRAMES_MAX)))
    indices = np.r_[np.arange(0, frames.shape[0], step), frames.shape[0] - 1] if frames.shape[0] > 1 else np.array([0])
    indices = np.unique(indices)
    limits = _limits(frames[indices], params)
    figure = plt.figure(figsize=(5, 4.5))
    axes = figure.add_subplot(projection="3d")

    def draw(number):
        axes.clear()
        _draw_scene(axes, frames[indices[number]], nx, ny, params, limits)
        axes.set_title(f"{label}\nt = {times[indices[number]]:.3f} s", fontsize=9)

    animation = FuncAnimation(figure, draw, frames=len(indices))
    output.parent.mkdir(parents=True, exist_ok=True)
    animation.save(output, writer=PillowWriter(fps=fps), dpi=80)
    plt.close(figure)
    return output
