"""From a validated ``contact`` config and the model it acts on to a ContactModel (or None without contact).

Every check that needs the model (dimensions, files, obstacle meshes, an initial state that already
intersects) is made here and raises ModelError naming the config field, which the config loader reports
as one line (``system.contact.colliders[1].radius: ...``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..vertex.errors import ModelError
from .colliders import build_collider, load_grid_sdf
from .model import ColliderContact, ContactModel
from .params import DEFAULT_PENALTY_STIFFNESS, ContactSpec


def build_contact(spec: ContactSpec, *, dim: int, rest: np.ndarray, x0: np.ndarray, masses: np.ndarray,
                  triangles: np.ndarray | None, edges: np.ndarray | None, field: str = "contact",
                  find_file=None) -> ContactModel | None:
    """The ContactModel of ``spec`` for a model of ``rest`` (n, d) vertices starting at ``x0`` (n, d); None when
    the spec asks for no contact. ``find_file(name, field)`` resolves file names as the model's are."""
    if not spec.active:
        return None
    penalty = spec.method == "penalty"
    default_stiffness = (DEFAULT_PENALTY_STIFFNESS if spec.stiffness == "auto" else float(spec.stiffness)) if penalty else None
    colliders: list[ColliderContact] = []
    obstacles = []
    try:
        if spec.ground is not None:  # the shorthands first, in the order their penalties were always summed
            normal = np.zeros(dim)
            normal[-1] = 1.0
            colliders.append(ColliderContact(build_collider("plane", dim, normal=normal, point=spec.ground.height * normal),
                                             spec.ground.stiffness if penalty else None))
        if spec.sphere is not None:
            center = _vector(spec.sphere.center, dim, f"{field}.sphere.center")
            colliders.append(ColliderContact(build_collider("sphere", dim, center=center, radius=spec.sphere.radius),
                                             spec.sphere.stiffness if penalty else None))
    except ValueError as error:
        raise ModelError(f"{field}: {error}") from None
    for number, entry in enumerate(spec.colliders):
        where = f"{field}.colliders[{number}]"
        if entry.shape == "mesh":
            obstacles.append(_obstacle(entry, dim, where, find_file))
            continue
        colliders.append(ColliderContact(_collider(entry, dim, where, find_file),
                                         (entry.stiffness or default_stiffness) if penalty else None,
                                         _spin(entry.rotation, dim, f"{where}.rotation")))
    mesh = None
    if obstacles or spec.self_contact:
        from .mesh_contact import MeshContact  # ipctk: only mesh contact needs it

        try:
            mesh = MeshContact(rest, triangles, edges, obstacles, self_contact=spec.self_contact, dhat=spec.dhat)
        except ValueError as error:
            raise ModelError(f"{field}: {error}") from None
    friction = None if spec.friction is None or spec.friction.mu == 0.0 else (spec.friction.mu, spec.friction.epsv)
    model = ContactModel(method=spec.method, colliders=colliders, dim=dim, vertex_count=rest.shape[0], dhat=spec.dhat,
                         stiffness=None if spec.stiffness == "auto" or penalty else float(spec.stiffness),
                         damping=spec.damping, friction=friction, mesh=mesh, masses=masses,
                         friction_relags=spec.friction.lag_iterations if friction is not None else 0)
    problem = model.intersection(np.ascontiguousarray(x0, dtype=float).ravel())
    if problem is not None:
        raise ModelError(f"{field}: the initial state already intersects: {problem}")
    return model


def _spin(rotation, dim: int, field: str) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(center (d,) m, unit axis (3,), rate rad/s) of a collider's rotation, or None."""
    if rotation is None or rotation.rate == 0.0:
        return None
    axis = _vector(rotation.axis, 3, f"{field}.axis")
    length = float(np.linalg.norm(axis))
    if not length > 0.0:
        raise ModelError(f"{field}.axis: the axis {rotation.axis} is zero")
    if dim == 2 and (axis[0] != 0.0 or axis[1] != 0.0):
        raise ModelError(f"{field}.axis: a 2-D collider turns about z; give [0, 0, 1] or [0, 0, -1]")
    return _vector(rotation.center, dim, f"{field}.center"), axis / length, float(np.radians(rotation.rate))


def _vector(values, dim: int, field: str) -> np.ndarray:
    if values is None:
        return np.zeros(dim)
    if len(values) != dim:
        raise ModelError(f"{field}: {len(values)} components given, but the model is {dim}-D: give {dim}")
    return np.array(values, dtype=float)


# config fields that are vectors in the model's dimension, per shape
_VECTOR_FIELDS = {"plane": ("normal", "point"), "sphere": ("center",), "box": ("center", "half_extents"),
                  "capsule": ("a", "b"), "torus": ("center", "axis")}


def _collider(entry, dim: int, where: str, find_file):
    arguments = entry.model_dump(exclude={"shape", "stiffness", "velocity", "rotation"}, exclude_none=True)
    try:
        for name in _VECTOR_FIELDS.get(entry.shape, ()):
            if name in arguments or name == "point":
                arguments[name] = _vector(arguments.get(name), 3 if (entry.shape == "torus" and name == "axis") else dim,
                                          f"{where}.{name}")
        velocity = None if entry.velocity is None else _vector(entry.velocity, dim, f"{where}.velocity")
        if entry.shape == "grid_sdf":
            path = find_file(entry.file, f"{where}.file") if find_file is not None else Path(entry.file)
            collider = load_grid_sdf(path, origin=arguments.get("origin"), spacing=arguments.get("spacing"), velocity=velocity)
            if collider.dim != dim:
                raise ValueError(f"the grid is {collider.dim}-D, but the model is {dim}-D")
        else:
            collider = build_collider(entry.shape, dim, velocity=velocity, **arguments)
    except ValueError as error:
        raise ModelError(f"{where}: {error}") from None
    return collider


def _obstacle(entry, dim: int, where: str, find_file) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (m, d), elements): the triangles (3-D) or line segments (2-D) of an obstacle mesh file."""
    import meshio  # only mesh obstacles need it

    path = find_file(entry.file, f"{where}.file") if find_file is not None else Path(entry.file)
    try:
        mesh = meshio.read(path)
    except Exception as error:  # meshio raises many kinds, each a bad file
        raise ModelError(f"{where}.file: cannot read {path}: {error}") from None
    kind = "triangle" if dim == 3 else "line"
    cells = [block.data for block in mesh.cells if block.type == kind]
    if not cells:
        raise ModelError(f"{where}.file: {path} has no {kind} cells (a {dim}-D model collides with "
                         f"{'triangles' if dim == 3 else 'line segments'})")
    points = np.asarray(mesh.points, dtype=float)
    if points.shape[1] < dim:
        raise ModelError(f"{where}.file: its points have {points.shape[1]} coordinates, the model {dim}")
    points = points[:, :dim].copy()
    if entry.translate is not None:
        points += _vector(entry.translate, dim, f"{where}.translate")
    return points, np.concatenate(cells).astype(np.intp)
