"""Meshes as a user has them: OBJ files as Blender, Maya or a scanner write them, PLY with per-face
colours, binary and ASCII STL, and scanned meshes with degenerate triangles. Every file here is written by the
test itself; each loads with the default config, keeps its vertices in the file's order, and gets the springs
docs/models.md promises."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest

from simrun.systems.mass_spring.params import MassSpringParams
from simrun.systems.vertex.errors import ModelError, ModelWarning
from simrun.systems.vertex.model_files import load_model_file

# an octahedron: 6 vertices, 8 triangles, 12 edges
OCTAHEDRON_VERTICES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
OCTAHEDRON_FACES = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])


def blender_obj(vertices, faces, uv_per_corner: bool = True, objects: int = 1) -> str:
    """An OBJ as Blender's exporter writes it: a header, mtllib, one ``o`` per object, normals and texture
    coordinates with counts of their own (a texture coordinate per face corner, as at UV seams), smoothing off,
    ``usemtl``, faces ``f v/vt/vn`` split among the objects."""
    lines = ["# Blender 4.2.0", "# www.blender.org", "mtllib model.mtl"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += ["vn 0.0000 0.0000 1.0000", "vn 0.0000 1.0000 0.0000"]
    corners = sum(len(face) for face in faces) if uv_per_corner else len(vertices) + 3
    lines += [f"vt {0.5 + 0.4 * np.cos(k):.6f} {0.5 + 0.4 * np.sin(k):.6f}" for k in range(corners)]
    per_object = -(-len(faces) // objects)
    corner = 0
    for number, start in enumerate(range(0, len(faces), per_object)):
        lines += [f"o Object.{number:03d}", "s 0", "usemtl Material"]
        for face in faces[start:start + per_object]:
            parts = []
            for vertex in face:
                parts.append(f"{vertex + 1}/{corner % corners + 1}/{1 + corner % 2}")
                corner += 1
            lines.append("f " + " ".join(parts))
    return "\n".join(lines) + "\n"


def test_a_textured_obj_as_blender_writes_it_keeps_its_vertices_in_their_order(tmp_path):
    """24 texture coordinates and 2 normals for 6 vertices: meshio refuses the file, trimesh reads it; the vertices
    are the file's, in its order, and the springs are the octahedron's 12 edges (stretch) and, across each of them,
    the two opposite vertices (bend: 3 distinct pairs, the octahedron's diagonals)."""
    path = tmp_path / "octahedron.obj"
    path.write_text(blender_obj(OCTAHEDRON_VERTICES, OCTAHEDRON_FACES, objects=2))
    model = load_model_file(path)
    np.testing.assert_array_equal(model.vertices, OCTAHEDRON_VERTICES)
    kinds = [model.kind_names[kind] for kind in model.kinds]
    assert kinds.count("stretch") == 12 and kinds.count("bend") == 3
    assert {tuple(sorted(face)) for face in model.triangles.tolist()} == {tuple(sorted(face)) for face in OCTAHEDRON_FACES.tolist()}


def test_quads_and_polygons_keep_the_springs_the_docs_promise(tmp_path):
    """An untextured OBJ of a quad and a pentagon (meshio): the quad's shear springs on both diagonals, the pentagon
    fanned into three triangles from its first corner (its two inner diagonals stretch springs)."""
    path = tmp_path / "faces.obj"
    path.write_text("o A\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0.5 0\nv 1.5 1.5 0\nv 2.5 1.5 0\n"
                    "f 1 2 3 4\no B\nf 2 5 7 6 3\n")
    model = load_model_file(path)
    springs = {tuple(pair): model.kind_names[kind] for pair, kind in zip(model.springs.tolist(), model.kinds)}
    assert springs[(0, 2)] == springs[(1, 3)] == "shear"
    assert springs[(1, 6)] == springs[(1, 5)] == "stretch"  # the fan's diagonals from corner 2 (index 1)
    assert len(model.triangles) == 2 + 3


def test_a_textured_quad_mesh_arrives_as_triangles(tmp_path):
    """Through trimesh (texture coordinates per corner) a quad mesh is triangulated: every vertex kept, no shear
    springs, one diagonal of each quad a stretch spring (docs/models.md says so)."""
    vertices = np.array([[x, y, 0.0] for y in range(3) for x in range(3)], dtype=float)
    quads = [[r * 3 + c, r * 3 + c + 1, (r + 1) * 3 + c + 1, (r + 1) * 3 + c] for r in range(2) for c in range(2)]
    path = tmp_path / "quads.obj"
    path.write_text(blender_obj(vertices, quads))
    model = load_model_file(path)
    assert len(model.vertices) == 9 and "shear" not in {model.kind_names[kind] for kind in model.kinds}
    assert len(model.triangles) == 8


def test_a_ply_with_per_face_colours(tmp_path):
    path = tmp_path / "coloured.ply"
    header = ["ply", "format ascii 1.0", f"element vertex {len(OCTAHEDRON_VERTICES)}", "property float x",
              "property float y", "property float z", f"element face {len(OCTAHEDRON_FACES)}",
              "property list uchar int vertex_indices", "property uchar red", "property uchar green",
              "property uchar blue", "end_header"]
    body = [" ".join(map(str, vertex)) for vertex in OCTAHEDRON_VERTICES]
    body += [f"3 {a} {b} {c} 200 30 {10 * k}" for k, (a, b, c) in enumerate(OCTAHEDRON_FACES)]
    path.write_text("\n".join(header + body) + "\n")
    model = load_model_file(path)
    np.testing.assert_allclose(model.vertices, OCTAHEDRON_VERTICES)
    assert model.spring_count == 12 + 3


@pytest.mark.parametrize("binary", [True, False])
def test_an_stl_has_its_corners_merged_into_vertices(tmp_path, binary):
    """STL stores each triangle's three corners apart: the 24 corners of the octahedron are its 6 vertices."""
    path = tmp_path / "octahedron.stl"
    corners = OCTAHEDRON_VERTICES[OCTAHEDRON_FACES]
    if binary:
        data = b"\0" * 80 + struct.pack("<I", len(corners))
        for triangle in corners:
            data += struct.pack("<12fH", 0.0, 0.0, 0.0, *triangle.ravel(), 0)
        path.write_bytes(data)
    else:
        lines = ["solid octahedron"]
        for triangle in corners:
            lines += ["facet normal 0 0 0", "outer loop", *(f"vertex {x} {y} {z}" for x, y, z in triangle), "endloop", "endfacet"]
        path.write_text("\n".join(lines + ["endsolid octahedron"]) + "\n")
    model = load_model_file(path)
    assert len(model.vertices) == 6 and model.spring_count == 12 + 3


def _built_with_warnings(path, vertices, faces):
    """The mass-spring system of a Blender-shaped OBJ of these vertices and faces (1 kg by area), and the
    ModelWarnings its loading gave."""
    path.write_text(blender_obj(np.array(vertices, dtype=float), faces))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        system = MassSpringParams(type="mass_spring", model=str(path), mass={"total": 1.0}).build()
    return system, [str(warning.message) for warning in caught if issubclass(warning.category, ModelWarning)]


def test_degenerate_triangles_of_a_scanned_mesh_load_with_one_warning(tmp_path):
    """A fan of four triangles around vertex 4, plus a sliver (1, 5, 1) with a repeated corner and a zero-area
    triangle of coincident vertices 6 = 7: the model loads with the default config. No spring has zero length,
    the degenerate faces count no area, vertices 5, 6 and 7 (on degenerate faces only) get the mean area of their
    spring neighbours, and one ModelWarning line says so."""
    vertices = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.5, 0), (2, 0, 0), (0, 2, 0), (0, 2, 0)]
    faces = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 5, 1], [3, 6, 7]]
    system, said = _built_with_warnings(tmp_path / "scan.obj", vertices, faces)
    assert len(said) == 1 and "2 degenerate triangles" in said[0] and "3 vertices without a triangle" in said[0], said
    assert system.vertex_count == 8 and np.all(system.vertex_masses > 0) and np.isclose(system.vertex_masses.sum(), 1.0)
    assert np.all(system.rest_length > 0)
    np.testing.assert_allclose(system.vertex_masses[5], system.vertex_masses[1])  # its one neighbour's area
    np.testing.assert_allclose(system.vertex_masses[6], system.vertex_masses[3])  # 6 and 7 are not joined: both 3's


def test_vertices_no_face_uses_are_kept_as_free_particles_with_one_warning(tmp_path):
    """Vertices that no face uses (the published Stanford bunny has 1,113 of its 35,947) keep their numbers, in the
    middle of a textured OBJ and after its last used vertex (which trimesh itself leaves out): the model has every
    vertex, the unused ones join no spring and take the mean area of the others, and the one warning line counts
    them apart from the vertices of degenerate faces."""
    vertices = [(0, 0, 0), (9, 9, 9), (1, 0, 0), (1, 1, 0), (0, 1, 0), (8, 8, 8)]
    faces = [[0, 2, 3], [0, 3, 4]]
    system, said = _built_with_warnings(tmp_path / "unused.obj", vertices, faces)
    assert len(said) == 1 and "2 vertices that no face uses: free particles" in said[0], said
    assert "degenerate" not in said[0] and "neighbours" not in said[0]
    assert system.vertex_count == 6
    np.testing.assert_allclose(system.x0.reshape(-1, 3), vertices)
    assert not np.isin([1, 5], system.frame_edges).any()
    areas = np.array([2 / 6, 1 / 6, 2 / 6, 1 / 6])  # corners 0, 2, 3, 4: a third of each 0.5 m^2 triangle they touch
    mean = areas.mean()
    expected = np.array([areas[0], mean, areas[1], areas[2], areas[3], mean])
    np.testing.assert_allclose(system.vertex_masses, expected / expected.sum())


def test_a_file_no_library_reads_is_one_line_naming_both(tmp_path):
    path = tmp_path / "broken.obj"
    path.write_text("v 0 0 0\nf 1 2 oops\n")
    with pytest.raises(ModelError, match=r"broken.obj: cannot read it as a mesh \(meshio: .*; trimesh: .*\)$"):
        load_model_file(path)


def test_the_shipped_spot_sized_mesh_loads_through_the_textured_path():
    """models/spot_like.obj (models/make_models.py) is written as Blender writes a textured mesh, its vertices in no
    useful order: it loads with all 2,930 vertices in the file's order and a closed surface of 5,856 triangles."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "models" / "spot_like.obj"
    text = path.read_text()
    assert text.count("\nvt ") != text.count("\nv ")  # meshio refuses it
    model = load_model_file(path)
    first = next(line for line in text.splitlines() if line.startswith("v "))
    np.testing.assert_allclose(model.vertices[0], [float(value) for value in first.split()[1:]])
    assert len(model.vertices) == 2930 and len(model.triangles) == 5856
    edges = np.sort(np.concatenate([model.triangles[:, [0, 1]], model.triangles[:, [1, 2]], model.triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed: every edge between two triangles
