"""What a run measures besides its steps: the kinds of its held vertices, its prescribed paths (where they are, the
power their drivers put in, their releases), its decay per period and its error against the exact solution. Shared
by simrun's own stepping (simulate.py), scipy's peers (peers.py) and the calibration's forward runs."""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from simrun.format.layout import VERTEX_KINDS
from simrun.integrators import State

# up to this many free dofs the explicit part's stiffest frequency is found by a dense eigensolve, beyond by Lanczos
DENSE_EIGEN_DOFS = 600
# relative size of an eigenvalue of K v = lambda M v that is a zero mode's round-off (no bound on the step)
ZERO_MODE = 1e-9

# a path's ``until`` within this fraction of a step below a step's end is reached there (t = n dt rounds)
RELEASE_SLACK = 1e-9


def vertex_constraint_kinds(system) -> np.ndarray | None:
    """(vertices,) int8 (``simrun.format.layout.VERTEX_KINDS``): each vertex of a system with frames free (0), pinned
    (1), on a prescribed path (2) or sliding (3: some of its directions held, a rail or a plane); None where every
    vertex is free. From the system's fixed dofs and its VertexConstraints, so that the figures name each kind."""
    dim = int(getattr(system, "vertex_dim", 0) or 0)
    fixed = np.asarray(getattr(system, "fixed_dofs", ()), dtype=np.intp)
    if dim <= 0 or system.dof_count % dim:
        return None
    count = system.dof_count // dim
    held = np.bincount(fixed // dim, minlength=count)[:count] if fixed.size else np.zeros(count, dtype=np.intp)
    kinds = np.where(held == dim, VERTEX_KINDS["pinned"], np.where(held > 0, VERTEX_KINDS["sliding"], 0)).astype(np.int8)
    constraints = getattr(system, "constraints", None)
    if constraints is not None:
        if getattr(constraints, "sliding", None) is not None:
            kinds[constraints.sliding.vertices] = VERTEX_KINDS["sliding"]
        kinds[constraints.moving_vertices] = VERTEX_KINDS["prescribed"]
    return kinds if kinds.any() else None


def release(system, release_times: list[float], t: float, dt: float):
    """(the system released from the paths that end by t, its remaining moving dofs); pops those times."""
    while release_times and t >= release_times[0] - RELEASE_SLACK * dt:
        system = system.released(release_times.pop(0))
    return system, moving_dofs(system)


def moving_dofs(system) -> np.ndarray:
    """The dofs of vertices on prescribed paths (empty for systems without them)."""
    constraints = system.constraints
    return constraints.moving_dofs if constraints is not None else np.zeros(0, dtype=np.intp)


def on_paths(constraints, moving: np.ndarray, state: State, t: float) -> State:
    """The state with the prescribed vertices exactly on their paths at t (new arrays; the step's own
    values there are the method's approximation of the path, exact for a constant velocity)."""
    positions, velocities = constraints.path(t)
    x, v = state.x.copy(), state.v.copy()
    x[moving], v[moving] = positions, velocities
    return State(state.t, x, v, state.aux, state.reusable)


def path_power(system, moving: np.ndarray, x: np.ndarray, v: np.ndarray, t: float) -> float:
    """The power (W) that the drivers of the prescribed vertices put into the system: sum over their dofs
    of v (m a - f), with f = -dP/dx - D v the forces of the system on them (unfiltered) and a the paths'
    accelerations: what holds the vertices on their paths against the springs, gravity and damping.
    Systems that can give f on those dofs alone (``driven_force``: the springs that touch them) do so."""
    driven_force = getattr(system, "driven_force", None)
    if driven_force is not None:
        force = driven_force(x, v)
    else:
        force = -system.gradient(x)
        if system.is_damped:
            force -= system.damping_matrix(x) @ v
        force = force[moving]
    accelerations = system.constraints.path_accelerations(t)
    if system.mass_correction is None:
        inertia = system.mass[moving] * accelerations
    else:  # M a on the paths' dofs couples them to the free ones' accelerations
        everywhere = system.acceleration(x, v)
        everywhere[moving] = accelerations
        inertia = system.mass_times(everywhere)[moving]
    return float(v[moving] @ (inertia - force))


# energies below this fraction of E(0) are in (or near) the subnormal range, where their digits go: not measured
DECAY_FLOOR = 1e-250
MAX_EXPONENT = math.log(np.finfo(float).max)


def decay_per_period(energy0: float, energy: float, t: float, frequency: float) -> float:
    """The amplitude's decay per period 2 pi / w of a linear oscillator, from its modal energy V(t) at one time t > 0:
    the amplitude goes as sqrt(V), so the factor per period is (V(t)/V(0))^(pi / (w t)); > 1 where it grows."""
    exponent = math.log(energy / energy0) * math.pi / (frequency * t)
    return math.inf if exponent > MAX_EXPONENT else math.exp(exponent)  # (math.exp raises beyond it)


def measured_decay(system, samples: dict[str, np.ndarray], frequency: float) -> float:
    """decay_per_period at the last sample whose modal energy (``System.modal_energy``: the spring's
    E + d x v / 2, which the exact damped motion loses at the steady rate 2 zeta w) is finite and above DECAY_FLOOR V(0)
    (NaN when none is, after t = 0): measured over the whole run, so a method's own damping adds to the model's."""
    energy, t = samples.get("energy"), samples.get("t")
    if energy is None or energy.size < 2 or "positions" not in samples:
        return math.nan
    modal = system.modal_energy(energy, samples["positions"], samples["velocities"])
    if not modal[0] > 0.0:
        return math.nan
    usable = np.flatnonzero(np.isfinite(modal) & (modal > DECAY_FLOOR * modal[0]))
    last = int(usable[-1]) if usable.size else 0
    if last == 0:
        return math.nan
    return decay_per_period(float(modal[0]), float(modal[last]), float(t[last]), frequency)


def error_at(system, t: float, x: np.ndarray, v: np.ndarray) -> float:
    """The distance (m) of (x, v) at time t from the exact solution, NaN where none is known.

    On the test equation (a declared test frequency w) it is the phase-space distance
    sqrt(|x - x_exact|^2 + |v - v_exact|^2 / w^2): a method's error there is a vector that turns with
    the motion, whose length this measures at any phase (|x - x_exact| alone vanishes twice a period).
    Otherwise max |x - x_exact| over the degrees of freedom."""
    exact = system.exact_solution(np.array([t]))
    if exact is None:
        return math.nan
    x_exact, v_exact = exact[0][0], exact[1][0]
    frequency = system.capabilities.test_frequency
    if frequency is None:
        return float(np.max(np.abs(x - x_exact)))
    return math.sqrt(float(np.sum((x - x_exact) ** 2)) + float(np.sum((v - v_exact) ** 2)) / frequency ** 2)


def final_error(system, samples: dict[str, np.ndarray]) -> float:
    """max |x - x_exact| at the last recorded sample (m), NaN where no exact solution is known."""
    if not samples.get("t", np.empty(0)).size or "positions" not in samples:
        return float("nan")
    exact = system.exact_solution(samples["t"][-1:])
    if exact is None:
        return float("nan")
    return float(np.max(np.abs(samples["positions"][-1] - exact[0][0])))


def error_norms(system, samples: dict[str, np.ndarray]) -> dict[str, float]:
    """The run's other error norms against the exact solution, from its stored samples: ``final_velocity_error``, max
    |v - v_exact| at the last sample (m/s), and over the run ``max_error``, max |x - x_exact| over every sample and
    dof (m), and ``max_velocity_error`` (m/s). Empty where no exact solution is known or no state was sampled; a
    NaN norm (a state or an exact solution that overflowed) is left out, as a run without it."""
    t = samples.get("t", np.empty(0))
    if not t.size or "positions" not in samples:
        return {}
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged run's state, or a pumped spring's e^(w t), overflows
        exact = system.exact_solution(t)
        if exact is None:
            return {}
        position_error = np.abs(samples["positions"] - exact[0])
        velocity_error = np.abs(samples["velocities"] - exact[1])
        norms = {"final_velocity_error": float(np.max(velocity_error[-1])), "max_error": float(np.max(position_error)),
                 "max_velocity_error": float(np.max(velocity_error))}
    return {key: value for key, value in norms.items() if not math.isnan(value)}


def explicit_frequency(system, integrator) -> float:
    """rad/s: the frequency that bounds ``integrator``'s stable step on ``system`` at (h w)*/w: the stiffest of its
    ``limiting_stiffness`` at the start shape (sqrt of the largest eigenvalue of K v = lambda M v over the free dofs;
    0 when none is positive: no bound); NaN for an implicit method, on the test equation and a linear oscillator
    (whose own frequency is that) and where no bound is known."""
    capabilities = system.capabilities
    if capabilities.test_frequency is not None or capabilities.oscillator is not None:  # declares its own frequency
        return math.nan
    stiffness = integrator.limiting_stiffness(system, system.x0)
    free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
    if stiffness is None or not free.size:
        return math.nan
    # an eigenvalue this small against K's largest diagonal entry over M's is a zero mode's round-off
    scale = float(np.max(np.abs(stiffness.diagonal()[free]) / system.mass[free]))
    mass = scipy.sparse.diags(system.mass)
    if system.mass_correction is not None:
        mass = mass + system.mass_correction
    if scipy.sparse.issparse(stiffness) and free.size > DENSE_EIGEN_DOFS:
        stiffness, mass = scipy.sparse.csr_matrix(stiffness), scipy.sparse.csr_matrix(mass)
        # a seeded start vector: ARPACK's own is random, and the attribute would differ in its last digits run to run;
        # a random one (not all ones) has a part along the top mode whatever the mesh's symmetry
        start = np.random.default_rng(0).standard_normal(free.size)
        largest = scipy.sparse.linalg.eigsh(stiffness[free][:, free], k=1, M=mass[free][:, free], which="LA",
                                            v0=start, return_eigenvectors=False)[0]
    else:
        stiffness = stiffness.toarray() if scipy.sparse.issparse(stiffness) else np.asarray(stiffness)
        mass = mass.toarray()
        largest = scipy.linalg.eigh(stiffness[np.ix_(free, free)], mass[np.ix_(free, free)], eigvals_only=True)[-1]
    return math.sqrt(largest) if largest > ZERO_MODE * scale else 0.0


def add_outcome(system, samples: dict, attrs: dict, error_state, with_frames: bool, constraint_kinds) -> dict:
    """What every run stores of its outcome, added to ``attrs`` and ``samples``: the oscillator's decay per period (which
    the damping map compares with its prediction) and, where the run reached its error time (``error_state``: (t, x,
    v) there), the error and the state there (its velocities too where no exact solution is known, for a reference to
    measure), and the other error norms (``error_norms``). Returns the drawn topology (model_edges, model_triangles,
    model_constraints) of a run with frames."""
    oscillator = system.capabilities.oscillator
    if oscillator is not None:
        with np.errstate(over="ignore", invalid="ignore"):  # a run that overflowed measures NaN (or a growth, inf)
            attrs["decay_per_period"] = measured_decay(system, samples, oscillator[0])
    attrs.update(error_norms(system, samples))
    if error_state is not None:
        attrs["error_time"], samples["error_positions"], velocities = error_state
        attrs["error"] = error_at(system, *error_state)
        if system.exact_solution(np.array([error_state[0]])) is None:
            samples["error_velocities"] = velocities  # for a reference solution to measure the run's velocity error by
    model = {}
    if system.frame_edges is not None and with_frames:
        model["model_edges"] = system.frame_edges
        if system.frame_triangles is not None:
            model["model_triangles"] = system.frame_triangles
        if constraint_kinds is not None:
            model["model_constraints"] = constraint_kinds
    return model
