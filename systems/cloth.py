"""`cloth`: a mass-spring cloth on a grid (stretch, shear and bend springs, gravity, pins, spring damping,
penalty contact), the config shorthand for a ``mass_spring`` system built from the grid generator."""

from __future__ import annotations

from typing import Annotated, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from .base import System, SystemParams
from .constraints import VertexConstraints
from .contact.build import build_contact
from .contact.params import ContactSpec
from .mass_spring.system import MassSpring
from .vertex.damping import Damping
from .vertex.errors import ModelError
from .vertex.fields import Finite, Positive
from .vertex.files import file_digest, find_file
from .vertex.grids import GridModel

PIN_NAMES = ("top_left", "top_right", "bottom_left", "bottom_right", "top", "bottom", "left", "right")



class ClothSphere(BaseModel):
    """Shorthand: penalty contact with a sphere, P = k/2 max(0, radius - |x - center|)^2 per vertex."""

    model_config = ConfigDict(extra="forbid")
    center: tuple[Finite, Finite, Finite] = Field((0.5, 0.5, -0.6), description="centre (m)")
    radius: Positive = Field(0.3, description="radius (m)")
    stiffness: Positive = Field(1.0e4, description="penalty stiffness (N/m)")


class ClothContact(ContactSpec):
    """The contact of every mass-spring model (systems/contact/params.py), with the cloth's sphere defaults."""

    sphere: ClothSphere | None = None


class ClothParams(SystemParams):
    """Config of `cloth`: an N x M grid of vertices, flat in the plane z = height at the start."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["cloth"] = "cloth"
    resolution: tuple[Annotated[int, Field(ge=2, le=1024)], Annotated[int, Field(ge=2, le=1024)]] = Field(
        (32, 32), description="vertices along x and y")
    size: tuple[Positive, Positive] = Field((1.0, 1.0), description="side lengths along x and y (m)")
    mass: Positive = Field(1.0, description="total mass (kg), lumped equally to the vertices")
    stretch_stiffness: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(1.0e4, description="structural springs along grid edges (N/m)")
    shear_stiffness: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(1.0e3, description="diagonal springs (N/m)")
    bend_stiffness: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(1.0e1, description="springs that skip one vertex (N/m)")
    damping: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(0.0, description="spring damping k_d (N s/m): f = -k_d ((v_i - v_j) . u) u")
    gravity: tuple[Finite, Finite, Finite] = Field((0.0, 0.0, -9.81), description="gravitational acceleration (m/s^2)")
    pinned: list[Union[Literal[PIN_NAMES], Annotated[int, Field(ge=0)]]] = Field(  # type: ignore[valid-type]
        ["top_left", "top_right"], description="pinned vertices: names (" + ", ".join(PIN_NAMES) + ") or indices j * nx + i")
    height: Finite = Field(0.0, description="z of the flat cloth at the start (m)")
    initial_velocity: tuple[Finite, Finite, Finite] = Field((0.0, 0.0, 0.0), description="uniform velocity at the start (m/s)")
    initial_spin: tuple[Finite, Finite, Finite] = Field((0.0, 0.0, 0.0), description="angular velocity about the cloth's centre at the start (rad/s)")
    contact: ClothContact = ClothContact()

    @model_validator(mode="after")
    def _pins_exist(self) -> "ClothParams":
        count = self.resolution[0] * self.resolution[1]
        for pin in self.pinned:
            if isinstance(pin, int) and pin >= count:
                raise ValueError(f"pinned: vertex {pin} does not exist; a {self.resolution[0]}x{self.resolution[1]} cloth has vertices 0..{count - 1}")
        return self

    _contact_files: dict = PrivateAttr(default_factory=dict)  # the colliders' files by config field, absolute

    @model_validator(mode="after")
    def _contact_fits(self) -> "ClothParams":
        """The contact's checks that need the model (files, meshes, an initial state that already intersects) when
        the config is loaded, as mass_spring makes them: one line naming the field, before anything runs. The
        colliders' files are found as a model file is (beside the config first) and kept absolute, for workers."""
        if self.contact.active:
            model = GridModel(resolution=self.resolution, size=self.size, height=self.height).build()
            try:
                for number, collider in enumerate(self.contact.colliders):
                    if getattr(collider, "file", None) is not None:
                        found = find_file(collider.file, f"contact.colliders[{number}].file")
                        collider.file = str(found)
                        self._contact_files[f"contact.colliders[{number}].file"] = found
                build_contact(self.contact, dim=3, rest=model.vertices, x0=model.vertices,
                              masses=np.full(model.vertex_count, self.mass / model.vertex_count),
                              triangles=model.triangles, edges=model.springs, find_file=find_file)
            except ModelError as error:
                raise ValueError(str(error)) from None
        return self

    def input_files(self) -> dict[str, str]:
        """The colliders' files with their sha256 (part of the config hash, as a mass_spring model file is)."""
        return {field: file_digest(path) for field, path in self._contact_files.items()}

    @property
    def dof_count(self) -> int:
        return 3 * self.resolution[0] * self.resolution[1]


def grid_springs(nx: int, ny: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Vertex pairs (i, j) of the stretch, shear and bend springs of an nx x ny grid (vertex = row * nx + col)."""
    index = np.arange(nx * ny).reshape(ny, nx)
    pairs = {
        "stretch": [(index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])],
        "shear": [(index[:-1, :-1], index[1:, 1:]), (index[:-1, 1:], index[1:, :-1])],
        "bend": [(index[:, :-2], index[:, 2:]), (index[:-2, :], index[2:, :])],
    }
    return {kind: (np.concatenate([a.ravel() for a, _ in items]), np.concatenate([b.ravel() for _, b in items]))
            for kind, items in pairs.items()}


class Cloth(MassSpring):
    """The mass-spring cloth on a grid: a ``MassSpring`` built from the grid generator with one stiffness
    per spring kind, equal vertex masses, spring damping and penalty contact: a config shorthand whose
    frames and energies equal those recorded before the general system existed, bit for bit.

    Spring Hessian block (lectures): H_e = k [u u^T + (1 - l0/L)(I - u u^T)], u = (x_i - x_j)/L;
    the SPD projection clamps 1 - l0/L at 0 (the only eigenvalue that can turn negative, when the
    spring is compressed). Spring damping -k_d ((v_i - v_j) . u) u is f_d = -D(x) v with
    D = sum_e k_d u u^T in the same block pattern.
    """

    def __init__(self, params: ClothParams):
        self.params = params
        nx, ny = params.resolution
        self.shape = (nx, ny)
        model = GridModel(resolution=(nx, ny), size=params.size, height=params.height).build()
        rest = model.vertices
        spin = np.cross(np.array(params.initial_spin), rest - rest.mean(axis=0))
        v0 = spin + np.array(params.initial_velocity)
        self.vertex_mass = params.mass / model.vertex_count
        stiffness_of = {"stretch": params.stretch_stiffness, "shear": params.shear_stiffness, "bend": params.bend_stiffness}
        kind_stiffness = np.array([stiffness_of[name.split("_")[0]] for name in model.kind_names])
        stiffness = kind_stiffness[model.kinds]
        # springs of a kind without stiffness add nothing, unless damping acts along them
        kept = np.flatnonzero((stiffness > 0) | (params.damping > 0))
        springs = model.springs[kept]
        pinned = np.unique(np.concatenate([model.named_vertices[pin] if isinstance(pin, str) else np.array([pin])
                                           for pin in params.pinned])).astype(np.intp) if params.pinned else np.zeros(0, dtype=np.intp)
        self.pinned_vertices = pinned
        masses = np.full(model.vertex_count, self.vertex_mass)
        super().__init__(
            rest=rest, x0=rest, v0=v0, springs=springs, stiffness=stiffness[kept],
            rest_length=np.linalg.norm(rest[springs[:, 0]] - rest[springs[:, 1]], axis=1),
            masses=masses, gravity=np.array(params.gravity, dtype=float),
            damping=(Damping("spring", params.damping),) if params.damping > 0 else (),
            constraints=VertexConstraints(3, model.vertex_count, pinned, [], []),
            contact=build_contact(params.contact, dim=3, rest=rest, x0=rest, masses=masses, triangles=model.triangles,
                                  edges=model.springs, find_file=find_file),
            triangles=model.triangles, grid_shape=model.grid_shape, spring_kinds=model.kinds[kept], kind_names=model.kind_names)

    energy_reference_name = "max(M |g| L, |KE0| + |PE0|)"

    def energy_scale(self) -> float:
        """Energy of lifting the cloth by its longest side, M |g| L, or |KE0| + |PE0| if larger (J): a cloth
        at rest has E0 = 0 and a nudge of 1e-8 m/s gives E0 ~ 1e-18 J, which no drift should be divided by."""
        lift = self.params.mass * float(np.linalg.norm(self.gravity)) * max(self.params.size)
        return max(System.energy_scale(self), lift) if lift > 0 else System.energy_scale(self)


ClothParams.system_class = Cloth
