"""The mass on a spring of the lectures: m q'' + d q' + k q = 0, the test equation of all stability analysis."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from .base import ParameterDerivative, System, SystemParams
from .oscillator import DISTINCT_ROOTS, near_critical_states
from .compliant import anchored_springs
from .forms import ProjectiveForm
from .lanes import SpringMassLanes


class SpringMassParams(SystemParams):
    """Config of `spring_mass`: a 1-D mass on a linear spring with optional viscous damping."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["spring_mass"] = "spring_mass"
    mass: float = Field(1.0, gt=0, allow_inf_nan=False, description="m (kg)")
    stiffness: float = Field(100.0, gt=0, allow_inf_nan=False, description="k (N/m)")
    damping: float = Field(0.0, allow_inf_nan=False, description="d (N s/m): q'' + (d/m) q' + (k/m) q = 0; a negative d "
                                                              "pumps energy in (what a calibration can need to match a damped method)")
    damping_ratio: float | None = Field(None, allow_inf_nan=False,
                                        description="zeta = d / (2 sqrt(k m)), instead of damping: sets d from k and m "
                                                    "(a map over (h w, zeta) sweeps it with the stiffness)")
    x0: float = Field(1.0, allow_inf_nan=False, description="initial position (m)")
    v0: float = Field(0.0, allow_inf_nan=False, description="initial velocity (m/s)")

    @model_validator(mode="after")
    def _one_damping(self):
        if self.damping_ratio is not None and self.damping != 0.0:
            raise ValueError("give damping or damping_ratio, not both")
        return self

    @property
    def effective_damping(self) -> float:
        """d (N s/m): ``damping``, or 2 zeta sqrt(k m) where ``damping_ratio`` zeta is given."""
        if self.damping_ratio is not None:
            return 2.0 * self.damping_ratio * math.sqrt(self.stiffness * self.mass)
        return self.damping

    @property
    def dof_count(self) -> int:
        return 1


class SpringMass(System):
    """P(q) = k q^2 / 2, f_d = -d q'; exact solution exp(t A) (q0, v0) with A = [[0, 1], [-k/m, -d/m]]."""

    dof_count = 1
    dim = 1
    lanes_class = SpringMassLanes

    def __init__(self, params: SpringMassParams):
        self.params = params
        self.stiffness = params.stiffness
        self.damping = params.effective_damping
        self.mass = np.array([params.mass])
        self.x0 = np.array([params.x0])
        self.v0 = np.array([params.v0])
        self._hessian = np.array([[params.stiffness]])
        self._damping = np.array([[self.damping]]) if self.damping != 0 else None

    @property
    def angular_frequency(self) -> float:
        """w = sqrt(k/m) (rad/s), the undamped natural frequency."""
        return float(np.sqrt(self.stiffness / self.mass[0]))

    @property
    def test_frequency(self) -> float | None:
        """w = sqrt(k/m) (rad/s) when undamped (d = 0): then this is the test equation itself; None when damped."""
        return math.sqrt(self.stiffness / self.params.mass) if self.damping == 0.0 else None

    @property
    def oscillator(self) -> tuple[float, float]:
        """(w0, zeta) = (sqrt(k/m), d / (2 sqrt(k m))), damped or not."""
        return math.sqrt(self.stiffness / self.params.mass), self.damping / (2.0 * math.sqrt(self.stiffness * self.params.mass))

    def modal_energy(self, energy, x, v):
        """V = E + d q v / 2 = (m v^2 + d q v + k q^2) / 2 below critical damping: the exact motion loses it at the
        steady rate dV/dt = -(d/m) V (E itself falls in steps, fastest where v peaks), so V measures a decay per
        period at any phase; E at and above critical damping, where V is not positive definite."""
        if self.damping >= 2.0 * math.sqrt(self.stiffness * self.params.mass):
            return energy
        return energy + (0.5 * self.damping) * (x[:, 0] * v[:, 0])

    def potential_energy(self, x):
        return 0.5 * self.stiffness * float(x[0] * x[0])

    # The step path of the test equation (energy check, samples, acceleration, velocity update): scalar
    # arithmetic instead of the base class's chains of one-element array operations (docs/performance.md).
    def total_energy(self, x, v):
        q, p = float(x[0]), float(v[0])
        return 0.5 * (self.params.mass * p * p + self.stiffness * q * q)

    def write_observables(self, x, v, row):
        """energy, kinetic_energy, potential_energy, momentum: the base class's formulas on scalars, bit for bit."""
        (q,), (p,) = x.tolist(), v.tolist()
        momentum = self.params.mass * p
        kinetic = 0.5 * (momentum * p)
        potential = 0.5 * self.stiffness * (q * q)
        energy = kinetic + potential
        row[:4] = (energy, kinetic, potential, momentum)
        return energy

    def acceleration(self, x, v):
        return np.array([(-self.stiffness * float(x[0]) - self.damping * float(v[0])) / self.params.mass])

    def kick(self, x, v, dt):
        (q,), (p,) = x.tolist(), v.tolist()
        return np.array(((p + dt * ((-self.stiffness * q - self.damping * p) / self.params.mass)),))

    def gradient(self, x):
        return self.stiffness * x

    def hessian(self, x, project_spd=False):
        return self._hessian  # constant and SPD (k > 0)

    def damping_matrix(self, x):
        return self._damping

    damping_is_constant = True  # D = d
    quadratic_potential = True  # k q^2 / 2 with k > 0

    def projective_form(self):
        # k q^2 / 2 is a zero-length Hookean spring to the origin, its rest stiffness the constant Hessian
        return ProjectiveForm(rest_stiffness=lambda: self._hessian)

    def compliant_form(self):
        # the same spring as a compliant constraint: C = q - 0 with compliance 1/k, its damper d along it (beta = d)
        return anchored_springs(self.stiffness, self.damping, dim=1)

    def parameter_derivative(self, changed, change):
        """k and d enter linearly: d(grad P)/dtheta = (dk/dtheta) q, dD/dtheta = dd/dtheta; None when the change
        moves the mass or the initial state, or d is set by a damping ratio."""
        if not isinstance(changed, SpringMass) or (changed.params.mass, changed.params.x0, changed.params.v0) != (
                self.params.mass, self.params.x0, self.params.v0):
            return None
        if self.params.damping_ratio is not None:  # d = 2 zeta sqrt(k m) is not linear in k: finite differences
            return None
        stiffness_rate = (changed.stiffness - self.stiffness) / change
        damping_rate = np.array([[(changed.damping - self.damping) / change]])
        return ParameterDerivative(gradient=lambda x: stiffness_rate * x,
                                   damping=(lambda x: damping_rate) if damping_rate[0, 0] != 0.0 else None)

    energy_reference_name = "E0 (initial energy)"  # = |KE0| + |PE0|: both parts are >= 0

    def exact_solution(self, t):
        """q(t) = c1 e^{l1 t} + c2 e^{l2 t} with the roots l1, l2 of m l^2 + d l + k = 0 (complex for an
        oscillation); near critical damping, where the two roots nearly coincide and the form loses digits, the
        propagator exp(t A) itself in closed form (``near_critical_states``)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        m = self.mass[0]
        q0, p0 = float(self.x0[0]), float(self.v0[0])
        discriminant = complex(self.damping * self.damping - 4.0 * m * self.stiffness)
        # the larger root without cancellation, the other from their product k/m (strong overdamping keeps its digits)
        first = (-self.damping - math.copysign(1.0, self.damping) * np.sqrt(discriminant)) / (2.0 * m)
        second = self.stiffness / (m * first)
        if abs(first - second) > DISTINCT_ROOTS * max(abs(first), abs(second)):
            c1, c2 = (p0 - second * q0) / (first - second), (first * q0 - p0) / (first - second)
            grow1, grow2 = np.exp(first * t), np.exp(second * t)
            q = (c1 * grow1 + c2 * grow2).real
            # c1 (l1 e^{l1 t}), not (c1 l1) e^{l1 t}: no product of two scalars, whose round-off (numpy's scalar
            # arithmetic against its array loops) would tell a run's velocity from its lane's (tests/test_lanes.py)
            p = (c1 * (first * grow1) + c2 * (second * grow2)).real
            return q[:, None], p[:, None]
        one = np.ones(1)  # the parameters as arrays: the same array arithmetic as the lanes' (systems/lanes.py)
        q, p = near_critical_states(m * one, self.stiffness * one, self.damping * one, q0 * one, p0 * one, t)
        return q[:, None], p[:, None]



SpringMassParams.system_class = SpringMass
