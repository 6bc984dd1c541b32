"""The config of contact: ``system.contact`` of a mass-spring model (and of the cloth shorthand).

    contact:
      method: ipc                  # penalty | ipc
      dhat: 1.0e-3                 # m, the barrier's reach (ipc)
      stiffness: auto              # penalty k_p (N/m), or the barrier stiffness (ipc; auto = IPC's estimate and update)
      damping: 0.0                 # penalty only: k_d in f_c = -k_p d - k_d v_n (N s/m)
      friction: {mu: 0.11, epsv: 1.0e-3}
      self: false                  # self-contact of models with triangles (ipc)
      colliders: [{shape: plane, normal: [0, 1], point: [0, -1]}, {shape: sphere, center: .., radius: ..}, ...]

``ground`` and ``sphere`` stay as shorthands for a plane with normal +e_last and a sphere, each with its own
penalty stiffness (the configs written before colliders existed). Checks that need the model (dimensions,
files, an initial state that already intersects) are made where the contact is built (``build.py``).
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..vertex.fields import ConstantRotation, Finite, NonNegative, Positive, Vector


CONTACT_METHODS = ("penalty", "ipc")
# A penalty stiffness where the config says auto: the stiffness the ground and sphere shorthands always had.
DEFAULT_PENALTY_STIFFNESS = 1.0e4


class GroundContact(BaseModel):
    """Shorthand: the half-space above the last coordinate = height (a plane with normal +e_last)."""

    model_config = ConfigDict(extra="forbid")
    height: Finite = Field(-1.0, description="the last coordinate (z in 3-D, y in 2-D) of the ground (m)")
    stiffness: Positive = Field(1.0e4, description="penalty stiffness (N/m)")


class SphereContact(BaseModel):
    """Shorthand: a sphere (a circle in 2-D) with its own penalty stiffness."""

    model_config = ConfigDict(extra="forbid")
    center: Vector = Field(description="centre (m), in the model's dimension")
    radius: Positive = Field(description="radius (m)")
    stiffness: Positive = Field(1.0e4, description="penalty stiffness (N/m)")


class _MovingShape(BaseModel):
    """What every analytic collider has: a motion (a constant velocity, a constant rotation) and an optional
    penalty stiffness of its own."""

    model_config = ConfigDict(extra="forbid")
    velocity: Vector | None = Field(None, description="constant translation velocity (m/s); static when omitted")
    rotation: ConstantRotation | None = Field(None, description="{center, axis, rate (deg/s)}: turning at a constant rate")
    stiffness: Positive | None = Field(None, description="penalty stiffness of this collider (N/m); default: contact.stiffness")

    @property
    def moves(self) -> bool:
        return (self.velocity is not None and any(component != 0.0 for component in self.velocity)) or (
            self.rotation is not None and self.rotation.rate != 0.0)


class PlaneSpec(_MovingShape):
    shape: Literal["plane"]
    normal: Vector = Field(description="outward normal (any length but zero)")
    point: Vector | None = Field(None, description="a point on the plane (m); default the origin")


class SphereSpec(_MovingShape):
    shape: Literal["sphere"]
    center: Vector = Field(description="centre (m)")
    radius: Positive = Field(description="radius (m)")


class BoxSpec(_MovingShape):
    shape: Literal["box"]
    center: Vector = Field(description="centre (m)")
    half_extents: list[Positive] = Field(description="half side lengths along the axes (m)")


class CapsuleSpec(_MovingShape):
    shape: Literal["capsule"]
    a: Vector = Field(description="one end of the axis segment (m)")
    b: Vector = Field(description="the other end (m)")
    radius: Positive = Field(description="radius (m)")


class TorusSpec(_MovingShape):
    shape: Literal["torus"]
    center: Vector = Field(description="centre (m), 3-D")
    axis: Vector = Field([0.0, 0.0, 1.0], description="the symmetry axis")
    major_radius: Positive = Field(description="from the centre to the tube's centre line (m)")
    minor_radius: Positive = Field(description="the tube's radius (m)")


class GridSpec(_MovingShape):
    shape: Literal["grid_sdf"]
    file: str = Field(description=".npy (values) or .npz (values, origin, spacing): signed distances sampled on a grid (m)")
    origin: Vector | None = Field(None, description="position of sample (0, 0(, 0)) (m); default the file's")
    spacing: Union[Positive, list[Positive], None] = Field(None, description="sample spacing (m), one or one per axis; default the file's")


class MeshSpec(BaseModel):
    """A static obstacle triangle mesh (a polyline in 2-D) from a file, for IPC."""

    model_config = ConfigDict(extra="forbid")
    shape: Literal["mesh"]
    file: str = Field(description="a mesh file meshio reads (OBJ, PLY, OFF, STL, ...): triangles in 3-D, lines in 2-D")
    translate: Vector | None = Field(None, description="offset added to the file's vertices (m)")


ColliderSpec = Annotated[Union[PlaneSpec, SphereSpec, BoxSpec, CapsuleSpec, TorusSpec, GridSpec, MeshSpec],
                         Field(discriminator="shape")]
COLLIDER_SHAPES = ("plane", "sphere", "box", "capsule", "torus", "grid_sdf", "mesh")


class FrictionSpec(BaseModel):
    """IPC's smoothed, lagged Coulomb friction: |f_t| = mu lambda f1(|v_t|), f1 rising from 0 to 1 over epsv."""

    model_config = ConfigDict(extra="forbid")
    mu: NonNegative = Field(description="Coulomb coefficient")
    epsv: Positive = Field(1.0e-3, description="smoothing velocity (m/s): below it friction grows with the sliding speed")
    lag_iterations: int = Field(0, ge=0, le=100, description="solves more per step, each with the normal forces and "
                                                            "tangent bases lagged at the last solution instead of the step's start")


class ContactSpec(BaseModel):
    """Contact of a mass-spring model: penalty or IPC against colliders, optional friction and self-contact."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    method: Literal[CONTACT_METHODS] = Field("penalty", description=" | ".join(CONTACT_METHODS))  # type: ignore[valid-type]
    dhat: Positive = Field(1.0e-3, description="the barrier's reach (m; ipc)")
    stiffness: Union[Positive, Literal["auto"]] = Field(
        "auto", description="penalty k_p (N/m; auto: 1e4), or the barrier stiffness (ipc; auto: IPC's estimate and update)")
    damping: NonNegative = Field(0.0, description="penalty only: k_d in f_c = -k_p d - k_d v_n (N s/m)")
    friction: FrictionSpec | None = None
    self_contact: bool = Field(False, alias="self", description="self-contact of models with triangles (ipc)")
    colliders: list[ColliderSpec] = Field([], description="shapes: " + ", ".join(COLLIDER_SHAPES))
    ground: GroundContact | None = None
    sphere: SphereContact | None = None

    @model_validator(mode="after")
    def _consistent(self) -> "ContactSpec":
        if self.method == "ipc" and self.damping > 0:
            raise ValueError("damping: contact damping belongs to the penalty method (IPC's barrier conserves "
                             "energy and friction dissipates): set damping: 0 or method: penalty")
        if self.self_contact and self.method != "ipc":
            raise ValueError("self: self-contact is IPC's (method: ipc)")
        for number, collider in enumerate(self.colliders):
            if collider.shape == "mesh" and self.method != "ipc":
                raise ValueError(f"colliders[{number}]: an obstacle mesh has no signed distance for a penalty: use method: ipc")
            if collider.shape != "mesh" and collider.stiffness is not None and self.method == "ipc":
                raise ValueError(f"colliders[{number}].stiffness: a penalty stiffness; IPC takes contact.stiffness")
            if self.damping > 0 and collider.shape != "mesh" and collider.moves:
                raise ValueError(f"colliders[{number}]: contact damping acts on the vertex velocity, "
                                 "so it needs static colliders (no velocity or rotation)")
        return self

    @property
    def active(self) -> bool:
        """Is there any contact at all?"""
        return bool(self.colliders) or self.ground is not None or self.sphere is not None or self.self_contact

    @property
    def needs_step_filter(self) -> bool:
        """IPC: every solver step must be cut to a collision-free fraction (a line search filtered by CCD)."""
        return self.method == "ipc" and self.active
