"""The materials of the finite-element system: their names, and the Lame parameters each energy takes.

mu = E / (2 (1 + nu)) and lambda = E nu / ((1 + nu) (1 - 2 nu)) for every energy, in 2-D as in 3-D (the plane-strain
reading of a 2-D solid, as the course code has it). The stable neo-Hookean energy takes them re-parametrised so
that its Hessian at rest is linear elasticity's with the given E and nu (Smith, de Goes & Kim 2018, sec. 3.4, there
for d = 3): mu' = mu (d + 1) / d, lambda' = lambda + mu' (d (d + 1) - 2) / (d + 1)^2, which in 3-D is mu' = 4 mu / 3,
lambda' = lambda + 5 mu / 6 (docs/fem.md derives it).

A shell's membrane is in plane stress (a thin sheet free to thin): lambda = E nu / (1 - nu^2), the 3-D lambda with the
normal stress eliminated, 2 mu lambda / (lambda + 2 mu), so that a membrane under uniaxial stress has Young's modulus
E and Poisson ratio nu in its own plane; the stable neo-Hookean re-parametrisation is then the one of d = 2.
"""

from __future__ import annotations

import numpy as np

from .energies import COROTATED, LINEAR, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK

# config name -> the kernels' code
MATERIALS = {"linear": LINEAR, "corotated": COROTATED, "stvk": STVK, "neo_hookean": NEO_HOOKEAN,
             "stable_neo_hookean": STABLE_NEO_HOOKEAN}


def lame(youngs_modulus: np.ndarray, poisson_ratio: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mu, lambda) (Pa) of E (Pa) and nu, element by element."""
    mu = youngs_modulus / (2.0 * (1.0 + poisson_ratio))
    lam = youngs_modulus * poisson_ratio / ((1.0 + poisson_ratio) * (1.0 - 2.0 * poisson_ratio))
    return mu, lam


def energy_parameters(material: str, dim: int, youngs_modulus: np.ndarray, poisson_ratio: np.ndarray,
                      shell: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The (mu, lambda) the kernels' energy ``material`` takes (Pa): the Lame parameters (plane stress for a shell,
    whose dim is 2), re-parametrised for the stable neo-Hookean energy."""
    mu, lam = lame(youngs_modulus, poisson_ratio)
    if shell:
        lam = youngs_modulus * poisson_ratio / (1.0 - poisson_ratio * poisson_ratio)
    if material == "stable_neo_hookean":
        mu_snh = mu * (dim + 1.0) / dim
        return mu_snh, lam + mu_snh * (dim * (dim + 1.0) - 2.0) / (dim + 1.0) ** 2
    return mu, lam
