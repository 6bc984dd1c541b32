"""Pictures of runs that keep frames of their vertex positions: snapshots at a few times, a GIF on request.

Any run with ``frames`` (frames, vertices, d) is drawn from the file alone: a 2-D model (``vertex_dim`` 2) in
the x-y plane at equal aspect, its springs as lines over its triangles (lightly filled where it has them); a
3-D model in perspective, its triangles shaded where it has them (a grid as today's shaded surface), else its
springs as lines. The springs and triangles are the run's ``model_edges`` and ``model_triangles`` (derived from
the grid for files written before them). Held vertices are marked by kind: pinned, on a prescribed path, sliding
(``model_constraints``; files written before it mark the vertices that never move).
The contact colliders are drawn beneath the model (figures/colliders.py).
"""

from __future__ import annotations


import numpy as np
from matplotlib import pyplot as plt
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from simrun.analysis.runs import format_value
from simrun.figures._data import FigureData
from simrun.figures.colliders import (COLLIDER_NOTE, COLLIDER_REACH, collider_boxes, collider_text, draw_collider,
                                      run_colliders)
from simrun.format.layout import VERTEX_KINDS
from simrun.format.summary import Status
from simrun.results import Results, StoredRun

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
# How the held vertices are marked (``StoredRun.model_constraints``), and the note that names each mark shown; files
# written before the kinds were stored mark the vertices that never move, as pinned.
HELD_MARKS = {VERTEX_KINDS["pinned"]: ("s", 1.0, "squares: pinned vertices"),
              VERTEX_KINDS["prescribed"]: ("^", 1.15, "triangles: vertices on a prescribed path"),
              VERTEX_KINDS["sliding"]: ("D", 0.8, "diamonds: sliding vertices")}
FIXED_NOTE = "squares: vertices that never move"
# The view box: no side shorter than this share of the longest (a rope or a flat cloth in 3-D would otherwise be a
# sliver whose ticks overlap; 2-D views keep equal aspect, so a thin model stays thin), and a margin around the
# model so that vertices on the box are not cut in half.
MIN_SIDE = {2: 0.05, 3: 0.2}
BOX_MARGIN = 0.04
VIEW_ZOOM = 0.8  # 3-D views a little smaller than their axes: room for the z label (a long x side pushes it out at 0.88)
TICK_BINS = 4  # at most this many ticks along an axis of a small panel


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
        limits = _limits(frames[shown], collider_boxes(run, times[shown]))
        fixed = _fixed_vertices(run, frames)
        figure = plt.figure(figsize=(3.2 * len(picks), 3.6))
        drawn: set[int] = set()
        for column, index in enumerate(picks):
            axes = figure.add_subplot(1, len(picks), column + 1, **_projection(run))
            drawn |= _draw_scene(axes, frames[index], times[index], run, limits, fixed)
            axes.set_title(f"t = {times[index]:.3g} s", fontsize=9)
        settings = "".join(f", {key} = {format_value(value)}" for key, value in run.swept.items())
        colliders = collider_text(run, drawn)
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
        boxes.setdefault(run.vertex_dim, []).extend(collider_boxes(run, t[framed]))
    limits = {}
    for dim in sorted({run.vertex_dim for run in runs}):
        frames = shown.get(dim) or [next(run for run in runs if run.vertex_dim == dim)["frames"][0]]
        # runs of other sizes (a swept resolution) have frames of other shapes: their vertices, pooled
        limits[dim] = _limits(np.concatenate([np.asarray(frame).reshape(-1, dim) for frame in frames]),
                              boxes.get(dim, []))
    extents = []
    for dim, (low, high) in limits.items():
        extent = ", ".join(f"{name} {round(low[axis], 2) + 0.0:g} to {round(high[axis], 2) + 0.0:g} m"
                           for axis, name in enumerate("xyz"[:dim]))
        extents.append(f"{dim}-D models {extent}" if len(limits) > 1 else extent)
    fixed = [_fixed_vertices(run, run["frames"]) for run in runs]
    columns = len(times)
    width, height = SNAPSHOT_CELL
    figure = plt.figure(figsize=(columns * width, len(runs) * height + SNAPSHOT_TITLE_HEIGHT))
    title, body = figure.subfigures(2, 1, height_ratios=[SNAPSHOT_TITLE_HEIGHT, len(runs) * height])
    notes = list(dict.fromkeys(part for run, kinds in zip(runs, fixed) if kinds.any()
                               for part in held_note(run, kinds).split("; ")))
    marked = "".join(f"; {note}" for note in notes)
    marked += f"; {COLLIDER_NOTE}" if any(run_colliders(run) for run in runs) else ""
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
        left_out = collider_text(run, drawn, legend=False)  # the legend is in the grid's title
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
    limits = _limits(frames[framed], collider_boxes(run, times[framed]))
    fixed = _fixed_vertices(run, frames)
    colliders = collider_text(run)
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
        # a finite-element model's lines are its elements' boundary edges; a mass-spring model's, its springs
        parts.append(f"{len(run.model_edges)} {'boundary edges' if run.system == 'fem' else 'springs'} as lines")
    return ", ".join(parts) + (f"; {held_note(run, fixed)}" if fixed.any() else "")


def _surface(run: StoredRun) -> bool:
    return run.model_triangles is not None and len(run.model_triangles) > 0


def _fixed_vertices(run: StoredRun, frames: np.ndarray) -> np.ndarray:
    """(vertices,) int8: the kind of each held vertex (HELD_MARKS; 0 free), as the run stored it; for files written
    before that, the vertices at the same place in every frame as pinned (none when nothing moves)."""
    kinds = run.model_constraints
    if kinds is not None and kinds.shape == (frames.shape[1],):
        return kinds
    if frames.shape[0] < 2:
        return np.zeros(frames.shape[1], dtype=np.int8)
    still = np.all(frames == frames[:1], axis=(0, 2))
    return (still if not still.all() else np.zeros_like(still)).astype(np.int8) * VERTEX_KINDS["pinned"]


def held_note(run: StoredRun, kinds: np.ndarray) -> str:
    """What the marks of ``kinds`` mean ("squares: pinned vertices; triangles: ..."), or FIXED_NOTE for a file
    without the stored kinds."""
    if run.model_constraints is None:
        return FIXED_NOTE
    return "; ".join(HELD_MARKS[kind][2] for kind in sorted(HELD_MARKS) if np.any(kinds == kind))


def _draw_held(axes, frame: np.ndarray, kinds: np.ndarray, near: np.ndarray, size: float) -> None:
    """The held vertices near the box, one marker per kind (HELD_MARKS)."""
    for kind, (marker, scale, _) in HELD_MARKS.items():
        chosen = near & (kinds == kind)
        if chosen.any():
            axes.plot(*(frame[chosen, axis] for axis in range(frame.shape[1])), linestyle="none", marker=marker,
                      markersize=size * scale, color=FIXED_COLOUR)


def _spring_width(count: int) -> float:
    return next((width for most, width in sorted(SPRING_WIDTH.items()) if count <= most), 0.35)


def _draw_scene(axes, frame: np.ndarray, t: float, run: StoredRun, limits, fixed: np.ndarray | None = None,
                zoom: float = VIEW_ZOOM) -> set[int]:
    """Draw one frame (vertices, d) of the run at time t (s) into axes (3-D axes for d = 3) inside the box
    limits = (low, high), over the run's colliders where they are at t; fixed: (vertices,) bool, the vertices to mark
    as never moving; zoom: of a 3-D view (1: it fills its axes). Returns the numbers (in run_colliders order) of the
    colliders with something inside the box."""
    fixed = np.zeros(frame.shape[0], dtype=bool) if fixed is None else fixed
    low, high = limits
    colliders = run_colliders(run)
    if colliders and run.vertex_dim == 3:
        axes.computed_zorder = False  # by zorder, not depth: the colliders stay beneath the model
    drawn = {number for number, collider in enumerate(colliders) if draw_collider(axes, collider, number, t, low, high)}
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
    free = near & (fixed == 0)
    axes.plot(frame[free, 0], frame[free, 1], linestyle="none", marker="o", markersize=2.5, color=EDGE_COLOUR)
    _draw_held(axes, frame, fixed, near, 4.5)


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
        free = near & (fixed == 0)
        axes.plot(frame[free, 0], frame[free, 1], frame[free, 2], linestyle="none", marker="o", markersize=2,
                  color=EDGE_COLOUR)
    _draw_held(axes, frame, fixed, near, 3.5)


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


