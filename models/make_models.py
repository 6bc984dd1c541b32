"""Write the small model files the shipped configs use into this folder; deterministic (same bytes every run).

- cloth_mesh.obj: a 1 m x 1 m cloth in the plane z = 0, 16 x 16 vertices, each cell split into two triangles
  along alternating diagonals (a triangle mesh, so its bend springs join opposite vertices, unlike a grid's);
- square.npz: the course square (SquareModel(segments=4, size=1)) with its spring kinds and named vertices;
- strip.obj: a quad mesh strip 1 m x 0.1 m with 21 x 3 vertices (as a grid, with the grid's springs);
- spot_like.obj: a closed triangle surface the size of Keenan Crane's spot (2,930 vertices, 5,856 triangles), a
  subdivided capsule bent and bulged into a cow-like body with a head, written as Blender writes a textured mesh
  (texture coordinates per corner at the UV seam, normals, ``f v/vt/vn``) with its vertices in no useful order, as
  a scan's or an export's are: the real-mesh case of configs/spot_drop.yaml and of ``make bench``;
- soft_ball.obj: a closed icosphere of radius 0.1 m (162 vertices, 320 triangles), the surface that
  configs/soft_drop.yaml fills with tetrahedra.

Run: .venv/bin/python models/make_models.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from simrun.systems.mass_spring.generators import SquareModel
from simrun.systems.vertex.grids import GridModel, grid_quads
from simrun.systems.vertex.model_files import save_npz

FOLDER = Path(__file__).resolve().parent


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray, comment: str) -> None:
    """A Wavefront OBJ of (n, 3) vertices and (f, k) faces (0-based), coordinates in shortest round-trip form.

    Written here rather than with meshio.write, whose header carries the time of writing.
    """
    lines = [f"# {comment}"]
    lines += ["v " + " ".join(repr(float(c)) for c in vertex) for vertex in vertices]
    lines += ["f " + " ".join(str(i) for i in face) for face in faces + 1]
    path.write_text("\n".join(lines) + "\n")


def alternating_triangles(index: np.ndarray) -> np.ndarray:
    """(2 cells, 3) counter-clockwise triangles of a vertex grid, the cell (r, c) split along a-c when r + c
    is even and along b-d when odd (a, b, c, d: the quad's corners counter-clockwise from its lower left)."""
    a, b, c, d = grid_quads(index).T
    even = ((np.arange(index.shape[0] - 1)[:, None] + np.arange(index.shape[1] - 1)).ravel() % 2) == 0
    first = np.where(even[:, None], np.stack([a, b, c], axis=1), np.stack([a, b, d], axis=1))
    second = np.where(even[:, None], np.stack([a, c, d], axis=1), np.stack([b, c, d], axis=1))
    return np.stack([first, second], axis=1).reshape(-1, 3)


SPOT_RINGS, SPOT_SEGMENTS = 61, 48  # 61 x 48 + 2 poles = 2,930 vertices, as spot.obj; 2 x 48 x 61 = 5,856 triangles


def spot_like_surface(seed: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (2930, 3) m, triangles (5856, 3)): a capsule along x of rings around it, bent, with a bulge for a head,
    about 1 m long; its vertices in a random order (``seed``), the triangles counter-clockwise seen from outside."""
    rings, segments = SPOT_RINGS, SPOT_SEGMENTS
    polar = np.linspace(0.0, np.pi, rings + 2)[1:-1]  # rings between the poles
    azimuth = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    theta, phi = np.meshgrid(polar, azimuth, indexing="ij")
    x = -np.cos(theta)  # -1 .. 1 along the body
    radius = np.sin(theta) * (0.32 + 0.06 * np.cos(3.0 * np.pi * x))  # a waist, a belly, a neck
    head = np.exp(-((x - 0.75) / 0.18) ** 2)  # the head: a bulge near one end, lifted
    ring = np.stack([0.55 * x, radius * np.cos(phi) * (1.0 + 0.25 * head), radius * np.sin(phi) * 0.85 + 0.18 * head], axis=-1)
    ring[..., 2] += 0.12 * x ** 2  # the back bent down at both ends
    vertices = np.concatenate([[[-0.55, 0.0, 0.12]], ring.reshape(-1, 3), [[0.55, 0.0, 0.12 + 0.18 * np.exp(-(0.25 / 0.18) ** 2)]]])
    index = 1 + np.arange(rings * segments).reshape(rings, segments)
    following = np.roll(index, -1, axis=1)
    bands = np.concatenate([np.stack([index[:-1], index[1:], following[1:]], axis=-1).reshape(-1, 3),
                            np.stack([index[:-1], following[1:], following[:-1]], axis=-1).reshape(-1, 3)])
    south = np.stack([np.zeros(segments, dtype=int), index[0], following[0]], axis=1)[:, [0, 2, 1]]
    north = np.stack([np.full(segments, len(vertices) - 1), following[-1], index[-1]], axis=1)[:, [0, 2, 1]]
    surface = trimesh.Trimesh(vertices, np.concatenate([south, bands, north]), process=False)
    trimesh.repair.fix_winding(surface)  # one orientation for every face ...
    trimesh.repair.fix_inversion(surface)  # ... and that one outward
    triangles = np.asarray(surface.faces)
    order = np.random.default_rng(seed).permutation(len(vertices))  # new vertex k is old vertex order[k]
    position = np.argsort(order)
    return vertices[order], position[triangles]


def write_textured_obj(path: Path, vertices: np.ndarray, triangles: np.ndarray, comment: str) -> None:
    """An OBJ as Blender writes a textured mesh: ``mtllib``, ``o``, normals, texture coordinates (one per vertex, and
    a second one for the corners on the UV seam, so that their count is not the vertices'), ``usemtl``, faces
    ``f v/vt/vn``; coordinates to 6 decimals, as Blender's."""
    centre = vertices.mean(axis=0)
    u = (np.arctan2(vertices[:, 2] - centre[2], vertices[:, 1] - centre[1]) / (2.0 * np.pi)) % 1.0
    w = (vertices[:, 0] - vertices[:, 0].min()) / np.ptp(vertices[:, 0])
    corners_u = u[triangles]
    seam = np.ptp(corners_u, axis=1) > 0.5  # a triangle across u = 0 / 1: its small-u corners take a copy at u + 1
    seam_vertices = np.unique(triangles[seam][corners_u[seam] < 0.5])
    seam_uv = {int(vertex): len(vertices) + k for k, vertex in enumerate(seam_vertices)}
    normals = vertices - centre
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    lines = [f"# {comment}", "mtllib spot_like.mtl", "o spot_like"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"vn {x:.4f} {y:.4f} {z:.4f}" for x, y, z in normals]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in zip(u, w)] + [f"vt {u[v] + 1.0:.6f} {w[v]:.6f}" for v in seam_vertices]
    lines += ["s 0", "usemtl Material"]
    for face, across in zip(triangles.tolist(), seam.tolist()):
        uvs = [seam_uv[v] if across and u[v] < 0.5 else v for v in face]
        lines.append("f " + " ".join(f"{v + 1}/{t + 1}/{v + 1}" for v, t in zip(face, uvs)))
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    cloth = GridModel(resolution=(16, 16), size=(1.0, 1.0)).build()
    write_obj(FOLDER / "cloth_mesh.obj", cloth.vertices,
              alternating_triangles(np.arange(cloth.vertex_count).reshape(cloth.grid_shape)),
              "1 m x 1 m cloth, 16 x 16 vertices, z = 0, triangles with alternating diagonals (models/make_models.py)")
    save_npz(SquareModel(segments=4, size=1.0).build(), FOLDER / "square.npz")
    strip = GridModel(resolution=(21, 3), size=(1.0, 0.1)).build()
    write_obj(FOLDER / "strip.obj", strip.vertices, grid_quads(np.arange(strip.vertex_count).reshape(strip.grid_shape)),
              "1 m x 0.1 m strip, 21 x 3 vertices, quads, z = 0 (models/make_models.py)")
    write_textured_obj(FOLDER / "spot_like.obj", *spot_like_surface(),
                       "Blender 4.2.0-like export of a spot-sized closed surface, 2930 vertices (models/make_models.py)")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    write_obj(FOLDER / "soft_ball.obj", ball.vertices, ball.faces,
              "icosphere of radius 0.1 m, 162 vertices, 320 triangles, closed (models/make_models.py)")


if __name__ == "__main__":
    main()
