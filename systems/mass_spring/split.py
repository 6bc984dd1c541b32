"""A mass-spring system's energy in named parts, for IMEX splits (integrators/imex.py).

The terms are the spring kinds (``stretch_x``, ``bend``, ...; a prefix names every kind it starts: ``stretch`` is
``stretch_x`` and ``stretch_y``), ``gravity`` and ``contact``. ``with_terms(system, names)`` is the same system with
only those terms: the same vertices, masses, constraints and state, the springs of the named kinds alone, gravity and
contact only if named; ``with_terms(system, names, complement=True)`` has every other term, so that the two parts'
forces sum to the whole's. Damping follows what it acts on: the spring and relative models and Rayleigh's beta K act
along their springs, so each part keeps them on its own springs; the per-vertex terms (drag, Rayleigh's alpha M) go
to the named part (an IMEX split's implicit one).
"""

from __future__ import annotations

import copy
import dataclasses
import functools

import numpy as np


def kind_matches(name: str, kind_names: tuple[str, ...]) -> list[int]:
    """The kinds a term name stands for: itself, or every kind it prefixes (stretch -> stretch_x, stretch_y)."""
    return [index for index, kind in enumerate(kind_names) if kind == name or kind.startswith(name + "_")]


def energy_terms(system) -> tuple[str, ...]:
    """The names a split may use: the spring kinds present, their prefixes, then gravity and contact where they act."""
    present = [system.kind_names[kind] for kind in np.unique(system.spring_kinds)]
    prefixes = [kind.split("_")[0] for kind in present if "_" in kind]
    names = list(dict.fromkeys(prefixes + present))
    if np.any(system.gravity != 0.0):
        names.append("gravity")
    if system.contact is not None:
        names.append("contact")
    return tuple(names)


def with_terms(system, names, complement: bool = False):
    """``system`` with only the terms ``names``, or with every other (see the module docstring): a new system,
    ``system`` unchanged."""
    names = tuple(names)
    kinds = sorted({kind for name in names for kind in kind_matches(name, system.kind_names)})
    kept = np.flatnonzero(np.isin(system.spring_kinds, kinds) != complement)
    part = copy.copy(system)
    for klass in type(system).__mro__:  # what was derived from the whole system is derived again for the part
        for attribute, value in vars(klass).items():
            if isinstance(value, functools.cached_property):
                part.__dict__.pop(attribute, None)
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
    part.damping_terms = tuple(term for term in (_damping_part(term, not complement) for term in system.damping_terms)
                               if term is not None)
    part._geometry = None
    part._build_pattern()
    part._constant_damping = part._assemble_constant_damping()
    part._prepare_paths()
    return part


def _damping_part(term, vertex_damping: bool):
    """The part of one damping term that a split part keeps (None: nothing)."""
    if term.model == "drag":
        return term if vertex_damping else None
    if term.model == "rayleigh" and not vertex_damping:
        return dataclasses.replace(term, alpha=0.0)
    return term
