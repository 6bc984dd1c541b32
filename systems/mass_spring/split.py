"""A mass-spring system's energy in named parts, for IMEX splits (integrators/imex.py).

The terms are the spring kinds (``stretch_x``, ``bend``, ...; a prefix names every kind it starts: ``stretch`` is
``stretch_x`` and ``stretch_y``), ``drag`` (the per-vertex damping: drag and Rayleigh's alpha M), ``gravity`` and
``contact``. ``with_terms(system, names)`` is the same system with only those terms: the same vertices, masses,
constraints and state, the springs of the named kinds alone, gravity, drag and contact only if named;
``with_terms(system, names, complement=True)`` has every other term, so that the two parts' forces sum to the
whole's. The damping along springs (the spring and relative models, Rayleigh's beta K)
follows its springs: each part keeps it on its own.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simrun.systems.split_parts import fresh_copy, has_vertex_damping


def kind_matches(name: str, kind_names: tuple[str, ...]) -> list[int]:
    """The kinds a term name stands for: itself, or every kind it prefixes (stretch -> stretch_x, stretch_y)."""
    return [index for index, kind in enumerate(kind_names) if kind == name or kind.startswith(name + "_")]


def energy_terms(system) -> tuple[str, ...]:
    """The names a split may use: the spring kinds present, their prefixes, then drag, gravity and contact where they
    act."""
    present = [system.kind_names[kind] for kind in np.unique(system.spring_kinds)]
    prefixes = [kind.split("_")[0] for kind in present if "_" in kind]
    names = list(dict.fromkeys(prefixes + present))
    if has_vertex_damping(system.damping_terms):
        names.append("drag")
    if np.any(system.gravity != 0.0):
        names.append("gravity")
    if system.contact is not None:
        names.append("contact")
    return tuple(names)


def with_terms(system, names, complement: bool = False):
    """``system`` with only the terms ``names``, or with every other (see the module docstring): a new system,
    ``system`` unchanged; None if that leaves no force."""
    names = tuple(names)
    kinds = sorted({kind for name in names for kind in kind_matches(name, system.kind_names)})
    kept = np.flatnonzero(np.isin(system.spring_kinds, kinds) != complement)
    part = fresh_copy(system)
    part.first, part.second = system.first[kept], system.second[kept]
    part.stiffness, part.rest_length = system.stiffness[kept], system.rest_length[kept]
    part.rest_length_squared = system.rest_length_squared[kept]
    part.spring_kinds = system.spring_kinds[kept]
    part.spring_count = kept.size
    part.frame_edges = system.frame_edges[kept]
    if ("gravity" in names) == complement:
        part.gravity = np.zeros_like(system.gravity)
        part._gravity_force = np.zeros_like(system._gravity_force)
    if ("contact" in names) == complement:
        part.contact = None
    vertex_damping = ("drag" in names) != complement
    part.damping_terms = tuple(term for term in (_damping_part(term, vertex_damping) for term in system.damping_terms)
                               if term is not None)
    if not (kept.size or np.any(part.gravity != 0.0) or part.contact is not None
            or has_vertex_damping(part.damping_terms)):
        return None  # no force at all: an IMEX split steps without it (no solve for an empty implicit part)
    part._geometry = None
    part._build_pattern()
    part._constant_damping = part._assemble_constant_damping()
    part._prepare_paths()
    return part


def _damping_part(term, vertex_damping: bool):
    """The part of one damping term that a split part keeps (None: nothing)."""
    if term.model == "drag":
        return term if vertex_damping else None
    if term.model == "rayleigh":
        return dataclasses.replace(term, alpha=term.alpha if vertex_damping else 0.0)
    return term
