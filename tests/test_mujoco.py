"""MuJoCo's integrators measured as simrun measures its own (integrators/mujoco.py), against what theory says of them.

Each MuJoCo step is probed on unit states of the test spring (a bank of slide joints with the joints' stiffness and
damping), as simrun's own methods are, and compared with the amplification matrix derived from MuJoCo's source
(src/engine/engine_forward.c), m = 1 kg, h = 1 s, k = (h w)^2, d = 2 zeta h w:
- Euler, implicit and implicitfast take the joint damping implicitly and the stiffness explicitly:
  v' = (v - k x) / (1 + d), x' = x + v'; undamped, that is symplectic Euler's [[1 - k, 1], [-k, 1]];
- RK4 is the classical RK4: R(h J) with R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24, J = [[0, 1], [-k, -d]];
- discrete (MuJoCo 4.0) is backward Euler: (1 + d + k) v' = v - k x, x' = x + v'.
A cloth of springs translated into tendons steps as simrun's own symplectic Euler and RK4 do, to round-off.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special

import simrun
from conftest import needs_engine, run_one
from simrun.analysis.oscillator import bank_matrices
from simrun.cli import main
from simrun.errors import ConfigError
from simrun.integrators.mujoco import MuJoCo, translate

pytestmark = needs_engine("mujoco")

HW = np.logspace(-2, np.log10(3.0), 25)


def probed(integrator: str, zeta: float) -> np.ndarray:
    return bank_matrices(MuJoCo(integrator=integrator), HW, np.full(HW.shape, zeta))


def semi_implicit(zeta: float) -> np.ndarray:
    k, d = HW ** 2, 2 * zeta * HW
    return np.stack([np.stack([1 - k / (1 + d), 1 / (1 + d)], axis=-1),
                     np.stack([-k / (1 + d), 1 / (1 + d)], axis=-1)], axis=1)


@pytest.mark.parametrize("integrator", ["Euler", "implicit", "implicitfast"])
@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.1])
def test_euler_and_the_implicit_integrators_damp_implicitly_and_spring_explicitly(integrator, zeta):
    """Undamped, MuJoCo's Euler is symplectic Euler to round-off; with joint damping all three are the same map."""
    np.testing.assert_allclose(probed(integrator, zeta), semi_implicit(zeta), rtol=0, atol=1e-13)


@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_rk4_is_the_classical_stability_polynomial(zeta):
    expected = []
    for hw in HW:
        jacobian = np.array([[0.0, 1.0], [-hw * hw, -2 * zeta * hw]])
        expected.append(sum(np.linalg.matrix_power(jacobian, power) / scipy.special.factorial(power)
                            for power in range(5)))
    np.testing.assert_allclose(probed("RK4", zeta), np.array(expected), rtol=0, atol=1e-12)


@pytest.mark.parametrize("zeta", [0.0, 0.1])
def test_discrete_is_backward_euler(zeta):
    k, d = HW ** 2, 2 * zeta * HW
    velocity = np.stack([-k / (1 + d + k), 1 / (1 + d + k)], axis=-1)
    position = np.stack([1 - k / (1 + d + k), 1 / (1 + d + k)], axis=-1)
    np.testing.assert_allclose(probed("discrete", zeta), np.stack([position, velocity], axis=1), rtol=0, atol=1e-13)


def test_the_long_run_energy_of_euler_is_symplectic_eulers(tmp_path):
    """600 steps of the undamped spring at h w = 0.5: the same energy, sample for sample, to round-off."""
    spring = {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0}
    own = run_one(spring, "symplectic_euler", 0.5, 300.0)
    engine = run_one(spring, {"type": "mujoco", "integrator": "Euler"}, 0.5, 300.0)
    assert engine.status == own.status == "ok"
    np.testing.assert_allclose(engine.samples["energy"], own.samples["energy"], rtol=1e-12, atol=0)
    assert engine.attrs["engine"].startswith("MuJoCo 4.0") and "engine" not in own.attrs


CLOTH = {"type": "cloth", "resolution": [5, 5], "size": [1.0, 1.0], "mass": 1.0, "stretch_stiffness": 1.0e3,
         "shear_stiffness": 1.0e2, "bend_stiffness": 1.0e1, "damping": 0.5, "gravity": [0.0, 0.0, -9.81],
         "pinned": ["top_left", "top_right"]}


@pytest.mark.parametrize("engine, own", [("Euler", "symplectic_euler"), ("RK4", "rk4")])
def test_a_cloth_of_tendons_steps_as_simruns_own_method(engine, own):
    """Springs as spatial tendons (stiffness, springlength, damping along them), gravity as MuJoCo's: 200 steps of a
    damped hanging cloth give simrun's own symplectic Euler's (tendon damping explicit in MuJoCo's Euler) and RK4's
    frames and energies to round-off."""
    ours = run_one(CLOTH, own, 0.002, 0.4, record={"every": 1, "frames_every": 1})
    theirs = run_one(CLOTH, {"type": "mujoco", "integrator": engine}, 0.002, 0.4, record={"every": 1, "frames_every": 1})
    assert theirs.status == ours.status == "ok"
    np.testing.assert_allclose(theirs.samples["frames"], ours.samples["frames"], rtol=0, atol=1e-12)
    scale = np.max(np.abs(ours.samples["energy"]))
    np.testing.assert_allclose(theirs.samples["energy"], ours.samples["energy"], rtol=0, atol=1e-11 * scale)


def test_a_pendulum_chain_in_the_plane_steps_as_symplectic_euler():
    """A 2-D rope of 10 masses on stiff springs, pinned at one end and swinging under gravity (a pendulum chain): two
    slide joints per vertex in MuJoCo's x-y plane, gravity along -y; 500 steps equal simrun's own to round-off."""
    rope = {"type": "mass_spring", "model": {"rope": {"count": 10, "length": 1.0, "direction": [1.0, 0.0]}},
            "stiffness": 1000.0, "mass": {"total": 0.04}, "gravity": [0.0, -9.81], "pinned": ["first"]}
    ours = run_one(rope, "symplectic_euler", 0.001, 0.5, record={"every": 1, "frames_every": 1})
    theirs = run_one(rope, {"type": "mujoco"}, 0.001, 0.5, record={"every": 1, "frames_every": 1})
    assert theirs.status == ours.status == "ok"
    np.testing.assert_allclose(theirs.samples["frames"], ours.samples["frames"], rtol=0, atol=1e-12)


def test_a_run_that_blows_up_is_diverged_not_reset(tmp_path):
    """Past symplectic Euler's limit (h w = 2.5) MuJoCo's Euler grows until MuJoCo would reset it: the run is
    diverged, at the same step as simrun's own."""
    spring = {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0}
    engine = run_one(spring, {"type": "mujoco", "integrator": "Euler"}, 2.5, 500.0)
    own = run_one(spring, "symplectic_euler", 2.5, 500.0)
    assert engine.status == own.status == "diverged"
    assert engine.steps == own.steps


@pytest.mark.parametrize("system, missing", [
    ({"type": "circular_motion", "force": "gravity"}, "its potential is not quadratic"),
    ({**CLOTH, "contact": {"colliders": [{"shape": "plane", "point": [0, 0, -0.5], "normal": [0, 0, 1]}]}},
     "contact (MuJoCo's soft contacts are another model"),
    ({"type": "mass_spring", "model": {"rope": {"count": 4, "length": 1.0, "direction": [1.0, 0.0]}},
      "spring_law": "squared_length", "pinned": ["first"]}, "spring_law squared_length is not a Hookean spring"),
])
def test_a_system_mujoco_cannot_express_is_one_line_exit_2(tmp_path, capsys, system, missing):
    config = {"name": "refused", "system": system, "integrators": [{"type": "mujoco"}], "duration": 0.1,
              "sweep": {"dt": [0.01]}, "output": str(tmp_path / "out")}
    with pytest.raises(ConfigError, match="integrators: mujoco: MuJoCo's translation cannot express"):
        simrun.run(config, jobs=1, progress=False)
    path = tmp_path / "refused.yaml"
    import yaml

    path.write_text(yaml.safe_dump(config))
    assert main([str(path), "-q"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and missing in error, error
    assert not (tmp_path / "out").exists()


def test_linear_circular_motion_translates_to_two_springs():
    """f = -m w^2 x in the plane: two slide joints of stiffness m w^2, so MuJoCo's Euler is symplectic Euler."""
    from simrun.systems import SYSTEMS

    system = SYSTEMS["circular_motion"](force="linear", angular_velocity=2.0, mass=3.0).build()
    translation = translate(system)
    assert translation.xml.count('type="slide"') == 2 and 'stiffness="12.0"' in translation.xml


def test_without_the_extra_the_method_is_refused_naming_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("simrun.integrators.mujoco.mujoco_missing", lambda: "needs MuJoCo: pip install '.[engines]' (mujoco)")
    config = {"name": "missing", "system": {"type": "spring_mass"}, "integrators": [{"type": "mujoco"}],
              "duration": 0.1, "sweep": {"dt": [0.01]}, "output": str(tmp_path / "out")}
    with pytest.raises(ConfigError, match=r"integrators: mujoco: needs MuJoCo: pip install '.\[engines\]'"):
        simrun.run(config, jobs=1, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("entry, message", [
    ({"type": "mujoco", "integrator": "Verlet"}, "integrator"),
    ({"type": "mujoco", "timestep": 0.01}, "timestep"),
])
def test_an_option_mujoco_does_not_have_is_one_line(tmp_path, entry, message):
    config = {"name": "bad", "system": {"type": "spring_mass"}, "integrators": [entry], "duration": 0.1,
              "sweep": {"dt": [0.01]}, "output": str(tmp_path / "out")}
    with pytest.raises(ConfigError, match=message):
        simrun.run(config, jobs=1, progress=False)


def test_step_control_is_refused():
    config = {"name": "controlled", "system": {"type": "spring_mass"}, "integrators": [{"type": "mujoco"}],
              "duration": 0.1, "step_control": {"tolerance": 1e-6}}
    with pytest.raises(ConfigError, match="takes steps of one size"):
        simrun.run(config, jobs=1, progress=False)


def test_the_report_states_each_engine_integrator_first(tmp_path):
    """The engines' findings lead: RK4 loses 1 - |R(i)|^(4 pi) = 7.39 % of the energy per period at h w = 1 (|R(i x)|^2
    = 1 - x^6/72 + x^8/576), none at all below h w = 2 for Euler; each names MuJoCo's version, precision and device."""
    from simrun.analysis.runs import run_set
    from simrun.findings import findings

    config = {"name": "cards", "system": {"type": "spring_mass", "stiffness": 1.0, "mass": 1.0, "x0": 1.0},
              "integrators": ["backward_euler", {"type": "mujoco", "integrator": "RK4"},
                              {"type": "mujoco", "integrator": "Euler"}],
              "duration": 20.0, "sweep": {"dt": [0.1, 1.0]}}
    results = simrun.run(config, output=tmp_path / "out", jobs=1, progress=False, figures=False)
    told = findings(run_set(results))
    assert told[0].topic == "engines" and told[1].topic != "engines"
    sentence = told[0].sentence
    assert sentence.startswith("MuJoCo 4.0.0, float64, CPU, its integrators on the test spring")
    lost = 1 - (1 - 1 / 72 + 1 / 576) ** (2 * np.pi)  # energy |R|^2 per step, 2 pi steps a period
    assert f"{100 * lost:.3g}" == "7.39"
    assert "mujoco[integrator=RK4]: loses 8.72e-05 % at h w = 0.1, 7.39 % at 1, stable for h w < 2.83" in sentence
    assert "mujoco[integrator=Euler]: none (ρ = 1) at h w = 0.1 and 1, stable for h w < 2." in sentence
