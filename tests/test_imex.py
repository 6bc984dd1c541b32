"""IMEX Runge-Kutta (integrators/imex.py) against theory.

- The split: the two parts' energies, forces, Hessians and damping matrices sum to the whole's, on a damped cloth.
- Ascher's "decouple fast and slow scales" on a two-frequency chain: masses along x joined by stiff springs, each
  tethered to an anchor below by a soft one. About the rest shape the stiff springs act on the x-dofs alone and the
  tethers on the y-dofs alone, so the probed step's spectral radius is the largest of the pair's closed-form
  stability function (Ascher, Ruuth & Spiteri 1997) over the modes: implicit on the stiff ones, explicit on the
  tethers. With the stiff springs implicit the step is stable at h w_stiff in the hundreds, up to the soft springs'
  explicit limit and no further; with everything explicit it blows up at the same step.
- The schemes' orders on a nonlinear chain (large transverse motion) against scipy's DOP853.
- The limits: every term implicit is backward Euler (euler) and Alexander's SDIRK2 (ars222); nothing implicit is
  symplectic Euler (euler).
- A split that names a term the system lacks is refused in one line that names the terms it has.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.optimize
import scipy.sparse

from simrun.cli import main
from simrun.errors import ConfigError
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs
from simrun.integrators import INTEGRATORS, State
from simrun.systems.constraints import VertexConstraints
from simrun.systems.vertex.damping import Damping
from simrun.systems.mass_spring.system import MassSpring
from test_integrators import TIGHT_SOLVER, imex_radius, spectral_radius

STIFF, SOFT = 1.0e4, 1.0  # N/m: the chain's springs along x and its tethers along y (masses of 1 kg)
W_SOFT = math.sqrt(SOFT)  # rad/s: every tether mode's frequency


def two_frequency_chain(count=6, stiff=STIFF, soft=SOFT, damping=()):
    """``count`` unit masses at (i, 0), i = 1..count, joined along x by springs of kind ``stretch`` (the ends to
    pinned anchors at (0, 0) and (count + 1, 0)), each tied by a ``tether`` to a pinned anchor at (i, -1)."""
    free = np.stack([np.arange(1, count + 1), np.zeros(count)], axis=1).astype(float)
    ends = np.array([[0.0, 0.0], [count + 1.0, 0.0]])
    below = free - np.array([0.0, 1.0])
    rest = np.concatenate([free, ends, below])
    line = [count] + list(range(count)) + [count + 1]  # left anchor, the masses, right anchor
    chain = np.array([line[:-1], line[1:]]).T
    tethers = np.stack([np.arange(count), count + 2 + np.arange(count)], axis=1)
    springs = np.concatenate([chain, tethers])
    kinds = np.concatenate([np.zeros(len(chain)), np.ones(len(tethers))]).astype(np.intp)
    vertex_count = len(rest)
    constraints = VertexConstraints(2, vertex_count, np.arange(count, vertex_count), [], [])
    return MassSpring(rest=rest, x0=rest.copy(), v0=np.zeros_like(rest), springs=springs,
                      stiffness=np.where(kinds == 0, stiff, soft), rest_length=np.ones(len(springs)),
                      masses=np.ones(vertex_count), gravity=np.zeros(2), damping=tuple(damping),
                      constraints=constraints, spring_kinds=kinds, kind_names=("stretch", "tether"))


def chain_frequencies(count=6, stiff=STIFF):
    """The x-modes of the fixed-fixed chain: 2 sqrt(k) sin(j pi / (2 (count + 1)))."""
    return 2.0 * math.sqrt(stiff) * np.sin(np.arange(1, count + 1) * math.pi / (2 * (count + 1)))


def probed_radius(method, system, dt, epsilon=1e-6):
    """Spectral radius of the step's Jacobian about rest over the free (x, v), by central differences (the
    quadratic terms of the transverse springs cancel; the implicit stages are solved to 1e-14)."""
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    size = free.size
    columns = []
    for unit in np.eye(2 * size):
        outcomes = []
        for sign in (1.0, -1.0):
            x, v = system.x0.copy(), np.zeros(system.dof_count)
            x[free] += sign * epsilon * unit[:size]
            v[free] += sign * epsilon * unit[size:]
            new, _ = method.step(system, State(0.0, x, v), dt, TIGHT_SOLVER)
            outcomes.append(np.concatenate([new.x[free], new.v[free]]))
        columns.append((outcomes[0] - outcomes[1]) / (2.0 * epsilon))
    return spectral_radius(np.column_stack(columns))


def pair_radius(scheme, x, force_implicit):
    """The pair's closed-form spectral radius on the undamped oscillator at h w = x, its force implicit or explicit."""
    stand_in = INTEGRATORS["imex"](scheme=scheme) if force_implicit else INTEGRATORS["imex"](scheme=scheme, implicit=[])
    return imex_radius(stand_in, np.asarray(x, dtype=float))


def explicit_limit(scheme):
    """The largest h w at which the explicit part's radius stays 1 (by bisection on the closed form)."""
    return scipy.optimize.brentq(lambda x: pair_radius(scheme, x, False) - 1.0 - 1e-9, 1.0, 3.0, xtol=1e-12)


def test_the_explicit_limits_are_the_known_ones():
    """IMEX Euler's explicit part is symplectic Euler: h w < 2. ARS(2,2,2)'s, with the kinematics implicit, reaches
    h w = 2.27 (its radius is 1 below: no growth, no damping)."""
    assert explicit_limit("euler") == pytest.approx(2.0, abs=1e-6)
    limit = explicit_limit("ars222")
    assert 2.2 < limit < 2.3
    assert np.all(np.abs(pair_radius("ars222", np.linspace(0.01, 0.999 * limit, 50), False) - 1.0) < 1e-9)


@pytest.mark.parametrize("scheme", ["euler", "ars222"])
@pytest.mark.parametrize("fraction", [0.5, 0.99, 1.01, 1.5])
def test_the_probed_step_is_the_pair_stability_on_every_mode(scheme, fraction):
    """Stiff springs implicit, tethers explicit: rho = max(max_j R_I(h w_j), R_E(h w_soft)), to 1e-6."""
    system = two_frequency_chain()
    method = INTEGRATORS["imex"](scheme=scheme, implicit=["stretch"])
    dt = fraction * explicit_limit(scheme) / W_SOFT
    predicted = max(pair_radius(scheme, dt * chain_frequencies(), True).max(), float(pair_radius(scheme, dt * W_SOFT, False)))
    assert probed_radius(method, system, dt) == pytest.approx(predicted, rel=1e-6)


@pytest.mark.parametrize("scheme", ["euler", "ars222"])
def test_stable_far_beyond_the_stiff_limit_and_unstable_beyond_the_soft_one(scheme):
    """Just below the tethers' explicit limit h w_stiff is over 350 (the stiff springs' own explicit limit is about
    2): the split step's radius is 1, the all-explicit one's is far above 1. Just above the limit the split step
    grows too: the step is bounded by the explicit part alone."""
    system = two_frequency_chain()
    limit = explicit_limit(scheme) / W_SOFT
    below, above = 0.99 * limit, 1.01 * limit
    assert below * chain_frequencies().max() > 350.0
    split = INTEGRATORS["imex"](scheme=scheme, implicit=["stretch"])
    assert probed_radius(split, system, below) <= 1.0 + 1e-7
    assert probed_radius(split, system, above) > 1.05
    assert probed_radius(INTEGRATORS["imex"](scheme=scheme, implicit=[]), system, below) > 100.0


def nonlinear_chain():
    """The chain with tethers of stiffness 10, stiff springs of 100, spring damping 0.3 N s/m on every spring and a
    drag of 0.1 N s/m, started with transverse offsets of a fifth of a spring: geometric nonlinearity in both
    parts."""
    system = two_frequency_chain(count=4, stiff=100.0, soft=10.0,
                                 damping=(Damping("spring", coefficient=0.3), Damping("drag", coefficient=0.1)))
    offsets = np.array([[0.05, 0.2], [-0.1, -0.15], [0.075, 0.25], [0.0, -0.1]])
    system.x0[:8] += offsets.ravel()
    return system


def dop853_reference(system, duration):
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    n = system.dof_count

    def rate(_, u):
        rates = np.zeros(2 * n)
        rates[free] = u[n + free]
        rates[n + free] = system.acceleration(u[:n], u[n:])[free]
        return rates

    solution = scipy.integrate.solve_ivp(rate, (0.0, duration), np.concatenate([system.x0, system.v0]),
                                         method="DOP853", rtol=1e-12, atol=1e-12)
    return solution.y[:n, -1], solution.y[n:, -1]


@pytest.mark.parametrize("scheme, order, per_second", [("euler", 1, 1600), ("ars222", 2, 200)])
def test_observed_order_on_a_nonlinear_damped_chain(scheme, order, per_second):
    """Final-time error in (x, v) against DOP853 at 1e-12, the stiff springs implicit: slope within 0.15. IMEX
    Euler's error constant on the stiff modes is backward Euler's, h w^2 / 2 per second: its slope is 0.72-0.87
    from 200 steps a second (h w_stiff = 0.1), and reaches 0.96 from 1600."""
    system, duration = nonlinear_chain(), 1.0
    x_reference, v_reference = dop853_reference(system, duration)
    method = INTEGRATORS["imex"](scheme=scheme, implicit=["stretch"])
    counts = np.round(per_second * 2.0 ** (np.arange(4) / 2)).astype(int)
    errors = []
    for count in counts:
        state = State(0.0, system.x0.copy(), system.v0.copy())
        for _ in range(count):
            state, _ = method.step(system, state, duration / count, TIGHT_SOLVER)
        errors.append(max(np.abs(state.x - x_reference).max(), np.abs(state.v - v_reference).max()))
    slope = np.polyfit(np.log(duration / counts), np.log(errors), 1)[0]
    assert abs(slope - order) < 0.15, (slope, errors)


def damped_cloth():
    """A 5 x 4 grid of the mass-spring system (the cloth's springs and kinds) with every damping model."""
    from simrun.systems import MassSpringParams

    return MassSpringParams(model={"grid": {"resolution": [5, 4]}}, stiffness={"stretch": 1e3, "shear": 1e2, "bend": 1.0},
                            damping=[{"model": "spring", "coefficient": 0.2}, {"model": "drag", "coefficient": 0.05},
                                     {"model": "rayleigh", "alpha": 0.1, "beta": 0.002}], pinned=[0, 4]).build()


def dense(matrix):
    return matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix)


@pytest.mark.parametrize("names", [("stretch",), ("stretch", "shear"), ("bend", "gravity"), ("stretch_x", "bend_y"), ("drag", "shear"), ()])
def test_the_parts_sum_to_the_whole(names):
    """Energy, gradient, Hessian, damping matrix and force of the part with ``names`` and of its complement sum to
    the whole system's, at a deformed state with velocities."""
    system = damped_cloth()
    assert system.energy_terms == ("stretch", "bend", "stretch_x", "stretch_y", "shear", "bend_x", "bend_y", "drag", "gravity")
    named, other = system.with_terms(names), system.with_terms(names, complement=True)
    assert (named is None) == (names == ())  # no term named: no force, no part
    rng = np.random.default_rng(3)
    x = system.x0 + 0.05 * rng.standard_normal(system.dof_count)
    v = rng.standard_normal(system.dof_count)

    def summed(evaluate):
        return sum(evaluate(part) for part in (named, other) if part is not None)

    assert summed(lambda part: part.potential_energy(x)) == pytest.approx(system.potential_energy(x), rel=1e-12)
    np.testing.assert_allclose(summed(lambda part: part.gradient(x)), system.gradient(x), rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(summed(lambda part: dense(part.hessian(x))), dense(system.hessian(x)), atol=1e-9)
    np.testing.assert_allclose(summed(lambda part: dense(part.damping_matrix(x))), dense(system.damping_matrix(x)), atol=1e-10)
    np.testing.assert_allclose(summed(lambda part: part.force(x, v)), system.force(x, v), rtol=1e-12, atol=1e-10)
    np.testing.assert_array_equal(system.x0, other.x0)  # the parts share the state and the constraints
    np.testing.assert_array_equal(system.fixed_dofs, other.fixed_dofs)


def cloth_steps(method, steps=20, dt=5e-3):
    """The grid with the damping whose matrix is constant (drag, Rayleigh): backward Euler takes a D(x) at x_n, the
    stages at their predictors."""
    from simrun.systems import MassSpringParams

    system = MassSpringParams(model={"grid": {"resolution": [5, 4]}}, stiffness={"stretch": 1e3, "shear": 1e2, "bend": 1.0},
                              damping=[{"model": "drag", "coefficient": 0.05}, {"model": "rayleigh", "alpha": 0.1, "beta": 0.002}],
                              pinned=[0, 4]).build()
    state = State(0.0, system.x0.copy(), system.v0.copy())
    for _ in range(steps):
        state, _ = method.step(system, state, dt, TIGHT_SOLVER)
    return state


@pytest.mark.parametrize("imex, same", [
    ({"scheme": "euler", "implicit": ["stretch", "shear", "bend", "drag", "gravity"]}, "backward_euler"),
    ({"scheme": "ars222", "implicit": ["stretch", "shear", "bend", "drag", "gravity"]}, "sdirk2"),
    ({"scheme": "euler", "implicit": []}, "symplectic_euler"),
])
def test_the_limits_of_the_split_are_the_known_methods(imex, same):
    """Everything implicit: IMEX Euler is backward Euler and ARS(2,2,2) is Alexander's SDIRK2 (its first, explicit
    stage is unused by the implicit tableau); nothing implicit: IMEX Euler is symplectic Euler. Twenty steps of
    the damped grid, equal to 1e-9 relative (the solver's tolerance)."""
    split, reference = cloth_steps(INTEGRATORS["imex"](**imex)), cloth_steps(INTEGRATORS[same]())
    np.testing.assert_allclose(split.x, reference.x, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(split.v, reference.v, rtol=1e-9, atol=1e-9)


def imex_config(implicit):
    return {"name": "bad", "system": {"type": "cloth", "resolution": [4, 4]},
            "integrators": [{"type": "imex", "implicit": implicit}], "sweep": {"dt": [0.01]}}


def test_a_split_naming_a_missing_term_is_refused_in_one_line():
    with pytest.raises(ConfigError) as error:
        expand_runs(load_experiment(imex_config(["stretch", "twist"]))[0])
    message = str(error.value)
    assert "implicit: the system has no term 'twist'" in message and "its terms are stretch, bend, stretch_x" in message
    assert "\n" not in message


def test_the_command_line_refuses_it_with_exit_2_and_writes_nothing(tmp_path, capsys):
    import yaml

    config = tmp_path / "bad.yaml"
    config.write_text(yaml.safe_dump(imex_config(["twist"])))
    output = tmp_path / "out"
    assert main(["run", str(config), "--output", str(output)]) == 2
    captured = capsys.readouterr()
    assert "twist" in captured.err and len(captured.err.strip().splitlines()) == 1
    assert not output.exists()


@pytest.mark.parametrize("implicit", [["stretch"], ["shear"], ["bend"]])
def test_imex_euler_turns_unstable_at_the_stored_bound_on_a_cloth(implicit):
    """A 5 x 5 cloth without gravity about its flat rest shape, whose split's modes are not common to both parts:
    the bound 2/w stored with each run (w the stiffest frequency of K_E - K_I, runner/execution/measures.py) has
    the probed step stable 2 % below it and unstable 2 % above."""
    from simrun.execution.measures import explicit_frequency
    from simrun.systems import ClothParams

    system = ClothParams(resolution=[5, 5], gravity=[0.0, 0.0, 0.0]).build()
    method = INTEGRATORS["imex"](implicit=implicit)
    bound = 2.0 / explicit_frequency(system, method)
    assert bound < 0.01  # the stiff terms left explicit set it
    assert probed_radius(method, system, 0.98 * bound) <= 1.0 + 1e-6
    assert probed_radius(method, system, 1.02 * bound) > 1.2


def test_the_stored_bound_of_each_kind_of_method():
    """Explicit: the system's stiffest frequency; IMEX Euler with the stiff cloth springs implicit: 0 (K_E - K_I
    has no positive eigenvalue: no bound); ARS(2,2,2) and implicit methods: none (NaN); on the test equation: none
    (its own frequency is the bound)."""
    from simrun.execution.measures import explicit_frequency
    from simrun.systems import ClothParams, SpringMassParams

    cloth = ClothParams(resolution=[6, 6]).build()
    free = np.setdiff1d(np.arange(cloth.dof_count), cloth.fixed_dofs)
    stiffness = dense(cloth.hessian(cloth.x0))[np.ix_(free, free)] / np.sqrt(np.outer(cloth.mass[free], cloth.mass[free]))
    assert explicit_frequency(cloth, INTEGRATORS["symplectic_euler"]()) == pytest.approx(
        math.sqrt(np.linalg.eigvalsh(stiffness)[-1]), rel=1e-10)
    assert explicit_frequency(cloth, INTEGRATORS["imex"](implicit=["stretch", "shear"])) == 0.0
    assert math.isnan(explicit_frequency(cloth, INTEGRATORS["imex"](scheme="ars222", implicit=["stretch", "shear"])))
    assert math.isnan(explicit_frequency(cloth, INTEGRATORS["backward_euler"]()))
    assert math.isnan(explicit_frequency(SpringMassParams().build(), INTEGRATORS["symplectic_euler"]()))
