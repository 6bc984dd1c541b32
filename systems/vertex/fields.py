"""The config's value types that every system of vertices shares, and their checks against the model.

Numbers that must be finite (``Finite``), positive or non-negative; vectors (``Vector``: checked against the
model's dimension by ``vector`` when the config is loaded, one message per field); axis-aligned boxes
(``Box``); rotation axes (``check_axis``); a rotation at a constant rate (``ConstantRotation``: of prescribed
vertices, or of a collider).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .errors import ModelError

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Vector = list[Finite]
Box = tuple[Vector, Vector]


class ConstantRotation(BaseModel):
    """A rotation at a constant rate about an axis through ``center``: of prescribed vertices, or of a collider
    (whose centre moves with its velocity)."""

    model_config = ConfigDict(extra="forbid")
    center: Vector = Field(description="a point on the axis (m), at t = 0")
    axis: Vector = Field([0.0, 0.0, 1.0], description="rotation axis (3 components; 2-D ones turn about z)")
    rate: Finite = Field(description="angular velocity (deg/s)")


def vector(values: list[float], dim: int, field: str) -> np.ndarray:
    if len(values) != dim:
        raise ModelError(f"{field}: {len(values)} components given, but the model is {dim}-D: give {dim}")
    return np.array(values, dtype=float)


def check_axis(axis: np.ndarray, dim: int, field: str) -> None:
    if not np.linalg.norm(axis) > 0.0:
        raise ModelError(f"{field}: the axis is zero")
    if dim == 2 and (axis[0] or axis[1]):
        raise ModelError(f"{field}: a 2-D model turns about z only; give [0, 0, 1] or [0, 0, -1]")
