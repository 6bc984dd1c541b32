"""The contact colliders in the frame figures (simrun.figures.frames), drawn from the results file alone.

Tiny runs through simrun.run: a still model (no gravity) among colliders of every shape, each in view, where the
figure must draw it, and each drawn point must lie on the shape where it is at the panel's time t:
- 2-D, the 1 m square (4 vertices at (+-0.5, +-0.5)): a plane y = -1.45, a circle of radius 0.3 moving at
  (0, 1) m/s from (1.2, 0), a box, a capsule, a grid_sdf sampling |p - (0, -1.2)| - 0.2 (its zero level: that circle)
  and an obstacle polyline (mesh file);
- 3-D, a 1 m x 1 m grid of 2 x 2 vertices at z = 0: the ground z = -0.5, a sphere moving at (0.5, 0, 0) m/s, a box,
  a capsule, a torus, a grid_sdf (drawn as its grid's box, which the title says) and two obstacle triangles.
dt = 0.1 s for 0.2 s: frames (and panels) at t = 0, 0.1 and 0.2 s.
"""

from __future__ import annotations

import warnings

import matplotlib.pyplot as plt
import meshio
import numpy as np
import pytest
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import to_hex
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

import simrun
from simrun.figures import FIGURES, figure_data
from simrun.figures.colliders import COLLIDER_COLOUR, COLLIDER_NOTE, COLLIDER_REACH
from simrun.figures.frames import BOX_MARGIN, snapshot_grid, write_gif

TOLERANCE = 1e-9  # m: the drawn points are the shapes' own formulas, cut to the box (round-off only)
GRID_CENTRE, GRID_RADIUS, GRID_SPACING = np.array([0.0, -1.2]), 0.2, 0.05  # m: the 2-D grid_sdf's circle
# the zero level of the bilinear interpolant of |p - c| - r: off the circle by about h^2 / (8 r) (2e-3 m here)
GRID_TOLERANCE = GRID_SPACING**2 / GRID_RADIUS

COLLIDERS_2D = [
    {"shape": "plane", "normal": [0.0, 1.0], "point": [0.0, -1.45]},
    {"shape": "sphere", "center": [1.2, 0.0], "radius": 0.3, "velocity": [0.0, 1.0]},
    {"shape": "box", "center": [-1.2, 0.0], "half_extents": [0.2, 0.3]},
    {"shape": "capsule", "a": [-0.4, 1.0], "b": [0.4, 1.1], "radius": 0.15},
    "grid_sdf",  # written beside the run (see experiment)
    "mesh",
]
COLLIDERS_3D = [
    {"shape": "plane", "normal": [0.0, 0.0, 1.0], "point": [0.0, 0.0, -0.5]},
    {"shape": "sphere", "center": [0.5, 0.5, -0.5], "radius": 0.3, "velocity": [0.5, 0.0, 0.0]},
    {"shape": "box", "center": [1.6, 0.5, 0.0], "half_extents": [0.2, 0.3, 0.2]},
    {"shape": "capsule", "a": [-0.5, 0.0, 0.0], "b": [-0.5, 1.0, 0.2], "radius": 0.15},
    {"shape": "torus", "center": [0.5, 1.6, 0.0], "axis": [0.0, 1.0, 1.0], "major_radius": 0.3, "minor_radius": 0.08},
    "grid_sdf",
    "mesh",
]


def experiment(tmp_path, dim: int, colliders: list, name: str) -> dict:
    """A still model among the colliders (IPC: the obstacle meshes ask for it), 2 steps of 0.1 s; "grid_sdf" and
    "mesh" entries become files written into tmp_path."""
    entries = []
    for entry in colliders:
        if entry == "grid_sdf":
            entries.append(grid_file(tmp_path, dim))
        elif entry == "mesh":
            entries.append(mesh_file(tmp_path, dim))
        else:
            entries.append(entry)
    model = ({"square": {"segments": 1, "size": 1.0}} if dim == 2
             else {"grid": {"resolution": [2, 2], "size": [1.0, 1.0]}})
    system = {"type": "mass_spring", "model": model, "stiffness": 100.0, "mass": {"per_vertex": 0.1},
              "gravity": [0.0] * dim, "contact": {"method": "ipc", "dhat": 1e-3, "colliders": entries}}
    return {"name": name, "system": system, "integrators": ["backward_euler"], "duration": 0.2,
            "sweep": {"dt": [0.1]}, "solver": {"type": "newton", "tolerance": 1e-6, "max_iterations": 20}}


def grid_file(tmp_path, dim: int) -> dict:
    """2-D: |p - GRID_CENTRE| - GRID_RADIUS on 13 x 13 samples 0.05 m apart from (-0.3, -1.5); 3-D: a 3 x 3 x 3 grid
    of the same kind over [0.4, 0.6] x [-0.6, -0.4] x [-0.1, 0.1]."""
    if dim == 2:
        origin, count = np.array([-0.3, -1.5]), 13
        centre, radius = GRID_CENTRE, GRID_RADIUS
    else:
        origin, count = np.array([0.4, -0.6, -0.1]), 3
        centre, radius = origin + 0.1, 0.05
    axes = np.meshgrid(*(origin[axis] + GRID_SPACING * np.arange(count) for axis in range(dim)), indexing="ij")
    values = np.linalg.norm(np.stack(axes, axis=-1) - centre, axis=-1) - radius
    path = tmp_path / f"sdf{dim}.npz"
    np.savez(path, values=values, origin=origin, spacing=GRID_SPACING)
    return {"shape": "grid_sdf", "file": str(path)}


MESH_2D = np.array([[0.8, 0.6], [1.0, 0.8], [1.2, 0.6]])  # m, a V over the square's upper right, moved up 0.1 m
MESH_3D = np.array([[0.0, 0.0, 0.3], [1.0, 0.0, 0.3], [1.0, 1.0, 0.3], [0.0, 1.0, 0.3]])  # m, a square 0.3 m above


def mesh_file(tmp_path, dim: int) -> dict:
    """2-D: a polyline of two segments; 3-D: a square of two triangles (meshio's VTK files)."""
    points = np.column_stack([MESH_2D, np.zeros(3)]) if dim == 2 else MESH_3D
    cells = [("line", np.array([[0, 1], [1, 2]]))] if dim == 2 else [("triangle", np.array([[0, 1, 2], [0, 2, 3]]))]
    path = tmp_path / f"obstacle{dim}.vtk"
    meshio.write_points_cells(path, points, cells)
    return {"shape": "mesh", "file": str(path), **({"translate": [0.0, 0.1]} if dim == 2 else {})}


def run_figures(tmp_path, config: dict):
    """The snapshot figures of the config's results, drawn through the registry; no warning allowed."""
    results = simrun.run(config, output=tmp_path / config["name"], figures=False, progress=False, jobs=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures = FIGURES["snapshots"].draw(figure_data(results))
        for _, figure in figures:
            figure.savefig(tmp_path / f"{config['name']}.png", dpi=60)
    return results, figures


@pytest.fixture(scope="module", params=[2, 3], ids=["2d", "3d"])
def scene(request, tmp_path_factory):
    """(dim, results, the run's one snapshot figure) of the still model among every shape."""
    tmp_path = tmp_path_factory.mktemp(f"colliders{request.param}")
    colliders = COLLIDERS_2D if request.param == 2 else COLLIDERS_3D
    results, figures = run_figures(tmp_path, experiment(tmp_path, request.param, colliders, f"shapes{request.param}"))
    ((_, figure),) = figures
    yield request.param, results, figure
    plt.close(figure)


# -- what the panels hold -------------------------------------------------------------------------------
def panel_time(axes) -> float:
    """t (s) of a panel, from its title "t = 0.1 s"."""
    return float(axes.get_title().split()[2])


def drawn_points(axes, gid: str) -> np.ndarray:
    """(k, d) the points of the collider lines tagged gid (NaN rows between segments dropped)."""
    lines = [line for line in axes.get_lines() if line.get_gid() == gid]
    assert lines, f"no lines {gid}"
    points = np.concatenate([np.column_stack(line.get_data_3d() if hasattr(line, "get_data_3d") else line.get_data())
                             for line in lines])
    return points[np.isfinite(points).all(axis=1)]


def collider_gids(axes) -> set[str]:
    return {artist.get_gid() for artist in [*axes.get_lines(), *axes.collections] if artist.get_gid()}


def box(axes):
    limits = [axes.get_xlim(), axes.get_ylim()] + ([axes.get_zlim()] if hasattr(axes, "get_zlim") else [])
    return np.array(limits).T


def inside(points: np.ndarray, limits: np.ndarray) -> bool:
    return bool(np.all((points >= limits[0] - TOLERANCE) & (points <= limits[1] + TOLERANCE)))


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    s = np.clip((points - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(points - a - s[:, None] * (b - a), axis=1)


# -- the tests ------------------------------------------------------------------------------------------
def test_every_shape_is_drawn_in_every_panel_on_its_surface(scene):
    """Each collider's points lie on its shape moved by velocity * t of the panel, inside the panel's box: the plane
    n.(p - point) = 0, the sphere |p - c - v t| = r, the box's boundary max_i |p_i - c_i| / h_i = 1, the capsule
    at distance r from its segment, the torus sqrt((rho - R)^2 + z^2) = r, a 2-D grid_sdf on its zero level (the
    sampled circle), the obstacle on its file's vertices and segments."""
    dim, results, figure = scene
    (run,) = results.runs.values()
    assert len(figure.axes) == 3 and [panel_time(axes) for axes in figure.axes] == pytest.approx(run["frame_t"])
    specs = COLLIDERS_2D if dim == 2 else COLLIDERS_3D
    shapes = [entry if isinstance(entry, str) else entry["shape"] for entry in specs]
    for axes in figure.axes:
        t, limits = panel_time(axes), box(axes)
        assert collider_gids(axes) == {f"collider-{number}-{shape}" for number, shape in enumerate(shapes)}
        for number, (shape, spec) in enumerate(zip(shapes, specs)):
            points = drawn_points(axes, f"collider-{number}-{shape}")
            assert len(points) and inside(points, limits), shape
            if shape == "plane":
                normal = np.array(spec["normal"]) / np.linalg.norm(spec["normal"])
                assert np.abs((points - spec["point"]) @ normal).max() < TOLERANCE
            elif shape == "sphere":
                centre = np.array(spec["center"]) + np.array(spec["velocity"]) * t
                assert np.abs(np.linalg.norm(points - centre, axis=1) - spec["radius"]).max() < TOLERANCE
            elif shape == "box":
                scaled = np.abs(points - spec["center"]) / spec["half_extents"]
                assert np.abs(scaled.max(axis=1) - 1.0).max() < TOLERANCE
            elif shape == "capsule":
                distance = segment_distance(points, np.array(spec["a"]), np.array(spec["b"]))
                assert np.abs(distance - spec["radius"]).max() < TOLERANCE
            elif shape == "torus":
                axis = np.array(spec["axis"]) / np.linalg.norm(spec["axis"])
                local = points - spec["center"]
                height = local @ axis
                rho = np.linalg.norm(local - height[:, None] * axis, axis=1)
                tube = np.hypot(rho - spec["major_radius"], height)
                assert np.abs(tube - spec["minor_radius"]).max() < TOLERANCE
            elif shape == "grid_sdf" and dim == 2:
                distance = np.linalg.norm(points - GRID_CENTRE, axis=1)
                assert np.abs(distance - GRID_RADIUS).max() < GRID_TOLERANCE
            elif shape == "grid_sdf":  # 3-D: the grid's box [0.4, 0.5] x [-0.6, -0.5] x [-0.1, 0.0]
                low, high = np.array([0.4, -0.6, -0.1]), np.array([0.5, -0.5, 0.0])
                on_face = np.isclose(points, low).sum(axis=1) + np.isclose(points, high).sum(axis=1)
                assert inside(points, np.array([low, high])) and np.all(on_face >= 2)  # on its 12 edges
            elif shape == "mesh":
                vertices = MESH_2D + [0.0, 0.1] if dim == 2 else MESH_3D
                assert np.all(np.isclose(points[:, None, :], vertices[None]).all(axis=2).any(axis=1))


def test_the_colliders_are_drawn_beneath_the_model(scene):
    """Grey, translucent, and below every artist of the model (in 3-D the axes draw by zorder, not by depth)."""
    dim, _, figure = scene
    for axes in figure.axes:
        artists = [*axes.get_lines(), *axes.collections]
        colliders = [artist for artist in artists if artist.get_gid()]
        model = [artist for artist in artists if not artist.get_gid()]
        assert model and max(a.get_zorder() for a in colliders) < min(a.get_zorder() for a in model)
        assert all(artist.get_alpha() is not None and artist.get_alpha() < 1 for artist in colliders)
        assert {to_hex(line.get_color()) for line in axes.get_lines() if line.get_gid()} == {COLLIDER_COLOUR}
        faces = [artist for artist in colliders if isinstance(artist, (PolyCollection, Poly3DCollection))]
        assert faces  # the plane's solid side (2-D) or patch (3-D), the circle, box, capsule (2-D), the mesh (3-D)
        if dim == 3:
            assert axes.computed_zorder is False


def test_the_title_says_grey_shapes_are_colliders_and_what_is_left_out(scene):
    dim, _, figure = scene
    title = figure.get_suptitle()
    assert f"{COLLIDER_NOTE} (plane, sphere moving, box, capsule" in title
    assert ("grid_sdf collider drawn as its grid's box, not its surface" in title) == (dim == 3), title
    assert "outside the view" not in title and "not drawn" not in title


def test_the_snapshot_grid_and_the_gif_draw_the_colliders(scene, tmp_path):
    dim, results, _ = scene
    (run_id,) = results.runs
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grid = snapshot_grid(figure_data(results))
        try:
            grid.savefig(tmp_path / "grid.png", dpi=50)
            panels = [axes for axes in grid.axes if axes.get_title().startswith("t = ")]
            assert panels and all(len(collider_gids(axes)) == len(COLLIDERS_2D if dim == 2 else COLLIDERS_3D)
                                  for axes in panels)
            assert COLLIDER_NOTE in grid.subfigs[0]._suptitle.get_text()
        finally:
            plt.close(grid)
        assert write_gif(results, run_id, tmp_path / "run.gif").stat().st_size > 0


def test_a_plane_does_not_widen_the_view_and_one_out_of_view_is_named(tmp_path):
    """The 2-D square with two planes: one cutting the corner of the view (x + y = -1.04), one 10 m below. The view
    stays the square's box [-0.5, 0.5]^2 widened by BOX_MARGIN of its side on every side; the first plane's line
    lies on it within the view, the second is not drawn and the title says it is outside the view."""
    corner = {"shape": "plane", "normal": [1.0, 1.0], "point": [-0.52, -0.52]}
    far = {"shape": "plane", "normal": [0.0, 1.0], "point": [0.0, -10.0]}
    _, ((_, figure),) = run_figures(tmp_path, experiment(tmp_path, 2, [corner, far], "planes"))
    try:
        half = 0.5 + BOX_MARGIN * 1.0
        for axes in figure.axes:
            assert axes.get_xlim() == pytest.approx((-half, half)) and axes.get_ylim() == pytest.approx((-half, half))
            points = drawn_points(axes, "collider-0-plane")
            assert inside(points, box(axes)) and np.ptp(points[:, 0]) > 0
            assert np.abs(points.sum(axis=1) + 1.04).max() < TOLERANCE
            assert "collider-1-plane" not in collider_gids(axes)
        assert "plane 2 collider outside the view" in figure.get_suptitle()
    finally:
        plt.close(figure)


def test_a_big_box_widens_the_view_by_at_most_the_reach(tmp_path):
    """A 100 m box whose top is 0.5 m under the square: the view holds the square and the box within COLLIDER_REACH
    of the square's 1 m side (cut there, its top edge drawn), not the whole box."""
    floor = {"shape": "box", "center": [0.0, -51.0], "half_extents": [50.0, 50.0]}
    _, ((_, figure),) = run_figures(tmp_path, experiment(tmp_path, 2, [floor], "floor"))
    try:
        reach = 0.5 + COLLIDER_REACH * 1.0
        for axes in figure.axes:
            limits = box(axes)
            assert np.all(limits[0] >= -reach - 3 * BOX_MARGIN) and np.all(limits[1] <= reach + 3 * BOX_MARGIN)
            points = drawn_points(axes, "collider-0-box")
            assert inside(points, limits) and np.any(np.isclose(points[:, 1], -1.0))  # the top face y = -1
    finally:
        plt.close(figure)


def test_a_collider_not_drawn_is_named_in_the_title(tmp_path):
    """An obstacle mesh whose file is gone by the time the figure is drawn: the panels draw the rest, the title says
    the mesh is not drawn and why."""
    config = experiment(tmp_path, 2, [COLLIDERS_2D[1], "mesh"], "gone")
    results = simrun.run(config, output=tmp_path / "gone", figures=False, progress=False, jobs=1)
    (tmp_path / "obstacle2.vtk").unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ((_, figure),) = FIGURES["snapshots"].draw(figure_data(results))
    try:
        assert "mesh collider not drawn (cannot read obstacle2.vtk" in figure.get_suptitle()
        assert all(collider_gids(axes) == {"collider-0-sphere"} for axes in figure.axes)
    finally:
        plt.close(figure)


def test_a_model_without_contact_draws_no_collider(tmp_path):
    config = experiment(tmp_path, 2, [], "free")
    del config["system"]["contact"]
    _, ((_, figure),) = run_figures(tmp_path, config)
    try:
        assert COLLIDER_NOTE not in figure.get_suptitle()
        assert all(not collider_gids(axes) for axes in figure.axes)
        assert [type(collection) for collection in figure.axes[0].collections] == [PolyCollection, LineCollection]
    finally:
        plt.close(figure)


@pytest.mark.parametrize("dim", [2, 3])
def test_a_turning_box_is_drawn_turned(dim):
    """A box turning at 90 deg/s about a point off its centre (and moving) is drawn, at t = 0.5 s, with every drawn
    point on the surface of the box as the system turns it (phi = 0 within round-off, phi from ColliderContact)."""
    from simrun.figures.colliders import _collider, draw_collider
    from simrun.systems.contact.colliders import build_collider
    from simrun.systems.contact.model import ColliderContact

    entry = {"shape": "box", "center": [0.0] * dim, "half_extents": [0.3] * dim, "velocity": [0.1] * dim,
             "rotation": {"center": [0.1] * dim, "axis": [0.0, 0.0, 1.0] if dim == 2 else [0.0, 1.0, 0.0], "rate": 90.0}}
    drawn = _collider("box", entry, dim)
    figure = plt.figure()
    axes = figure.add_subplot(**({"projection": "3d"} if dim == 3 else {}))
    t = 0.5
    assert draw_collider(axes, drawn, 0, t, np.full(dim, -2.0), np.full(dim, 2.0))
    points = np.concatenate([np.column_stack(line.get_data_3d() if dim == 3 else line.get_data()) for line in axes.lines])
    points = points[np.all(np.isfinite(points), axis=1)]
    box = build_collider("box", dim, center=np.zeros(dim), half_extents=np.full(dim, 0.3), velocity=np.full(dim, 0.1))
    axis = np.array(entry["rotation"]["axis"])
    system_box = ColliderContact(box, None, (np.full(dim, 0.1), axis, np.radians(90.0)))
    assert points.shape[0] >= 8  # the outline's corners at least
    np.testing.assert_allclose(system_box.signed_distance(points, t), 0.0, atol=1e-12)
    plt.close(figure)
