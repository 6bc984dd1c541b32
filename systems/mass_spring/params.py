"""The config of `mass_spring`: a model (file or generator) with materials, masses, damping, constraints and contact.

Everything that depends on the model (vertex indices, names, dimensions, array lengths) is checked when
the config is loaded, so that a bad config fails with one line naming its field before anything runs.
The model is loaded once per process (``_loaded_model``), keyed by its source and, for files, by the
file's size and modification time.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, field_validator, model_validator

from ..base import SystemParams
from ..contact.params import ContactSpec
from ..vertex.constraint_config import Prescribed, Sliding
from ..vertex.damping import DampingTerm
from ..vertex.errors import ModelError
from ..vertex.fields import Box, NonNegative, Positive, Vector
from ..vertex.files import file_digest, find_file
from ..vertex.initial_state import InitialShape
from ..vertex.model_files import load_model_file
from ..vertex.selectors import Selector
from ..vertex.spring_model import SpringModel
from .assemble import resolve
from .generators import model_source
from .laws import SPRING_LAWS
from .system import MassSpring

__all__ = ["MassSpringParams"]


class Region(BaseModel):
    """A heterogeneous material: the springs whose two ends (at rest) lie in the box get this stiffness."""

    model_config = ConfigDict(extra="forbid")
    box: Box = Field(description="[[min...], [max...]] (m), in the model's rest shape")
    stiffness: Union[NonNegative, dict[str, NonNegative]] = Field(description="N/m: one value, or one per spring kind")


class MassSpec(BaseModel):
    """How the vertex masses are set: at most one of per_vertex, total, density, file. None of them (the
    default): the model file's masses where it has them, else a total of 1 kg."""

    model_config = ConfigDict(extra="forbid")
    per_vertex: Positive | None = Field(None, description="kg at every vertex")
    total: Positive | None = Field(None, description="kg in all, shared as `by` says")
    by: Literal["auto", "equal", "area"] = Field("auto", description="how a total is shared out: equal shares, by area "
                                                                     "(a third of each triangle's), or auto: by area where the model has triangles")
    density: Positive | None = Field(None, description="kg/m^2: each triangle's area times the density, a third to each corner")
    file: bool = Field(False, description="the model file's per-vertex masses (config: mass: file)")

    @model_validator(mode="before")
    @classmethod
    def _file_shorthand(cls, data: Any) -> Any:
        return {"file": True} if data == "file" else data

    @model_validator(mode="after")
    def _one_rule(self) -> "MassSpec":
        given = [name for name in ("per_vertex", "total", "density", "file") if getattr(self, name) not in (None, False)]
        if len(given) > 1:
            raise ValueError(f"give one of per_vertex, total, density (or mass: file); got {given}")
        return self


class MassSpringParams(SystemParams):
    """Config of `mass_spring`: point masses and springs from a model file or a generator (2-D or 3-D)."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["mass_spring"] = "mass_spring"
    model: Union[str, dict[str, Any]] = Field({"square": {"segments": 4, "size": 1.0}},
                                              description="a model file (.npz or a mesh), or {grid: ...}, {square: ...}, {rope: ...}, {file: ...}")
    spring_law: Literal[tuple(SPRING_LAWS)] = Field("hookean", description="hookean: k/2 (L - l0)^2 | squared_length: k l0^2/2 (L^2/l0^2 - 1)^2")  # type: ignore[valid-type]
    stiffness: Union[NonNegative, dict[str, NonNegative], Literal["file", "auto"]] = Field(
        "auto", description="N/m: one value, one per spring kind ({stretch: .., shear: .., bend: ..}; stretch covers stretch_x "
                            "and stretch_y), file, or auto: the model file's per-spring stiffness where it has one, else 1e4")
    regions: list[Region] = Field([], description="boxes with their own stiffness (later entries win)")
    mass: MassSpec = Field(MassSpec(), description="{per_vertex: kg} | {total: kg, by: auto|equal|area} | {density: kg/m^2} | file; "
                                                   "default: the model file's masses, else {total: 1}")
    gravity: Vector | None = Field(None, description="m/s^2, one component per dimension of the model (default: -9.81 along the last axis)")
    initial: InitialShape = InitialShape()
    damping: Union[NonNegative, list[DampingTerm]] = Field([], description="a number (spring damping k_d, N s/m) or a list of {model, coefficient} / {model: rayleigh, alpha, beta}")
    pinned: Selector = Field([], description="vertices that never move: indices, names of the model, {box: [[min], [max]]}")
    constraints: list[Sliding] = Field([], description="vertices that slide in a plane (normal) or along a line (direction)")
    prescribed: list[Prescribed] = Field([], description="vertices on a path: {vertices, velocity} or {vertices, rotation: {center, axis, rate}}")
    contact: ContactSpec = Field(ContactSpec(), description="penalty or IPC contact with colliders, friction, self-contact "
                                                            "(docs/contact.md); {ground, sphere} as shorthands")
    _file: Path | None = PrivateAttr(None)  # the model file, absolute (workers may start elsewhere)
    _initial_file: Path | None = PrivateAttr(None)  # initial.file, absolute
    _contact_files: dict = PrivateAttr(default_factory=dict)  # the colliders' files by config field, absolute

    @field_validator("model")
    @classmethod
    def _known_source(cls, value):
        model_source(value)  # raises ValueError with the allowed forms
        return value

    @model_validator(mode="after")
    def _consistent_with_model(self) -> "MassSpringParams":
        source = model_source(self.model)
        file = getattr(source, "file", None)
        try:
            if file is not None:
                self._file = find_file(str(file), "model")
                if self._file != (Path.cwd() / Path(file).expanduser()).resolve():  # found beside the config: kept
                    self.model = (str(self._file) if isinstance(self.model, str)  # absolute, for the runs validated
                                  else {**self.model, "file": str(self._file)})  # again elsewhere
            if self.initial.file is not None:
                self._initial_file = find_file(self.initial.file, "initial.file")
                if self._initial_file != (Path.cwd() / Path(self.initial.file).expanduser()).resolve():
                    self.initial.file = str(self._initial_file)
            for number, collider in enumerate(self.contact.colliders):
                if getattr(collider, "file", None) is not None:  # absolute, for the workers (which may start elsewhere)
                    found = find_file(collider.file, f"contact.colliders[{number}].file")
                    collider.file = str(found)
                    self._contact_files[f"contact.colliders[{number}].file"] = found
            resolve(self)
        except ModelError as error:
            raise ValueError(str(error)) from None
        return self

    def input_files(self) -> dict[str, str]:
        """The files this system reads, by config field, with their sha256 (part of the config hash)."""
        files = {"model": self._file, "initial.file": self._initial_file, **self._contact_files}
        return {field: file_digest(path) for field, path in files.items() if path is not None}

    @property
    def dof_count(self) -> int:
        model = self.spring_model()
        return model.dim * model.vertex_count

    def spring_model(self) -> SpringModel:
        source = model_source(self.model)
        if self._file is not None:
            stat = self._file.stat()
            return _loaded_file(str(self._file), getattr(source, "dimension", None), stat.st_size, stat.st_mtime_ns)
        return _generated(json.dumps(self.model, sort_keys=True))

    def build(self) -> MassSpring:
        return MassSpring(**resolve(self))


MassSpringParams.system_class = MassSpring


@functools.lru_cache(maxsize=8)
def _loaded_file(path: str, dimension: int | None, size: int, mtime: int) -> SpringModel:
    try:
        return load_model_file(Path(path), dimension).validate()
    except ModelError as error:
        raise ModelError(f"model: {error}") from None


@functools.lru_cache(maxsize=8)
def _generated(source_json: str) -> SpringModel:
    try:
        return model_source(json.loads(source_json)).build().validate()
    except ModelError as error:
        raise ModelError(f"model: {error}") from None


