"""The flat grid of vertices that the cloth hangs from its corners: ``{grid: {resolution, size, height}}`` of
mass_spring and of the ``cloth`` system (its springs), and of fem (its triangles, a shell), vertex for vertex.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .fields import Finite, Positive
from .spring_model import SpringModel, spring_pairs, springs_by_kind

GridCount = Annotated[int, Field(ge=2, le=1024)]

GRID_KINDS = ("stretch_x", "stretch_y", "shear", "bend_x", "bend_y")


def grid_quads(index: np.ndarray) -> np.ndarray:
    """(cells, 4) quads of a vertex grid ``index`` (rows, cols), counter-clockwise when rows run along +y and
    cols along +x: (a, a + 1 col, a + 1 row + 1 col, a + 1 row)."""
    return np.stack([index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]], axis=-1).reshape(-1, 4)


class GridModel(BaseModel):
    """A flat nx x ny grid in the plane z = height, vertex = row * nx + col (rows along y): the `cloth` config's grid.

    Springs in the cloth's order (``systems.cloth.grid_springs``): stretch along x, stretch along y, the two
    shear diagonals of every cell, bend (skip one vertex) along x, bend along y.
    """

    model_config = ConfigDict(extra="forbid")
    resolution: tuple[GridCount, GridCount] = Field((32, 32), description="vertices along x and y")
    size: tuple[Positive, Positive] = Field((1.0, 1.0), description="side lengths along x and y (m)")
    height: Finite = Field(0.0, description="z of the flat grid (m)")

    def build(self) -> SpringModel:
        nx, ny = self.resolution
        grid_x, grid_y = np.meshgrid(np.linspace(0.0, self.size[0], nx), np.linspace(0.0, self.size[1], ny))
        vertices = np.stack([grid_x.ravel(), grid_y.ravel(), np.full(nx * ny, self.height)], axis=1)
        index = np.arange(nx * ny).reshape(ny, nx)
        springs, kinds = springs_by_kind([
            spring_pairs([(index[:, :-1], index[:, 1:])]),
            spring_pairs([(index[:-1, :], index[1:, :])]),
            spring_pairs([(index[:-1, :-1], index[1:, 1:]), (index[:-1, 1:], index[1:, :-1])]),
            spring_pairs([(index[:, :-2], index[:, 2:])]),
            spring_pairs([(index[:-2, :], index[2:, :])]),
        ])
        quads = grid_quads(index)
        # each cell split along its first diagonal (a, c), both halves counter-clockwise (normal +z)
        triangles = np.stack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
        named = {
            "top_left": index[-1, :1], "top_right": index[-1, -1:], "bottom_left": index[0, :1],
            "bottom_right": index[0, -1:], "top": index[-1, :], "bottom": index[0, :],
            "left": index[:, 0], "right": index[:, -1],
        }
        return SpringModel(vertices, springs, kinds, GRID_KINDS, triangles=triangles.astype(np.intp),
                           named_vertices={name: np.asarray(ids, dtype=np.intp) for name, ids in named.items()},
                           grid_shape=(ny, nx), source=f"grid {nx}x{ny}").validate()
