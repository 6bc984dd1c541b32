"""The colliders' per-vertex terms in vertex block descent's compiled sweeps (systems/contact/point_kernels.py)
against the numpy forms they replace (contact/model.py ``point_terms`` and ``point_energy_changes``, kept as the
reference here):

1. at random points, moving and spinning, the penalty's and the barrier's gradient, Hessian (as it is, clamped and
   mirrored) and energy change of the plane, sphere, box, capsule (2-D and 3-D) and torus (3-D), to 1e-12;
2. the compiled mass-spring and finite-element sweeps with colliders land where the numpy sweep lands (1e-12 of the
   move) with the same halvings: a cloth on a sphere, a box and a capsule (penalty with contact damping, and IPC), a
   cloth on a torus (IPC), a soft box on a tilted plane and a sphere;
3. the solver takes the compiled sweep with colliders, E never increases, and under IPC no vertex ends inside;
4. a grid SDF (no compiled form) keeps the numpy sweep;
5. IPC's step filter per vertex: the compiled fraction of a point's move that stops short of the first collider it
   would reach is numpy's (``ContactModel.point_step_fractions``), its segment never touches a collider, and neither
   sweep carries a falling cloth or soft box through a board thinner than one step's move.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import agreeing_sweeps, step_problem
from simrun.solvers import VertexBlockDescent
from simrun.solvers.dofs import free_dofs
from simrun.solvers.line_search import ENERGY_ROUNDOFF
from simrun.solvers.vbd import IncrementalParts, colour_plans
from simrun.systems import ClothParams
from simrun.systems.contact.colliders import build_collider
from simrun.systems.contact.model import ContactModel
from simrun.systems.contact.point_kernels import colliders_of, point_blocks, point_moves
from simrun.systems.contact.pose import ColliderContact
from simrun.systems.fem.params import FemParams
from simrun.systems.vertex.kernel_arguments import PROJECTION_CODES

SHAPES = {
    "plane": {"normal": [0.3, -0.2, 1.0], "point": [0.0, 0.0, -0.2]},
    "sphere": {"center": [0.1, 0.2, 0.0], "radius": 0.3},
    "box": {"center": [-0.1, 0.1, 0.05], "half_extents": [0.2, 0.15, 0.25]},
    "capsule": {"a": [-0.2, -0.1, 0.0], "b": [0.25, 0.2, 0.1], "radius": 0.12},
    "torus": {"center": [0.05, -0.05, 0.0], "axis": [0.3, 0.2, 1.0], "major_radius": 0.25, "minor_radius": 0.08},
}


def shape_arguments(shape: str, dim: int) -> dict:
    return {name: value[:dim] if isinstance(value, list) and name != "axis" else value
            for name, value in SHAPES[shape].items()}


def contact_model(shapes, dim: int, method: str, motion: str) -> ContactModel:
    """Colliders of ``shapes`` static, moving (a velocity) or spinning (a velocity and a turn about an axis), at
    t = 0.3 s; IPC with a reach of 0.1 m so that many points are near."""
    colliders = []
    for number, shape in enumerate(shapes):
        velocity = None if motion == "static" else [0.4, -0.3, 0.2][:dim]
        collider = build_collider(shape, dim, velocity=velocity, **shape_arguments(shape, dim))
        spin = None
        if motion == "spinning":
            axis = np.array([0.2, 0.5, 1.0]) if dim == 3 else np.array([0.0, 0.0, 1.0])
            spin = (np.array([0.05, -0.1, 0.02][:dim]), axis / np.linalg.norm(axis), 1.7)
        colliders.append(ColliderContact(collider, 800.0 * (number + 1) if method == "penalty" else None, spin))
    model = ContactModel(method=method, colliders=colliders, dim=dim, vertex_count=1, dhat=0.1,
                         stiffness=50.0 if method == "ipc" else None, damping=0.0, friction=None)
    model.time = 0.3
    return model


def sample(model: ContactModel, dim: int, count: int = 4000):
    """Points around the colliders and random steps; under IPC only points at least 5 mm outside every collider
    (numpy's ``point_terms`` gives a state with one point inside infinite energy and no terms, and the barrier's
    derivatives magnify the round-off of phi by about dhat / phi, differently in each form). No point within 2 cm of a
    sphere's centre, a capsule's segment, a torus's core circle or its axis: there the curvature terms' 1 / rho
    magnify the round-off of P, whose entries cancel (P = 0 exactly along a 2-D capsule's side), in the numpy form and
    the compiled one alike."""
    rng = np.random.default_rng(4)
    points = rng.uniform(-0.45, 0.45, (count, dim))
    for contact in model.colliders:
        collider = contact.collider
        if hasattr(collider, "radius"):
            points = points[contact.signed_distance(points, model.time) + collider.radius > 0.02]
        if collider.shape == "torus":
            points = points[contact.signed_distance(points, model.time) + collider.minor_radius > 0.02]
            # the distance from the axis, in the torus's t = 0 frame
            local = contact._local(points, model.time) if contact.spin is not None else (
                points - collider.velocity * model.time)
            offset = local - collider.center
            radial = offset - np.outer(offset @ collider.axis, collider.axis)
            points = points[np.linalg.norm(radial, axis=1) > 0.02]
    if model.method == "ipc":
        outside = np.all([contact.signed_distance(points, model.time) > 0.005 for contact in model.colliders], axis=0)
        points = points[outside]
    return points, 0.08 * rng.standard_normal(points.shape)


def relative(a, b) -> float:
    scale = np.max(np.abs(b))
    assert scale > 0.0
    return float(np.max(np.abs(a - b)) / scale)


@pytest.mark.parametrize("motion", ["static", "moving", "spinning"])
@pytest.mark.parametrize("method", ["penalty", "ipc"])
@pytest.mark.parametrize("shapes, dim", [
    pytest.param(shapes, dim, id=f"{'+'.join(shapes)}-{dim}d")
    for shapes in (["plane"], ["sphere"], ["box"], ["capsule"], ["torus"], ["plane", "sphere", "box", "capsule"],
                   ["plane", "sphere", "box", "capsule", "torus"])
    for dim in (2, 3) if dim == 3 or "torus" not in shapes])  # a torus exists in 3-D only
def test_the_compiled_point_terms_are_numpys(shapes, dim, method, motion):
    model = contact_model(shapes, dim, method, motion)
    points, steps = sample(model, dim)
    colliders = colliders_of(model, dim)
    acting = 0
    for projection in (False, "clamp", "abs"):
        gradient, hessian = np.zeros_like(points), np.zeros(points.shape + (dim,))
        energy = model.point_terms(points, gradient, hessian, projection)
        assert math.isfinite(energy)
        compiled_gradient, compiled_hessian = np.zeros_like(points), np.zeros(points.shape + (dim,))
        point_blocks(points, colliders, PROJECTION_CODES[projection], compiled_gradient, compiled_hessian)
        assert relative(compiled_gradient, gradient) < 1e-12
        assert relative(compiled_hessian, hessian) < 1e-12
        acting = int(np.count_nonzero(np.any(gradient != 0.0, axis=1)))
    assert acting > 50, "the sample must put many points in contact"
    changes = model.point_energy_changes(points, steps)
    compiled = np.empty(len(points))
    point_moves(points, steps, colliders, compiled, np.empty(len(points)))
    finite = np.isfinite(changes)
    np.testing.assert_array_equal(np.isfinite(compiled), finite)
    np.testing.assert_array_equal(compiled[~finite], changes[~finite])  # a step into a collider under IPC: inf
    assert relative(compiled[finite], changes[finite]) < 1e-12


@pytest.mark.parametrize("motion", ["static", "moving", "spinning"])
@pytest.mark.parametrize("shapes, dim", [
    pytest.param(shapes, dim, id=f"{'+'.join(shapes)}-{dim}d")
    for shapes in (["plane"], ["sphere"], ["box"], ["capsule"], ["torus"], ["plane", "sphere", "box", "capsule", "torus"])
    for dim in (2, 3) if dim == 3 or "torus" not in shapes])
def test_the_compiled_impact_fractions_are_numpys_and_stop_short_of_every_collider(shapes, dim, motion):
    """Exact roots for the plane, sphere and capsule, conservative advancement for the box and torus, in both forms;
    every cut move's segment stays outside every collider (checked at 200 points along it)."""
    model = contact_model(shapes, dim, "ipc", motion)
    points, steps = sample(model, dim)
    steps *= 5.0  # 0.4 m moves: many reach a collider, some would cross one
    fractions = model.point_step_fractions(points, steps)
    compiled = np.empty(len(points))
    point_moves(points, steps, colliders_of(model, dim), np.empty(len(points)), compiled)
    cut = fractions < 1.0
    assert np.count_nonzero(cut) > 100, "the sample must cut many moves"
    assert np.max(np.abs(compiled - fractions)) < 1e-12
    along = np.linspace(0.0, 1.0, 200)
    ends = points[cut, None, :] + (fractions[cut, None] * along)[:, :, None] * steps[cut, None, :]
    for contact in model.colliders:
        assert np.all(contact.signed_distance(ends.reshape(-1, dim), model.time) > 0.0)


def test_the_curved_shapes_curvature_terms_are_exercised():
    """The filtered curvature term P s / rho is where the projection acts: clamped, the sphere's penalty keeps none of
    it (s < 0 inside), mirrored it keeps it, so the two Hessians differ (the comparison above covers both)."""
    model = contact_model(["sphere"], 3, "penalty", "static")
    points, _ = sample(model, 3)
    colliders = colliders_of(model, 3)
    blocks = {}
    for projection in ("clamp", "abs"):
        gradient, hessian = np.zeros_like(points), np.zeros(points.shape + (3,))
        point_blocks(points, colliders, PROJECTION_CODES[projection], gradient, hessian)
        blocks[projection] = hessian
    assert np.max(np.abs(blocks["abs"] - blocks["clamp"])) > 1.0


# -- the sweeps -----------------------------------------------------------------------------------------------------
def draped_cloth(method: str, spinning: bool = False):
    """A 9 x 9 cloth (1 m) falling at 2 m/s onto a sphere, a box and a capsule below its middle; penalty with contact
    damping, or IPC (reach 2 cm) with the colliders moving (and the box spinning) when asked."""
    motion = {"velocity": [0.0, 0.1, 0.3]} if spinning else {}
    colliders = [
        {"shape": "sphere", "center": [0.3, 0.5, -0.25], "radius": 0.22, **motion},
        {"shape": "box", "center": [0.72, 0.3, -0.12], "half_extents": [0.1, 0.12, 0.08],
         **({"rotation": {"center": [0.72, 0.3, -0.12], "axis": [0.0, 0.3, 1.0], "rate": 40.0}} if spinning else {})},
        {"shape": "capsule", "a": [0.6, 0.65, -0.08], "b": [0.9, 0.85, -0.1], "radius": 0.05},
    ]
    if method == "penalty":
        contact = {"method": "penalty", "stiffness": 3e3, "damping": 2.0, "colliders": colliders}
    else:
        contact = {"method": "ipc", "dhat": 0.02, "stiffness": 20.0, "colliders": colliders}
    return ClothParams(resolution=(9, 9), mass=0.5, stretch_stiffness=300.0, shear_stiffness=50.0, bend_stiffness=2.0,
                       pinned=[], contact=contact).build()


def cloth_on_a_torus():
    """The same cloth falling onto a tilted torus (IPC, reach 2 cm): the torus's two curvatures, one negative in its
    hole, in the sweep."""
    torus = {"shape": "torus", "center": [0.5, 0.5, -0.16], "axis": [0.0, 0.3, 1.0], "major_radius": 0.25,
             "minor_radius": 0.06}
    return ClothParams(resolution=(9, 9), mass=0.5, stretch_stiffness=300.0, shear_stiffness=50.0, bend_stiffness=2.0,
                       pinned=[], contact={"method": "ipc", "dhat": 0.02, "stiffness": 20.0, "colliders": [torus]}).build()


def dropped(system, lowered=0.0, speed=2.0, dt=0.05):
    """The first step's problem from x0 moved down by ``lowered`` (m) at ``speed`` (m/s) downwards."""
    x = system.x0.reshape(-1, system.dim).copy()
    x[:, -1] -= lowered
    v = np.zeros_like(x)
    v[:, -1] = -speed
    return step_problem(system, x.ravel(), v.ravel(), dt)


def soft_box(method: str):
    """A neo-Hookean box (10 x 5 x 5 cm, its bottom at z = 0) on a tilted plane and a sphere: lowered by 2 cm into
    both (penalty), or by 1.2 cm to within the barrier's 5 mm of both (IPC)."""
    colliders = [{"shape": "plane", "normal": [-0.2, 0.0, 1.0], "point": [0.0, 0.0, -0.025 if method == "penalty" else -0.035]},
                 {"shape": "sphere", "center": [0.06, 0.025, -0.06], "radius": 0.045}]
    contact = ({"method": "penalty", "stiffness": 1e4, "colliders": colliders} if method == "penalty"
               else {"method": "ipc", "dhat": 0.005, "stiffness": 5.0, "colliders": colliders})
    return FemParams(model={"box": {"size": [0.1, 0.05, 0.05], "cells": [4, 2, 2]}},
                     material={"model": "neo_hookean", "youngs_modulus": 2e4, "poisson_ratio": 0.3},
                     gravity=[0.0, 0.0, -9.81], contact=contact).build()


# (the system, how far its start is lowered (m))
CASES = {
    "cloth-penalty": (lambda: draped_cloth("penalty"), 0.05),  # in the colliders at x_n: contact damping in D
    "cloth-ipc": (lambda: draped_cloth("ipc"), 0.0),
    "cloth-ipc-moving": (lambda: draped_cloth("ipc", spinning=True), 0.0),
    "cloth-torus-ipc": (cloth_on_a_torus, 0.0),
    "fem-penalty": (lambda: soft_box("penalty"), 0.02),
    "fem-ipc": (lambda: soft_box("ipc"), 0.012),
}


def in_contact(system, y) -> int:
    return system.contact.active_count(y)


@pytest.mark.parametrize("projection", ["clamp", "abs"])
@pytest.mark.parametrize("case", list(CASES))
def test_the_compiled_sweep_with_colliders_is_the_numpy_sweep(case, projection):
    build, lowered = CASES[case]
    system = build()
    problem, start = dropped(system, lowered)
    sweep, parts = system.vertex_form().sweep(), IncrementalParts.of(problem)
    assert sweep is not None and sweep.colliders[0].size == len(system.contact.colliders)
    if case == "cloth-penalty":  # the contact damping k_d n n^T of the vertices inside at x_n
        assert parts.damping_weight > 0.0 and np.any(parts.damping_data != 0.0)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding),
                         system.dim)
    solver = VertexBlockDescent(spd_projection=projection)
    touched = 0
    for _, y, _ in agreeing_sweeps(solver, problem, start, plans, sweep, parts, 5):
        touched = max(touched, in_contact(system, y))
    assert touched > 3, "the sweeps must reach the colliders"
    if system.contact.method == "ipc":
        assert system.contact.minimum_distance(y) > 0.0


@pytest.mark.parametrize("case", ["cloth-ipc-moving", "fem-penalty"])
def test_the_solver_takes_the_compiled_sweep_with_colliders_and_e_never_increases(case, monkeypatch):
    build, lowered = CASES[case]
    system = build()
    problem, start = dropped(system, lowered)

    def numpy_sweep(*args):
        raise AssertionError("the numpy sweep ran")

    monkeypatch.setattr(VertexBlockDescent, "_sweep", numpy_sweep)
    energies, iterates = [], []

    def record(y, gradient):
        energies.append(problem.value(y))
        iterates.append(y.copy())

    VertexBlockDescent(tolerance=1e-9, max_iterations=60, callback=record).minimize(problem, start)
    energies = np.array(energies)
    assert energies.size > 10 and np.all(np.isfinite(energies))
    assert np.all(np.diff(energies) <= ENERGY_ROUNDOFF * np.abs(energies[:-1]))
    assert in_contact(system, iterates[-1]) > 3
    if system.contact.method == "ipc":
        assert min(system.contact.minimum_distance(y) for y in iterates) > 0.0


def test_a_grid_sdf_keeps_the_numpy_sweep():
    """A sampled SDF has no compiled form (nor an exact distance, which the sweep's reach test needs): the system then
    offers no compiled sweep, and the solver sweeps with the numpy blocks."""
    from simrun.systems.contact.point_kernels import placed

    ball = np.linalg.norm(np.stack(np.meshgrid(*[np.linspace(-1.0, 1.0, 9)] * 3, indexing="ij")), axis=0) - 0.5
    grid = build_collider("grid_sdf", 3, values=ball, origin=[-1.0, -1.0, -1.0], spacing=0.25)
    model = ContactModel(method="penalty", colliders=[ColliderContact(grid, 1e3)], dim=3, vertex_count=1, dhat=0.1,
                         stiffness=None, damping=0.0, friction=None)
    system = draped_cloth("penalty")
    assert system.vertex_form().sweep() is not None
    assert colliders_of(model, 3) is None and placed(system.vertex_form().sweep(), model, 3) is None


def over_a_board(kind: str):
    """A cloth (5 x 5, 0.4 m) or a jelly box (10 x 5 x 5 cm) 2 cm above a 1 cm board (IPC, reach 5 mm), falling at
    6 m/s: the backward Euler step of 1/60 s predicts a 10 cm fall, to 7 cm below the board."""
    board = {"shape": "box", "center": [0.2, 0.2, -0.025], "half_extents": [1.0, 1.0, 0.005]}
    contact = {"method": "ipc", "dhat": 0.005, "stiffness": 5.0, "colliders": [board]}
    if kind == "cloth":
        return ClothParams(resolution=(5, 5), size=(0.4, 0.4), mass=0.2, stretch_stiffness=300.0, shear_stiffness=50.0,
                           bend_stiffness=2.0, pinned=[], contact=contact).build()
    # a jelly (E = 20 Pa): its vertices' steps follow their inertia, as the cloth's do, not the elements' stiffness
    return FemParams(model={"box": {"size": [0.1, 0.05, 0.05], "cells": [4, 2, 2]}},
                     material={"model": "neo_hookean", "youngs_modulus": 20.0, "poisson_ratio": 0.3},
                     gravity=[0.0, 0.0, -9.81], contact=contact).build()


@pytest.mark.parametrize("kind", ["cloth", "fem"])
def test_vbd_never_carries_a_vertex_through_a_thin_board(kind, monkeypatch):
    """Under IPC the barrier is infinite inside a collider, but a step can jump a thin one whole: from 2 cm above the
    board to 7 cm below it, where the barrier is 0 again. Each vertex's step is cut to stop short of the first collider
    it would reach, by both sweeps alike; without that cut the same sweep lands vertices under the board."""
    system = over_a_board(kind)
    problem, start = dropped(system, 0.0, speed=6.0, dt=1.0 / 60.0)
    sweep, parts = system.vertex_form().sweep(), IncrementalParts.of(problem)
    plans = colour_plans(system.vertex_form().colouring(), free_dofs(system.dof_count, system.fixed_dofs, system.sliding),
                         system.dim)
    solver = VertexBlockDescent()
    heights = []
    for _, y, _ in agreeing_sweeps(solver, problem, start, plans, sweep, parts, 6):
        heights.append(y.reshape(-1, 3)[:, 2].min())
        assert system.contact.minimum_distance(y) > 0.0
    assert min(heights) > -0.02 and min(heights) < -0.015, "the vertices come down to the board and stay above it"
    monkeypatch.setattr(type(system.vertex_form()), "step_fractions", lambda self, x, vertices, steps: None)
    unfiltered, _, _ = solver._sweep(problem, start, plans)
    assert unfiltered.reshape(-1, 3)[:, 2].min() < -0.03, "the sweep without the cut jumps the board"
