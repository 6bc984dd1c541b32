"""Where mass-spring models come from: generators, model files and meshes against known answers and bad input."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import meshio
import numpy as np
import pytest

from simrun.systems.cloth import PIN_NAMES, grid_springs
from simrun.systems.mass_spring.generators import MODEL_GENERATORS, FileModel, RopeModel, SquareModel, model_source
from simrun.systems.vertex.errors import ModelError
from simrun.systems.vertex.grids import GridModel, grid_quads
from simrun.systems.vertex.model_files import MESH_KINDS, load_model_file, lumped_area_masses, mesh_springs, save_npz

MODELS = Path(__file__).resolve().parents[1] / "models"
GRID_AS_MESH = {"stretch_x": "stretch", "stretch_y": "stretch", "shear": "shear", "bend_x": "bend", "bend_y": "bend"}


def spring_set(model, rename=None) -> set:
    """{(i, j, kind name)} with i < j: the springs as an unordered set."""
    names = [(rename or {}).get(name, name) for name in model.kind_names]
    return {(int(i), int(j), names[k]) for (i, j), k in zip(np.sort(model.springs, axis=1), model.kinds)}


def write_mesh(path: Path, points, **cells) -> Path:
    meshio.write(path, meshio.Mesh(np.asarray(points, dtype=float),
                                   [(kind, np.asarray(faces, dtype=np.int32)) for kind, faces in cells.items()]))
    return path


def kinds_of(model) -> dict:
    """kind name -> number of springs."""
    counts = np.bincount(model.kinds, minlength=len(model.kind_names))
    return dict(zip(model.kind_names, counts.tolist()))


# -- generators ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(set(MODEL_GENERATORS) - {"file"}))
def test_every_generator_builds_a_valid_model_from_its_defaults(name):
    model = model_source({name: {}}).build()
    assert model.validate() is model
    assert model.spring_count == len(model.kinds) > 0


@pytest.mark.parametrize("nx, ny", [(2, 2), (5, 4), (3, 7)])
def test_grid_reproduces_the_cloth_springs_in_order(nx, ny):
    """Same pairs in the same order as systems.cloth.grid_springs; kinds split stretch and bend by axis."""
    model = GridModel(resolution=(nx, ny), size=(2.0, 0.5), height=0.3).build()
    reference = grid_springs(nx, ny)
    first = np.concatenate([reference[kind][0] for kind in reference])
    second = np.concatenate([reference[kind][1] for kind in reference])
    np.testing.assert_array_equal(model.springs, np.stack([first, second], axis=1))
    assert model.kind_names == ("stretch_x", "stretch_y", "shear", "bend_x", "bend_y")
    assert kinds_of(model) == {"stretch_x": ny * (nx - 1), "stretch_y": (ny - 1) * nx, "shear": 2 * (nx - 1) * (ny - 1),
                               "bend_x": ny * max(nx - 2, 0), "bend_y": max(ny - 2, 0) * nx}
    assert np.all(np.diff(model.kinds) >= 0)
    assert model.vertex_count == nx * ny and model.grid_shape == (ny, nx)
    assert model.rest_lengths is None and model.stiffness is None and model.masses is None


def test_grid_rest_shape_and_names_are_the_former_cloths():
    """The cloth before it became a grid mass_spring (Cloth.__init__, Cloth._pinned_vertices), written out as the known answer:
    vertices from linspace and meshgrid, row-major, z = height; pins as index expressions on (ny, nx)."""
    nx, ny, size, height = 6, 4, (1.5, 0.8), 0.25
    model = GridModel(resolution=(nx, ny), size=size, height=height).build()
    grid_x, grid_y = np.meshgrid(np.linspace(0.0, size[0], nx), np.linspace(0.0, size[1], ny))
    np.testing.assert_array_equal(model.vertices, np.stack([grid_x.ravel(), grid_y.ravel(), np.full(nx * ny, height)], 1))
    index = np.arange(nx * ny).reshape(ny, nx)
    former_pins = {"top_left": index[-1, :1], "top_right": index[-1, -1:], "bottom_left": index[0, :1],
                   "bottom_right": index[0, -1:], "top": index[-1, :], "bottom": index[0, :],
                   "left": index[:, 0], "right": index[:, -1]}
    assert set(model.named_vertices) == set(PIN_NAMES) == set(former_pins)
    for name, ids in former_pins.items():
        np.testing.assert_array_equal(model.named_vertices[name], ids)
    assert former_pins["top_left"].tolist() == [18] and former_pins["right"].tolist() == [5, 11, 17, 23]


def test_grid_triangles_cover_the_cells_counter_clockwise():
    """2 (nx - 1)(ny - 1) triangles, every normal +z, total area sx * sy."""
    model = GridModel(resolution=(5, 4), size=(2.0, 3.0)).build()
    corner = model.vertices[model.triangles]
    normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    assert model.triangles.shape == (2 * 4 * 3, 3)
    assert np.all(normal[:, 2] > 0) and np.allclose(normal[:, :2], 0)
    assert np.isclose(0.5 * normal[:, 2].sum(), 6.0)


@pytest.mark.parametrize("segments", [1, 2, 4, 7])
def test_square_counts_and_rest_lengths(segments):
    """(s+1)^2 vertices, 2 s (s+1) axis springs, 2 s^2 diagonals; lengths size/s or sqrt(2) size/s."""
    size = 2.0
    model = SquareModel(segments=segments, size=size).build()
    assert model.vertices.shape == ((segments + 1) ** 2, 2)
    assert kinds_of(model) == {"stretch_x": segments * (segments + 1), "stretch_y": segments * (segments + 1),
                               "shear": 2 * segments**2}
    lengths = np.linalg.norm(np.subtract(*model.vertices[model.springs.T]), axis=1)
    diagonal = model.kinds == model.kind_names.index("shear")
    np.testing.assert_allclose(lengths[~diagonal], size / segments, rtol=1e-12)
    np.testing.assert_allclose(lengths[diagonal], np.sqrt(2) * size / segments, rtol=1e-12)
    np.testing.assert_allclose(model.vertices.min(axis=0), -size / 2)
    np.testing.assert_allclose(model.vertices.max(axis=0), size / 2)
    assert np.isclose(lumped_area_masses(model.vertices, model.triangles).sum(), size**2)


def test_square_follows_the_course_order():
    """square_mesh.generate: vertex i (s+1) + j at (-L/2 + i h, -L/2 + j h); along x, along y, then per cell
    (i,j)-(i+1,j+1) and (i+1,j)-(i,j+1). For s = 1: vertices (-.5,-.5), (-.5,.5), (.5,-.5), (.5,.5)."""
    model = SquareModel(segments=1, size=1.0).build()
    np.testing.assert_array_equal(model.vertices, [[-0.5, -0.5], [-0.5, 0.5], [0.5, -0.5], [0.5, 0.5]])
    np.testing.assert_array_equal(model.springs, [[0, 2], [1, 3], [0, 1], [2, 3], [0, 3], [2, 1]])
    np.testing.assert_array_equal(model.kinds, [0, 0, 1, 1, 2, 2])
    named = {name: model.vertices[ids].tolist() for name, ids in model.named_vertices.items()}
    assert named["top_left"] == [[-0.5, 0.5]] and named["bottom_right"] == [[0.5, -0.5]]
    assert named["top"] == [[-0.5, 0.5], [0.5, 0.5]] and named["left"] == [[-0.5, -0.5], [-0.5, 0.5]]


@pytest.mark.parametrize("direction, start", [((0.0, 0.0, -3.0), (0.5, 0.5, 1.0)), ((1.0, 1.0), None)])
def test_rope_lengths_and_springs(direction, start):
    """count vertices from start, spaced length / (count - 1) along the unit direction."""
    model = RopeModel(count=6, length=2.5, direction=direction, start=start, bend=True).build()
    unit = np.array(direction) / np.linalg.norm(direction)
    origin = np.zeros(len(direction)) if start is None else np.array(start)
    assert model.dim == len(direction)
    np.testing.assert_allclose(model.vertices[-1], origin + 2.5 * unit)
    lengths = np.linalg.norm(np.subtract(*model.vertices[model.springs.T]), axis=1)
    assert kinds_of(model) == {"stretch": 5, "bend": 4}
    np.testing.assert_allclose(lengths, np.where(model.kinds == 0, 0.5, 1.0))
    np.testing.assert_array_equal(model.named_vertices["first"], [0])
    np.testing.assert_array_equal(model.named_vertices["last"], [5])
    assert kinds_of(RopeModel(count=6).build()) == {"stretch": 5, "bend": 0}


@pytest.mark.parametrize("fields, message", [
    ({"direction": [0, 0, 0]}, "direction must not be zero"),
    ({"direction": [1, 0], "start": [0, 0, 0]}, "same dimension"),
    ({"direction": [1]}, "at least 2"),
    ({"count": 1}, "greater than or equal to 2"),
])
def test_rope_rejects_bad_fields(fields, message):
    with pytest.raises(ValueError, match=message):
        RopeModel(**fields)


# -- model_source ----------------------------------------------------------------------------------
@pytest.mark.parametrize("value, kind", [
    ({"grid": {"resolution": [3, 4]}}, GridModel), ({"square": {"segments": 2}}, SquareModel),
    ({"rope": None}, RopeModel), ("models/strip.obj", FileModel), ({"file": "a.obj", "dimension": 2}, FileModel),
    (SquareModel(), SquareModel),
])
def test_model_source_accepts_paths_and_one_key_mappings(value, kind):
    assert isinstance(model_source(value), kind)


@pytest.mark.parametrize("value, message", [
    ({"grd": {}}, r"expected a file path or one of \{grid: \.\.\.\}, \{square: \.\.\.\}, \{rope: \.\.\.\}, "
                  r"\{file: \.\.\.\}; got \{'grd': \.\.\.\}"),
    ({"grid": {}, "rope": {}}, r"got \{'grid': \.\.\., 'rope': \.\.\.\}"),
    (42, "expected a file path .*; got 42"),
    ({"grid": [3, 3]}, "grid: expected a mapping of its fields"),
    ({"grid": {"resolution": [1, 3]}}, "greater than or equal to 2"),
    ({"square": {"segmnts": 3}}, "Extra inputs are not permitted"),
    ({"file": "a.obj", "dimension": 4}, "dimension"),
])
def test_model_source_rejects_anything_else(value, message):
    with pytest.raises(ValueError, match=message):
        model_source(value)


# -- meshes ----------------------------------------------------------------------------------------
SQUARE_POINTS = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]]


@pytest.mark.parametrize("cells, counts, bends", [
    ({"triangle": [[0, 1, 2]]}, {"stretch": 3, "shear": 0, "bend": 0}, set()),
    ({"triangle": [[0, 1, 2], [0, 2, 3]]}, {"stretch": 5, "shear": 0, "bend": 1}, {(1, 3)}),
    ({"quad": [[0, 1, 2, 3]]}, {"stretch": 4, "shear": 2, "bend": 0}, set()),
    ({"quad": [[0, 1, 2, 3], [1, 4, 5, 2]]}, {"stretch": 7, "shear": 4, "bend": 2}, {(0, 4), (3, 5)}),
    ({"quad": [[0, 1, 2, 3], [2, 5, 4, 1]]}, {"stretch": 7, "shear": 4, "bend": 2}, {(0, 4), (3, 5)}),  # flipped
])
def test_mesh_springs_of_small_meshes(tmp_path, cells, counts, bends):
    """Two triangles: bend joins the vertices opposite the shared edge; two quads: each off-edge neighbour
    with its counterpart (the grid's skip-one springs)."""
    model = load_model_file(write_mesh(tmp_path / "mesh.obj", SQUARE_POINTS, **cells))
    assert model.kind_names == MESH_KINDS
    assert kinds_of(model) == counts
    assert {(i, j) for i, j, kind in spring_set(model) if kind == "bend"} == bends
    assert model.triangles.shape == (len(cells.get("triangle", [])) + 2 * len(cells.get("quad", [])), 3)


@pytest.mark.parametrize("suffix", ["obj", "ply", "vtk"])
@pytest.mark.parametrize("nx, ny", [(5, 4), (2, 6)])
def test_grid_as_quad_mesh_gives_the_grids_springs(tmp_path, suffix, nx, ny):
    """stretch = stretch_x + stretch_y, shear = shear, bend = bend_x + bend_y, as sets of unordered pairs."""
    grid = GridModel(resolution=(nx, ny), size=(1.0, 0.7)).build()
    quads = grid_quads(np.arange(grid.vertex_count).reshape(grid.grid_shape))
    model = load_model_file(write_mesh(tmp_path / f"grid.{suffix}", grid.vertices, quad=quads))
    assert model.spring_count == grid.spring_count
    assert spring_set(model) == spring_set(grid, GRID_AS_MESH)
    np.testing.assert_allclose(model.vertices, grid.vertices)


def test_mesh_springs_keep_the_first_kind_and_are_unique():
    """A bend pair that is also an edge stays a stretch spring: a tetrahedron's surface has 6 edges, no more."""
    springs, kinds = mesh_springs(np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [0, 2, 3]]), np.zeros((0, 4), int))
    assert len(springs) == 6 and np.all(kinds == 0)
    assert len(np.unique(np.sort(springs, axis=1), axis=0)) == 6


def test_mesh_dimension(tmp_path):
    """dimension 2 drops a constant z; a 2-D npz gets z = 0 with dimension 3."""
    planar = write_mesh(tmp_path / "planar.obj", np.array(SQUARE_POINTS[:4]) + [0, 0, 0.5], quad=[[0, 1, 2, 3]])
    assert load_model_file(planar).dim == 3
    np.testing.assert_array_equal(load_model_file(planar, dimension=2).vertices, [[0, 0], [1, 0], [1, 1], [0, 1]])
    square = tmp_path / "square.npz"
    save_npz(SquareModel(segments=2).build(), square)
    lifted = FileModel(file=square, dimension=3).build()
    assert lifted.dim == 3 and np.all(lifted.vertices[:, 2] == 0)


def test_lumped_area_masses():
    """A third of each triangle's area per corner: the unit square sums to 1, in 2-D and 3-D."""
    grid = GridModel(resolution=(4, 3), size=(1.0, 1.0)).build()
    masses = lumped_area_masses(grid.vertices, grid.triangles)
    assert masses.shape == (12,) and np.isclose(masses.sum(), 1.0)
    np.testing.assert_allclose(lumped_area_masses(grid.vertices[:, :2], grid.triangles), masses)
    np.testing.assert_allclose(lumped_area_masses([[0, 0], [2, 0], [0, 3], [9, 9]], [[0, 1, 2]]), [1, 1, 1, 0])


# -- .npz ------------------------------------------------------------------------------------------
def test_npz_round_trip(tmp_path):
    model = SquareModel(segments=3, size=0.6).build()
    path = tmp_path / "square.npz"
    save_npz(model, path)
    loaded = load_model_file(path)
    for name in ("vertices", "springs", "kinds", "triangles"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(model, name))
    assert loaded.kind_names == model.kind_names
    assert loaded.named_vertices.keys() == model.named_vertices.keys()
    for name, ids in model.named_vertices.items():
        np.testing.assert_array_equal(loaded.named_vertices[name], ids)


def test_npz_kinds_as_strings_and_optional_arrays(tmp_path):
    """Kind strings map to indices in order of first appearance (or of kind_names when given)."""
    path = tmp_path / "rope.npz"
    np.savez(path, vertices=[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], springs=[[0, 1], [1, 2], [0, 2]],
             kinds=np.array(["stretch", "stretch", "bend"]), rest_lengths=[1.0, 1.0, 2.5], stiffness=[10.0, 10.0, 1.0],
             masses=[1.0, 2.0, 3.0])
    model = load_model_file(path)
    assert model.kind_names == ("stretch", "bend") and model.kinds.tolist() == [0, 0, 1]
    np.testing.assert_array_equal(model.rest_lengths, [1.0, 1.0, 2.5])
    np.testing.assert_array_equal(model.masses, [1.0, 2.0, 3.0])
    np.savez(path, vertices=[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], springs=[[0, 1], [1, 2]],
             kinds=np.array(["bend", "stretch"]), kind_names=np.array(["stretch", "shear", "bend"]))
    model = load_model_file(path)
    assert model.kind_names == ("stretch", "shear", "bend") and model.kinds.tolist() == [2, 0]
    np.savez(path, vertices=[[0.0, 0.0], [1.0, 0.0]], springs=[[0, 1]])
    assert load_model_file(path).kind_names == ("stretch",)
    np.savez(path, vertices=[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], springs=[[0, 1], [1, 2]], kinds=[1, 0])
    model = load_model_file(path)
    assert model.kind_names == ("kind_0", "kind_1") and model.kinds.tolist() == [1, 0]


def test_save_npz_is_deterministic(tmp_path):
    save_npz(SquareModel().build(), tmp_path / "a.npz")
    save_npz(SquareModel().build(), tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()


# -- bad input -------------------------------------------------------------------------------------
TRIANGLE = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
BAD_NPZ = {
    "no springs": ({"vertices": TRIANGLE},
                   r"has no array 'springs'; a model file needs vertices \(n x 2 or n x 3\) and springs \(m x 2\)"),
    "no vertices": ({"springs": [[0, 1]]}, "has no array 'vertices'"),
    "non-finite": ({"vertices": [[0.0, 0.0], [np.nan, 0.0]], "springs": [[0, 1]]}, "vertex 1 has a non-finite"),
    "zero length": ({"vertices": [[0.0, 0.0], [0.0, 0.0]], "springs": [[0, 1]]}, "rest length 0"),
    "out of range": ({"vertices": TRIANGLE, "springs": [[0, 3]]}, r"vertex indices must be in 0\.\.2"),
    "negative index": ({"vertices": TRIANGLE, "springs": [[-1, 1]]}, r"vertex indices must be in 0\.\.2"),
    "duplicate": ({"vertices": TRIANGLE, "springs": [[0, 1], [1, 2], [1, 0]]}, "joined by more than one spring"),
    "self loop": ({"vertices": TRIANGLE, "springs": [[1, 1]]}, "joins vertex 1 to itself"),
    "masses length": ({"vertices": TRIANGLE, "springs": [[0, 1]], "masses": [1.0, 1.0]},
                      r"masses must have one entry per vertex \(3\)"),
    "stiffness length": ({"vertices": TRIANGLE, "springs": [[0, 1]], "stiffness": [1.0, 1.0]},
                         r"stiffness must have one entry per spring \(1\)"),
    "float springs": ({"vertices": TRIANGLE, "springs": [[0.0, 1.0]]}, "'springs' must hold integers"),
    "text vertices": ({"vertices": np.array([["a", "b"]]), "springs": [[0, 1]]}, "'vertices' must hold real numbers"),
    "4-D vertices": ({"vertices": np.zeros((2, 4)), "springs": [[0, 1]]}, "n x 2 or n x 3"),
    "flat springs": ({"vertices": TRIANGLE, "springs": [0, 1]}, "m x 2"),
    "unknown kind": ({"vertices": TRIANGLE, "springs": [[0, 1]], "kinds": np.array(["twist"]),
                      "kind_names": np.array(["stretch"])}, "kind 'twist' is not in kind_names"),
    "too many kinds": ({"vertices": TRIANGLE, "springs": [[0, 1]], "kinds": [7]}, "kinds go up to 7 for 1 springs"),
    "typo": ({"vertices": TRIANGLE, "springs": [[0, 1]], "stifness": [1.0]}, "unknown array 'stifness'"),
    "bad name set": ({"vertices": TRIANGLE, "springs": [[0, 1]], "named_top": [5]}, "'named_top' must hold vertex"),
}


@pytest.mark.parametrize("case", sorted(BAD_NPZ))
def test_bad_npz_files_raise_model_error_naming_the_file(tmp_path, case):
    arrays, message = BAD_NPZ[case]
    path = tmp_path / "bad.npz"
    np.savez(path, **{name: np.asarray(array) for name, array in arrays.items()})
    with pytest.raises(ModelError, match=message) as error:
        load_model_file(path)
    assert str(path) in str(error.value) and "\n" not in str(error.value)


BAD_FILES = {
    "missing": (None, "no such file"),
    "garbage npz": ("x.npz", "cannot read it as .npz"),
    "garbage obj": ("x.obj", "cannot read it as a mesh"),
    "unknown format": ("x.unknown", "cannot read it as a mesh"),
    "only points": ("points.obj", r"has no triangles or quads \(cells: none\)"),
    "only lines": ("lines.obj", "has no triangles or quads"),
    "line cells": ("lines.vtk", r"has no triangles or quads \(cells: line\)"),
    "not planar": ("bent.obj", r"dimension 2 needs a planar model with constant z, but z ranges over \[0, 0\.5\]"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_mesh_files_raise_model_error_naming_the_file(tmp_path, case):
    name, message = BAD_FILES[case]
    path = tmp_path / (name or "absent.obj")
    if name in ("x.npz", "x.obj", "x.unknown"):
        path.write_text("v 0 0 zero\nthis is not a model\n")
    elif name == "points.obj":
        path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    elif name == "lines.obj":
        path.write_text("v 0 0 0\nv 1 0 0\nl 1 2\n")
    elif name == "lines.vtk":
        write_mesh(path, TRIANGLE, line=[[0, 1], [1, 2]])
    elif name == "bent.obj":
        write_mesh(path, [[0, 0, 0], [1, 0, 0], [1, 1, 0.5], [0, 1, 0]], quad=[[0, 1, 2, 3]])
    with pytest.raises(ModelError, match=message) as error:
        load_model_file(path, dimension=2 if name == "bent.obj" else None)
    assert str(path) in str(error.value) and "\n" not in str(error.value)


def test_a_mesh_edge_of_zero_length_makes_no_spring(tmp_path):
    """A triangle with two coincident corners (a scan's degenerate face): its zero-length edge makes no spring, the
    face counts no area, and the vertices keep their count (mended with a warning, not refused)."""
    path = write_mesh(tmp_path / "collapsed.obj", [[0, 0, 0], [1, 0, 0], [1, 0, 0]], triangle=[[0, 1, 2]])
    model = load_model_file(path)
    assert len(model.vertices) == 3 and sorted(map(tuple, model.springs.tolist())) == [(0, 1), (0, 2)]
    assert len(model.triangles) == 0 and model.degenerate_triangles == 1


# -- the shipped files -----------------------------------------------------------------------------
def test_shipped_models_are_what_make_models_writes(tmp_path, monkeypatch):
    """models/make_models.py rewrites the committed files byte for byte, and they load as described."""
    spec = importlib.util.spec_from_file_location("make_models", MODELS / "make_models.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    monkeypatch.setattr(script, "FOLDER", tmp_path)
    script.main()
    for name in ("cloth_mesh.obj", "square.npz", "strip.obj", "spot_like.obj", "soft_ball.obj"):
        assert (tmp_path / name).read_bytes() == (MODELS / name).read_bytes(), name
    cloth = load_model_file(MODELS / "cloth_mesh.obj")
    assert cloth.vertices.shape == (256, 3) and np.all(cloth.vertices[:, 2] == 0)
    assert kinds_of(cloth)["shear"] == 0 and len(cloth.triangles) == 2 * 15 * 15
    assert spring_set(load_model_file(MODELS / "square.npz")) == spring_set(SquareModel(segments=4, size=1.0).build())
    strip = GridModel(resolution=(21, 3), size=(1.0, 0.1)).build()
    assert spring_set(load_model_file(MODELS / "strip.obj")) == spring_set(strip, GRID_AS_MESH)
