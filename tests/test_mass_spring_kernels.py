"""The springs' compiled geometry and gradient at one state (systems/mass_spring/kernels.py: projective
dynamics' local step and right-hand side, and every solver's gradient) against the numpy forms they replace, kept
here as the reference:

1. delta, L, L - l0, k (L - l0) and the gradient equal the numpy forms bit for bit, for both spring laws, in 2-D and
   3-D, on a grid, the course square and a cloth, at a stretched, a compressed and a random state;
2. the gradient is the energy's derivative (central differences), so the gather's signs and components are right
   whatever the numpy form says.
"""

from __future__ import annotations

import numpy as np
import pytest

from simrun.systems import ClothParams
from simrun.systems.mass_spring.params import MassSpringParams


def grid(law: str):
    return MassSpringParams(
        model={"grid": {"resolution": [7, 5], "size": [0.3, 0.2]}}, spring_law=law,
        stiffness={"stretch": 60.0, "shear": 10.0, "bend": 1.0}, mass={"total": 0.2}, pinned=[0]).build()


def square_2d(law: str):
    return MassSpringParams(model={"square": {"segments": 6, "size": 1.0}}, spring_law=law, stiffness=500.0,
                            mass={"per_vertex": 0.1}, gravity=[0.0, -9.81], pinned=[0]).build()


def cloth(law: str):
    return ClothParams(resolution=(24, 24), mass=1.0, stretch_stiffness=200.0, shear_stiffness=50.0, bend_stiffness=5.0,
                       pinned=["top_left", "top_right"]).build()


SYSTEMS = [pytest.param(build, law, id=f"{build.__name__}-{law}")
           for build in (grid, square_2d) for law in ("hookean", "squared_length")] + [
    pytest.param(cloth, "hookean", id="cloth-hookean")]


def states(system):
    """The rest shape stretched 30 %, squeezed to 60 % with noise, and a random one."""
    rest = system.rest.reshape(-1, system.dim)
    centre = rest.mean(axis=0)
    rng = np.random.default_rng(7)
    squeezed = centre + 0.6 * (rest - centre) + 0.01 * rng.standard_normal(rest.shape)
    return {"stretched": (centre + 1.3 * (rest - centre)).ravel(), "compressed": squeezed.ravel(),
            "random": rng.standard_normal(rest.size)}


def numpy_geometry(system, x):
    """The numpy form the kernel replaced: a flat gather of the dofs, L = sqrt(delta^2 . 1)."""
    first = (system.dim * system.first[:, None] + np.arange(system.dim)).ravel()
    second = (system.dim * system.second[:, None] + np.arange(system.dim)).ravel()
    delta = (np.take(x, first) - np.take(x, second)).reshape(-1, system.dim)
    length = np.sqrt(np.square(delta) @ np.ones(system.dim))
    stretch = length - system.rest_length
    return delta, length, stretch, system.stiffness * stretch


def numpy_gradient(system, x):
    """The incidence matrix times the springs' c_e delta_e, minus gravity."""
    geometry = system._geometry_at(x)
    factor = system.law.gradient_factor(system, geometry)
    return (system._incidence @ (geometry.delta.T * factor).T).ravel() - system._gravity_force


@pytest.mark.parametrize("build, law", SYSTEMS)
def test_geometry_and_gradient_are_the_numpy_forms_bit_for_bit(build, law):
    system = build(law)
    for name, x in states(system).items():
        geometry = system._geometry_at(x)
        for computed, expected, part in zip((geometry.delta, geometry.length, geometry.stretch, geometry.tension),
                                            numpy_geometry(system, x), ("delta", "length", "stretch", "tension")):
            assert np.array_equal(computed, expected), f"{name}: {part}"
        system._geometry = None
        assert np.array_equal(system.gradient(x), numpy_gradient(system, x)), name


@pytest.mark.parametrize("build, law", SYSTEMS)
def test_the_gradient_is_the_energys_derivative(build, law):
    system = build(law)
    x = states(system)["random"]
    gradient = system.gradient(x)
    h = 1e-6
    rng = np.random.default_rng(3)
    for direction in rng.standard_normal((3, x.size)):
        difference = (system.potential_energy(x + h * direction) - system.potential_energy(x - h * direction)) / (2 * h)
        assert difference == pytest.approx(gradient @ direction, rel=1e-6, abs=1e-9 * np.abs(gradient).sum())
