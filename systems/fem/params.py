"""The config of `fem`: a simplex mesh (file or generator), a hyperelastic material, masses, damping, constraints and
contact; everything that depends on the mesh is checked when the config is loaded (one line naming the field).

The keys shared with `mass_spring` mean what they mean there: ``gravity``, ``initial``, ``pinned``, ``constraints``,
``prescribed``, ``contact`` and the Rayleigh and drag terms of ``damping`` (the vertex selectors, the start state and
the constraints are the shared code of systems/vertex/, given the mesh's vertices and named sets).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, field_validator, model_validator

from ..base import SystemParams
from ..contact.build import build_contact
from ..contact.params import ContactSpec
from ..vertex.constraint_config import Prescribed, Sliding, vertex_constraints
from ..vertex.damping import Damping, DampingTerm
from ..vertex.errors import ModelError
from ..vertex.fields import Box, Positive, Vector, vector
from ..vertex.files import file_digest, find_file
from ..vertex.initial_state import InitialShape, initial_state
from ..vertex.selectors import Selector, in_box
from .materials import MATERIALS, energy_parameters, shell_materials
from .mesh import MeshFile, SimplexMesh, TetrahedralizedSurface, mesh_source, read_mesh_file
from .system import Fem

__all__ = ["FemParams", "Material"]

Poisson = Annotated[float, Field(gt=-1.0, lt=0.5, allow_inf_nan=False)]


class MaterialRegion(BaseModel):
    """The elements whose vertices (at rest) all lie in the box get these values instead."""

    model_config = ConfigDict(extra="forbid")
    box: Box = Field(description="[[min...], [max...]] (m), in the mesh's rest shape")
    youngs_modulus: Positive | None = Field(None, description="E (Pa)")
    poisson_ratio: Poisson | None = Field(None, description="nu, in (-1, 0.5)")
    density: Positive | None = Field(None, description="kg/m^3 (kg/m^2 for a 2-D solid or a shell)")


class Material(BaseModel):
    model_config = ConfigDict(extra="forbid")
    model: Literal[tuple(MATERIALS)] = Field("stable_neo_hookean", description=" | ".join(MATERIALS))  # type: ignore[valid-type]
    youngs_modulus: Positive = Field(1.0e5, description="E (Pa)")
    poisson_ratio: Poisson = Field(0.4, description="nu, in (-1, 0.5)")
    density: Positive = Field(1000.0, description="kg/m^3 (kg/m^2 for a 2-D solid or a shell)")
    regions: list[MaterialRegion] = Field([], description="boxes with their own E, nu or density (later entries win)")


class Bending(BaseModel):
    """The bending energy of a shell: discrete_shell, the hinge energy of Grinspun et al. 2003 (docs/fem.md)."""

    model_config = ConfigDict(extra="forbid")
    model: Literal["discrete_shell"] = Field("discrete_shell", description="discrete_shell")
    stiffness: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(
        description="k (N m): E = k 3 |e|^2 / (A_1 + A_2) (theta - theta_rest)^2 per interior edge")


class FemMass(BaseModel):
    """lumped (default): each element's mass, density x rest volume, shared equally among its vertices; or
    consistent: the mass matrix of the linear shape functions, M_e = m_e / (k (k + 1)) (1 + delta_ab) I per element of
    k vertices (its rows sum to the lumped shares); or {total: kg} (the shares scaled to this total; by: equal for
    equal shares) or {per_vertex: kg}."""

    model_config = ConfigDict(extra="forbid")
    matrix: Literal["lumped", "consistent"] = Field("lumped", description="lumped (diagonal) | consistent (the shape "
                                                                         "functions' mass matrix)")
    total: Positive | None = Field(None, description="kg in all")
    by: Literal["volume", "equal"] = Field("volume", description="how a total is shared: by lumped volume, or equally")
    per_vertex: Positive | None = Field(None, description="kg at every vertex")

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data: Any) -> Any:
        return {"matrix": data} if data in ("lumped", "consistent") else data

    @model_validator(mode="after")
    def _one_rule(self) -> "FemMass":
        if self.total is not None and self.per_vertex is not None:
            raise ValueError("give total or per_vertex, not both")
        if self.matrix == "consistent" and (self.per_vertex is not None or self.by == "equal"):
            raise ValueError("a consistent mass matrix comes from the elements' masses: it takes a total (scaled by "
                             "volume), not per_vertex or by: equal")
        return self


class FemParams(SystemParams):
    """Config of `fem`: hyperelastic solids of linear simplices (triangles in 2-D, tetrahedra in 3-D)."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["fem"] = "fem"
    model: Union[str, dict[str, Any]] = Field({"square": {"segments": 4, "size": 1.0}},
                                              description="a mesh file (tetra cells; triangles, flat in z for a 2-D "
                                                          "solid, else a shell; any meshio format), {box: {size, cells}}, "
                                                          "{square: {segments, size}}, {grid: {resolution, size, height}} "
                                                          "(a shell) or {tetrahedralize: {surface, edge_length}}")
    material: Material = Material()
    thickness: Positive | None = Field(None, description="a shell's thickness (m): its membrane energy is thickness x "
                                                         "area x psi; required for shells, refused for solids; makes a "
                                                         "file's triangles flat in z a shell, not a 2-D solid")
    bending: Bending | None = Field(None, description="a shell's bending: {model: discrete_shell, stiffness: N m}")
    mass: FemMass = Field(FemMass(), description="lumped (default) | consistent | {matrix: lumped|consistent, total: kg, "
                                                 "by: volume|equal} | {per_vertex: kg}")
    gravity: Vector | None = Field(None, description="m/s^2, one component per dimension (default: -9.81 along the last axis)")
    initial: InitialShape = InitialShape()
    damping: list[DampingTerm] = Field([], description="{model: rayleigh, alpha, beta} (K: the elastic Hessian at rest) "
                                                       "and {model: drag, coefficient}")
    pinned: Selector = Field([], description="vertices that never move: indices, the mesh's names (left, x_max, ...), {box}")
    constraints: list[Sliding] = Field([], description="vertices that slide in a plane (normal) or along a line (direction)")
    prescribed: list[Prescribed] = Field([], description="vertices on a path: {vertices, velocity} or {vertices, rotation}")
    contact: ContactSpec = Field(ContactSpec(), description="penalty or IPC contact of the boundary with colliders "
                                                            "(docs/contact.md)")
    _file: Path | None = PrivateAttr(None)
    _surface: Path | None = PrivateAttr(None)  # tetrahedralize's surface, absolute
    _initial_file: Path | None = PrivateAttr(None)
    _contact_files: dict = PrivateAttr(default_factory=dict)

    @field_validator("model")
    @classmethod
    def _known_source(cls, value):
        mesh_source(value)
        return value

    @field_validator("damping")
    @classmethod
    def _element_damping(cls, terms):
        for number, term in enumerate(terms):
            if term.model not in ("rayleigh", "drag"):
                raise ValueError(f"[{number}]: {term.model} damping acts along springs; a finite-element model takes "
                                 "rayleigh (alpha M + beta K) and drag")
        return terms

    @model_validator(mode="after")
    def _consistent_with_mesh(self) -> "FemParams":
        source = mesh_source(self.model)
        try:
            if isinstance(source, MeshFile):
                self._file = find_file(str(source.file), "model")
                self.model = str(self._file)  # absolute, for the runs validated again elsewhere
            elif isinstance(source, TetrahedralizedSurface):
                self._surface = find_file(str(source.surface), "model.tetrahedralize.surface")
                self.model = {"tetrahedralize": {"surface": str(self._surface), "edge_length": source.edge_length}}
            if self.initial.file is not None:
                self._initial_file = find_file(self.initial.file, "initial.file")
                self.initial.file = str(self._initial_file)
            for number, collider in enumerate(self.contact.colliders):
                if getattr(collider, "file", None) is not None:
                    found = find_file(collider.file, f"contact.colliders[{number}].file")
                    collider.file = str(found)
                    self._contact_files[f"contact.colliders[{number}].file"] = found
            resolve(self)
        except ModelError as error:
            raise ValueError(str(error)) from None
        return self

    def input_files(self) -> dict[str, str]:
        files = {"model": self._file, "model.tetrahedralize.surface": self._surface, "initial.file": self._initial_file,
                 **self._contact_files}
        if self._surface is not None:  # the tets the runs use: fTetWild's first mesh of the surface, from the cache
            from .tetrahedralize import cached_path

            files["model.tetrahedralize.tets"] = cached_path(self._surface, self.model["tetrahedralize"]["edge_length"])
        return {field: file_digest(path) for field, path in files.items() if path is not None}

    def mesh(self) -> SimplexMesh:
        if self._file is not None:
            stat = self._file.stat()
            return _loaded_file(str(self._file), stat.st_size, stat.st_mtime_ns, self.thickness is not None)
        if self._surface is not None:
            stat = self._surface.stat()
            return _loaded_file(json.dumps(self.model, sort_keys=True), stat.st_size, stat.st_mtime_ns, False)
        return _generated(json.dumps(self.model, sort_keys=True))

    @property
    def dof_count(self) -> int:
        mesh = self.mesh()
        return mesh.dim * mesh.vertex_count

    def build(self) -> Fem:
        return Fem(**resolve(self))


FemParams.system_class = Fem


@functools.lru_cache(maxsize=8)
def _loaded_file(source: str, size: int, mtime: int, shell: bool) -> SimplexMesh:
    """The mesh of a file (its path; its triangles a shell where ``shell``, the config giving a thickness) or of a
    tetrahedralized surface (the model's JSON), keyed by the file's stat too."""
    try:
        if source.startswith("{"):
            return mesh_source(json.loads(source)).build()
        return read_mesh_file(Path(source), shell=shell)
    except ModelError as error:
        raise ModelError(f"model: {error}") from None


@functools.lru_cache(maxsize=8)
def _generated(source_json: str) -> SimplexMesh:
    try:
        return mesh_source(json.loads(source_json)).build()
    except ModelError as error:
        raise ModelError(f"model: {error}") from None


def resolve(params: FemParams) -> dict[str, Any]:
    """The keyword arguments of Fem; ModelError naming the config field for anything inconsistent with the mesh."""
    mesh = params.mesh()
    dim = mesh.dim
    rest = mesh.vertices
    if params.gravity is None:
        gravity = np.zeros(dim)
        gravity[-1] = -9.81
    else:
        gravity = vector(params.gravity, dim, "gravity")
    _check_shell_keys(params, mesh)
    youngs, poisson, density = _element_materials(params.material, mesh)
    mu, lam = energy_parameters(params.material.model, mesh.element_dim, youngs, poisson, shell=mesh.is_shell)
    volumes = mesh.rest_volumes()
    element_masses = volumes * density
    masses = _masses(params.mass, mesh, element_masses)
    if params.mass.total is not None:
        element_masses = element_masses * (params.mass.total / float(element_masses.sum()))
    consistent = params.mass.matrix == "consistent"
    if consistent and params.constraints:
        raise ModelError("mass: a consistent mass matrix couples a sliding vertex's constrained direction to its "
                         "neighbours, which the sliding filters do not keep: use lumped mass with sliding constraints")
    x0, v0 = initial_state(params, mesh, rest)
    _refuse_inverted(mesh, x0)
    constraints = vertex_constraints(params, mesh, rest, x0)
    boundary = mesh.boundary_faces()
    if mesh.is_shell:  # the surface is the shell itself: every triangle and edge collides
        surface, edges = mesh.elements, mesh.edges()
    elif dim == 3:
        surface = boundary
        edges = np.unique(np.sort(np.concatenate([boundary[:, [0, 1]], boundary[:, [1, 2]], boundary[:, [2, 0]]]),
                                  axis=1), axis=0)
    else:
        surface, edges = None, boundary
    hinges = None
    if params.bending is not None and params.bending.stiffness > 0:
        try:
            hinges = mesh.hinges()
        except ModelError as error:
            raise ModelError(f"bending: {error}") from None
    contact = build_contact(params.contact, dim=dim, rest=rest, x0=x0, masses=masses, triangles=surface, edges=edges,
                            find_file=find_file)
    damping = tuple(Damping(term.model, term.coefficient, term.alpha, term.beta) for term in params.damping
                    if term.coefficient > 0 or term.alpha > 0 or term.beta > 0)
    return dict(mesh=mesh, material=params.material.model, mu=mu, lam=lam, youngs_modulus=youngs, poisson_ratio=poisson,
                masses=masses, gravity=gravity, x0=x0, v0=v0, damping=damping, constraints=constraints, contact=contact,
                boundary=boundary, surface_edges=edges, thickness=params.thickness, hinges=hinges,
                consistent_masses=element_masses if consistent else None,
                bending_stiffness=params.bending.stiffness if params.bending is not None else 0.0)


def _check_shell_keys(params: FemParams, mesh: SimplexMesh) -> None:
    """ModelError for the keys that belong to shells alone, or that a shell cannot take."""
    kind = "a shell" if mesh.is_shell else ("a tetrahedral solid" if mesh.dim == 3 else "a 2-D solid")
    if mesh.is_shell:
        if params.thickness is None:
            raise ModelError(f"thickness: {mesh.source or 'the model'} is a shell (triangles in 3-D), whose membrane "
                             "energy is thickness x area x psi: give thickness (m)")
        material = MATERIALS[params.material.model]
        if not material.shells:
            *others, last = shell_materials()
            raise ModelError(f"material.model: {material.not_for_shells}: take {', '.join(others)} or {last}")
        return
    if params.thickness is not None:
        raise ModelError(f"thickness: the model is {kind}, whose elements have their own volume; thickness is for "
                         "shells (triangles in 3-D)")
    if params.bending is not None:
        raise ModelError(f"bending: the model is {kind}; the discrete-shell hinges bend shells (triangles in 3-D), "
                         "whose elements have no thickness of their own")


def _element_materials(material: Material, mesh: SimplexMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """E (Pa), nu and density per element, the regions applied in order."""
    count = mesh.element_count
    youngs = np.full(count, material.youngs_modulus)
    poisson = np.full(count, material.poisson_ratio)
    density = np.full(count, material.density)
    for number, region in enumerate(material.regions):
        field = f"material.regions[{number}]"
        inside = in_box(mesh.vertices, region.box, mesh.dim, field + ".box")
        chosen = inside[mesh.elements].all(axis=1)
        if not chosen.any():
            raise ModelError(f"{field}.box: no element has all its vertices in {region.box}")
        for values, value in ((youngs, region.youngs_modulus), (poisson, region.poisson_ratio), (density, region.density)):
            if value is not None:
                values[chosen] = value
    return youngs, poisson, density


def _masses(spec: FemMass, mesh: SimplexMesh, element_masses: np.ndarray) -> np.ndarray:
    """Vertex masses (kg): each element's mass shared equally among its d + 1 vertices, then scaled or replaced as
    ``spec`` says; a vertex that no element uses is refused (it would have no mass and no force)."""
    corners = mesh.elements.shape[1]
    lumped = np.bincount(mesh.elements.ravel(), weights=np.repeat(element_masses / corners, corners),
                         minlength=mesh.vertex_count)
    unused = np.flatnonzero(lumped == 0.0)
    if unused.size:
        raise ModelError(f"model: vertex {int(unused[0])} belongs to no element ({unused.size} such vertices): a "
                         "finite-element model's vertices are its elements' corners")
    if spec.per_vertex is not None:
        return np.full(mesh.vertex_count, spec.per_vertex)
    if spec.total is not None:
        if spec.by == "equal":
            return np.full(mesh.vertex_count, spec.total / mesh.vertex_count)
        return lumped * (spec.total / float(lumped.sum()))
    return lumped


def _refuse_inverted(mesh: SimplexMesh, x0: np.ndarray) -> None:
    """ModelError naming the first element whose start state has no positive volume (the neo-Hookean energy is
    undefined there, and no step filter can bring an element back through zero)."""
    from .kernels import volume_ratios
    from .membrane import area_ratios
    from .system import shape_gradients

    ratios = (area_ratios if mesh.is_shell else volume_ratios)(np.ascontiguousarray(x0, dtype=float).ravel(),
                                                                mesh.elements, shape_gradients(mesh))
    bad = np.flatnonzero(~(ratios > 0.0))
    if bad.size:
        element = int(bad[0])
        raise ModelError(f"initial: element {element} (vertices {mesh.elements[element].tolist()}) is inverted in the "
                         f"start state (volume ratio J = {ratios[element]:.3g}; {bad.size} such elements): every element "
                         "needs a positive volume to start")
