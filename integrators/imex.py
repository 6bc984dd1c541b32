"""IMEX Runge-Kutta methods: the named energy terms implicit, the rest explicit (Ascher's "decouple fast and slow
scales").

The force splits as f = f_I + f_E: f_I from the terms named in ``implicit`` (the system's ``energy_terms``: spring
kinds or a finite-element system's elements and hinges, drag, gravity, contact), f_E from the others. On u = (x, v)
the split is u' = F_I(u) + F_E(u) with F_I = (v, M^-1 f_I) and F_E = (0, M^-1 f_E): the kinematics go with the
implicit part. An additive Runge-Kutta method with an implicit tableau (A, b, c), diagonally implicit, and an
explicit one (A^, b^, c), strictly lower triangular, has the stages

    X_i = x_n + h sum_{j<i} A_ij V_j + h gamma_i V_i,
    V_i = v_n + h sum_{j<i} (A_ij a_j + A^_ij e_j) + h gamma_i a_i,

a_j = M^-1 f_I(X_j, V_j), e_j = M^-1 f_E(X_j, V_j). As in a DIRK method (integrators/dirk.py) an implicit stage is
the incremental potential of backward Euler, here of the implicit part's system alone, with y~ = o_i + b_i v^_i,
scale b_i^2 and the velocity map (y - o_i)/b_i, o_i and v^_i the known sums and b_i = h gamma_i; a damping matrix
that depends on x is taken at y~ (backward Euler takes it at x_n: with spring damping IMEX Euler with every term
implicit differs from it by O(h^2) per step). The explicit
forces are evaluated once per stage, where a later stage needs them. Both schemes are stiffly accurate in both
tableaux: the step ends at the last stage, which IPC's CCD kept out of the colliders.

Schemes:
- ``euler``: IMEX Euler (A = [[0, 0], [0, 1]], A^ = [[0, 0], [1, 0]]): v_{n+1} = v_n + h M^-1 (f_E(x_n, v_n) +
  f_I(x_{n+1}, v_{n+1})), x_{n+1} = x_n + h v_{n+1}: backward Euler on the implicit terms, symplectic Euler on the
  explicit ones (its stability limit h w < 2 on an undamped explicit term). Order 1.
- ``ars222``: Ascher, Ruuth & Spiteri 1997, "Implicit-explicit Runge-Kutta methods for time-dependent partial
  differential equations", the (2, 2, 2) scheme: gamma = 1 - 1/sqrt(2), delta = 1 - 1/(2 gamma); the implicit
  tableau is Alexander's L-stable SDIRK2 after an explicit first stage. Order 2.

The stability limit of the step is the explicit part's: the implicit terms may be as stiff as they like.
- IMEX Euler on M x'' = -K_I x - K_E x, on a mode common to both (frequencies w_I, w_E): (1 + h^2 w_I^2) mu^2 -
  (2 - h^2 w_E^2) mu + 1 = 0, stable while h^2 (w_E^2 - w_I^2) <= 4. So the step is bounded by the stiffest
  frequency of K_E - K_I (``limiting_stiffness``), h w < 2: an explicit term's stiff mode that the implicit terms
  stiffen more costs nothing (a cloth's bending springs in its plane, beside implicit stretch springs). The modes of
  a cloth's split are not common to both; its probed step still turns unstable within 2 % of that bound
  (tests/test_imex.py).
- ARS(2,2,2) has no bound of that form: its limit on a common mode falls from h w_E = 2.26 at w_I = 0 to 1.82 at
  h w_I = 3 before it grows with h w_I, so simrun predicts its limit only on decoupled terms (the tests' chain).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from simrun.solvers.base import EXPLICIT_STEP
from simrun.systems.forms import contact_needs_step_filter

from .base import Integrator, State, StepPlan, mass_refusal, solve_step
from .dirk import ORDER_TOLERANCE, _add


@dataclass(frozen=True)
class ImexTableau:
    """An additive Runge-Kutta pair: the implicit (A, b) (lower triangular), the explicit (A_hat, b_hat) (strictly
    lower triangular), their common stage times c, and the order of the pair."""

    A: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    A_hat: tuple[tuple[float, ...], ...]
    b_hat: tuple[float, ...]
    c: tuple[float, ...]
    order: int

    @property
    def stage_count(self) -> int:
        return len(self.b)

    @property
    def stiffly_accurate(self) -> bool:
        """b = the last row of A and b_hat = the last row of A_hat: the step ends at the last stage."""
        last = self.stage_count - 1
        return all(abs(self.b[j] - self.A[last][j]) <= ORDER_TOLERANCE and abs(self.b_hat[j] - self.A_hat[last][j])
                   <= ORDER_TOLERANCE for j in range(self.stage_count))


def _ars222() -> ImexTableau:
    gamma = 1.0 - 1.0 / math.sqrt(2.0)
    delta = 1.0 - 1.0 / (2.0 * gamma)
    return ImexTableau(A=((0.0, 0.0, 0.0), (0.0, gamma, 0.0), (0.0, 1.0 - gamma, gamma)), b=(0.0, 1.0 - gamma, gamma),
                       A_hat=((0.0, 0.0, 0.0), (gamma, 0.0, 0.0), (delta, 1.0 - delta, 0.0)), b_hat=(delta, 1.0 - delta, 0.0),
                       c=(0.0, gamma, 1.0), order=2)


SCHEMES = {
    "euler": ImexTableau(A=((0.0, 0.0), (0.0, 1.0)), b=(0.0, 1.0), A_hat=((0.0, 0.0), (1.0, 0.0)), b_hat=(1.0, 0.0),
                         c=(0.0, 1.0), order=1),
    "ars222": _ars222(),
}
assert all(tableau.stiffly_accurate for tableau in SCHEMES.values())  # ``step`` ends at the last stage

# system -> {(implicit names): (implicit part, explicit part)}: a split is built once per system (a path's release
# makes a new system, and so a new split), and dropped with the system
_SPLITS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
# the terms left explicit by default: the soft ones of a cloth (bending springs) and the constant gravity
EXPLICIT_BY_DEFAULT = ("bend", "gravity")


class IMEX(Integrator):
    """An IMEX Runge-Kutta method (IMEX Euler, order 1; ARS(2,2,2), order 2): see the module docstring."""

    name: ClassVar[str] = "imex"
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = False
    problem_kind: ClassVar[str | None] = "incremental_potential"
    family: ClassVar[str] = "imex"
    summary: ClassVar[str] = "IMEX Runge-Kutta: the named terms implicit (incremental potentials), the rest explicit"

    scheme: Literal["euler", "ars222"] = Field("euler", description="euler (IMEX Euler, order 1) or ars222 (Ascher, "
                                                                     "Ruuth & Spiteri's (2,2,2), order 2)")
    implicit: tuple[str, ...] | None = Field(
        None, description="the energy terms taken implicitly, of the system's energy_terms (a mass-spring model's spring "
                          "kinds, drag, gravity, contact; a finite-element system's elastic, bending, drag, gravity, "
                          "contact); the others are explicit. Default: every term but bending and gravity (a system "
                          "without named terms: all of it, `potential`)")

    @property
    def pair(self) -> ImexTableau:
        return SCHEMES[self.scheme]

    @property
    def order_of_accuracy(self) -> int:
        return self.pair.order

    def implicit_terms(self, system) -> tuple[str, ...]:
        """The terms this method takes implicitly on ``system``."""
        if self.implicit is not None:
            return self.implicit
        return tuple(name for name in system.energy_terms if not name.startswith(EXPLICIT_BY_DEFAULT))

    def refusal(self, system):
        terms = system.energy_terms
        unknown = [name for name in self.implicit or () if name not in terms]
        if unknown:
            return f"implicit: the system has no term {unknown[0]!r}; its terms are {', '.join(terms)}"
        reason = mass_refusal(self.name, system)
        if reason is not None:
            return reason
        if contact_needs_step_filter(system) and "contact" not in self.implicit_terms(system):
            return ("takes IPC contact explicitly, which nothing cuts short of a collision: name contact in implicit, "
                    "where each stage's line search is CCD-filtered")
        return super().refusal(system)

    def parts(self, system):
        """(implicit part, explicit part) of ``system``: the system with the implicit terms, and with the others;
        None for a part without any force."""
        per_system = _SPLITS.setdefault(system, {})
        names = self.implicit_terms(system)
        split = per_system.get(names)
        if split is None:
            split = (system.with_terms(names), system.with_terms(names, complement=True))
            per_system[names] = split
        return split

    def limiting_stiffness(self, system, x):
        """IMEX Euler: K_E - K_I (see the module docstring); ARS(2,2,2): None, no bound of this form."""
        implicit, explicit = self.parts(system)
        if self.scheme != "euler" or explicit is None:
            return None
        stiffness = explicit.hessian(x)
        return stiffness if implicit is None else stiffness - implicit.hessian(x)

    def explicit_form(self):
        return self.model_copy(update={"implicit": ()})

    def step(self, system, state, dt, solver):
        tableau = self.pair
        implicit, explicit = self.parts(system)
        count = tableau.stage_count
        # which stages' forces a later stage uses (a stiffly accurate pair ends at its last stage: no final sum)
        needs_implicit = [any(tableau.A[k][j] for k in range(j + 1, count)) for j in range(count)]
        needs_explicit = [any(tableau.A_hat[k][j] for k in range(j + 1, count)) for j in range(count)]
        velocities, implicit_accelerations, explicit_accelerations = [], [], []
        stats, y = None, state.x
        for i in range(count):
            row, explicit_row, gamma = tableau.A[i], tableau.A_hat[i], tableau.A[i][i]
            origin, v_hat = state.x, state.v
            for j in range(i):
                if row[j]:
                    origin = origin + (dt * row[j]) * velocities[j]
                    v_hat = v_hat + (dt * row[j]) * implicit_accelerations[j]
                if explicit_row[j]:
                    v_hat = v_hat + (dt * explicit_row[j]) * explicit_accelerations[j]
            if gamma == 0.0 or implicit is None:  # an explicit stage, or no implicit force: X_i = o_i + b_i v^_i, V_i = v^_i
                velocity = v_hat
                y = origin + (dt * gamma) * v_hat if gamma else origin
                implicit_acceleration = (implicit.acceleration(y, velocity) if implicit is not None and needs_implicit[i]
                                         else np.zeros_like(velocity))
            else:
                divisor = dt * gamma
                predictor = origin + divisor * v_hat
                plan = StepPlan(predictor, divisor * divisor, origin, divisor, predictor)
                problem = plan.problem(implicit, state, tableau.c[i] * dt)
                y, stage_stats = solve_step(solver, problem, problem.start_point(state.x))
                stats = _add(stats, stage_stats)
                velocity = (y - origin) / divisor
                implicit_acceleration = (velocity - v_hat) / divisor
            velocities.append(velocity)
            implicit_accelerations.append(implicit_acceleration)
            explicit_accelerations.append(explicit.acceleration(y, velocity) if explicit is not None and needs_explicit[i]
                                          else np.zeros_like(velocity))
        return State(state.t + dt, y, velocities[-1]), EXPLICIT_STEP if stats is None else stats
