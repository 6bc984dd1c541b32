"""Vertex selectors: the config's way to name vertices (an index, a name of the model, a box, or a list of them), in
``pinned``, ``constraints``, ``prescribed`` and regions of a material, and what one selects in a model."""

from __future__ import annotations

from typing import Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .errors import ModelError
from .fields import Box, vector
from .spring_model import SpringModel


class BoxSelector(BaseModel):
    """The vertices whose rest positions lie in the axis-aligned box [min, max] (bounds included)."""

    model_config = ConfigDict(extra="forbid")
    box: Box = Field(description="[[min x, min y(, min z)], [max x, max y(, max z)]] (m), in the model's rest shape")


# a vertex selection: an index, a name of the model (a generator's "top", "left", ...), a box, or a list of them
# (indices are checked against the model, negative ones too, when the config is loaded: one message per field)
Selector = Union[int, str, BoxSelector, list[Union[int, str, BoxSelector]]]


def in_box(vertices: np.ndarray, box, dim: int, field: str) -> np.ndarray:
    lower, upper = (vector(corner, dim, field) for corner in box)
    if np.any(lower > upper):
        raise ModelError(f"{field}: the lower corner {lower.tolist()} is above the upper corner {upper.tolist()}")
    return np.all((vertices >= lower) & (vertices <= upper), axis=1)


def select(selector, model: SpringModel, field: str) -> np.ndarray:
    """The vertex indices a selector names (sorted, unique); ModelError naming ``field`` otherwise."""
    items = selector if isinstance(selector, list) else [selector]
    chosen = []
    for item in items:
        if hasattr(item, "box"):  # a BoxSelector
            inside = np.flatnonzero(in_box(model.vertices, item.box, model.dim, field + ".box"))
            if inside.size == 0:
                raise ModelError(f"{field}: the box {item.box} holds no vertex of the model")
            chosen.append(inside)
        elif isinstance(item, str):
            if item not in model.named_vertices:
                names = ", ".join(model.named_vertices) or "none"
                raise ModelError(f"{field}: the model has no vertex set {item!r} (its names: {names})")
            chosen.append(np.asarray(model.named_vertices[item]))
        else:
            if not 0 <= item < model.vertex_count:
                raise ModelError(f"{field}: vertex {item} does not exist; the model has vertices 0..{model.vertex_count - 1}")
            chosen.append(np.array([item]))
    if not chosen:
        raise ModelError(f"{field}: selects no vertex (give indices, names or boxes)")
    return np.unique(np.concatenate(chosen)).astype(np.intp)
