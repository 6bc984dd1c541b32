"""Prescribed paths that end (``until``): the vertices follow the path to the release and move freely after it.

A two-vertex spring along x (k = 20 N/m, 0.05 kg at the free end, the other end pinned) is pulled at a constant
velocity v until T and let go. From there the motion is the harmonic oscillator's with the release state as its
start, u(t) = v T cos(w s) + (v / w) sin(w s), s = t - T, w = sqrt(k / m), and its energy is m v^2 / 2 + k (v T)^2 / 2
for good; the puller's work is k (v T)^2 / 2. Implicit midpoint keeps a quadratic energy exactly, and converges to
the motion at order 2; the reference solution (scipy, solved piecewise over the release) equals it; the forward
sensitivities of a fit carry through the release; the figures still mark the vertex as driven."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import run_one
from simrun.analysis.reference import reference_positions
from simrun.calibration.engine import step_run
from simrun.calibration.keys import system_at
from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment
from simrun.format.layout import VERTEX_KINDS
from simrun.integrators import INTEGRATORS
from simrun.integrators.sensitivity import ForwardSensitivity
from simrun.solvers import solver_params
from simrun.systems import SYSTEMS

STIFFNESS, MASS, SPEED, RELEASE, LENGTH = 20.0, 0.05, 0.1, 0.3, 0.2
OMEGA = math.sqrt(STIFFNESS / MASS)


def pulled_spring(until: float | None = RELEASE) -> dict:
    path = {"vertices": "last", "velocity": [SPEED, 0.0], **({"until": until} if until is not None else {})}
    return {"type": "mass_spring", "model": {"rope": {"count": 2, "length": LENGTH, "direction": [1.0, 0.0]}},
            "stiffness": STIFFNESS, "mass": {"per_vertex": MASS}, "gravity": [0.0, 0.0], "pinned": ["first"],
            "prescribed": [path]}


def stretch(t: np.ndarray) -> np.ndarray:
    """The free end's displacement from rest along x (m): on the path to T, the released oscillator after it."""
    s = t - RELEASE
    return np.where(t <= RELEASE, SPEED * t, SPEED * RELEASE * np.cos(OMEGA * s) + SPEED / OMEGA * np.sin(OMEGA * s))


def end_error(result) -> float:
    frames, t = result.samples["frames"], result.samples["frame_t"]
    return float(np.max(np.abs(frames[:, 1, 0] - LENGTH - stretch(t))))


def test_the_released_end_swings_as_the_oscillator_and_keeps_its_energy():
    errors = []
    for dt in (0.002, 0.001):
        result = run_one(pulled_spring(), "implicit_midpoint", dt, 1.0, record={"frames_every": 1})
        assert result.status == "ok"
        t, energy, work = (result.samples[key] for key in ("t", "energy", "prescribed_work"))
        after = t >= RELEASE - 1e-12
        expected = 0.5 * MASS * SPEED ** 2 + 0.5 * STIFFNESS * (SPEED * RELEASE) ** 2
        assert np.max(np.abs(energy[after] / expected - 1.0)) < 1e-9
        # the power k v^2 t is linear in t: the trapezoidal rule's work is exact; none after the release
        assert abs(work[-1] / (0.5 * STIFFNESS * (SPEED * RELEASE) ** 2) - 1.0) < 1e-9
        assert np.ptp(work[after]) == 0.0
        errors.append(end_error(result))
    # let go (on the path it would end 3.3x further out), with the phase error of (h w)^2 / 12 per radian: 2e-3 here
    assert errors[0] < 1e-2 * SPEED * RELEASE
    assert math.log2(errors[0] / errors[1]) > 1.9


def test_without_until_the_end_stays_on_its_path():
    result = run_one(pulled_spring(None), "implicit_midpoint", 0.002, 1.0, record={"frames_every": 1})
    frames, t = result.samples["frames"], result.samples["frame_t"]
    assert np.max(np.abs(frames[:, 1, 0] - LENGTH - SPEED * t)) < 1e-12


@pytest.mark.parametrize("name", ["backward_euler", "bdf2", "newmark", "symplectic_euler", "xpbd",
                                  "exponential_rosenbrock_euler"])
def test_every_kind_of_method_lets_the_end_go(name):
    """One-step, multistep, explicit, constraint-based and exponential methods: after the release the end moves
    back towards rest (the spring pulls it), where the path would have taken it on; the frames mark it as driven."""
    result = run_one(pulled_spring(), name, 0.001, 0.6, record={"frames_every": 1})
    assert result.status == "ok"
    frames, t = result.samples["frames"], result.samples["frame_t"]
    assert np.max(np.abs(frames[t <= RELEASE + 1e-12, 1, 0] - LENGTH - SPEED * t[t <= RELEASE + 1e-12])) < 1e-12
    tolerance = 0.1 * SPEED * RELEASE  # first-order methods: O(h w) of the amplitude
    assert np.max(np.abs(frames[:, 1, 0] - LENGTH - stretch(t))) < tolerance
    assert result.model["model_constraints"][1] == VERTEX_KINDS["prescribed"]


def test_the_reference_solution_restarts_at_the_release():
    system = SYSTEMS["mass_spring"].model_validate(pulled_spring()).build()
    times = [0.1, RELEASE, 0.45, 0.8, 1.0]
    positions = reference_positions(system, times)
    for t in times:
        assert abs(positions[t][2] - LENGTH - float(stretch(np.array(t)))) < 1e-9


@pytest.mark.parametrize("name", ["backward_euler", "bdf2", "implicit_midpoint"])
def test_sensitivities_carry_through_the_release(name):
    """dx(end)/dk by the forward sensitivity on a run released half-way equals central differences (1e-6)."""
    params = SYSTEMS["mass_spring"].model_validate(pulled_spring())
    system = params.build()
    integrator, solver, dofs = INTEGRATORS[name](), solver_params(tolerance=1e-13, max_iterations=50).build(), np.arange(4)
    derivative = system.parameter_derivative(system_at(params, ["system.stiffness"], [STIFFNESS + 1.0]).build(), 1.0)
    exact = step_run(system, integrator, solver, 0.005, 120, dofs, ForwardSensitivity(system, integrator, [derivative]))
    step = 1e-5 * STIFFNESS
    plus, minus = (step_run(system_at(params, ["system.stiffness"], [STIFFNESS + sign * step]).build(), integrator,
                            solver, 0.005, 120, dofs) for sign in (1.0, -1.0))
    difference = (plus.x[-1] - minus.x[-1]) / (2 * step)
    assert abs(difference[2]) > 1e-4  # the released end's position depends on k
    assert np.allclose(exact.dx[-1, :, 0], difference, rtol=1e-6, atol=1e-9 * abs(difference[2]))


@pytest.mark.parametrize("until", [0.0, -1.0, "soon"])
def test_a_bad_until_is_one_line_naming_the_field(until):
    system = pulled_spring()
    system["prescribed"][0]["until"] = until
    with pytest.raises(ConfigError) as caught:
        load_experiment({"name": "x", "system": system, "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}})
    assert "system.prescribed.0.until" in str(caught.value) and "\n" not in str(caught.value)
