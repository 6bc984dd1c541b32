"""Frames of any model with vertices, read and drawn from the file alone: the reader's vertex_dim, model_edges and
model_triangles, the snapshot figures and `simrun animate`, in 2-D and 3-D, with lines and with shaded triangles.

The results files are written here with h5py in the documented layout (docs/results-format.md), so that the
reader and the pictures are tested against the format rather than against one writer:
- ``square``: the course code's 2-D square, 3 x 3 vertices 0.5 m apart with horizontal, vertical and both diagonal
  springs (20), no triangles, released from a 1.4x stretch along x: x(t) = x_rest (1 + 0.4 cos(2 pi t));
- ``mesh``: a triangulated disc of radius 0.5 m (3-D, ``frame_shape`` empty) sagging over time, z = -a t r^2;
- ``rope``: 10 vertices on a 0.9 m line, vertex 0 pinned, swinging down in the x-z plane (springs only);
- tests/data/format1_cloth.h5: a 4 x 3 cloth of format 1 (frames (F, 12, 3), no vertex_dim nor model_edges).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import h5py
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import LineCollection, PolyCollection
from mpl_toolkits.mplot3d import Axes3D
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from simrun.cli import main
from simrun.figures import figure_data
from simrun.figures.frames import SNAPSHOT_COUNT, frame_runs, snapshot_grid, snapshots
from simrun.results import load

DATA = Path(__file__).parent / "data"
FORMAT1_CLOTH = DATA / "format1_cloth.h5"
FRAME_COUNT = 11
FRAME_T = np.linspace(0.0, 1.0, FRAME_COUNT)


# -- the models ---------------------------------------------------------------------------------------
def square_model() -> dict:
    """3 x 3 vertices 0.5 m apart (vertex = row * 3 + column); 6 horizontal, 6 vertical, 8 diagonal springs."""
    index = np.arange(9).reshape(3, 3)
    pairs = [(index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :]),
             (index[:-1, :-1], index[1:, 1:]), (index[:-1, 1:], index[1:, :-1])]
    edges = np.concatenate([np.stack([a.ravel(), b.ravel()], axis=1) for a, b in pairs]).astype(np.int32)
    rows, columns = np.divmod(np.arange(9), 3)
    rest = np.stack([0.5 * columns - 0.5, 0.5 * rows - 0.5], axis=1)
    stretch = 1.0 + 0.4 * np.cos(2 * np.pi * FRAME_T)
    frames = np.stack([rest * [s, 1.0 / math.sqrt(s)] for s in stretch])
    return {"frames": frames, "edges": edges, "triangles": None, "frame_shape": ()}


def mesh_model() -> dict:
    """A disc of radius 0.5 m: a centre vertex and rings of 6 and 12, triangulated (Delaunay); sags as z = -0.4 t r^2."""
    from scipy.spatial import Delaunay

    points = [(0.0, 0.0)] + [(radius * math.cos(angle), radius * math.sin(angle))
                             for radius, count in ((0.25, 6), (0.5, 12))
                             for angle in np.linspace(0, 2 * np.pi, count, endpoint=False)]
    points = np.array(points)
    triangles = Delaunay(points).simplices.astype(np.int32)
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1),
                      axis=0).astype(np.int32)
    r2 = (points ** 2).sum(axis=1)
    frames = np.stack([np.column_stack([points, -0.4 * t * (1.0 - 4.0 * r2) - 0.2 * t]) for t in FRAME_T])
    return {"frames": frames, "edges": edges, "triangles": triangles, "frame_shape": ()}


def rope_model() -> dict:
    """10 vertices 0.1 m apart along x from the origin, vertex 0 fixed; rotates down by up to 80 degrees in x-z."""
    s = 0.1 * np.arange(10)
    edges = np.concatenate([np.stack([np.arange(9), np.arange(1, 10)], axis=1),
                            np.stack([np.arange(8), np.arange(2, 10)], axis=1)]).astype(np.int32)
    frames = []
    for t in FRAME_T:
        angle = np.radians(80.0) * t * (0.6 + 0.4 * s / s[-1])  # the free end lags: a bent rope
        frames.append(np.column_stack([s * np.cos(angle), np.zeros_like(s), -s * np.sin(angle)]))
    return {"frames": np.array(frames), "edges": edges, "triangles": None, "frame_shape": ()}


MODELS = {"square": square_model, "mesh": mesh_model, "rope": rope_model}


def write_results(path: Path, model: dict, labels=("backward_euler", "implicit_midpoint")) -> Path:
    """A format-2 results file of one run per label, each with the model's frames (the second run's a little
    different), in the layout of docs/results-format.md."""
    with h5py.File(path, "w") as file:
        file.attrs.update({"format_version": 2, "name": path.stem, "config": ""})
        for index, label in enumerate(labels):
            group = file.create_group(f"runs/{index:04d}-{label}-dt=0.01")
            frames = model["frames"] * (1.0 + 0.02 * index)
            samples = np.linspace(0.0, 1.0, 21)
            group.attrs.update({
                "index": index, "system": "mass_spring", "system_params": json.dumps({"type": "mass_spring"}),
                "integrator": label, "integrator_label": label, "order": 1, "explicit": False,
                "solver": json.dumps({"type": "newton"}), "dt": 0.01, "duration": 1.0, "status": "ok", "steps": 100,
                "planned_steps": 100, "wall_time": 0.1, "params": json.dumps({"dt": 0.01}), "message": "",
                "final_error": math.nan, "test_frequency": math.nan, "length_scale": 1.0, "energy_scale": 1.0,
                "energy_reference_name": "E0", "frame_shape": np.array(model["frame_shape"], dtype=np.int64),
                "planar": False, "dof_count": frames[0].size, "vertex_dim": frames.shape[2]})
            for key in ("energy", "kinetic_energy", "potential_energy"):
                group.create_dataset(key, data=np.cos(samples) ** 2 if key != "potential_energy" else np.zeros(21))
            group.create_dataset("t", data=samples)
            for key in ("newton_iterations", "linear_iterations", "line_search_steps"):
                group.create_dataset(key, data=np.full(100, 2, dtype=np.int32))
            group.create_dataset("frames", data=frames)
            group.create_dataset("frame_t", data=FRAME_T)
            group.create_dataset("model_edges", data=model["edges"])
            if model["triangles"] is not None:
                group.create_dataset("model_triangles", data=model["triangles"])
    return path


@pytest.fixture(params=sorted(MODELS))
def model_file(request, tmp_path) -> tuple[str, dict, Path]:
    model = MODELS[request.param]()
    return request.param, model, write_results(tmp_path / f"{request.param}.h5", model)


# -- the reader ---------------------------------------------------------------------------------------
def test_the_accessors_return_the_stored_model(model_file):
    name, model, path = model_file
    for run in load(path).runs.values():
        assert run.vertex_dim == model["frames"].shape[2]
        assert run.model_edges.shape == model["edges"].shape and np.array_equal(run.model_edges, model["edges"])
        if model["triangles"] is None:
            assert run.model_triangles is None
        else:
            assert np.array_equal(run.model_triangles, model["triangles"])
        assert run.frame_shape is None  # not a grid


def test_a_format1_cloth_derives_its_dimension_edges_and_triangles_from_the_grid():
    """A 4 x 3 cloth (resolution [nx, ny] = [4, 3], size 1 m x 1 m) of format 1: vertex_dim 3 from the frames; edges
    between row and column neighbours (3 rows x 3 + 2 x 4 columns = 17) of length 1/3 m or 1/2 m in the flat first
    frame; two triangles per cell (2 x 3 x 2 = 12) that cover the 1 m^2 of the cloth."""
    run = next(iter(load(FORMAT1_CLOTH).runs.values()))
    assert (run.vertex_dim, run.frame_shape) == (3, (3, 4))
    first = run["frames"][0]
    assert np.ptp(first[:, 2]) == 0  # starts flat
    edges = run.model_edges
    assert edges.shape == (17, 2) and len({tuple(sorted(edge)) for edge in edges.tolist()}) == 17
    rows, columns = np.divmod(edges, 4)
    assert np.all(np.abs(rows[:, 0] - rows[:, 1]) + np.abs(columns[:, 0] - columns[:, 1]) == 1)
    lengths = np.linalg.norm(first[edges[:, 0]] - first[edges[:, 1]], axis=1)
    assert np.allclose(np.sort(np.unique(lengths.round(12))), [1 / 3, 1 / 2])
    triangles = run.model_triangles
    assert triangles.shape == (12, 3)
    a, b, c = (first[triangles[:, k]] for k in range(3))
    assert np.isclose(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum(), 1.0)


def test_runs_without_frames_have_no_vertices():
    for run in load(DATA / "format1_circ.h5").runs.values():
        assert (run.vertex_dim, run.model_edges, run.model_triangles) == (0, None, None)


# -- the snapshot figures -----------------------------------------------------------------------------
def collections(axes) -> set[type]:
    return {type(collection) for collection in axes.collections}


def expected_collection(name: str) -> type:
    return {"square": LineCollection, "mesh": Poly3DCollection, "rope": Line3DCollection, "cloth": Poly3DCollection}[name]


def check_panel(name: str, axes, labelled: bool = True) -> None:
    assert isinstance(axes, Axes3D) == (name != "square")
    assert expected_collection(name) in collections(axes), (name, collections(axes))
    if name == "rope":  # lines only
        assert Poly3DCollection not in collections(axes)
    if name == "square":
        assert axes.get_aspect() == 1.0 and PolyCollection not in collections(axes)
    if not labelled:  # the grid states its one box in its title instead
        return
    assert axes.get_xlabel() == "x (m)" and axes.get_ylabel() == "y (m)"
    if isinstance(axes, Axes3D):
        assert axes.get_zlabel() == "z (m)"


@pytest.mark.parametrize("name", [*sorted(MODELS), "cloth"])
def test_one_snapshot_figure_per_run_with_one_panel_per_time(name, tmp_path):
    path = FORMAT1_CLOTH if name == "cloth" else write_results(tmp_path / f"{name}.h5", MODELS[name]())
    results = load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures = snapshots(figure_data(results))
        try:
            assert [figure_name for figure_name, _ in figures] == [f"frames_{run_id}" for run_id in results.runs]
            for run, (_, figure) in zip(results.runs.values(), figures):
                figure.savefig(tmp_path / "snapshot.png", dpi=60)
                assert len(figure.axes) == min(SNAPSHOT_COUNT, run["frame_t"].size)  # format1_cloth: 4 and 3 frames
                for axes in figure.axes:
                    check_panel(name, axes)
        finally:
            for _, figure in figures:
                plt.close(figure)


@pytest.mark.parametrize("name", [*sorted(MODELS), "cloth"])
def test_the_snapshot_grid_has_a_row_per_run(name, tmp_path):
    path = FORMAT1_CLOTH if name == "cloth" else write_results(tmp_path / f"{name}.h5", MODELS[name]())
    results = load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figure = snapshot_grid(figure_data(results))
        try:
            figure.savefig(tmp_path / "grid.png", dpi=60)
            shown = [axes for axes in figure.axes if axes.get_title().startswith("t = ")]
            ended = [axes for axes in figure.axes if axes not in shown]
            assert len(figure.axes) == len(results.runs) * SNAPSHOT_COUNT
            assert all(axes.texts for axes in ended)  # "run ended at t = ..."
            for axes in shown:
                check_panel(name, axes, labelled=False)
            box = figure.texts[0].get_text() if figure.texts else figure.subfigs[0]._suptitle.get_text()
            assert "every cell the same box: x " in box and box.count(" to ") == (2 if name == "square" else 3), box
        finally:
            plt.close(figure)


def test_vertices_that_never_move_are_marked(tmp_path):
    """The rope's vertex 0 stays at the origin: drawn as a square marker, and the title says what squares mean."""
    results = load(write_results(tmp_path / "rope.h5", rope_model()))
    (_, figure), *others = snapshots(figure_data(results))
    try:
        squares = [line for line in figure.axes[0].get_lines() if line.get_marker() == "s"]
        assert len(squares) == 1 and np.allclose(np.ravel(squares[0].get_data_3d()), 0.0)
        assert "never move" in figure.get_suptitle()
    finally:
        for _, each in [(None, figure), *others]:
            plt.close(each)


def test_a_diverged_run_with_non_finite_frames_still_draws(tmp_path):
    """The last frame of a run that blew up holds NaN and inf: the views frame the frames before it."""
    model = mesh_model()
    path = write_results(tmp_path / "mesh.h5", model)
    with h5py.File(path, "r+") as file:
        group = next(iter(file["runs"].values()))
        frames = group["frames"][()]
        frames[-1, :3] = np.nan
        frames[-1, 3:] = 1e300
        group["frames"][...] = frames
        group.attrs.update({"status": "diverged", "t_diverged": 1.0})
    results = load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures = snapshots(figure_data(results))
        grid = snapshot_grid(figure_data(results))
        try:
            for figure in [grid, *(figure for _, figure in figures)]:
                figure.savefig(tmp_path / "diverged.png", dpi=60)
            assert abs(figures[0][1].axes[0].get_zlim()[0]) < 10
        finally:
            for figure in [grid, *(figure for _, figure in figures)]:
                plt.close(figure)


# -- simrun animate -----------------------------------------------------------------------------------
def gif_frames(path: Path) -> int:
    from PIL import Image

    with Image.open(path) as image:
        return image.n_frames


@pytest.mark.parametrize("name", [*sorted(MODELS), "cloth"])
def test_animate_writes_a_gif_of_every_model(name, tmp_path, capsys):
    path = FORMAT1_CLOTH if name == "cloth" else write_results(tmp_path / f"{name}.h5", MODELS[name]())
    results = load(path)
    assert frame_runs(results) == list(results.runs)
    last = list(results.runs)[-1]
    output = tmp_path / f"{name}.gif"
    assert main(["animate", str(path), last, "--output", str(output)]) == 0
    assert capsys.readouterr().out.strip() == f"animation: {output}"
    assert output.stat().st_size > 0
    assert gif_frames(output) == results.runs[last]["frame_t"].shape[0]


def test_animate_lists_the_runs_with_frames(tmp_path, capsys):
    path = write_results(tmp_path / "square.h5", square_model())
    assert main(["animate", str(path), "--list"]) == 0
    assert capsys.readouterr().out.split() == list(load(path).runs)


def test_animate_refuses_a_file_without_frames_in_one_line(capsys):
    path = DATA / "format1_circ.h5"
    assert main(["animate", str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and "runs with frames" in lines[0] and "cloth" not in lines[0], captured.err
    assert captured.out == ""


def test_a_2d_model_with_triangles_fills_them_under_its_springs(tmp_path):
    """The square with its 8 triangles (each cell split along a diagonal): filled (PolyCollection), springs on top."""
    model = square_model()
    index = np.arange(9).reshape(3, 3)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    model["triangles"] = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    results = load(write_results(tmp_path / "square.h5", model))
    assert np.array_equal(next(iter(results.runs.values())).model_triangles, model["triangles"])
    figures = snapshots(figure_data(results))
    try:
        axes = figures[0][1].axes[0]
        assert [type(collection) for collection in axes.collections] == [PolyCollection, LineCollection]
        assert "8 triangles filled" in figures[0][1].get_suptitle()
    finally:
        for _, figure in figures:
            plt.close(figure)


@pytest.mark.parametrize("config, kinds, marks", [
    ("twist", {"pinned": 3, "prescribed": 3}, {"s": "squares: pinned vertices", "^": "triangles: vertices on a prescribed path"}),
    ("curtain", {"pinned": 1, "prescribed": 1, "sliding": 4},
     {"s": "squares: pinned vertices", "D": "diamonds: sliding vertices", "^": "triangles: vertices on a prescribed path"}),
])
def test_held_vertices_are_named_by_what_holds_them(tmp_path, config, kinds, marks):
    """twist.yaml's far end turns on a prescribed path (its middle vertex on the axis does not move, and is still
    no pinned vertex); curtain.yaml's top slides on a rail between a pinned corner and a pulled one: the run stores each
    vertex's kind (model_constraints), and the frames mark each kind with its own marker, named in the title."""
    import simrun
    from simrun.format.layout import VERTEX_KINDS

    configs = Path(__file__).resolve().parents[1] / "configs"
    overrides = ["duration=0.02", "integrators=[backward_euler]"]
    if config == "curtain":
        overrides += ["system.model={grid: {resolution: [6, 5], size: [1.0, 0.8]}}", "sweep.solver.mpcg_start=[zero]"]
    results = simrun.run(configs / f"{config}.yaml", output=tmp_path / "out", jobs=1, progress=False, figures=False,
                         overrides=overrides)
    (run,) = results.runs.values()
    stored = run.model_constraints
    assert {name: int(np.count_nonzero(stored == value)) for name, value in VERTEX_KINDS.items() if np.any(stored == value)} == kinds
    (_, figure), *others = snapshots(figure_data(results))
    try:
        title = figure.get_suptitle()
        drawn = {line.get_marker() for axes in figure.axes for line in axes.get_lines()} - {"o"}
        assert drawn == set(marks) and all(note in title for note in marks.values()), (drawn, title)
        assert "never move" not in title
    finally:
        for _, each in [(None, figure), *others]:
            plt.close(each)
