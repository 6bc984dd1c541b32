"""The materials of the finite-element system: one module each (its energy density, stress and tangent, its membrane
form, its terms at one vertex, its projection's eigensystem and its Lame re-parametrisation), the kernels' choice among
them (dispatch.py), and the registry ``MATERIALS``: each config name, its kernels' code and what it supports, which
the config's validation, the system and the tests read (docs/fem.md, "Adding a material").

mu = E / (2 (1 + nu)) and lambda = E nu / ((1 + nu) (1 - 2 nu)) for every energy, in 2-D as in 3-D (the plane-strain
reading of a 2-D solid, as the course code has it), then re-parametrised where a material says so (the stable
neo-Hookean energy, so that its Hessian at rest is linear elasticity's with the given E and nu).

A shell's membrane is in plane stress (a thin sheet free to thin): lambda = E nu / (1 - nu^2), the 3-D lambda with the
normal stress eliminated, 2 mu lambda / (lambda + 2 mu), so that a membrane under uniaxial stress has Young's modulus
E and Poisson ratio nu in its own plane; a re-parametrisation is then the one of d = 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import stable_neo_hookean
from .dispatch import COROTATED, LINEAR, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK


def _unchanged(mu: np.ndarray, lam: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray]:
    return mu, lam


@dataclass(frozen=True)
class Material:
    """One material: its kernels' code and what it supports.

    - code: the int the kernels take as ``model`` (dispatch.py numbers them).
    - solid_dims: the dimensions of the solids it models (triangles in 2-D, tetrahedra in 3-D).
    - shells: whether it is a shell's membrane (dispatch's ``membrane_terms``, ``membrane_vertex_terms``,
      ``membrane_change``); where not, not_for_shells says why, as the config's error does.
    - membrane: how its membrane is written: "strain" (in Green's strain E = (C - I)/2, directly) or "invariants"
      (f(I_1, J), invariant_membrane.py); None without one.
    - vbd: whether vertex block descent's per-vertex terms exist for it (solids, and shells where ``shells``).
    - projection: "closed_form" (its tangent's SPD projection from the analytic eigensystem in the singular values,
      dispatch's ``singular_hessian`` and ``pair_eigenvalues``) or "never_needed" (its tangent is PSD at every F).
    - defined_where_inverted: False where psi is infinite at J <= 0 (no line search accepts such a state).
    - as_rigid_as_possible: whether it is projective dynamics' element constraint where lambda = 0 (system.py's
      ``projective_form()``).
    - lame_parameters: (mu, lambda, dim) -> the (mu, lambda) its kernels take, from the Lame parameters.
    - rest_volume_term: (mu, lambda, dim) -> the per-element constant its vertex terms take (``alpha`` of the
      sweeps), or None (zeros).
    - linear_at_rest: whether its Hessian at F = I, with ``lame_parameters``' (mu, lambda), is linear elasticity's
      with the Lame parameters.
    """

    code: int
    shells: bool
    membrane: str | None
    projection: str
    defined_where_inverted: bool
    solid_dims: tuple[int, ...] = (2, 3)
    vbd: bool = True
    not_for_shells: str = ""
    as_rigid_as_possible: bool = False
    lame_parameters: Callable[[np.ndarray, np.ndarray, int], tuple[np.ndarray, np.ndarray]] = _unchanged
    rest_volume_term: Callable[[np.ndarray, np.ndarray, int], np.ndarray] | None = None
    linear_at_rest: bool = True


# config name -> the material (the order the config's schema lists them in)
MATERIALS = {
    "linear": Material(LINEAR, shells=False, membrane=None, projection="never_needed", defined_where_inverted=True,
                       not_for_shells="linear elasticity is not rotation invariant, and a shell's triangles turn out "
                                      "of their plane"),
    "corotated": Material(COROTATED, shells=True, membrane="invariants", projection="closed_form",
                          defined_where_inverted=True, as_rigid_as_possible=True),
    "stvk": Material(STVK, shells=True, membrane="strain", projection="closed_form", defined_where_inverted=True),
    "neo_hookean": Material(NEO_HOOKEAN, shells=True, membrane="invariants", projection="closed_form",
                            defined_where_inverted=False),
    "stable_neo_hookean": Material(STABLE_NEO_HOOKEAN, shells=True, membrane="invariants", projection="closed_form",
                                   defined_where_inverted=True, lame_parameters=stable_neo_hookean.lame_parameters,
                                   rest_volume_term=stable_neo_hookean.rest_volume_term),
}
# config name -> the kernels' code
CODES = {name: material.code for name, material in MATERIALS.items()}


def shell_materials() -> list[str]:
    """The names of the materials a shell may take: those written in the strain first, then those in the invariants,
    each in MATERIALS' order."""
    return [name for form in ("strain", "invariants") for name, material in MATERIALS.items()
            if material.shells and material.membrane == form]


def lame(youngs_modulus: np.ndarray, poisson_ratio: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mu, lambda) (Pa) of E (Pa) and nu, element by element."""
    mu = youngs_modulus / (2.0 * (1.0 + poisson_ratio))
    lam = youngs_modulus * poisson_ratio / ((1.0 + poisson_ratio) * (1.0 - 2.0 * poisson_ratio))
    return mu, lam


def energy_parameters(material: str, dim: int, youngs_modulus: np.ndarray, poisson_ratio: np.ndarray,
                      shell: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The (mu, lambda) the kernels' energy ``material`` takes (Pa): the Lame parameters (plane stress for a shell,
    whose dim is 2), re-parametrised as the material says (``Material.lame_parameters``)."""
    mu, lam = lame(youngs_modulus, poisson_ratio)
    if shell:
        lam = youngs_modulus * poisson_ratio / (1.0 - poisson_ratio * poisson_ratio)
    return MATERIALS[material].lame_parameters(mu, lam, dim)
