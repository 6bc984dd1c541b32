"""Lanes: many runs of one small system stepped together, one row of an array per run.

A dense parameter map (100 step sizes x 60 damping ratios of the spring, for every implicit method) is tens
of thousands of runs of a one-dof system: stepped one by one, the per-run and per-step Python overhead is the
whole cost. Lanes step them together: the state has shape (lanes, dofs), each lane with its own parameters
(stiffness, damping, mass, initial state) and its own dt, shape (lanes, 1). The integrators' own ``step``,
``start``, ``plan`` and ``finish`` run unchanged on such states, since they are elementwise numpy arithmetic;
the implicit steps' problems are ``integrators.lanes.LaneIncrementalPotential``, solved by
``solvers.lanes.LaneNewton`` (a batched Newton with per-lane convergence).

A system joins by naming a lane class (``System.lanes_class``, in its own class body: a subclass is not stepped by
its parent's lanes) that takes its built systems and offers, with a leading lane axis, what the runner and the
integrators ask of one: ``mass`` (lanes, dofs), ``x0``, ``v0``, ``acceleration``, ``kick``, ``gradient``,
``hessian_blocks`` ((lanes, dofs, dofs)), ``damping_times`` (D r per lane), ``observables``, ``total_energy``,
``dissipation``, ``modal_energy`` (lanes,), the capabilities that differ between lanes (``capability_columns``),
``exact_states`` where the system has an exact solution, and ``lane_kind`` (runs of one kind share a chunk). Every
lane's numbers are those of its run stepped alone, operation for operation (tests/test_lanes.py holds them to that).
Only systems whose incremental potential is quadratic (one Newton step is its minimiser) take lanes: a
batched line search is not offered.
"""

from __future__ import annotations

import functools

import numpy as np

from .base import ENERGY_ROUND_OFF
from .oscillator import DISTINCT_ROOTS, near_critical_states


class SpringMassLanes:
    """The mass on a spring, one lane per run: m q'' + d q' + k q = 0 with m, d, k, q0, v0 of shape (lanes, 1).

    Each method repeats ``SpringMass``'s scalar arithmetic in the same order, so a lane's numbers are its run's."""

    quadratic_potential = True
    damping_is_constant = True
    records_state_per_sample = True
    fixed_dofs = np.empty(0, dtype=np.intp)
    sliding = None
    constraints = None
    dof_count = 1
    dim = 1

    def contact_form(self):
        return None  # no contact

    @staticmethod
    def lane_kind(params) -> bool:
        """Runs of one kind share a chunk: damped and undamped springs apart, so that neither masks the other's terms."""
        return params.effective_damping != 0.0

    def __init__(self, systems):
        self.systems = list(systems)
        self.lane_count = len(self.systems)
        column = lambda values: np.array(values, dtype=float).reshape(-1, 1)  # noqa: E731
        self.mass = column([system.params.mass for system in self.systems])
        self.stiffness = column([system.stiffness for system in self.systems])
        self.damping = column([system.damping for system in self.systems])
        self.x0 = column([system.params.x0 for system in self.systems])
        self.v0 = column([system.params.v0 for system in self.systems])
        # SpringMass has no damping matrix at d = 0: its lanes add no damping term (not even d = 0 times a rate)
        self.damped = (self.damping != 0.0).ravel()
        self.is_damped = bool(self.damped.any())
        self.all_damped = bool(self.damped.all())
        self.negative_stiffness = -self.stiffness  # SpringMass's -k q, negated once
        self.observable_layout = self.systems[0].observable_layout

    # -- what the integrators ask ------------------------------------------------------------------
    def acceleration(self, x, v):
        return (self.negative_stiffness * x - self.damping * v) / self.mass

    def kick(self, x, v, dt):
        return v + dt * ((self.negative_stiffness * x - self.damping * v) / self.mass)

    # -- what the incremental potential asks -------------------------------------------------------
    def gradient(self, x):
        return self.stiffness * x

    def hessian_blocks(self, scale, damping_weight):
        """M + s K + (s/b) D per lane, shape (lanes, 1, 1), summed as IncrementalPotential.hessian sums them:
        (s k + (s/b) d) + m, where the lane is damped (SpringMass has no D at d = 0)."""
        blocks = scale * self.stiffness
        if damping_weight is not None:
            damped = blocks + damping_weight * self.damping
            blocks = damped if self.all_damped else np.where(self.damped[:, None], damped, blocks)
        return (blocks + self.mass)[:, :, None]

    def damping_times(self, rate):
        """D r per lane (0 where undamped: that lane's run adds no term)."""
        return self.damping * rate if self.all_damped else np.where(self.damped[:, None], self.damping * rate, 0.0)

    # -- what the runner records -------------------------------------------------------------------
    def observables(self, x, v):
        """energy, kinetic_energy, potential_energy (lanes,) and momentum (lanes, 1): SpringMass.write_observables."""
        momentum = self.mass * v
        kinetic = 0.5 * (momentum * v)
        potential = 0.5 * self.stiffness * (x * x)
        energy = kinetic + potential
        return {"energy": energy[:, 0], "kinetic_energy": kinetic[:, 0], "potential_energy": potential[:, 0],
                "momentum": momentum}

    def total_energy(self, x, v):
        """SpringMass.total_energy, 0.5 ((m v) v + (k x) x), with two temporaries (it runs at every step)."""
        energy = np.multiply(self.mass, v)
        energy *= v
        potential = np.multiply(self.stiffness, x)
        potential *= x
        energy += potential
        energy *= 0.5
        return energy[:, 0]

    def dissipation(self, mean_velocity):
        """v^T D v per lane (W): the power the damping force takes out at velocity v; 0 where undamped."""
        power = (mean_velocity * (self.damping * mean_velocity))[:, 0]
        return power if self.all_damped else np.where(self.damped, power, 0.0)

    def capability_columns(self) -> dict[str, np.ndarray]:
        """The capabilities that differ between lanes, (lanes,) each: test_frequency (NaN where damped), length_scale,
        energy_scale, natural_frequency and damping_ratio, as System.capabilities computes them."""
        m, k, d, x0, v0 = (array[:, 0] for array in (self.mass, self.stiffness, self.damping, self.x0, self.v0))
        kinetic = 0.5 * ((m * v0) * v0)
        potential = 0.5 * k * (x0 * x0)
        initial = np.abs(kinetic) + np.abs(potential)
        length = np.abs(x0)
        length = np.where(np.isfinite(length) & (length > 0.0), length, 1.0)
        force = -(k * x0)
        force = np.where(self.damped, force + -(d * v0), force)
        work = length * np.abs(force)
        work = np.where(np.isfinite(work), work, 0.0)
        energy_scale = np.where(initial > ENERGY_ROUND_OFF * work, initial, np.where(work > 0.0, work, 1.0))
        natural = np.sqrt(k / m)
        frequency = np.where(self.damped, np.nan, natural)
        ratio = d / (2.0 * np.sqrt(k * m))
        return {"test_frequency": frequency, "length_scale": length, "energy_scale": energy_scale,
                "natural_frequency": natural, "damping_ratio": ratio}

    def modal_energy(self, energy, x, v):
        """SpringMass.modal_energy per lane: energy (lanes, ...) with x, v (lanes, ..., 1) at the same samples."""
        critical = (self.damping >= 2.0 * np.sqrt(self.stiffness * self.mass))[:, 0]
        half = (0.5 * self.damping)[:, 0].reshape((-1,) + (1,) * (energy.ndim - 1))
        modal = energy + half * (x[..., 0] * v[..., 0])
        return np.where(critical.reshape(half.shape), energy, modal)

    def exact_states(self, t):
        """(q, v) of every lane's exact solution at its own time t (lanes,): SpringMass.exact_solution's two-exponential
        form, evaluated for all lanes at once; lanes near critical damping SpringMass's closed-form propagator. The
        roots and coefficients are the lanes' own, computed once (a map's error norms ask at every sample)."""
        first, second, c1, c2, near, constants = self._exact_constants
        grow1, grow2 = np.exp(first * t), np.exp(second * t)
        q = (c1 * grow1 + c2 * grow2).real
        p = (c1 * (first * grow1) + c2 * (second * grow2)).real  # SpringMass.exact_solution's order
        if near.size:
            q[near], p[near] = near_critical_states(*constants, np.asarray(t, dtype=float)[near])
        return q, p

    @functools.cached_property
    def _exact_constants(self):
        """exact_states' roots l1, l2 and coefficients c1, c2 per lane, the lanes near critical damping and their
        (m, k, d, q0, p0)."""
        m, k, d, q0, p0 = (array[:, 0] for array in (self.mass, self.stiffness, self.damping, self.x0, self.v0))
        discriminant = (d * d - 4.0 * m * k).astype(complex)
        first = (-d - np.copysign(1.0, d) * np.sqrt(discriminant)) / (2.0 * m)
        with np.errstate(divide="ignore", invalid="ignore"):  # a critical lane's are NaN, and not used
            second = k / (m * first)
            distinct = np.abs(first - second) > DISTINCT_ROOTS * np.maximum(np.abs(first), np.abs(second))
            c1, c2 = (p0 - second * q0) / (first - second), (first * q0 - p0) / (first - second)
        near = np.flatnonzero(~distinct)
        return first, second, c1, c2, near, (m[near], k[near], d[near], q0[near], p0[near])
