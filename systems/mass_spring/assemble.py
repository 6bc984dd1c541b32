"""From a validated `mass_spring` config and its model to the arrays ``MassSpring`` is built from.

Every check that needs the model (vertex indices and names, dimensions, kinds, array lengths, overlapping
constraints) is here or in the code of systems/vertex/ it calls, which fem shares (vectors, selectors, the start
state, the constraints of vertices); each raises ModelError naming the config field, which the config loader reports as
one line (``system.pinned: vertex 99 does not exist; ...``). ``params`` is always a ``MassSpringParams``
(params.py, which calls ``resolve``; this module builds below it and names no type of it).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from ..contact.build import build_contact
from ..vertex.constraint_config import vertex_constraints
from ..vertex.damping import Damping
from ..vertex.errors import ModelError, ModelWarning
from ..vertex.fields import vector
from ..vertex.files import find_file
from ..vertex.initial_state import initial_state
from ..vertex.model_files import lumped_area_masses
from ..vertex.selectors import in_box
from ..vertex.spring_model import SpringModel


def resolve(params) -> dict[str, Any]:
    """The keyword arguments of MassSpring; ModelError (naming the config field) for anything inconsistent."""
    model = params.spring_model()
    dim = model.dim
    rest = model.vertices.astype(float)
    if params.gravity is None:  # -9.81 m/s^2 along the last axis: y in 2-D, z in 3-D
        gravity = np.zeros(dim)
        gravity[-1] = -9.81
    else:
        gravity = vector(params.gravity, dim, "gravity")
    stiffness = _stiffness(params, model)
    rest_length = (model.rest_lengths if model.rest_lengths is not None
                   else np.linalg.norm(rest[model.springs[:, 0]] - rest[model.springs[:, 1]], axis=1))
    damping = _damping(params)
    along_springs = any(term.model in ("spring", "relative") for term in damping)
    kept = np.flatnonzero((stiffness > 0) | along_springs)
    if kept.size == 0:
        raise ModelError("stiffness: every spring has stiffness 0 and no damping acts along the springs: nothing holds the model together")
    x0, v0 = initial_state(params, model, rest)
    constraints = vertex_constraints(params, model, rest, x0)
    return dict(rest=rest, x0=x0, v0=v0, springs=model.springs[kept], stiffness=stiffness[kept], rest_length=rest_length[kept],
                masses=_masses(params, model), gravity=gravity, law=params.spring_law, damping=damping,
                constraints=constraints, contact=_contact(params, model, x0), triangles=model.triangles, grid_shape=model.grid_shape,
                spring_kinds=model.kinds[kept], kind_names=model.kind_names)


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


DEFAULT_STIFFNESS = 1.0e4  # N/m, for models that bring none of their own
DEFAULT_TOTAL_MASS = 1.0  # kg, for models that bring no masses


def _stiffness(params, model: SpringModel) -> np.ndarray:
    if params.stiffness == "auto":
        stiffness = (model.stiffness.astype(float).copy() if model.stiffness is not None
                     else np.full(model.spring_count, DEFAULT_STIFFNESS))
    elif params.stiffness == "file":
        if model.stiffness is None:
            raise ModelError("stiffness: file, but the model file has no 'stiffness' array")
        stiffness = model.stiffness.astype(float).copy()
    elif isinstance(params.stiffness, dict):
        stiffness = _per_kind(params.stiffness, model, "stiffness", complete=True)[model.kinds]
    else:
        stiffness = np.full(model.spring_count, float(params.stiffness))
    for number, region in enumerate(params.regions):
        field = f"regions[{number}]"
        inside = in_box(model.vertices, region.box, model.dim, field + ".box")
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


def _masses(params, model: SpringModel) -> np.ndarray:
    n = model.vertex_count
    spec = params.mass
    if spec.file:
        if model.masses is None:
            raise ModelError("mass: file, but the model file has no 'masses' array")
        return model.masses.astype(float)
    if spec.per_vertex is None and spec.total is None and spec.density is None:  # nothing said: the file's, else 1 kg
        if model.masses is not None:
            return model.masses.astype(float)
        spec = spec.model_copy(update={"total": DEFAULT_TOTAL_MASS})
    if spec.per_vertex is not None:
        return np.full(n, spec.per_vertex)
    if spec.total is not None and (spec.by == "equal" or (spec.by == "auto" and model.triangles is None)):
        return np.full(n, spec.total / n)
    if model.triangles is None:
        raise ModelError(f"mass: {'by: area' if spec.total is not None else 'density'} needs a model with triangles; "
                         "this one has none: use {total: kg} (equal shares) or {per_vertex: kg}")
    areas = _areas_with_neighbours(model)
    return areas * spec.density if spec.density is not None else areas * (spec.total / float(np.sum(areas)))


def _areas_with_neighbours(model: SpringModel) -> np.ndarray:
    """The area (m^2) lumped to each vertex; a vertex that touches no triangle of positive area (a scanned mesh's
    degenerate faces) takes the mean of its spring neighbours' areas, and one that no spring joins (a vertex no face
    uses: the published Stanford bunny has 1,113) the mean of every vertex's; a ModelWarning says so in one line,
    with the degenerate faces the file had."""
    areas = lumped_area_masses(model.vertices, model.triangles)
    empty = ~(areas > 0.0)
    said = ([f"{_count(model.degenerate_triangles, 'degenerate triangle')} (zero area) left out of the surface: no "
             "spring of zero length, no area"] if model.degenerate_triangles else [])
    if not np.any(empty):
        if said:
            _warn_once(f"{model.source}: {said[0]}")
        return areas
    if not np.any(~empty):
        raise ModelError("mass: no triangle of the model has a positive area, so area lumping gives no vertex a mass")
    i, j = model.springs[:, 0], model.springs[:, 1]
    known = np.where(empty, 0.0, areas)
    neighbours = np.bincount(i, weights=known[j], minlength=len(areas)) + np.bincount(j, weights=known[i], minlength=len(areas))
    counted = np.bincount(i, weights=~empty[j], minlength=len(areas)) + np.bincount(j, weights=~empty[i], minlength=len(areas))
    joined = np.bincount(model.springs.ravel(), minlength=len(areas)) > 0
    filled = np.where(counted > 0, neighbours / np.maximum(counted, 1.0), float(np.mean(areas[~empty])))
    areas = np.where(empty, filled, areas)
    near = int(np.count_nonzero(empty & (counted > 0)))
    unused = int(np.count_nonzero(empty & ~joined))
    others = int(np.count_nonzero(empty)) - near - unused  # joined only to vertices without area themselves
    if near:
        said.append(f"{_count(near, 'vertex', 'vertices')} without a triangle of positive area take the mean area of "
                    "their spring neighbours")
    if others:
        said.append(f"{_count(others, 'vertex', 'vertices')} whose spring neighbours have no area either take the "
                    "mean area of every vertex")
    if unused:
        said.append(f"{_count(unused, 'vertex', 'vertices')} that no face uses: free particles (no spring; kept, so "
                    "that the file's vertex numbers hold) with the mean area of every vertex")
    _warn_once(f"{model.source}: " + "; ".join(said))
    return areas


_WARNED: set[str] = set()  # what was said already in this process: validation builds a model more than once


def _warn_once(text: str) -> None:
    if text not in _WARNED:
        _WARNED.add(text)
        warnings.warn(ModelWarning(text), stacklevel=3)


def _count(number: int, one: str, many: str | None = None) -> str:
    return f"{number} {one if number == 1 else (many or one + 's')}"


def _damping(params) -> tuple[Damping, ...]:
    if not isinstance(params.damping, list):
        return (Damping("spring", float(params.damping)),) if params.damping > 0 else ()
    return tuple(Damping(term.model, term.coefficient, term.alpha, term.beta) for term in params.damping
                 if term.coefficient > 0 or term.alpha > 0 or term.beta > 0)


def _contact(params, model: SpringModel, x0: np.ndarray):
    """The ContactModel of ``params.contact`` (None without contact); files were made absolute by the params."""
    return build_contact(params.contact, dim=model.dim, rest=model.vertices.astype(float), x0=x0,
                         masses=_masses(params, model), triangles=model.triangles, edges=model.springs,
                         find_file=find_file)
