"""The start state from the config's ``initial``: the rest shape scaled, rotated about its centroid and translated, or
the positions of a file; then a uniform velocity and a spin about the centroid."""

from __future__ import annotations

import math
from typing import Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ..constraints import cross, rotate
from .errors import ModelError
from .fields import Finite, Positive, Vector, check_axis, vector
from .files import find_file
from .model_files import load_model_file
from .spring_model import SpringModel


class Rotation(BaseModel):
    model_config = ConfigDict(extra="forbid")
    axis: Vector = Field([0.0, 0.0, 1.0], description="rotation axis (3 components; 2-D models turn about z)")
    degrees: Finite = Field(description="angle (deg)")


class InitialShape(BaseModel):
    """The start state from the rest shape: scale, then rotate about the centroid, then translate; or a file."""

    model_config = ConfigDict(extra="forbid")
    scale: Union[Positive, list[Positive]] = Field(1.0, description="factor, or one per axis, about the centroid")
    rotate: Union[Finite, Rotation] = Field(0.0, description="deg about z through the centroid, or {axis, degrees}")
    translate: Vector | None = Field(None, description="offset (m)")
    file: str | None = Field(None, description="start positions from a model file with the same vertices (instead of the transforms)")
    velocity: Vector | None = Field(None, description="uniform start velocity (m/s)")
    spin: Union[Finite, Vector] = Field(0.0, description="angular velocity about the centroid (rad/s): a number (about z) or a 3-vector")


def initial_state(params, model: SpringModel, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    initial, dim = params.initial, model.dim
    centroid = rest.mean(axis=0)
    if initial.file is not None:
        path = params._initial_file if params._initial_file is not None else find_file(initial.file, "initial.file")
        x0 = _start_positions(path, dim)
        if x0.shape != rest.shape:
            raise ModelError(f"initial.file: {x0.shape[0]} vertices in {dim}-D, but the model has {rest.shape[0]}")
    else:
        scale = np.full(dim, initial.scale) if not isinstance(initial.scale, list) else vector(initial.scale, dim, "initial.scale")
        rotation = initial.rotate
        axis, degrees = ((np.array([0.0, 0.0, 1.0]), float(rotation)) if not hasattr(rotation, "degrees")
                         else (vector(rotation.axis, 3, "initial.rotate.axis"), rotation.degrees))
        check_axis(axis, dim, "initial.rotate.axis")
        x0 = rotate((rest - centroid) * scale, axis / np.linalg.norm(axis), math.radians(degrees)) + centroid
        if initial.translate is not None:
            x0 = x0 + vector(initial.translate, dim, "initial.translate")
    v0 = np.zeros_like(x0)
    if initial.velocity is not None:
        v0 += vector(initial.velocity, dim, "initial.velocity")
    spin = initial.spin
    offset = x0 - x0.mean(axis=0)
    if isinstance(spin, list):
        omega = vector(spin, 3, "initial.spin")
        if dim == 2 and (omega[0] or omega[1]):
            raise ModelError("initial.spin: a 2-D model spins about z only; give a number or [0, 0, w]")
        v0 += cross(omega, offset)
    elif spin:
        v0 += cross(np.array([0.0, 0.0, float(spin)]), offset)
    return x0, v0


def _start_positions(path, dim: int) -> np.ndarray:
    """initial.file's vertex positions: an .npz's `vertices` array alone (no springs needed), or any model file's."""
    if str(path).endswith(".npz"):
        with np.load(path, allow_pickle=False) as arrays:
            if "vertices" not in arrays:
                raise ModelError(f"initial.file: {path} has no array 'vertices'")
            vertices = np.asarray(arrays["vertices"], dtype=float)
        if vertices.ndim != 2 or vertices.shape[1] != dim or not np.all(np.isfinite(vertices)):
            raise ModelError(f"initial.file: 'vertices' in {path} must be finite, n x {dim}; got shape {vertices.shape}")
        return vertices
    return load_model_file(path, dim).vertices.astype(float)
