"""What the IMEX splits of the mass-spring and finite-element systems share (systems/mass_spring/split.py,
systems/fem/split.py): a part starts as a copy of the whole, and the per-vertex damping goes with ``drag``."""

from __future__ import annotations

import copy
import functools


def fresh_copy(system):
    """A shallow copy of ``system`` without the values its cached properties derived from the whole: a part derives
    them again from what it keeps (its forms, systems/forms.py, are built for the part itself)."""
    part = copy.copy(system)
    for klass in type(system).__mro__:
        for attribute, value in vars(klass).items():
            if isinstance(value, functools.cached_property):
                part.__dict__.pop(attribute, None)
    return part


def has_vertex_damping(terms) -> bool:
    """Whether any damping term acts per vertex (drag, or Rayleigh's alpha M)."""
    return any(term.model == "drag" or (term.model == "rayleigh" and term.alpha) for term in terms)
