"""The forms a system offers its solver families (systems/forms.py), and the contract check that holds them to what
they stand for (runner/contracts/system.py ``check_forms``): a wrong block, a colour that joins two vertices, a K_r
that is not PSD and springs that are not the force are each found."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from simrun.contracts.system import check_forms
from simrun.experiment.config import validate_system
from simrun.systems.forms import NotOffered, VertexForm, refusal_reason
from simrun.systems.mass_spring.blocks import SpringVertexForm

CLOTH = {"type": "cloth", "resolution": [4, 3], "size": [0.3, 0.2], "pinned": []}
SPRING = {"type": "spring_mass"}


def built(params: dict):
    return validate_system(params).build()


def test_a_form_not_offered_is_false_and_says_why():
    refused = NotOffered("the gravitational law -GMm/|x| is not a Hookean spring")
    assert not refused and refusal_reason(refused, "generic") == refused.reason
    assert refusal_reason(None, "generic") == "generic"
    orbit = built({"type": "circular_motion", "force": "gravity"})
    assert not orbit.projective_form() and not orbit.compliant_form() and orbit.contact_form() is None
    assert "gravitational" in orbit.projective_form().reason


def test_a_form_is_built_once_per_system_and_afresh_for_a_copy():
    cloth = built(CLOTH)
    form = cloth.vertex_form()
    assert isinstance(form, SpringVertexForm) and cloth.vertex_form() is form
    assert form.colouring() is form.colouring()
    part = copy.copy(cloth)  # what ``released`` and an IMEX part start from
    assert part.vertex_form() is not form and part.vertex_form().system is part
    assert cloth.vertex_form() is form


def test_every_shipped_form_passes_its_check():
    for params in (CLOTH, SPRING, {"type": "circular_motion", "force": "linear"}):
        check = check_forms(built(params))
        assert check.passed is True, check.detail


def test_a_vertex_block_off_by_one_in_a_million_fails(monkeypatch):
    blocks = SpringVertexForm.blocks
    monkeypatch.setattr(SpringVertexForm, "blocks",
                        lambda self, x, vertices, project_spd=False: tuple(part * (1 + 1e-6) for part in
                                                                           blocks(self, x, vertices, project_spd)))
    check = check_forms(built(CLOTH))
    assert check.passed is False and "vertex form: its blocks differ" in check.detail


def test_a_colour_that_joins_two_neighbours_fails(monkeypatch):
    monkeypatch.setattr(SpringVertexForm, "colouring", lambda self: [np.arange(self.system.vertex_count)])
    check = check_forms(built(CLOTH))
    assert check.passed is False and "join two vertices of one colour" in check.detail


def test_energy_changes_that_are_not_p_fail(monkeypatch):
    changes = SpringVertexForm.energy_changes
    monkeypatch.setattr(SpringVertexForm, "energy_changes",
                        lambda self, x, vertices, steps: 1.01 * changes(self, x, vertices, steps))
    check = check_forms(built(CLOTH))
    assert check.passed is False and "energy changes differ" in check.detail


def test_a_rest_stiffness_that_is_not_psd_fails(monkeypatch):
    system = built(SPRING)
    form = system.projective_form()
    monkeypatch.setattr(type(system), "projective_form",
                        lambda self: type(form)(rest_stiffness=lambda: -form.rest_stiffness(), inexact=None))
    check = check_forms(system)
    assert check.passed is False and "K_r has an eigenvalue" in check.detail


def test_springs_that_are_not_the_force_fail(monkeypatch):
    system = built(SPRING)
    springs = system.compliant_form()
    wrong = type(springs)(first=springs.first, second=springs.second, anchor=springs.anchor,
                          rest_length=springs.rest_length, stiffness=1.01 * springs.stiffness, damping=springs.damping,
                          vertex_count=springs.vertex_count, other_forces=False)
    monkeypatch.setattr(type(system), "compliant_form", lambda self: wrong)
    check = check_forms(system)
    assert check.passed is False and "the springs' force differs" in check.detail


def test_the_generic_vertex_form_reads_the_gradient_and_hessian():
    system = built(SPRING)
    x = np.array([0.3])
    gradient, hessian = VertexForm(system).blocks(x, np.array([0]))
    assert gradient[0, 0] == system.gradient(x)[0] and hessian[0, 0, 0] == np.asarray(system.hessian(x))[0, 0]
    step = np.array([[1e-3]])
    expected = system.potential_energy(x + step[0]) - system.potential_energy(x)
    assert VertexForm(system).energy_changes(x, np.array([0]), step)[0] == pytest.approx(expected, rel=1e-12)
