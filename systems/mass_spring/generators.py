"""Where mass-spring models come from: the config's ``model:`` entry, as pydantic models that build a SpringModel.

A config names its model as a file path or as a one-key mapping (``{grid: {...}}``, ``{square: {...}}``,
``{rope: {...}}``, ``{file: path, dimension: 2}``); ``model_source`` turns either into one of the classes
registered in ``MODEL_GENERATORS``, and its ``build()`` gives the validated ``SpringModel``.

Spring kinds are fixed per source, so a config can name a kind's stiffness whether or not the model has
springs of that kind: a grid has ("stretch_x", "stretch_y", "shear", "bend_x", "bend_y"), the course square
("stretch_x", "stretch_y", "shear"), a rope ("stretch", "bend"), a mesh ("stretch", "shear", "bend"). The grid
(``GridModel``) and the model files are systems/vertex/'s, which fem and the cloth read too.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..vertex.fields import Finite, Positive
from ..vertex.grids import GridModel
from ..vertex.model_files import load_model_file
from ..vertex.spring_model import SpringModel, spring_pairs, springs_by_kind

SQUARE_KINDS = ("stretch_x", "stretch_y", "shear")
ROPE_KINDS = ("stretch", "bend")


class SquareModel(BaseModel):
    """The 2-D square of the course "Physics-Based Simulation" (solid-sim-tutorial, 1_mass_spring/square_mesh.py).

    (segments + 1)^2 vertices on [-size/2, size/2]^2 in the course's order: vertex = i (segments + 1) + j at
    (-size/2 + i step, -size/2 + j step), so x varies slowest (the transpose of the grid's row-major order;
    ``grid_shape`` reshapes to [i_x, i_y]). Springs in the course's order: along x ("horizontal edges"),
    along y ("vertical edges"), then both diagonals of each cell, cell by cell.
    """

    model_config = ConfigDict(extra="forbid")
    segments: int = Field(4, ge=1, le=1023, description="cells along each side")
    size: Positive = Field(1.0, description="side length (m)")

    def build(self) -> SpringModel:
        count = self.segments + 1
        step = self.size / self.segments
        coordinate = -self.size / 2 + step * np.arange(count)
        along_x, along_y = np.meshgrid(coordinate, coordinate, indexing="ij")  # [i, j]: x from i, y from j
        vertices = np.stack([along_x.ravel(), along_y.ravel()], axis=1)
        index = np.arange(count * count).reshape(count, count)  # index[i_x, i_y]
        cell = index[:-1, :-1]
        diagonals = (np.stack([cell, index[1:, :-1]], axis=-1), np.stack([index[1:, 1:], index[:-1, 1:]], axis=-1))
        springs, kinds = springs_by_kind([
            spring_pairs([(index[:-1, :], index[1:, :])]),
            spring_pairs([(index[:, :-1], index[:, 1:])]),
            spring_pairs([diagonals]),
        ])
        # the course's render triangles: (i,j), (i+1,j), (i+1,j+1) and (i,j), (i+1,j+1), (i,j+1), counter-clockwise
        triangles = np.stack([np.stack([cell, index[1:, :-1], index[1:, 1:]], axis=-1),
                              np.stack([cell, index[1:, 1:], index[:-1, 1:]], axis=-1)], axis=2).reshape(-1, 3)
        named = {
            "top_left": index[:1, -1], "top_right": index[-1:, -1], "bottom_left": index[:1, 0],
            "bottom_right": index[-1:, 0], "top": index[:, -1], "bottom": index[:, 0],
            "left": index[0, :], "right": index[-1, :],
        }
        return SpringModel(vertices, springs, kinds, SQUARE_KINDS, triangles=triangles.astype(np.intp),
                           named_vertices={name: np.asarray(ids, dtype=np.intp) for name, ids in named.items()},
                           grid_shape=(count, count), source=f"square {self.segments}x{self.segments}").validate()


class RopeModel(BaseModel):
    """``count`` vertices evenly along ``direction`` from ``start``, ``length`` m end to end; dimension = len(direction).

    Springs: neighbours ("stretch"), then, with ``bend``, vertices two apart ("bend").
    """

    model_config = ConfigDict(extra="forbid")
    count: int = Field(20, ge=2, le=10**6, description="vertices")
    length: Positive = Field(1.0, description="distance from the first vertex to the last (m)")
    direction: tuple[Finite, ...] = Field((1.0, 0.0, 0.0), min_length=2, max_length=3,
                                          description="direction from the first vertex to the last (2 or 3 components, normalised)")
    start: tuple[Finite, ...] | None = Field(None, description="position of the first vertex (m); default the origin")
    bend: bool = Field(False, description="add springs between vertices two apart")

    @model_validator(mode="after")
    def _direction_and_start_agree(self) -> "RopeModel":
        if not any(self.direction):
            raise ValueError("direction must not be zero")
        if self.start is not None and len(self.start) != len(self.direction):
            raise ValueError(f"start has {len(self.start)} components but direction has {len(self.direction)}; "
                             "they must have the same dimension")
        return self

    def build(self) -> SpringModel:
        direction = np.array(self.direction) / np.linalg.norm(self.direction)
        start = np.zeros(direction.size) if self.start is None else np.array(self.start, dtype=float)
        vertices = start + np.linspace(0.0, self.length, self.count)[:, None] * direction
        index = np.arange(self.count)
        bend = spring_pairs([(index[:-2], index[2:])]) if self.bend else np.zeros((0, 2), dtype=np.intp)
        springs, kinds = springs_by_kind([spring_pairs([(index[:-1], index[1:])]), bend])
        named = {"first": index[:1], "last": index[-1:]}
        return SpringModel(vertices, springs, kinds, ROPE_KINDS, named_vertices=named,
                           source=f"rope of {self.count}").validate()


class FileModel(BaseModel):
    """A model file: ``.npz`` arrays or any surface mesh meshio reads (see systems/vertex/model_files.py)."""

    model_config = ConfigDict(extra="forbid")
    file: Path = Field(description="path of a .npz model or a triangle/quad mesh (OBJ, PLY, OFF, STL, VTK, ...)")
    dimension: Literal[2, 3] | None = Field(None, description="2: drop a constant z (error if the model is not planar); "
                                                              "3: add z = 0 to a 2-D model; null: as in the file")

    def build(self) -> SpringModel:
        return load_model_file(self.file, self.dimension)


# config key -> generator; a new source joins here and model_source accepts it
MODEL_GENERATORS: dict[str, type[BaseModel]] = {"grid": GridModel, "square": SquareModel, "rope": RopeModel,
                                                "file": FileModel}
ModelSourceType = GridModel | SquareModel | RopeModel | FileModel


def _allowed() -> str:
    return "a file path or one of " + ", ".join(f"{{{key}: ...}}" for key in MODEL_GENERATORS)


def model_source(value) -> ModelSourceType:
    """The generator a config's ``model:`` names: a path string, ``{file: path, dimension: ...}``, or a one-key
    mapping ``{grid: {...}}`` (likewise square, rope; ``{grid: null}`` takes the defaults).

    Raises ValueError naming what is allowed (pydantic's ValidationError, itself a ValueError, for bad fields).
    Usable as a pydantic ``BeforeValidator``: an already built generator passes through.
    """
    if isinstance(value, tuple(MODEL_GENERATORS.values())):
        return value
    if isinstance(value, (str, Path)):
        return FileModel(file=value)
    if isinstance(value, Mapping) and "file" in value:  # the file's options sit beside it: {file: x, dimension: 2}
        return FileModel.model_validate(dict(value))
    if isinstance(value, Mapping) and len(value) == 1:
        (key, fields), = value.items()
        if key in MODEL_GENERATORS:
            if fields is not None and not isinstance(fields, Mapping):
                raise ValueError(f"{key}: expected a mapping of its fields, got {fields!r}")
            return MODEL_GENERATORS[key].model_validate(dict(fields or {}))
    shown = "{" + ", ".join(f"{key!r}: ..." for key in value) + "}" if isinstance(value, Mapping) else repr(value)
    raise ValueError(f"expected {_allowed()}; got {shown}")
