"""Write the small model files the shipped configs use into this folder; deterministic (same bytes every run).

- cloth_mesh.obj: a 1 m x 1 m cloth in the plane z = 0, 16 x 16 vertices, each cell split into two triangles
  along alternating diagonals (a triangle mesh, so its bend springs join opposite vertices, unlike a grid's);
- square.npz: the course square (SquareModel(segments=4, size=1)) with its spring kinds and named vertices;
- strip.obj: a quad mesh strip 1 m x 0.1 m with 21 x 3 vertices (as a grid, with the grid's springs).

Run: .venv/bin/python models/make_models.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simrun.systems.mass_spring.files import save_npz
from simrun.systems.mass_spring.generators import GridModel, SquareModel, grid_quads

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


def main() -> None:
    cloth = GridModel(resolution=(16, 16), size=(1.0, 1.0)).build()
    write_obj(FOLDER / "cloth_mesh.obj", cloth.vertices,
              alternating_triangles(np.arange(cloth.vertex_count).reshape(cloth.grid_shape)),
              "1 m x 1 m cloth, 16 x 16 vertices, z = 0, triangles with alternating diagonals (models/make_models.py)")
    save_npz(SquareModel(segments=4, size=1.0).build(), FOLDER / "square.npz")
    strip = GridModel(resolution=(21, 3), size=(1.0, 0.1)).build()
    write_obj(FOLDER / "strip.obj", strip.vertices, grid_quads(np.arange(strip.vertex_count).reshape(strip.grid_shape)),
              "1 m x 0.1 m strip, 21 x 3 vertices, quads, z = 0 (models/make_models.py)")


if __name__ == "__main__":
    main()
