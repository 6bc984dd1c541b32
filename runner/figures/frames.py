"""Pictures of runs that keep frames of their vertex positions: snapshots at a few times, a GIF on request.

Any run with ``frames`` (frames, vertices, d) is drawn from the file alone: a 2-D model (``vertex_dim`` 2) in
the x-y plane at equal aspect, its springs as lines over its triangles (lightly filled where it has them); a
3-D model in perspective, its triangles shaded where it has them (a grid as today's shaded surface), else its
springs as lines. The springs and triangles are the run's ``model_edges`` and ``model_triangles`` (derived from
the grid for files written before them). Vertices that never move (pinned) are marked.

The contact colliders among the system's stored parameters (``system_params`` ``contact``: its ``colliders`` and the
``ground`` and ``sphere`` shorthands) are drawn lightly in grey beneath the model, each where it is at the frame's
time (moved by velocity * t): a plane as its line and solid side (2-D) or its patch (3-D) within the view; a sphere
as a circle or a wireframe; a box as a rectangle or its edges; a capsule as its outline or a wireframe of cylinder
and caps; a torus as a wireframe; a sampled SDF as its zero level (2-D) or its grid's box (3-D); an obstacle mesh
as its segments or triangles. A bounded collider widens the view to hold it (by at most COLLIDER_REACH of the
model's size), a plane never does. The titles say that grey shapes are the colliders and name what is not drawn.
"""

from __future__ import annotations

import contextlib
import functools
import io
import itertools
import math
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.spatial.transform
from matplotlib import pyplot as plt
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from simrun.figures._data import FigureData, format_value
from simrun.results import Results, Status, StoredRun

SNAPSHOT_COUNT = 4
# A sweep of many such runs would drown its figure folder in snapshots: beyond this many runs,
# draw one per method and swept setting (its largest dt); `simrun animate` reaches any run.
MAX_SNAPSHOT_FIGURES = 12
# The file names of the per-run snapshots: frames_<run_id> (any model with vertices: cloth, meshes, ropes, 2-D).
SNAPSHOT_PREFIX = "frames_"
GIF_FRAMES_MAX = 120  # a longer GIF only grows the file; 120 frames at 20 fps is 6 s
SNAPSHOT_DPI = 110
# One cell of the snapshot grid (in): four columns of 3D views fit the page's 1280 px at REPORT_DPI.
SNAPSHOT_CELL = (2.7, 2.4)
# The snapshot grid's title and row headings (in).
SNAPSHOT_TITLE_HEIGHT = 0.6
SURFACE_COLOUR, EDGE_COLOUR, SPRING_COLOUR = "#4c72b0", "#1f3552", "#2b4a7e"
FIXED_COLOUR = "#222222"
# Springs of a big model (a 64 x 64 grid has ~24 000) merge into a blue area: thinner lines the more there are.
SPRING_WIDTH = {100: 1.2, 1000: 0.7}  # at most this many springs -> line width (pt); beyond: 0.35 pt
FIXED_NOTE = "squares: vertices that never move"
# The view box: no side shorter than this share of the longest (a rope or a flat cloth in 3-D would otherwise be a
# sliver whose ticks overlap; 2-D views keep equal aspect, so a thin model stays thin), and a margin around the
# model so that vertices on the box are not cut in half.
MIN_SIDE = {2: 0.05, 3: 0.2}
BOX_MARGIN = 0.04
VIEW_ZOOM = 0.8  # 3-D views a little smaller than their axes: room for the z label (a long x side pushes it out at 0.88)
TICK_BINS = 4  # at most this many ticks along an axis of a small panel
# The colliders: light grey beneath the model, so that the model drawn over them stays readable.
COLLIDER_COLOUR = "#808080"
COLLIDER_FILL_ALPHA, COLLIDER_LINE_ALPHA = 0.2, 0.75
COLLIDER_WIDTH = 0.6  # pt
COLLIDER_ZORDER = 0.5  # beneath the model's collections (1) and markers (2)
COLLIDER_NOTE = "grey: the colliders"
# A bounded collider widens the view to hold it, by at most this share of the model's longest side on every side: a
# table-sized box under a small cloth would otherwise shrink the cloth to a few pixels. A plane never widens it.
COLLIDER_REACH = 1.0
CIRCLE_POINTS = 49  # points of a drawn circle (48 facets): round at a panel's size
SPHERE_WIRES = (6, 5)  # great circles through the poles, parallels between them: a 3-D sphere's wireframe
TORUS_WIRES = (16, 6)  # circles around the tube, circles around the axis
CAPSULE_WIRES = 8  # lines along a 3-D capsule's cylinder and half circles over each cap


def frame_runs(results: Results) -> list[str]:
    """The runs with frames of 2-D or 3-D vertices: what snapshots and `simrun animate` can draw."""
    return [run.run_id for run in results.runs.values()
            if run.vertex_dim in (2, 3) and run["frame_t"].shape[0] > 0]


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
    """One figure per frame run (see snapshot_runs): the model at SNAPSHOT_COUNT times spread over the run."""
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
        limits = _limits(frames[shown], _collider_boxes(run, times[shown]))
        fixed = _fixed_vertices(frames)
        figure = plt.figure(figsize=(3.2 * len(picks), 3.6))
        drawn: set[int] = set()
        for column, index in enumerate(picks):
            axes = figure.add_subplot(1, len(picks), column + 1, **_projection(run))
            drawn |= _draw_scene(axes, frames[index], times[index], run, limits, fixed)
            axes.set_title(f"t = {times[index]:.3g} s", fontsize=9)
        settings = "".join(f", {key} = {format_value(value)}" for key, value in run.swept.items())
        colliders = _collider_text(run, drawn)
        lines = "".join(f"\n{line}" for line in (colliders, note.lstrip("\n")) if line)  # a line each
        figure.suptitle(f"{run.label}{settings}, dt = {run.dt:g} s ({run.status}); {_model_text(run, fixed)}{lines}",
                        fontsize=10 if not lines else 9)
        figure.tight_layout()
        figures.append((f"{SNAPSHOT_PREFIX}{run_id}", figure))
    return figures or None


def snapshot_grid(data: FigureData):
    """One figure of the frame runs (rows; simrun.figures.frames.snapshot_runs) at SNAPSHOT_COUNT times (columns),
    spread over the longest run and drawn at the same scale (per vertex dimension); a run that stopped earlier
    leaves its later cells empty."""
    run_ids = snapshot_runs(data.results)
    if not run_ids:
        return None
    runs = [data.results.runs[run_id] for run_id in run_ids]
    end = max(float(run["frame_t"][-1]) for run in runs)
    times = np.linspace(0.0, end, SNAPSHOT_COUNT)
    picks, shown, boxes = [], {}, {}
    for run in runs:
        t = np.asarray(run["frame_t"], dtype=float)
        spacing = (t[-1] - t[0]) / (len(t) - 1) if len(t) > 1 else 0.0
        row = [int(np.argmin(np.abs(t - time))) if time <= t[-1] + 0.5 * spacing + 1e-12 else None for time in times]
        picks.append(row)
        last = len(t) - 1
        # a diverged run's last frame is the blow-up: frame the view on the frames before it
        framed = [index for index in row
                  if index is not None and not (run.status is Status.DIVERGED and index == last and last > 0)]
        shown.setdefault(run.vertex_dim, []).extend(run["frames"][index] for index in framed)
        boxes.setdefault(run.vertex_dim, []).extend(_collider_boxes(run, t[framed]))
    limits = {}
    for dim in sorted({run.vertex_dim for run in runs}):
        frames = shown.get(dim) or [next(run for run in runs if run.vertex_dim == dim)["frames"][0]]
        limits[dim] = _limits(np.array(frames), boxes.get(dim, []))
    extents = []
    for dim, (low, high) in limits.items():
        extent = ", ".join(f"{name} {round(low[axis], 2) + 0.0:g} to {round(high[axis], 2) + 0.0:g} m"
                           for axis, name in enumerate("xyz"[:dim]))
        extents.append(f"{dim}-D models {extent}" if len(limits) > 1 else extent)
    fixed = [_fixed_vertices(run["frames"]) for run in runs]
    columns = len(times)
    width, height = SNAPSHOT_CELL
    figure = plt.figure(figsize=(columns * width, len(runs) * height + SNAPSHOT_TITLE_HEIGHT))
    title, body = figure.subfigures(2, 1, height_ratios=[SNAPSHOT_TITLE_HEIGHT, len(runs) * height])
    marked = f"; {FIXED_NOTE}" if any(mask.any() for mask in fixed) else ""
    marked += f"; {COLLIDER_NOTE}" if any(_colliders(run) for run in runs) else ""
    title.suptitle(f"{data.name}: snapshots (rows: runs; columns: times{marked})\nevery cell the same box: "
                   + "; ".join(extents), fontsize=10, y=0.75)
    for number, (subfigure, run, row, still) in enumerate(
            zip(body.subfigures(len(runs), 1, squeeze=False)[:, 0], runs, picks, fixed)):
        status = "" if run.status is Status.OK else f", {run.status}"
        if run.status is Status.DIVERGED and "t_diverged" in run.attrs:
            status += f" at t = {float(run.attrs['t_diverged']):.3g} s"
        subfigure.set_facecolor("#f4f6f9" if number % 2 == 0 else "white")  # rows told apart
        heading = subfigure.text(0.01, 0.97, f"{run.label}, dt = {run.dt:g} s{status}", fontsize=9, fontweight="bold",
                                 va="top")
        subfigure.subplots_adjust(left=0.0, right=0.98, bottom=0.02, top=0.84, wspace=0.05)
        drawn: set[int] = set()
        for column, index in enumerate(row):
            axes = subfigure.add_subplot(1, columns, column + 1, **_projection(run))
            if index is None:
                axes.set_axis_off()
                (axes.text2D if run.vertex_dim == 3 else axes.text)(
                    0.5, 0.5, f"run ended at t = {float(run['frame_t'][-1]):.3g} s", ha="center",
                    va="center", transform=axes.transAxes, fontsize=8, color="#5a6270")
                continue
            drawn |= _draw_scene(axes, run["frames"][index], float(run["frame_t"][index]), run, limits[run.vertex_dim],
                                 still, zoom=1.0)  # no labels to fit
            axes.set_facecolor("none")
            axes.set_title(f"t = {float(run['frame_t'][index]):.3g} s", fontsize=8, pad=0)
            # one box for the whole grid, stated in its title: ticks in every cell would only crowd it
            axes.set_xlabel("")
            axes.set_ylabel("")
            axis_list = [axes.xaxis, axes.yaxis]
            if run.vertex_dim == 3:
                axes.set_zlabel("")
                axis_list.append(axes.zaxis)
            for axis in axis_list:
                axis.set_ticklabels([])
        left_out = _collider_text(run, drawn, legend=False)  # the legend is in the grid's title
        if left_out:
            heading.set_text(f"{heading.get_text()}; {left_out}")
    return figure


def write_gif(results: Results, run_id: str, output, fps: int = 20):
    """An animated GIF of one frame run; returns its path."""
    run = results.runs[run_id]
    frames, times = run["frames"], run["frame_t"]
    label = f"{run.label}, dt = {run.dt:g} s"
    step = max(1, int(np.ceil(frames.shape[0] / GIF_FRAMES_MAX)))
    indices = np.r_[np.arange(0, frames.shape[0], step), frames.shape[0] - 1] if frames.shape[0] > 1 else np.array([0])
    indices = np.unique(indices)
    # a diverged run's last frame is the blow-up: frame the view on the frames before it
    framed = indices[:-1] if run.status is Status.DIVERGED and len(indices) > 1 else indices
    limits = _limits(frames[framed], _collider_boxes(run, times[framed]))
    fixed = _fixed_vertices(frames)
    colliders = _collider_text(run)
    figure = plt.figure(figsize=(5, 4.5))
    axes = figure.add_subplot(**_projection(run))

    def draw(number):
        axes.clear()
        _draw_scene(axes, frames[indices[number]], times[indices[number]], run, limits, fixed)
        axes.set_title(f"{label}\nt = {times[indices[number]]:.3f} s{'; ' + colliders if colliders else ''}", fontsize=9)

    animation = FuncAnimation(figure, draw, frames=len(indices))
    output.parent.mkdir(parents=True, exist_ok=True)
    animation.save(output, writer=PillowWriter(fps=fps), dpi=80)
    plt.close(figure)
    return output


# -- drawing one frame --------------------------------------------------------------------------------
def _projection(run: StoredRun) -> dict:
    """add_subplot's keywords for the run's vertex dimension: perspective axes for 3-D, plain ones for 2-D."""
    return {"projection": "3d"} if run.vertex_dim == 3 else {}


def _model_text(run: StoredRun, fixed: np.ndarray) -> str:
    """What the pictures show, e.g. "2-D model, 9 vertices, 20 springs as lines"."""
    parts = [f"{run.vertex_dim}-D model", f"{run['frames'].shape[1]} vertices"]
    if _surface(run):
        parts.append(f"{len(run.model_triangles)} triangles " + ("shaded" if run.vertex_dim == 3 else "filled"))
    if run.model_edges is not None and not (_surface(run) and run.vertex_dim == 3):
        parts.append(f"{len(run.model_edges)} springs as lines")
    return ", ".join(parts) + (f"; {FIXED_NOTE}" if fixed.any() else "")


def _surface(run: StoredRun) -> bool:
    return run.model_triangles is not None and len(run.model_triangles) > 0


def _fixed_vertices(frames: np.ndarray) -> np.ndarray:
    """(vertices,) bool: the vertices at the same place in every frame (pinned ones), none when nothing moves."""
    if frames.shape[0] < 2:
        return np.zeros(frames.shape[1], dtype=bool)
    still = np.all(frames == frames[:1], axis=(0, 2))
    return still if not still.all() else np.zeros_like(still)


def _spring_width(count: int) -> float:
    return next((width for most, width in sorted(SPRING_WIDTH.items()) if count <= most), 0.35)


def _draw_scene(axes, frame: np.ndarray, t: float, run: StoredRun, limits, fixed: np.ndarray | None = None,
                zoom: float = VIEW_ZOOM) -> set[int]:
    """Draw one frame (vertices, d) of the run at time t (s) into axes (3-D axes for d = 3) inside the box
    limits = (low, high), over the run's colliders where they are at t; fixed: (vertices,) bool, the vertices to mark
    as never moving; zoom: of a 3-D view (1: it fills its axes). Returns the numbers (in _colliders order) of the
    colliders with something inside the box."""
    fixed = np.zeros(frame.shape[0], dtype=bool) if fixed is None else fixed
    low, high = limits
    colliders = _colliders(run)
    if colliders and run.vertex_dim == 3:
        axes.computed_zorder = False  # by zorder, not depth: the colliders stay beneath the model
    drawn = {number for number, collider in enumerate(colliders) if _draw_collider(axes, collider, number, t, low, high)}
    # a blown-up frame's far vertices (inf, NaN, 1e300) would be drawn outside the box and break the shading:
    # only the elements whose vertices are within the box, grown by its size on every side, are drawn
    margin = high - low
    near = np.all((frame >= low - margin) & (frame <= high + margin), axis=1)
    (_draw_3d if run.vertex_dim == 3 else _draw_2d)(axes, frame, run, fixed, near)
    axes.set_xlim(low[0], high[0])
    axes.set_ylim(low[1], high[1])
    axes.set_xlabel("x (m)", fontsize=7)
    axes.set_ylabel("y (m)", fontsize=7)
    if run.vertex_dim == 3:
        axes.set_zlim(low[2], high[2])
        axes.set_box_aspect(high - low, zoom=zoom)
        axes.set_zlabel("z (m)", fontsize=7)
        axes.zaxis.set_major_locator(MaxNLocator(TICK_BINS))
    else:
        axes.set_aspect("equal", adjustable="box")
    axes.xaxis.set_major_locator(MaxNLocator(TICK_BINS))
    axes.yaxis.set_major_locator(MaxNLocator(TICK_BINS))
    axes.tick_params(labelsize=6)
    return drawn


def _draw_2d(axes, frame: np.ndarray, run: StoredRun, fixed: np.ndarray, near: np.ndarray) -> None:
    """The x-y plane: triangles lightly filled (where the model has them), springs as lines, vertices as dots."""
    if _surface(run):
        axes.add_collection(PolyCollection(frame[_within(run.model_triangles, near)], facecolors=SURFACE_COLOUR,
                                           alpha=0.25, edgecolors="none"), autolim=False)
    if run.model_edges is not None:
        axes.add_collection(LineCollection(frame[_within(run.model_edges, near)], colors=SPRING_COLOUR,
                                           linewidths=_spring_width(len(run.model_edges))), autolim=False)
    free, still = near & ~fixed, near & fixed
    axes.plot(frame[free, 0], frame[free, 1], linestyle="none", marker="o", markersize=2.5, color=EDGE_COLOUR)
    if still.any():
        axes.plot(frame[still, 0], frame[still, 1], linestyle="none", marker="s", markersize=4.5, color=FIXED_COLOUR)


def _draw_3d(axes, frame: np.ndarray, run: StoredRun, fixed: np.ndarray, near: np.ndarray) -> None:
    """Perspective: a grid as a shaded surface, other triangle models as shaded triangles, else springs as lines."""
    grid = run.frame_shape if run.frame_shape is not None and len(run.frame_shape) == 2 else None
    if _surface(run) and grid is not None and np.prod(grid) == frame.shape[0] and near.all():
        surface = frame.reshape(*grid, 3)
        axes.plot_surface(surface[..., 0], surface[..., 1], surface[..., 2], color=SURFACE_COLOUR, edgecolor=EDGE_COLOUR,
                          linewidth=0.2, alpha=0.9, shade=True)
    elif _surface(run):
        triangles = _within(run.model_triangles, near)
        if len(triangles):
            axes.add_collection3d(Poly3DCollection(frame[triangles], facecolors=SURFACE_COLOUR, edgecolors=EDGE_COLOUR,
                                                   linewidths=0.2, alpha=0.9, shade=True), autolim=False)
    else:
        if run.model_edges is not None:
            axes.add_collection3d(Line3DCollection(frame[_within(run.model_edges, near)], colors=SPRING_COLOUR,
                                                   linewidths=_spring_width(len(run.model_edges))), autolim=False)
        free = near & ~fixed
        axes.plot(frame[free, 0], frame[free, 1], frame[free, 2], linestyle="none", marker="o", markersize=2,
                  color=EDGE_COLOUR)
    still = near & fixed
    if still.any():
        axes.plot(frame[still, 0], frame[still, 1], frame[still, 2], linestyle="none", marker="s", markersize=3.5,
                  color=FIXED_COLOUR)


def _within(elements: np.ndarray, near: np.ndarray) -> np.ndarray:
    """The elements (springs or triangles: rows of vertex indices) whose vertices are all near the box."""
    return elements[near[elements].all(axis=1)]


def _limits(frames: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The box (low, high) (m) around the frames' finite vertices and the colliders' boxes (low, high) (each cut to
    COLLIDER_REACH of the frames' longest side around them), BOX_MARGIN of its longest side wider on every side; no
    side shorter than MIN_SIDE of the longest."""
    finite = frames[np.isfinite(frames).all(axis=-1)]
    if finite.size == 0:  # every shown frame is the blow-up
        finite = np.zeros((1, frames.shape[-1]))
    low, high = finite.min(axis=0), finite.max(axis=0)
    reach = COLLIDER_REACH * max(float(np.max(high - low)), 1e-3)
    near_low, near_high = low - reach, high + reach
    for box_low, box_high in boxes:
        if box_low.shape != low.shape:
            continue
        box_low, box_high = np.maximum(box_low, near_low), np.minimum(box_high, near_high)
        if np.all(box_low <= box_high):  # a collider beyond the reach leaves the view as it is
            low, high = np.minimum(low, box_low), np.maximum(high, box_high)
    longest = max(float(np.max(high - low)), 1e-3)
    span = np.maximum(high - low, MIN_SIDE[frames.shape[-1]] * longest) + 2 * BOX_MARGIN * longest
    middle = (low + high) / 2
    return middle - span / 2, middle + span / 2


# -- the colliders --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Collider:
    """A collider as the figures draw it: its shape, its fields at t = 0 (arrays, m; for a grid_sdf its values, origin
    and spacing, for a mesh its points and cells), its velocity (d,) (m/s), its name ("ground" for the shorthand,
    else its shape), and what of it is not drawn, e.g. "not drawn (...)" ("" when all of it is drawn; ``fields`` is
    empty when none of it is)."""

    shape: str
    name: str
    fields: dict = field(default_factory=dict)
    velocity: np.ndarray | None = None
    note: str = ""
    spin: tuple | None = None  # (center (d,) m, unit axis (3,), rate rad/s) of a turning collider

    def turned(self, points: np.ndarray, t: float) -> np.ndarray:
        """Points (k, d) of the t = 0 shape (already moved by velocity t) turned about the moved centre by rate t."""
        if self.spin is None or not len(points):
            return points
        center, axis, rate = self.spin
        center = center + self.velocity * t
        return center + _rotate(points - center, axis, rate * t)


def _rotate(offsets: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """The rows of offsets (k, d) turned by angle (rad) about the unit axis (3,) (2-D: about z, axis[2]'s sign)."""
    turn = scipy.spatial.transform.Rotation.from_rotvec(angle * axis)
    if offsets.shape[1] == 3:
        return turn.apply(offsets)
    return turn.apply(np.column_stack([offsets, np.zeros(len(offsets))]))[:, :2]


def _colliders(run: StoredRun) -> tuple[_Collider, ...]:
    """The colliders of the run's stored contact parameters: the ``ground`` and ``sphere`` shorthands, then
    ``colliders`` in their order (what build_contact builds); () without contact or frames."""
    contact = run.system_params.get("contact")
    if not isinstance(contact, dict) or run.vertex_dim not in (2, 3):
        return ()
    dim = run.vertex_dim
    entries = []
    if isinstance(contact.get("ground"), dict):  # the plane last coordinate = height, solid below
        up = np.eye(dim)[-1]
        height = float(contact["ground"].get("height", -1.0))
        entries.append(("ground", {"shape": "plane", "normal": up, "point": height * up}))
    if isinstance(contact.get("sphere"), dict):
        entries.append(("sphere", {**contact["sphere"], "shape": "sphere"}))
    entries += [(str(entry.get("shape")), entry) for entry in contact.get("colliders") or [] if isinstance(entry, dict)]
    return tuple(_collider(name, entry, dim) for name, entry in entries)


def _collider(name: str, entry: dict, dim: int) -> _Collider:
    """One collider from its config entry, its files read; what cannot be drawn is said in its note."""
    shape = str(entry.get("shape"))

    def vector(key, size=dim):
        value = np.asarray(entry[key], dtype=float)
        if value.shape != (size,) or not np.all(np.isfinite(value)):
            raise ValueError(f"{key} is not {size} finite numbers")
        return value

    try:
        velocity = np.zeros(dim) if entry.get("velocity") is None else vector("velocity")
        collider = _shape(shape, name, entry, dim, vector, velocity)
        rotation = entry.get("rotation")
        if isinstance(rotation, dict) and float(rotation.get("rate", 0.0)) != 0.0 and collider.fields:
            axis = np.asarray(rotation.get("axis", [0.0, 0.0, 1.0]), dtype=float)
            center = np.asarray(rotation["center"], dtype=float)
            if center.shape != (dim,) or axis.shape != (3,) or not np.any(axis):
                raise ValueError("rotation is not {center, axis, rate} in the model's dimension")
            collider = replace(collider, spin=(center, axis / np.linalg.norm(axis), math.radians(float(rotation["rate"]))))
        return collider
    except (KeyError, TypeError, ValueError) as error:
        return _Collider(shape, name, note=f"not drawn ({error})")


def _shape(shape: str, name: str, entry: dict, dim: int, vector, velocity: np.ndarray) -> _Collider:
    """The collider of one config entry, without its rotation."""
    if shape == "plane":
        normal = vector("normal")
        if not np.any(normal):
            raise ValueError("normal is zero")
        point = np.zeros(dim) if entry.get("point") is None else vector("point")
        return _Collider(shape, name, {"normal": normal / np.linalg.norm(normal), "point": point}, velocity)
    if shape == "sphere":
        return _Collider(shape, name, {"center": vector("center"), "radius": float(entry["radius"])}, velocity)
    if shape == "box":
        return _Collider(shape, name, {"center": vector("center"), "half_extents": vector("half_extents")},
                         velocity)
    if shape == "capsule":
        return _Collider(shape, name, {"a": vector("a"), "b": vector("b"), "radius": float(entry["radius"])},
                         velocity)
    if shape == "torus":
        if dim != 3:
            return _Collider(shape, name, note="not drawn (a torus exists only in 3-D)")
        axis = vector("axis") if entry.get("axis") is not None else np.eye(3)[2]
        if not np.any(axis):
            raise ValueError("axis is zero")
        return _Collider(shape, name, {"center": vector("center"), "axis": axis / np.linalg.norm(axis),
                                       "major_radius": float(entry["major_radius"]),
                                       "minor_radius": float(entry["minor_radius"])}, velocity)
    if shape == "grid_sdf":
        return _grid_collider(name, entry, dim, velocity)
    if shape == "mesh":
        return _mesh_collider(name, entry, dim)
    return _Collider(shape, name, note="not drawn (a shape this figure does not know)")


def _grid_collider(name: str, entry: dict, dim: int, velocity: np.ndarray) -> _Collider:
    """A grid_sdf: its zero level in 2-D (when its samples change sign), else the grid's box."""
    path = Path(str(entry["file"]))  # absolute: the config loader resolved it
    origin, spacing = (None if value is None else tuple(np.ravel(value).tolist()) if np.ndim(value) else float(value)
                       for value in (entry.get("origin"), entry.get("spacing")))
    try:
        values, origin, spacing = _read_grid(str(path), _stamp(path), origin, spacing)
    except (OSError, ValueError) as error:
        return _unreadable("grid_sdf", name, path, error)
    if values.ndim != dim:
        return _Collider("grid_sdf", name, note=f"not drawn ({values.ndim}-D grid, {dim}-D model)")
    fields = {"values": values, "origin": origin, "spacing": spacing}
    if dim == 3:
        note = "drawn as its grid's box, not its surface"
    elif not (np.any(values < 0) and np.any(values > 0)):
        note = "drawn as its grid's box (its samples have no zero level)"
    else:
        note = ""
    return _Collider("grid_sdf", name, fields, velocity, note)


def _mesh_collider(name: str, entry: dict, dim: int) -> _Collider:
    """An obstacle mesh (static): its line cells in 2-D, its triangles in 3-D, as build_contact reads them."""
    path = Path(str(entry["file"]))  # absolute: the config loader resolved it
    kind = "triangle" if dim == 3 else "line"
    try:
        points, cells = _read_mesh(str(path), _stamp(path), kind)
    except (OSError, ValueError) as error:
        return _unreadable("mesh", name, path, error)
    if len(cells) == 0 or points.shape[1] < dim:
        return _Collider("mesh", name, note=f"not drawn ({path.name} has no {dim}-D {kind} cells)")
    if entry.get("translate") is not None:
        points = points[:, :dim] + np.asarray(entry["translate"], dtype=float)
    points = points[:, :dim]
    return _Collider("mesh", name, {"points": points, "cells": cells}, np.zeros(dim))


def _unreadable(shape: str, name: str, path: Path, error: Exception) -> _Collider:
    """A collider whose file cannot be read: not drawn, and why ("No such file or directory", not errno and path)."""
    reason = getattr(error, "strerror", None) or error
    return _Collider(shape, name, note=f"not drawn (cannot read {path.name}: {reason})")


def _stamp(path: Path) -> tuple[int, int]:
    """(size, modification time) of a file, which keys the caches below: a changed file is read again."""
    stat = path.stat()
    return stat.st_size, stat.st_mtime_ns


@functools.lru_cache(maxsize=8)
def _read_grid(path: str, stamp, origin: tuple | None, spacing: tuple | float | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(values, origin (d,) m, spacing (d,) m) of a grid_sdf file, read as the contact reads it; origin and spacing
    (m) override the file's."""
    from simrun.systems.contact.colliders import load_grid_sdf

    grid = load_grid_sdf(path, origin, spacing)
    return grid.values, grid.origin, grid.spacing


@functools.lru_cache(maxsize=8)
def _read_mesh(path: str, stamp, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """(points (m, 3) m, cells (c, 2 or 3)) of the cells of one kind in a mesh file meshio reads."""
    import meshio  # only mesh obstacles need it

    chatter = io.StringIO()
    try:  # some of meshio's readers print their complaint and exit: kept out of the figure's output
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            mesh = meshio.read(path)
    except (Exception, SystemExit) as error:  # meshio raises many kinds, each a bad file
        raise ValueError(" ".join(chatter.getvalue().split()) or f"{type(error).__name__}: {error}") from None
    cells = [block.data for block in mesh.cells if block.type == kind]
    return np.asarray(mesh.points, dtype=float), np.concatenate(cells or [np.zeros((0, 2))]).astype(np.intp)


def _collider_text(run: StoredRun, drawn: set[int] | None = None, legend: bool = True) -> str:
    """What the titles say of the run's colliders: that grey shapes are the colliders (legend), e.g. "grey: the
    colliders (sphere, box, plane)", then what is not drawn: their notes and, given the numbers of those drawn in
    some panel, the colliders outside every panel's view; "" without colliders."""
    colliders = _colliders(run)
    if not colliders:
        return ""
    counts = Counter(collider.name for collider in colliders)
    seen: Counter[str] = Counter()
    names = []  # "plane 1", "plane 2" when there are two
    for collider in colliders:
        seen[collider.name] += 1
        names.append(collider.name + (f" {seen[collider.name]}" if counts[collider.name] > 1 else ""))
    moving = [(collider.velocity is not None and bool(np.any(collider.velocity))) or collider.spin is not None
              for collider in colliders]
    listed = ", ".join(name + " moving" * move for name, move in zip(names, moving))
    parts = [f"{COLLIDER_NOTE} ({listed})"] if legend else []
    parts += [f"{name} collider {collider.note}" for name, collider in zip(names, colliders) if collider.note]
    if drawn is not None:
        parts += [f"{name} collider outside the view" for number, (name, collider) in enumerate(zip(names, colliders))
                  if collider.fields and number not in drawn]
    return "; ".join(parts)


def _collider_boxes(run: StoredRun, times: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(low, high) (m) around each bounded collider of the run at each of the times (s); planes are unbounded."""
    boxes = []
    for collider in _colliders(run):
        box = _bounds(collider) if collider.fields else None
        if box is not None:
            boxes += [(box[0] + collider.velocity * t, box[1] + collider.velocity * t) for t in np.atleast_1d(times)]
    return boxes


def _bounds(collider: _Collider) -> tuple[np.ndarray, np.ndarray] | None:
    """(low, high) (m) around the collider at t = 0; None for a plane."""
    f = collider.fields
    if collider.shape == "sphere":
        return f["center"] - f["radius"], f["center"] + f["radius"]
    if collider.shape == "box":
        return f["center"] - f["half_extents"], f["center"] + f["half_extents"]
    if collider.shape == "capsule":
        return np.minimum(f["a"], f["b"]) - f["radius"], np.maximum(f["a"], f["b"]) + f["radius"]
    if collider.shape == "torus":  # the core circle reaches R sqrt(1 - axis_i^2) along axis i
        half = f["major_radius"] * np.sqrt(np.clip(1 - f["axis"] ** 2, 0.0, None)) + f["minor_radius"]
        return f["center"] - half, f["center"] + half
    if collider.shape == "grid_sdf":
        return f["origin"], f["origin"] + (np.array(f["values"].shape) - 1) * f["spacing"]
    if collider.shape == "mesh":
        return f["points"].min(axis=0), f["points"].max(axis=0)
    return None


def _draw_collider(axes, collider: _Collider, number: int, t: float, low: np.ndarray, high: np.ndarray) -> bool:
    """Draw the collider where it is at time t (s) into axes, cut to the box (low, high): its faces translucent, its
    lines thin, both grey beneath the model, tagged with the gid "collider-<number>-<shape>". Returns whether any
    of it lies in the box."""
    if not collider.fields:
        return False
    dim = low.size
    if collider.spin is not None and collider.shape == "plane":  # a plane turns as its normal and point do
        center, axis, rate = collider.spin
        center = center + collider.velocity * t
        fields = {"normal": _rotate(collider.fields["normal"][None], axis, rate * t)[0],
                  "point": center + _rotate((collider.fields["point"] + collider.velocity * t - center)[None], axis, rate * t)[0]}
        lines, faces = _geometry(replace(collider, fields=fields, spin=None), np.zeros(dim), low, high)
    else:
        lines, faces = _geometry(collider, collider.velocity * t, low, high)
        lines = [collider.turned(line, t) for line in lines]
        faces = [collider.turned(face, t) for face in faces]
    segments = _clip_segments(lines, low, high)
    polygons = [polygon for polygon in (_clip_polygon(face, low, high) for face in faces) if len(polygon) >= 3]
    gid = f"collider-{number}-{collider.shape}"
    if polygons:
        style = {"facecolors": COLLIDER_COLOUR, "edgecolors": "none", "alpha": COLLIDER_FILL_ALPHA,
                 "zorder": COLLIDER_ZORDER}
        if dim == 3:
            axes.add_collection3d(Poly3DCollection(polygons, shade=False, **style), autolim=False).set_gid(gid)
        else:
            axes.add_collection(PolyCollection(polygons, **style), autolim=False).set_gid(gid)
    if len(segments):
        # one line per collider, its segments apart (NaN rows between them)
        points = np.concatenate([segments, np.full((len(segments), 1, dim), np.nan)], axis=1).reshape(-1, dim)
        axes.plot(*points.T, color=COLLIDER_COLOUR, alpha=COLLIDER_LINE_ALPHA, linewidth=COLLIDER_WIDTH,
                  zorder=COLLIDER_ZORDER, gid=gid)
    return bool(polygons) or len(segments) > 0


def _geometry(collider: _Collider, offset: np.ndarray, low: np.ndarray, high: np.ndarray
              ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(lines, faces) of the collider moved by offset (d,) (m): polylines (k, d) and polygons (k, d) to fill, in m,
    not yet cut to the box (low, high), which only sizes a plane."""
    f, dim, shape = collider.fields, low.size, collider.shape
    if shape == "plane":
        normal, point = f["normal"], f["point"] + offset
        middle, size = (low + high) / 2, float(np.linalg.norm(high - low))
        foot = middle - ((middle - point) @ normal) * normal  # the plane's point nearest the box's middle
        if dim == 2:  # its line across the box, and the box's part on its solid side (phi <= 0)
            along = np.array([-normal[1], normal[0]])
            box = np.array([low, [high[0], low[1]], high, [low[0], high[1]]])
            return [np.array([foot - size * along, foot + size * along])], [_clip_half(box, normal, normal @ point)]
        u, w = _across(normal)  # a square on the plane bigger than the box, cut to the box
        patch = _clip_polygon(foot + size * np.array([u + w, w - u, -u - w, u - w]), low, high)
        return ([_closed(patch)] if len(patch) >= 3 else []), [patch]
    if shape == "sphere":
        center, radius = f["center"] + offset, f["radius"]
        if dim == 2:
            circle = _circle(center, radius, *np.eye(2))
            return [circle], [circle[:-1]]
        axes3 = np.eye(3)
        meridians = [_circle(center, radius, np.cos(angle) * axes3[0] + np.sin(angle) * axes3[1], axes3[2])
                     for angle in np.pi * np.arange(SPHERE_WIRES[0]) / SPHERE_WIRES[0]]
        parallels = [_circle(center + radius * np.cos(polar) * axes3[2], radius * np.sin(polar), axes3[0], axes3[1])
                     for polar in np.pi * np.arange(1, SPHERE_WIRES[1] + 1) / (SPHERE_WIRES[1] + 1)]
        return meridians + parallels, []
    if shape == "box":
        return _box_geometry(f["center"] - f["half_extents"] + offset, f["center"] + f["half_extents"] + offset)
    if shape == "grid_sdf":
        if dim == 3 or collider.note:  # no zero level drawn (see _grid_collider): the grid's box
            grid_low, grid_high = _bounds(collider)
            return _box_geometry(grid_low + offset, grid_high + offset)
        import contourpy  # matplotlib's own contouring: the zero level of the bilinear interpolant

        values, origin = f["values"], f["origin"] + offset
        x, y = (origin[axis] + f["spacing"][axis] * np.arange(values.shape[axis]) for axis in range(2))
        return list(contourpy.contour_generator(x, y, values.T, line_type="Separate").lines(0.0)), []
    if shape == "capsule":
        a, b, radius = f["a"] + offset, f["b"] + offset, f["radius"]
        axis = (b - a) / np.linalg.norm(b - a)
        if dim == 2:  # two half circles joined by the straight sides
            start = np.arctan2(axis[1], axis[0]) - np.pi / 2
            half = np.linspace(0.0, np.pi, CIRCLE_POINTS // 2 + 1)
            outline = np.concatenate([end + radius * np.column_stack([np.cos(start + turn + half),
                                                                      np.sin(start + turn + half)])
                                      for end, turn in ((b, 0.0), (a, np.pi))])
            return [_closed(outline)], [outline]
        u, w = _across(axis)
        angles = 2 * np.pi * np.arange(CAPSULE_WIRES) / CAPSULE_WIRES
        spokes = [np.cos(angle) * u + np.sin(angle) * w for angle in angles]
        quarter = np.linspace(0.0, np.pi / 2, CIRCLE_POINTS // 4 + 1)[:, None]
        lines = [_circle(a, radius, u, w), _circle(b, radius, u, w)]
        lines += [np.array([a + radius * spoke, b + radius * spoke]) for spoke in spokes]
        lines += [end + radius * (np.cos(quarter) * spoke + np.sin(quarter) * direction)
                  for end, direction in ((a, -axis), (b, axis)) for spoke in spokes]
        return lines, []
    if shape == "torus":
        center, axis, major, minor = f["center"] + offset, f["axis"], f["major_radius"], f["minor_radius"]
        u, w = _across(axis)
        tubes = [_circle(center + major * (np.cos(angle) * u + np.sin(angle) * w), minor,
                         np.cos(angle) * u + np.sin(angle) * w, axis)
                 for angle in 2 * np.pi * np.arange(TORUS_WIRES[0]) / TORUS_WIRES[0]]
        rings = [_circle(center + minor * np.sin(angle) * axis, major + minor * np.cos(angle), u, w)
                 for angle in 2 * np.pi * np.arange(TORUS_WIRES[1]) / TORUS_WIRES[1]]
        return tubes + rings, []
    if shape == "mesh":
        elements = f["points"][f["cells"]]  # (c, 2, 2) segments or (c, 3, 3) triangles
        if dim == 2:
            return list(elements), []
        return [_closed(triangle) for triangle in elements], list(elements)
    return [], []


def _box_geometry(low: np.ndarray, high: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """An axis-aligned box: a filled rectangle with its outline (2-D), its 12 edges (3-D)."""
    if low.size == 2:
        rectangle = np.array([low, [high[0], low[1]], high, [low[0], high[1]]])
        return [_closed(rectangle)], [rectangle]
    corners = np.array([np.where(bits, high, low) for bits in itertools.product((False, True), repeat=3)])
    edges = [np.array([corners[i], corners[j]]) for i, j in itertools.combinations(range(8), 2)
             if bin(i ^ j).count("1") == 1]  # corners that differ along one axis
    return edges, []


def _across(unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors normal to unit (3,) and to each other."""
    axis = np.eye(3)[np.argmin(np.abs(unit))]  # the coordinate axis least aligned with unit
    u = axis - (axis @ unit) * unit
    u /= np.linalg.norm(u)
    return u, np.cross(unit, u)


def _circle(center: np.ndarray, radius: float, u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(CIRCLE_POINTS, d) closed polyline center + radius (cos a u + sin a w), a from 0 to 2 pi."""
    angles = np.linspace(0.0, 2 * np.pi, CIRCLE_POINTS)[:, None]
    return center + radius * (np.cos(angles) * u + np.sin(angles) * w)


def _closed(polygon: np.ndarray) -> np.ndarray:
    return np.concatenate([polygon, polygon[:1]])


def _clip_segments(lines: list[np.ndarray], low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(m, 2, d) the parts inside the box (low, high) of the polylines' segments (Liang-Barsky: a segment
    p + s (q - p), s in [0, 1], is inside for s between the last entry through a face and the first exit)."""
    lines = [line for line in lines if len(line) >= 2]
    if not lines:
        return np.zeros((0, 2, low.size))
    segments = np.concatenate([np.stack([line[:-1], line[1:]], axis=1) for line in lines])
    start, step = segments[:, 0], segments[:, 1] - segments[:, 0]
    enter, leave = np.zeros(len(segments)), np.ones(len(segments))
    outside = np.zeros(len(segments), dtype=bool)
    for axis in range(low.size):
        for sign, bound in ((1.0, low[axis]), (-1.0, high[axis])):
            rate, gap = sign * step[:, axis], sign * (start[:, axis] - bound)  # inside where gap + s rate >= 0
            crossing = np.divide(-gap, rate, out=np.zeros_like(gap), where=rate != 0)
            enter = np.where(rate > 0, np.maximum(enter, crossing), enter)
            leave = np.where(rate < 0, np.minimum(leave, crossing), leave)
            outside |= (rate == 0) & (gap < 0)
    keep = ~outside & (enter <= leave)
    return np.stack([start + enter[:, None] * step, start + leave[:, None] * step], axis=1)[keep]


def _clip_polygon(polygon: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The part (k, d) of a flat convex polygon (n, d) inside the box (low, high): cut by each face in turn."""
    if np.all((polygon >= low) & (polygon <= high)):
        return polygon
    for axis in range(low.size):
        unit = np.eye(low.size)[axis]
        polygon = _clip_half(_clip_half(polygon, -unit, -low[axis]), unit, high[axis])
    return polygon


def _clip_half(polygon: np.ndarray, normal: np.ndarray, level: float) -> np.ndarray:
    """The part of a polygon (n, d) where normal . p <= level (Sutherland-Hodgman against one plane)."""
    if len(polygon) == 0:
        return polygon
    height = polygon @ normal - level
    if np.all(height <= 0):
        return polygon
    kept = []
    for index in range(len(polygon)):
        after = (index + 1) % len(polygon)
        p, q, hp, hq = polygon[index], polygon[after], height[index], height[after]
        if hp <= 0:
            kept.append(p)
        if (hp < 0 < hq) or (hq < 0 < hp):  # the edge crosses the plane
            kept.append(p + hp / (hp - hq) * (q - p))
    return np.array(kept) if kept else np.zeros((0, polygon.shape[1]))
