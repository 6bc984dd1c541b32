"""A finite-element system's energy in named parts, for IMEX splits (integrators/imex.py).

The terms are ``elastic`` (the elements: a solid's simplices, a shell's membrane triangles), ``bending`` (a shell's
discrete-shell hinges, where the bending stiffness is positive), ``drag`` (the per-vertex damping: drag and
Rayleigh's alpha M), ``gravity`` (where it is nonzero) and ``contact`` (where there is any). ``with_terms(system,
names)`` is the same system with only those terms: the same mesh, vertices, masses (a consistent mass too),
constraints and state, and ``with_terms(system, names, complement=True)`` has every other term, so that the two
parts' energies, forces, Hessians and damping matrices sum to the whole's.

Rayleigh's beta K_rest follows the stiffness it multiplies, as the damping along springs follows its springs in
the mass-spring split: K_rest is the elements' and the hinges' Hessian at rest, so the part with ``elastic`` keeps
beta times its elements' share and the part with ``bending`` beta times its hinges'. Its alpha M acts per vertex, as
drag does, and goes with ``drag``. Each part's D is then constant and symmetric, as the whole's.

A part keeps the whole's step bound (``max_step``: every element above a fraction of its volume, or area) even
without ``elastic``: the state it steps is the whole's, whose explicit elastic forces are undefined at an inverted
element, and the hinges are undefined at a collapsed triangle.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simrun.systems.split_parts import fresh_copy, has_vertex_damping


def energy_terms(system) -> tuple[str, ...]:
    """The names a split may use: elastic, bending, drag, gravity and contact, those that act on ``system``."""
    present = {"elastic": system.includes_elements, "bending": len(system.hinges) > 0,
               "drag": has_vertex_damping(system.damping_terms), "gravity": bool(np.any(system.gravity != 0.0)),
               "contact": system.contact is not None}
    return tuple(name for name, acts in present.items() if acts)


def with_terms(system, names, complement: bool = False):
    """``system`` with only the terms ``names``, or with every other (see the module docstring): a new system,
    ``system`` unchanged; None if that leaves no force."""
    names = tuple(names)

    def kept(term: str) -> bool:
        return (term in names) != complement

    part = fresh_copy(system)
    part.includes_elements = system.includes_elements and kept("elastic")
    if not kept("bending"):
        part.hinges = system.hinges[:0]
        part.hinge_stiffness, part.rest_angles = system.hinge_stiffness[:0], system.rest_angles[:0]
    if not kept("gravity"):
        part.gravity = np.zeros_like(system.gravity)
        part._gravity_force = np.zeros_like(system._gravity_force)
    if not kept("contact"):
        part.contact = None
    stiffness_kept = part.includes_elements or len(part.hinges) > 0
    part.damping_terms = tuple(term for term in (_damping_part(term, kept("drag"), stiffness_kept)
                                                 for term in system.damping_terms) if term is not None)
    if not (stiffness_kept or np.any(part.gravity != 0.0) or part.contact is not None
            or has_vertex_damping(part.damping_terms)):
        return None  # no force at all: an IMEX split steps without it (no solve for an empty implicit part)
    part._build_pattern()
    if system.consistent_masses is not None:  # the same M, in the part's pattern
        part.mass_correction = part._consistent_correction(system.consistent_masses)
    part._rest_stiffness = part._elastic_hessian_data(part.rest.ravel(), 1)  # the part's own elements and hinges
    part._constant_damping = part._assemble_constant_damping()
    part._prepare_paths()
    return part


def _damping_part(term, vertex_damping: bool, stiffness_kept: bool):
    """The part of one damping term that a split part keeps (None: nothing): drag and Rayleigh's alpha with
    ``drag``; Rayleigh's beta wherever the part has elements or hinges, whose rest stiffness it multiplies."""
    if term.model == "drag":
        return term if vertex_damping else None
    alpha = term.alpha if vertex_damping else 0.0
    beta = term.beta if stiffness_kept else 0.0
    return dataclasses.replace(term, alpha=alpha, beta=beta) if alpha or beta else None
