"""The config's constraints of vertices: ``pinned`` (never move), ``constraints`` (sliding in a plane or along a line)
and ``prescribed`` (on a path), checked against the model and made into the system's ``VertexConstraints``."""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..constraints import PrescribedMotion, VertexConstraints, filter_block
from .errors import ModelError
from .fields import ConstantRotation, Positive, Vector, check_axis, vector
from .selectors import Selector, select
from .spring_model import SpringModel


class Sliding(BaseModel):
    """Vertices that slide in a plane (its normal) or along a line (its direction) through their start positions."""

    model_config = ConfigDict(extra="forbid")
    vertices: Selector
    normal: Vector | None = Field(None, description="the plane's normal: the vertices move perpendicular to it")
    direction: Vector | None = Field(None, description="the line's direction: the vertices move along it only")

    @model_validator(mode="after")
    def _one_of(self) -> "Sliding":
        if (self.normal is None) == (self.direction is None):
            raise ValueError("give either normal (sliding in a plane) or direction (sliding along a line)")
        vector = self.normal if self.normal is not None else self.direction
        if not math.hypot(*vector) > 0.0:  # its length must survive in floating point, for the unit vector
            raise ValueError(f"the {'normal' if self.normal is not None else 'direction'} {vector} is zero")
        return self


class Prescribed(BaseModel):
    """Vertices moved by the user: a constant velocity, or a rotation about an axis at a constant rate."""

    model_config = ConfigDict(extra="forbid")
    vertices: Selector
    velocity: Vector | None = Field(None, description="m/s")
    rotation: ConstantRotation | None = None
    until: Positive | None = Field(
        None, description="s: the vertices follow the path until this time, then are released (free, with the "
                          "path's velocity there); none: for the whole run")

    @model_validator(mode="after")
    def _one_of(self) -> "Prescribed":
        if (self.velocity is None) == (self.rotation is None):
            raise ValueError("give either velocity or rotation")
        return self


def vertex_constraints(params, model: SpringModel, rest: np.ndarray, x0: np.ndarray) -> VertexConstraints:
    dim = model.dim
    owner = np.full(model.vertex_count, "", dtype=object)  # which config entry constrains each vertex

    def claim(vertices: np.ndarray, field: str) -> None:
        taken = vertices[owner[vertices] != ""]
        if taken.size:
            raise ModelError(f"{field}: vertex {int(taken[0])} is already constrained by {owner[taken[0]]}; a vertex takes one constraint")
        owner[vertices] = field

    pinned = select(params.pinned, model, "pinned") if params.pinned != [] else np.zeros(0, dtype=np.intp)
    claim(pinned, "pinned")
    sliding = []
    for number, entry in enumerate(params.constraints):
        field = f"constraints[{number}]"
        vertices = select(entry.vertices, model, field + ".vertices")
        claim(vertices, field)
        if entry.normal is not None:
            block = filter_block(dim, normal=vector(entry.normal, dim, field + ".normal"))
        else:
            block = filter_block(dim, direction=vector(entry.direction, dim, field + ".direction"))
        sliding.append((vertices, block))
    prescribed = []
    for number, entry in enumerate(params.prescribed):
        field = f"prescribed[{number}]"
        vertices = select(entry.vertices, model, field + ".vertices")
        claim(vertices, field)
        if entry.velocity is not None:
            motion = PrescribedMotion(vertices, x0[vertices], velocity=vector(entry.velocity, dim, field + ".velocity"),
                                      until=entry.until)
        else:
            axis = vector(entry.rotation.axis, 3, field + ".rotation.axis")
            check_axis(axis, dim, field + ".rotation.axis")
            center = vector(entry.rotation.center, dim, field + ".rotation.center")
            motion = PrescribedMotion(vertices, x0[vertices],
                                      rotation=(center, axis / np.linalg.norm(axis), math.radians(entry.rotation.rate)),
                                      until=entry.until)
        prescribed.append(motion)
    return VertexConstraints(dim, model.vertex_count, pinned, sliding, prescribed)
