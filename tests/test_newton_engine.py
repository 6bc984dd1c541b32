"""NVIDIA Newton's particle solvers measured as simrun measures its own (integrators/newton_engine.py), against what
theory says of them. Newton computes in float32: "to round-off" is float32's here.

Each Newton step is probed on unit states of the test spring (a bank of particles, each tied by a Newton spring to a
massless anchor particle), m = 1 kg, h = 1 s, k = (h w)^2, d = 2 zeta h w, and compared with:
- semi_implicit: symplectic Euler with every force at the start, v' = (1 - d) v - k x, x' = x + v': simrun's own
  symplectic Euler's matrix;
- xpbd and vbd: on one linear spring per particle, one iteration solves the step exactly, and both are backward
  Euler, (1 + d + k) v' = v - k x, x' = x + v', whatever the iteration count.
On a cloth the two iterative solvers are not the same algorithm as simrun's: VBD's Gauss-Seidel Newton sweeps converge
to backward Euler's step; Newton's XPBD sweeps the springs Jacobi-style and, as XPBD does, drops the geometric term of
the constraint's Newton step (Macklin, Mueller & Chentanez 2016, eq. 11), so it converges near backward Euler, not to
it. The tests state each difference and check the property that holds.
"""

from __future__ import annotations

import numpy as np
import pytest

import simrun
from conftest import needs_engine, run_one
from simrun.analysis.oscillator import bank_matrices
from simrun.errors import ConfigError
from simrun.integrators import SymplecticEuler
from simrun.integrators.newton_engine import ANCHOR_MARGIN, Newton

pytestmark = needs_engine("newton")

HW = np.logspace(-2, np.log10(3.0), 13)
FLOAT32 = 2e-7  # a float32 ulp near 1, with one rounding to spare
# the test spring's anchor sits ANCHOR_MARGIN reaches away: the spring force k q is rounded at that length's ulp
ON_THE_BANK = (ANCHOR_MARGIN * FLOAT32 * (1 + HW ** 2))[:, None, None]
EVERY_STEP = {"every": 1, "frames_every": 1}


def backward_euler(zeta: float) -> np.ndarray:
    k, d = HW ** 2, 2 * zeta * HW
    velocity = np.stack([-k / (1 + d + k), 1 / (1 + d + k)], axis=-1)
    position = np.stack([1 - k / (1 + d + k), 1 / (1 + d + k)], axis=-1)
    return np.stack([position, velocity], axis=1)


@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_semi_implicit_is_symplectic_euler_on_the_test_spring(zeta):
    damping = np.full(HW.shape, zeta)
    engine = bank_matrices(Newton(), HW, damping)
    own = bank_matrices(SymplecticEuler(), HW, damping)
    k, d = HW ** 2, 2 * zeta * HW
    closed_form = np.stack([np.stack([1 - k, 1 - d], axis=-1), np.stack([-k, 1 - d], axis=-1)], axis=1)
    np.testing.assert_allclose(own, closed_form, rtol=0, atol=1e-15)
    assert np.all(np.abs(engine - closed_form) <= ON_THE_BANK)


@pytest.mark.parametrize("solver", ["xpbd", "vbd"])
@pytest.mark.parametrize("iterations", [1, 10])
@pytest.mark.parametrize("zeta", [0.0, 0.1])
def test_xpbd_and_vbd_are_backward_euler_on_the_test_spring(solver, iterations, zeta):
    engine = bank_matrices(Newton(solver=solver, iterations=iterations), HW, np.full(HW.shape, zeta))
    assert np.all(np.abs(engine - backward_euler(zeta)) <= ON_THE_BANK)


def test_semi_implicit_steps_the_spring_as_symplectic_euler_for_100_steps():
    spring = {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0}
    own = run_one(spring, "symplectic_euler", 0.5, 50.0, record=EVERY_STEP)
    engine = run_one(spring, {"type": "newton"}, 0.5, 50.0, record=EVERY_STEP)
    assert engine.status == own.status == "ok" and engine.steps == own.steps == 100
    np.testing.assert_allclose(engine.samples["energy"], own.samples["energy"], rtol=0, atol=100 * FLOAT32 * 0.5)
    assert engine.attrs["engine"] == "Newton 1.8.0 on Warp 1.19.0, float32, CPU"


CLOTH = {"type": "cloth", "resolution": [5, 5], "size": [1.0, 1.0], "mass": 1.0, "stretch_stiffness": 1.0e3,
         "shear_stiffness": 1.0e2, "bend_stiffness": 1.0e1, "damping": 0.5, "gravity": [0.0, 0.0, -9.81],
         "pinned": ["top_left", "top_right"]}


def test_semi_implicit_steps_a_damped_spring_cloth_as_symplectic_euler():
    """100 steps of a hanging cloth (springs with dampers along them, gravity): simrun's symplectic Euler's frames
    to float32 round-off of the 0.2 m the cloth falls."""
    ours = run_one(CLOTH, "symplectic_euler", 0.002, 0.2, record=EVERY_STEP)
    theirs = run_one(CLOTH, {"type": "newton"}, 0.002, 0.2, record=EVERY_STEP)
    assert theirs.status == ours.status == "ok" and theirs.steps == 100
    fall = np.max(np.abs(ours.samples["frames"] - ours.samples["frames"][0]))
    assert fall > 0.15
    np.testing.assert_allclose(theirs.samples["frames"], ours.samples["frames"], rtol=0, atol=100 * FLOAT32 * fall)


def test_semi_implicit_swings_a_pendulum_chain_in_the_plane_as_symplectic_euler():
    rope = {"type": "mass_spring", "model": {"rope": {"count": 10, "length": 1.0, "direction": [1.0, 0.0]}},
            "stiffness": 1000.0, "mass": {"total": 0.04}, "gravity": [0.0, -9.81], "pinned": ["first"]}
    ours = run_one(rope, "symplectic_euler", 0.001, 0.1, record=EVERY_STEP)
    theirs = run_one(rope, {"type": "newton"}, 0.001, 0.1, record=EVERY_STEP)
    assert theirs.status == ours.status == "ok"
    np.testing.assert_allclose(theirs.samples["frames"], ours.samples["frames"], rtol=0, atol=100 * FLOAT32)


BEAM = {"type": "fem", "model": {"box": {"size": [0.4, 0.1, 0.1], "cells": [4, 1, 1]}},
        "material": {"model": "stable_neo_hookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3, "density": 500.0},
        "gravity": [0.0, 0.0, -9.81], "pinned": ["left"]}


def test_semi_implicit_steps_a_stable_neo_hookean_beam_as_symplectic_euler():
    """Newton's tetrahedra under semi_implicit are Smith et al.'s stable neo-Hookean with alpha = 1 + 3 mu / (4 lambda),
    the energy of simrun's stable_neo_hookean: 100 steps of a clamped beam sagging under gravity give simrun's own
    symplectic Euler's frames to float32 round-off of its 14 mm sag."""
    ours = run_one(BEAM, "symplectic_euler", 0.0005, 0.05, record=EVERY_STEP)
    theirs = run_one(BEAM, {"type": "newton"}, 0.0005, 0.05, record=EVERY_STEP)
    assert theirs.status == ours.status == "ok" and theirs.steps == 100
    sag = np.max(np.abs(ours.samples["frames"] - ours.samples["frames"][0]))
    assert sag > 0.01
    np.testing.assert_allclose(theirs.samples["frames"], ours.samples["frames"], rtol=0, atol=100 * FLOAT32 * sag)


UNDAMPED_CLOTH = {**CLOTH, "damping": 0.0}


def test_vbd_converges_to_backward_euler_on_a_cloth():
    """VBD's sweeps are Newton steps on each vertex's incremental potential: more iterations, closer to backward
    Euler's step (simrun's, solved by Newton), to float32 round-off at 100."""
    ours = run_one(UNDAMPED_CLOTH, "backward_euler", 0.01, 0.2, record=EVERY_STEP)
    distance = []
    for iterations in (1, 10, 100):
        theirs = run_one(UNDAMPED_CLOTH, {"type": "newton", "solver": "vbd", "iterations": iterations}, 0.01, 0.2,
                         record=EVERY_STEP)
        assert theirs.status == "ok"
        distance.append(np.max(np.abs(theirs.samples["frames"] - ours.samples["frames"])))
    assert distance[0] > 5 * distance[1] > 500 * distance[2]
    assert distance[2] < 20 * 20 * FLOAT32  # 20 steps of float32 rounding in coordinates of about 1 m


def test_xpbd_converges_near_backward_euler_on_a_cloth():
    """Newton's XPBD's Jacobi sweeps settle by 10 iterations at 2 ms, within 2e-4 m of backward Euler's frames
    (XPBD drops the geometric term of each constraint's Newton step) and no closer with 300."""
    ours = run_one(UNDAMPED_CLOTH, "backward_euler", 0.002, 0.2, record=EVERY_STEP)
    distance = {}
    for iterations in (1, 10, 300):
        theirs = run_one(UNDAMPED_CLOTH, {"type": "newton", "solver": "xpbd", "iterations": iterations}, 0.002, 0.2,
                         record=EVERY_STEP)
        distance[iterations] = np.max(np.abs(theirs.samples["frames"] - ours.samples["frames"]))
    assert distance[1] > 10 * distance[10]
    assert 1e-5 < distance[300] < 2e-4 and abs(distance[300] - distance[10]) < 0.05 * distance[10]


def test_a_run_that_blows_up_is_diverged_not_clamped():
    """Past symplectic Euler's limit (h w = 2.5) the run grows until simrun's bound: Newton's velocity clamp is
    lifted, so the run is diverged where simrun's own is."""
    spring = {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0}
    engine = run_one(spring, {"type": "newton"}, 2.5, 500.0)
    own = run_one(spring, "symplectic_euler", 2.5, 500.0)
    assert engine.status == own.status == "diverged"
    assert abs(engine.steps - own.steps) <= 1


def _refused(tmp_path, system, entry) -> str:
    config = {"name": "refused", "system": system, "integrators": [entry], "duration": 0.1,
              "sweep": {"dt": [0.01]}, "output": str(tmp_path / "out")}
    with pytest.raises(ConfigError) as error:
        simrun.run(config, jobs=1, progress=False)
    assert not (tmp_path / "out").exists()
    return str(error.value)


@pytest.mark.parametrize("system, entry, missing", [
    ({"type": "circular_motion", "force": "gravity"}, {"type": "newton"}, "its potential is not quadratic"),
    ({**CLOTH, "contact": {"colliders": [{"shape": "plane", "point": [0, 0, -0.5], "normal": [0, 0, 1]}]}},
     {"type": "newton", "solver": "vbd"}, "contact (Newton's particle contacts are another model"),
    ({"type": "spring_mass"}, {"type": "newton", "iterations": 5}, "iterations: Newton's semi_implicit solver takes none"),
    (BEAM, {"type": "newton", "solver": "vbd"}, "Newton's vbd solver steps its tetrahedra as Smith et al.'s energy without"),
    (BEAM, {"type": "newton", "solver": "xpbd"}, "Newton's xpbd solver steps its tetrahedra as two compliant constraints"),
    ({**BEAM, "material": {"model": "neo_hookean"}}, {"type": "newton"}, "its material is neo_hookean"),
    ({**BEAM, "damping": [{"model": "rayleigh", "alpha": 0.1}]}, {"type": "newton"}, "its damping (rayleigh)"),
    ({"type": "spring_mass"}, {"type": "newton", "solver": "style3d"}, "solver"),
])
def test_what_newton_cannot_express_is_refused_in_one_line(tmp_path, system, entry, missing):
    message = _refused(tmp_path, system, entry)
    assert missing in message and "\n" not in message, message


def test_without_the_extra_the_solver_is_refused_naming_it(tmp_path, monkeypatch):
    monkeypatch.setattr("simrun.integrators.newton_engine.newton_missing",
                        lambda: "needs NVIDIA Newton on Warp: pip install '.[engines]' (newton, warp-lang)")
    message = _refused(tmp_path, {"type": "spring_mass"}, {"type": "newton"})
    assert "integrators: newton: needs NVIDIA Newton on Warp: pip install '.[engines]'" in message


def test_the_report_states_newtons_solvers_and_times_them_apart(tmp_path):
    """One sentence per engine, naming its version, precision and device: Newton's semi_implicit undamped below
    h w = 2 (float32's probe: |rho - 1| within its round-off), its VBD backward Euler's
    1 - (1 + (h w)^2)^(-2 pi / h w); the accuracy findings rank its wall times apart from simrun's methods'."""
    from simrun.analysis.runs import run_set
    from simrun.findings import findings

    config = {"name": "cards", "system": {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0},
              "integrators": ["symplectic_euler", {"type": "newton", "solver": "semi_implicit"},
                              {"type": "newton", "solver": "vbd", "iterations": 1}],
              "duration": 20.0, "sweep": {"dt": [0.01, 0.1, 1.0]}}
    results = simrun.run(config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    found = findings(run_set(results))
    (told,) = [finding for finding in found if finding.topic == "engines"]
    assert told.sentence.startswith("Newton 1.8.0 on Warp 1.19.0, float32, CPU, its integrators on the test spring")
    lost = 1 - 2.0 ** (-2 * np.pi)  # backward Euler at h w = 1: |R|^2 = 1 / 2 per step, 2 pi steps a period
    assert f"newton[solver=vbd,iterations=1]: loses 46.5 % at h w = 0.1, {100 * lost:.3g} % at 1" in told.sentence
    assert "newton[solver=semi_implicit]: none (ρ = 1) at h w = 0.1 and 1, stable for h w < 2" in told.sentence
    # the engine's wall times are ranked apart from simrun's, under the engine's name, precision and device
    accuracy = [finding for finding in found if finding.topic == "accuracy" and "ranking" in finding.evidence]
    assert accuracy
    for finding in accuracy:
        assert all(not label.startswith("newton") for label, *_ in finding.evidence["ranking"])
        if "newton[" in finding.sentence.split("; not reached")[0]:
            assert "; Newton 1.8.0 on Warp 1.19.0, float32, CPU, timed apart: newton[" in finding.sentence
            assert set(finding.evidence["engines"]) == {"Newton 1.8.0 on Warp 1.19.0, float32, CPU"}
