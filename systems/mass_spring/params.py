"""The config of `mass_spring`: a model (file or generator) with materials, masses, damping, constraints and contact.

Everything that depends on the model (vertex indices, names, dimensions, array lengths) is checked when
the config is loaded, so that a bad config fails with one line naming its field before anything runs.
The model is loaded once per process (``_loaded_model``), keyed by its source and, for files, by the
file's size and modification time.
"""

from __future__ import annotations

import contextvars
import functools
import hashlib
import json
import math
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, field_validator, model_validator

from ..base import SystemParams
from ..constraints import PrescribedMotion, VertexConstraints, filter_block
from .files import load_model_file, lumped_area_masses
from .generators import model_source
from .model import ModelError, SpringModel
from .system import DAMPING_MODELS, SPRING_LAWS, Contact, Damping, MassSpring

# Folders where relative model paths are looked for after the current one: the config file's folder, set by
# the config loader while it validates a config read from a file (runner/config.py: load_experiment).
SEARCH_FOLDERS: contextvars.ContextVar[tuple[Path, ...]] = contextvars.ContextVar("model_search_folders", default=())


def find_file(name: str, field: str) -> Path:
    """The absolute path of a model file: as given, else relative to the current folder, else to the config's
    folder; ModelError naming the field and where it looked."""
    path = Path(name).expanduser()
    candidates = [path] if path.is_absolute() else [Path.cwd() / path, *(folder / path for folder in SEARCH_FOLDERS.get())]
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    looked = ", ".join(str(candidate.parent) for candidate in candidates)
    raise ModelError(f"{field}: file {name!r} not found (looked in {looked})")


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes: a changed model file is a changed experiment (config hash, resume)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Vector = list[Finite]
Box = tuple[Vector, Vector]


class BoxSelector(BaseModel):
    """The vertices whose rest positions lie in the axis-aligned box [min, max] (bounds included)."""

    model_config = ConfigDict(extra="forbid")
    box: Box = Field(description="[[min x, min y(, min z)], [max x, max y(, max z)]] (m), in the model's rest shape")


# a vertex selection: an index, a name of the model (a generator's "top", "left", ...), a box, or a list of them
Selector = Union[Annotated[int, Field(ge=0)], str, BoxSelector, list[Union[Annotated[int, Field(ge=0)], str, BoxSelector]]]


class Region(BaseModel):
    """A heterogeneous material: the springs whose two ends (at rest) lie in the box get this stiffness."""

    model_config = ConfigDict(extra="forbid")
    box: Box = Field(description="[[min...], [max...]] (m), in the model's rest shape")
    stiffness: Union[NonNegative, dict[str, NonNegative]] = Field(description="N/m: one value, or one per spring kind")


class MassSpec(BaseModel):
    """How the vertex masses are set: exactly one of per_vertex, total, density; or ``file``."""

    model_config = ConfigDict(extra="forbid")
    per_vertex: Positive | None = Field(None, description="kg at every vertex")
    total: Positive | None = Field(None, description="kg in all, in equal shares (by: equal) or by area (by: area, triangle meshes)")
    by: Literal["equal", "area"] = Field("equal", description="how a total is shared out")
    density: Positive | None = Field(None, description="kg/m^2: each triangle's area times the density, a third to each corner")
    file: bool = Field(False, description="the model file's per-vertex masses (config: mass: file)")

    @model_validator(mode="before")
    @classmethod
    def _file_shorthand(cls, data: Any) -> Any:
        return {"file": True} if data == "file" else data

    @model_validator(mode="after")
    def _one_rule(self) -> "MassSpec":
        given = [name for name in ("per_vertex", "total", "density", "file") if getattr(self, name) not in (None, False)]
        if len(given) != 1:
            raise ValueError(f"give exactly one of per_vertex, total, density (or mass: file); got {given or 'none'}")
        return self


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


class DampingTerm(BaseModel):
    """One damping force f = -D v of the lectures: spring, relative, drag, or rayleigh (alpha M + beta K_rest)."""

    model_config = ConfigDict(extra="forbid")
    model: Literal[DAMPING_MODELS] = Field(description=" | ".join(DAMPING_MODELS))  # type: ignore[valid-type]
    coefficient: NonNegative = Field(0.0, description="k_d (N s/m): spring, relative, drag")
    alpha: NonNegative = Field(0.0, description="rayleigh: mass factor (1/s)")
    beta: NonNegative = Field(0.0, description="rayleigh: stiffness factor (s)")


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
        if not any(component != 0.0 for component in vector):
            raise ValueError(f"the {'normal' if self.normal is not None else 'direction'} {vector} is zero")
        return self


class PathRotation(BaseModel):
    model_config = ConfigDict(extra="forbid")
    center: Vector = Field(description="a point on the axis (m)")
    axis: Vector = Field([0.0, 0.0, 1.0], description="rotation axis (3 components; 2-D models turn about z)")
    rate: Finite = Field(description="angular velocity (deg/s)")


class Prescribed(BaseModel):
    """Vertices moved by the user: a constant velocity, or a rotation about an axis at a constant rate."""

    model_config = ConfigDict(extra="forbid")
    vertices: Selector
    velocity: Vector | None = Field(None, description="m/s")
    rotation: PathRotation | None = None

    @model_validator(mode="after")
    def _one_of(self) -> "Prescribed":
        if (self.velocity is None) == (self.rotation is None):
            raise ValueError("give either velocity or rotation")
        return self


class GroundContact(BaseModel):
    model_config = ConfigDict(extra="forbid")
    height: Finite = Field(-1.0, description="the last coordinate (z in 3-D, y in 2-D) of the ground (m)")
    stiffness: Positive = Field(1.0e4, description="penalty stiffness (N/m)")


class SphereContact(BaseModel):
    model_config = ConfigDict(extra="forbid")
    center: Vector = Field(description="centre (m), in the model's dimension")
    radius: Positive = Field(description="radius (m)")
    stiffness: Positive = Field(1.0e4, description="penalty stiffness (N/m)")


class ContactSpec(BaseModel):
    """Penalty contact P = k/2 depth^2 per vertex with a ground and/or a sphere (a circle in 2-D)."""

    model_config = ConfigDict(extra="forbid")
    ground: GroundContact | None = None
    sphere: SphereContact | None = None


class MassSpringParams(SystemParams):
    """Config of `mass_spring`: point masses and springs from a model file or a generator (2-D or 3-D)."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["mass_spring"] = "mass_spring"
    model: Union[str, dict[str, Any]] = Field({"square": {"segments": 4, "size": 1.0}},
                                              description="a model file (.npz or a mesh), or {grid: ...}, {square: ...}, {rope: ...}, {file: ...}")
    spring_law: Literal[tuple(SPRING_LAWS)] = Field("hookean", description="hookean: k/2 (L - l0)^2 | squared_length: k l0^2/2 (L^2/l0^2 - 1)^2")  # type: ignore[valid-type]
    stiffness: Union[NonNegative, dict[str, NonNegative], Literal["file"]] = Field(
        1.0e4, description="N/m: one value, one per spring kind ({stretch: .., shear: .., bend: ..}; stretch covers stretch_x and stretch_y), or file")
    regions: list[Region] = Field([], description="boxes with their own stiffness (later entries win)")
    mass: MassSpec = Field(MassSpec(total=1.0), description="{per_vertex: kg} | {total: kg, by: equal|area} | {density: kg/m^2} | file")
    gravity: Vector | None = Field(None, description="m/s^2, one component per dimension of the model (default: -9.81 along the last axis)")
    initial: InitialShape = InitialShape()
    damping: Union[NonNegative, list[DampingTerm]] = Field([], description="a number (spring damping k_d, N s/m) or a list of {model, coefficient} / {model: rayleigh, alpha, beta}")
    pinned: Selector = Field([], description="vertices that never move: indices, names of the model, {box: [[min], [max]]}")
    constraints: list[Sliding] = Field([], description="vertices that slide in a plane (normal) or along a line (direction)")
    prescribed: list[Prescribed] = Field([], description="vertices on a path: {vertices, velocity} or {vertices, rotation: {center, axis, rate}}")
    contact: ContactSpec = ContactSpec()
    _file: Path | None = PrivateAttr(None)  # the model file, absolute (workers may start elsewhere)
    _initial_file: Path | None = PrivateAttr(None)  # initial.file, absolute

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
                if not (Path.cwd() / Path(file).expanduser()).is_file():  # found beside the config: keep where,
                    self.model = (str(self._file) if isinstance(self.model, str)  # for the runs validated later
                                  else {**self.model, "file": str(self._file)})
            if self.initial.file is not None:
                self._initial_file = find_file(self.initial.file, "initial.file")
                if not (Path.cwd() / Path(self.initial.file).expanduser()).is_file():
                    self.initial.file = str(self._initial_file)
            resolve(self)
        except ModelError as error:
            raise ValueError(str(error)) from None
        return self

    def input_files(self) -> dict[str, str]:
        """The files this system reads, by config field, with their sha256 (part of the config hash)."""
        files = {"model": self._file, "initial.file": self._initial_file}
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


# -- from config and model to the arrays of MassSpring -----------------------------------------------
def resolve(params: MassSpringParams) -> dict[str, Any]:
    """The keyword arguments of MassSpring; ModelError (naming the config field) for anything inconsistent."""
    model = params.spring_model()
    dim, n = model.dim, model.vertex_count
    rest = model.vertices.astype(float)
    gravity = np.zeros(dim) if params.gravity is None else None
    if params.gravity is None:
        gravity[-1] = -9.81
    else:
        gravity = _vector(params.gravity, dim, "gravity")
    stiffness = _stiffness(params, model)
    rest_length = (model.rest_lengths if model.rest_lengths is not None
                   else np.linalg.norm(rest[model.springs[:, 0]] - rest[model.springs[:, 1]], axis=1))
    damping = _damping(params)
    along_springs = any(term.model in ("spring", "relative") for term in damping)
    kept = np.flatnonzero((stiffness > 0) | along_springs)
    if kept.size == 0:
        raise ModelError("stiffness: every spring has stiffness 0 and no damping acts along the springs: nothing holds the model together")
    x0, v0 = _initial_state(params, model, rest)
    constraints = _constraints(params, model, rest, x0)
    return dict(rest=rest, x0=x0, v0=v0, springs=model.springs[kept], stiffness=stiffness[kept], rest_length=rest_length[kept],
                masses=_masses(params, model), gravity=gravity, law=params.spring_law, damping=damping,
                constraints=constraints, contact=_contact(params, dim), triangles=model.triangles, grid_shape=model.grid_shape)


def _vector(values: list[float], dim: int, field: str) -> np.ndarray:
    if len(values) != dim:
        raise ModelError(f"{field}: {len(values)} components given, but the model is {dim}-D: give {dim}")
    return np.array(values, dtype=float)


def _kind_matches(key: str, kind_names: tuple[str, ...]) -> list[int]:
    """The kinds a stiffness key names: itself, or every kind it prefixes (stretch -> stretch_x, stretch_y)."""
    return [index for index, name in enumerate(kind_names) if name == key or name.startswith(key + "_")]


def _per_kind(values: dict[str, float], model: SpringModel, field: str, complete: bool) -> np.ndarray:
    """Per-kind stiffness as an array over kinds (NaN where unset); specific keys win over prefixes."""
    result = np.full(len(model.kind_names), np.nan)
    for key in sorted(values, key=lambda key: len(_kind_matches(key, model.kind_names)), reverse=True):
        matches = _kind_matches(key, model.kind_names)
        if not matches:
            raise ModelError(f"{field}: this model has no spring kind {key!r}; its kinds are {', '.join(model.kind_names)}")
        result[matches] = values[key]
    present = np.unique(model.kinds)
    missing = [model.kind_names[kind] for kind in present if np.isnan(result[kind])]
    if complete and missing:
        raise ModelError(f"{field}: no stiffness for the spring kinds {', '.join(missing)}; give one per kind "
                         f"(kinds: {', '.join(model.kind_names[kind] for kind in present)}) or one number")
    return result


def _stiffness(params: MassSpringParams, model: SpringModel) -> np.ndarray:
    if params.stiffness == "file":
        if model.stiffness is None:
            raise ModelError("stiffness: file, but the model file has no 'stiffness' array")
        stiffness = model.stiffness.astype(float).copy()
    elif isinstance(params.stiffness, dict):
        stiffness = _per_kind(params.stiffness, model, "stiffness", complete=True)[model.kinds]
    else:
        stiffness = np.full(model.spring_count, float(params.stiffness))
    for number, region in enumerate(params.regions):
        field = f"regions[{number}]"
        inside = _in_box(model.vertices, region.box, model.dim, field + ".box")
        chosen = inside[model.springs[:, 0]] & inside[model.springs[:, 1]]
        if not chosen.any():
            raise ModelError(f"{field}.box: no spring has both ends in {region.box}")
        if isinstance(region.stiffness, dict):
            per_kind = _per_kind(region.stiffness, model, field + ".stiffness", complete=False)[model.kinds]
            chosen &= ~np.isnan(per_kind)
            stiffness[chosen] = per_kind[chosen]
        else:
            stiffness[chosen] = region.stiffness
    return stiffness


def _masses(params: MassSpringParams, model: SpringModel) -> np.ndarray:
    n = model.vertex_count
    if params.mass.file:
        if model.masses is None:
            raise ModelError("mass: file, but the model file has no 'masses' array")
        return model.masses.astype(float)
    spec = params.mass
    if spec.per_vertex is not None:
        return np.full(n, spec.per_vertex)
    if spec.total is not None and spec.by == "equal":
        return np.full(n, spec.total / n)
    if model.triangles is None:
        raise ModelError(f"mass: {'by: area' if spec.total is not None else 'density'} needs a model with triangles; "
                         "this one has none: use {total: kg} (equal shares) or {per_vertex: kg}")
    areas = lumped_area_masses(model.vertices, model.triangles)
    if np.any(areas <= 0):
        raise ModelError(f"mass: vertex {int(np.flatnonzero(areas <= 0)[0])} touches no triangle of positive area, so area lumping gives it no mass")
    return areas * spec.density if spec.density is not None else areas * (spec.total / float(np.sum(areas)))


def _damping(params: MassSpringParams) -> tuple[Damping, ...]:
    if not isinstance(params.damping, list):
        return (Damping("spring", float(params.damping)),) if params.damping > 0 else ()
    return tuple(Damping(term.model, term.coefficient, term.alpha, term.beta) for term in params.damping
                 if term.coefficient > 0 or term.alpha > 0 or term.beta > 0)


def _rotation_matrix(axis: np.ndarray, degrees: float, dim: int) -> np.ndarray:
    angle = math.radians(degrees)
    cos, sin = math.cos(angle), math.sin(angle)
    if dim == 2:
        sign = 1.0 if axis[2] >= 0 else -1.0
        return np.array([[cos, -sign * sin], [sign * sin, cos]])
    unit = axis / np.linalg.norm(axis)
    cross = np.array([[0, -unit[2], unit[1]], [unit[2], 0, -unit[0]], [-unit[1], unit[0], 0]])
    return cos * np.eye(3) + sin * cross + (1 - cos) * np.outer(unit, unit)


def _initial_state(params: MassSpringParams, model: SpringModel, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    initial, dim = params.initial, model.dim
    centroid = rest.mean(axis=0)
    if initial.file is not None:
        path = params._initial_file if params._initial_file is not None else find_file(initial.file, "initial.file")
        x0 = load_model_file(path, dim).vertices.astype(float)
        if x0.shape != rest.shape:
            raise ModelError(f"initial.file: {x0.shape[0]} vertices in {dim}-D, but the model has {rest.shape[0]}")
    else:
        scale = np.full(dim, initial.scale) if not isinstance(initial.scale, list) else _vector(initial.scale, dim, "initial.scale")
        rotation = initial.rotate
        axis, degrees = ((np.array([0.0, 0.0, 1.0]), float(rotation)) if not isinstance(rotation, Rotation)
                         else (_vector(rotation.axis, 3, "initial.rotate.axis"), rotation.degrees))
        if not np.any(axis):
            raise ModelError("initial.rotate.axis: the axis is zero")
        x0 = (rest - centroid) * scale @ _rotation_matrix(axis, degrees, dim).T + centroid
        if initial.translate is not None:
            x0 = x0 + _vector(initial.translate, dim, "initial.translate")
    v0 = np.zeros_like(x0)
    if initial.velocity is not None:
        v0 += _vector(initial.velocity, dim, "initial.velocity")
    spin = initial.spin
    offset = x0 - x0.mean(axis=0)
    if isinstance(spin, list):
        omega = _vector(spin, 3, "initial.spin")
        v0 += np.cross(omega, offset) if dim == 3 else omega[2] * np.stack([-offset[:, 1], offset[:, 0]], axis=1)
    elif spin:
        v0 += (np.cross([0.0, 0.0, spin], offset) if dim == 3 else spin * np.stack([-offset[:, 1], offset[:, 0]], axis=1))
    return x0, v0


def _in_box(vertices: np.ndarray, box, dim: int, field: str) -> np.ndarray:
    lower, upper = (_vector(corner, dim, field) for corner in box)
    if np.any(lower > upper):
        raise ModelError(f"{field}: the lower corner {lower.tolist()} is above the upper corner {upper.tolist()}")
    return np.all((vertices >= lower) & (vertices <= upper), axis=1)


def select(selector, model: SpringModel, field: str) -> np.ndarray:
    """The vertex indices a selector names (sorted, unique); ModelError naming ``field`` otherwise."""
    items = selector if isinstance(selector, list) else [selector]
    chosen = []
    for item in items:
        if isinstance(item, BoxSelector):
            inside = np.flatnonzero(_in_box(model.vertices, item.box, model.dim, field + ".box"))
            if inside.size == 0:
                raise ModelError(f"{field}: the box {item.box} holds no vertex of the model")
            chosen.append(inside)
        elif isinstance(item, str):
            if item not in model.named_vertices:
                names = ", ".join(model.named_vertices) or "none"
                raise ModelError(f"{field}: the model has no vertex set {item!r} (its names: {names})")
            chosen.append(np.asarray(model.named_vertices[item]))
        else:
            if item >= model.vertex_count:
                raise ModelError(f"{field}: vertex {item} does not exist; the model has vertices 0..{model.vertex_count - 1}")
            chosen.append(np.array([item]))
    return np.unique(np.concatenate(chosen)).astype(np.intp) if chosen else np.zeros(0, dtype=np.intp)


def _constraints(params: MassSpringParams, model: SpringModel, rest: np.ndarray, x0: np.ndarray) -> VertexConstraints:
    dim = model.dim
    owner = np.full(model.vertex_count, "", dtype=object)  # which config entry constrains each vertex

    def claim(vertices: np.ndarray, field: str) -> None:
        taken = vertices[owner[vertices] != ""]
        if taken.size:
            raise ModelError(f"{field}: vertex {int(taken[0])} is already constrained by {owner[taken[0]]}; a vertex takes one constraint")
        owner[vertices] = field

    pinned = select(params.pinned, model, "pinned")
    claim(pinned, "pinned")
    sliding = []
    for number, entry in enumerate(params.constraints):
        field = f"constraints[{number}]"
        vertices = select(entry.vertices, model, field + ".vertices")
        claim(vertices, field)
        if entry.normal is not None:
            block = filter_block(dim, normal=_vector(entry.normal, dim, field + ".normal"))
        else:
            block = filter_block(dim, direction=_vector(entry.direction, dim, field + ".direction"))
        sliding.append((vertices, block))
    prescribed = []
    for number, entry in enumerate(params.prescribed):
        field = f"prescribed[{number}]"
        vertices = select(entry.vertices, model, field + ".vertices")
        claim(vertices, field)
        if entry.velocity is not None:
            motion = PrescribedMotion(vertices, x0[vertices], velocity=_vector(entry.velocity, dim, field + ".velocity"))
        else:
            axis = _vector(entry.rotation.axis, 3, field + ".rotation.axis")
            if not np.any(axis):
                raise ModelError(f"{field}.rotation.axis: the axis is zero")
            if dim == 2 and (axis[0] or axis[1]):
                raise ModelError(f"{field}.rotation.axis: a 2-D model turns about z only; give [0, 0, 1] or [0, 0, -1]")
            center = _vector(entry.rotation.center, dim, field + ".rotation.center")
            motion = PrescribedMotion(vertices, x0[vertices],
                                      rotation=(center, axis / np.linalg.norm(axis), math.radians(entry.rotation.rate)))
        prescribed.append(motion)
    return VertexConstraints(dim, model.vertex_count, pinned, sliding, prescribed)


def _contact(params: MassSpringParams, dim: int) -> Contact:
    spec = params.contact
    sphere = None
    if spec.sphere is not None:
        sphere = (_vector(spec.sphere.center, dim, "contact.sphere.center"), spec.sphere.radius, spec.sphere.stiffness)
    ground = None if spec.ground is None else (spec.ground.height, spec.ground.stiffness)
    return Contact(ground=ground, sphere=sphere)
