"""The contact colliders in the frame figures: read from a run's stored parameters, drawn where they are at a time.

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
from matplotlib.collections import PolyCollection
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from simrun.results import StoredRun

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


def run_colliders(run: StoredRun) -> tuple[_Collider, ...]:
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


def collider_text(run: StoredRun, drawn: set[int] | None = None, legend: bool = True) -> str:
    """What the titles say of the run's colliders: that grey shapes are the colliders (legend), e.g. "grey: the
    colliders (sphere, box, plane)", then what is not drawn: their notes and, given the numbers of those drawn in
    some panel, the colliders outside every panel's view; "" without colliders."""
    colliders = run_colliders(run)
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


def collider_boxes(run: StoredRun, times: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(low, high) (m) around each bounded collider of the run at each of the times (s); planes are unbounded."""
    boxes = []
    for collider in run_colliders(run):
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


def draw_collider(axes, collider: _Collider, number: int, t: float, low: np.ndarray, high: np.ndarray) -> bool:
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
