"""XPBD's compiled distance-constraint projection (integrators/xpbd_kernels.py) against the vectorised numpy
update it replaced (kept here as the reference): each colour group's update of the displacements and multipliers to
1e-12, with dampers, sliding ends (planes and lines), anchored springs (no shipped system has one of nonzero length: a group
made here), in 2-D and 3-D; and the same with one thread
and with two, bit for bit."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from simrun.experiment.config import load_experiment
from simrun.integrators.xpbd import _filtered, _group, spring_projection
from simrun.systems.compliant import ANCHORED, CompliantSprings

SYSTEMS = {
    "cloth_sliding_damped": {"type": "mass_spring", "model": {"grid": {"resolution": [5, 5], "size": [0.4, 0.4]}},
                             "stiffness": {"stretch": 80.0, "shear": 10.0, "bend": 1.0}, "mass": {"total": 0.2},
                             "damping": [{"model": "spring", "coefficient": 0.05}], "pinned": [0],
                             "constraints": [{"vertices": [6, 7], "normal": [0.3, -0.5, 0.8]},
                                             {"vertices": [12], "direction": [1.0, 2.0, -0.5]}]},
    "square_2d": {"type": "mass_spring", "model": {"square": {"segments": 3, "size": 1.0}}, "stiffness": 300.0,
                  "mass": {"per_vertex": 0.1}, "gravity": [0.0, -9.81], "pinned": [0],
                  "damping": [{"model": "spring", "coefficient": 0.02}]},
}


def numpy_distance_update(group, start, displacement, multiplier, stiffness_h2, damping_h):
    """The numpy form of one group's distance-constraint update (integrators/xpbd.py's update before it was compiled)."""
    d = group.first_weight.shape[1]
    start, moves = start.reshape(-1, d), displacement.reshape(-1, d)
    moved = moves[group.first] - group._second_ends(moves, None)
    delta = (start[group.first] - group._second_ends(start, group.anchor)) + moved
    length = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    direction = delta / np.where(length > 0.0, length, np.inf)[:, None]
    first_gradient = _filtered(group.first_weight * direction, group.sliding[0])
    second_gradient = _filtered(group.second_weight * direction, group.sliding[1])
    weight = np.einsum("ij,ij->i", first_gradient + second_gradient, direction)
    numerator = -stiffness_h2 * (length - group.rest_length) - multiplier
    if damping_h.any():
        numerator -= damping_h * np.einsum("ij,ij->i", moved, direction)
    change = numerator / ((stiffness_h2 + damping_h) * weight + 1.0)
    multiplier += change
    moves[group.first] += first_gradient * change[:, None]
    moves[group.second] -= (second_gradient * change[:, None]) if group.free_rows is None else \
        (second_gradient * change[:, None])[group.free_rows]


def build(config):
    return load_experiment({"name": "xpbd", "system": config, "integrators": ["xpbd"],
                            "sweep": {"dt": [0.01]}})[0].system.build()


@pytest.mark.parametrize("name", sorted(SYSTEMS))
def test_the_compiled_projection_is_the_numpy_update(name):
    system = build(SYSTEMS[name])
    projection = spring_projection(system)
    h = 0.004
    rng = np.random.default_rng(5)
    start = system.x0 + 0.02 * rng.standard_normal(system.dof_count)
    groups = [group for group in projection.groups if not group.vector]
    assert groups
    kinds = {"sliding": False, "damped": False}
    for group, (stiffness_h2, damping_h) in zip(projection.groups, projection.scaled(h)):
        if group.vector:
            continue
        kinds["sliding"] |= any(end is not None for end in group.sliding)
        kinds["damped"] |= bool(damping_h.any())
        displacement = 0.01 * rng.standard_normal(system.dof_count)
        multiplier = 1e-3 * rng.standard_normal(group.first.size)
        expected_displacement, expected_multiplier = displacement.copy(), multiplier.copy()
        numpy_distance_update(group, start, expected_displacement, expected_multiplier, stiffness_h2, damping_h)
        group.project(start, displacement, multiplier, stiffness_h2, damping_h)
        np.testing.assert_allclose(displacement, expected_displacement, rtol=0.0,
                                   atol=1e-12 * np.max(np.abs(expected_displacement)))
        np.testing.assert_allclose(multiplier, expected_multiplier, rtol=0.0,
                                   atol=1e-12 * np.max(np.abs(expected_multiplier)))
    expected_kinds = {"cloth_sliding_damped": {"sliding", "damped"}, "square_2d": {"damped"}}[name]
    assert {kind for kind, seen in kinds.items() if seen} >= expected_kinds


def test_one_thread_and_two_project_the_same_bit_for_bit():
    system = build({"type": "cloth", "resolution": [40, 40], "stretch_stiffness": 1e4, "shear_stiffness": 1e3,
                    "bend_stiffness": 10.0, "damping": 0.1})
    projection = spring_projection(system)
    group, (stiffness_h2, damping_h) = next((group, scaled) for group, scaled in zip(projection.groups, projection.scaled(1e-3))
                                            if not group.vector)
    assert group.first.size > 256, "the group must span several chunks"
    rng = np.random.default_rng(2)
    start = system.x0 + 0.01 * rng.standard_normal(system.dof_count)
    base = 0.01 * rng.standard_normal(system.dof_count)
    threads = numba.get_num_threads()
    results = []
    try:
        for count in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(count)
            displacement, multiplier = base.copy(), np.zeros(group.first.size)
            group.project(start, displacement, multiplier, stiffness_h2, damping_h)
            results.append((displacement, multiplier))
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(results[0][0], results[-1][0]) and np.array_equal(results[0][1], results[-1][1])


def test_anchored_distance_springs_project_as_the_numpy_update():
    """Springs tied to fixed points at nonzero rest length, beside a free one, with dampers: the anchored rows'
    second ends stay at their anchors."""
    springs = CompliantSprings(first=np.array([0, 1, 2]), second=np.array([1, ANCHORED, ANCHORED]),
                               anchor=np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.5, 0.5]]),
                               rest_length=np.array([0.5, 0.3, 0.2]), stiffness=np.array([50.0, 20.0, 10.0]),
                               damping=np.array([0.1, 0.2, 0.3]), vertex_count=3, other_forces=False)
    weights = np.array([[2.0, 2.0, 2.0], [1.0, 1.0, 1.0], [4.0, 4.0, 4.0]])
    rng = np.random.default_rng(3)
    start, base = rng.standard_normal(9), 0.1 * rng.standard_normal(9)
    for rows in (np.array([0, 2]), np.array([1])):  # colours: springs of one group share no vertex
        group = _group(springs, rows, weights, np.full(3, -1), None, vector=False)
        assert group.free_rows is not None or rows.size == 1
        stiffness_h2, damping_h = group.stiffness * 1e-4, group.damping * 1e-2
        displacement, multiplier = base.copy(), np.zeros(rows.size)
        expected_displacement, expected_multiplier = base.copy(), np.zeros(rows.size)
        numpy_distance_update(group, start, expected_displacement, expected_multiplier, stiffness_h2, damping_h)
        group.project(start, displacement, multiplier, stiffness_h2, damping_h)
        np.testing.assert_allclose(displacement, expected_displacement, rtol=0.0, atol=1e-14)
        np.testing.assert_allclose(multiplier, expected_multiplier, rtol=1e-13)
        assert np.any(displacement != base)
