"""The contract of an integrator (integrators/base.py, docs/integrators.md) as checks that measure the method
against what it declares: what ``simrun check-integrator`` prints, and what tests/test_check_integrator.py holds for
every built-in method and for planted defects.

- **order**: the observed order of the error at t = 3/8 of a period on the undamped spring and on Kepler's circular
  orbit (away from the turning points and zeros, where one part of the error hides; short, so that a first-order
  method reaches its asymptotic range within FINEST_STEPS), against the declared ``order_of_accuracy``, within ORDER_TOLERANCE. The step is halved from 8 steps per run
  until ASYMPTOTIC_POINTS successive errors lie between round-off and saturation with local slopes that agree to
  SLOPE_AGREEMENT: the asymptotic range, found by the check itself.
- **linearity**: one step of the damped test spring is linear in the state (x, v and what the method carries):
  superposition to LINEARITY_TOLERANCE. A method that declares ``linear = False`` is measured by runs instead.
- **card**: the amplification matrix over h w = 1e-3 ... 1e3 at damping ratios 0 and 0.1, and what follows from it:
  spectral radius, rho_inf, the stability limit, artificial damping d/w, period error (``IntegratorCard``); checked
  against the method's closed form where it declares one (``closed_form_spectral_radius``).
- **free motion**: the linear momentum of a free, stretched, spinning mass-spring square stays at its start to
  round-off; **determinism**: the same step twice gives the same bytes; **not refused**: the method steps the
  systems every method must (the test spring, the free square).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from simrun.analysis import oscillator
from simrun.integrators import Integrator, State
from simrun.systems import CircularMotionParams, MassSpringParams, SpringMassParams
from simrun.systems.base import System

from .system import Check, stable_dt

ORDER_TOLERANCE = 0.2  # |observed - declared|
ORDER_PERIODS = 0.375  # the error is measured at t = 3/8 of a period
# steps per run to that time: from 2 (a fifth-order method's error is then still well above round-off) up to 2^15 (a
# first-order method's asymptotic range on Kepler's orbit lies below 2^12 steps)
COARSEST_STEPS, FINEST_STEPS = 2, 2 ** 15
ASYMPTOTIC_POINTS = 4  # successive halvings whose local slopes agree make the asymptotic range
SLOPE_AGREEMENT = 0.1  # local slopes within this of each other
# of the length scale: errors below ROUND_OFF_ERROR are round-off (a run of at most a few thousand steps accumulates
# about 1e-13), above SATURATED_ERROR no longer O(h^p)
ROUND_OFF_ERROR, SATURATED_ERROR = 1e-11, oscillator.SATURATED_ERROR
# superposition of one step: a linear step's round-off is a few ulps of its terms; a nonlinear one is off by O(1)
LINEARITY_TOLERANCE = 1e-9
LINEARITY_HW = (0.5, 5.0)
LINEARITY_DAMPING_RATIO = 0.1
# the card's grid and damping ratios, as the issue of the contract asks them
CARD_HW_RANGE = (1e-3, 1e3)
CARD_POINTS_PER_DECADE = 20
CARD_DAMPING_RATIOS = (0.0, 0.1)
CLOSED_FORM_TOLERANCE = 1e-10  # relative, on rho
# a nonlinear method's card, measured: runs of MEASURED_PERIODS periods of the spring at these h w
MEASURED_HW = tuple(np.logspace(-2, 1, 13).tolist())
MEASURED_PERIODS = 20
DIVERGENCE = 1e6  # E / E0 above this: the run diverged
# momentum of the free square: each step's round-off is a few ulps of sum_i m_i |v_i| and of h sum_i |f_i|, and an
# implicit step's Newton iterates conserve it to the linear solve's round-off (about 5e-13 over the run): 1e-10 of
# sum_i m_i |v_i| is round-off; a method that takes O(h^3) of v a step (at dt ~ 1e-3 s) loses 1e-8
FREE_STEPS = 20
MOMENTUM_TOLERANCE = 1e-10  # of sum_i m_i |v_i|
# the free square: stretched by 10 %, moving and spinning, no gravity, no pins
FREE_SQUARE = {"type": "mass_spring", "model": {"square": {"segments": 2, "size": 1.0}}, "stiffness": 100.0,
               "mass": {"per_vertex": 0.1}, "gravity": [0.0, 0.0],
               "initial": {"scale": 1.1, "velocity": [0.3, -0.2], "spin": 0.5}}
CHECK_SOLVER = oscillator.PROBE_SOLVER_PARAMS  # Newton to round-off, a direct linear solve


def spring_system(damping_ratio: float = 0.0) -> System:
    """q'' + 2 zeta q' + q = 0: m = 1 kg, k = 1 N/m, q0 = 1 m (w = 1 rad/s, so dt = h w)."""
    return SpringMassParams(stiffness=1.0, mass=1.0, damping_ratio=damping_ratio or None).build()


def kepler_orbit() -> System:
    """A circular Kepler orbit, r = 1 m, w = 1 rad/s (GM = 1): nonlinear, with its exact motion."""
    return CircularMotionParams(force="gravity").build()


def free_square() -> System:
    """FREE_SQUARE built: nine vertices, nonlinear Hookean springs, nothing holding it."""
    return MassSpringParams.model_validate(FREE_SQUARE).build()


# -- stepping ------------------------------------------------------------------------------------------------
def run(integrator: Integrator, system: System, dt: float, steps: int) -> State | None:
    """``steps`` steps of dt from the system's start; None where a step raises or the state stops being finite."""
    solver = CHECK_SOLVER.build()
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)  # the coarse steps of a diverging run
        try:
            state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
            for _ in range(steps):
                state, _ = integrator.step(system, state, dt, solver)
                if not (np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v))):
                    return None
        except Exception:  # noqa: BLE001 - a diverging step may raise anywhere (a singular matrix, an overflow)
            return None
    return state


# -- order --------------------------------------------------------------------------------------------------
@dataclass
class OrderMeasurement:
    """The errors at t = 3/8 of a period against dt (s), and the slope over the asymptotic range found."""

    problem: str
    dts: list[float] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)  # of the length scale; NaN where the run failed
    order: float = math.nan
    used: list[int] = field(default_factory=list)  # indices of the asymptotic range (or of the finest points in range)
    confirmed: bool = False  # ASYMPTOTIC_POINTS errors whose local slopes agree: the asymptotic range itself
    exact: bool = False  # every error at round-off
    reason: str = ""

    def as_dict(self) -> dict:
        return {"problem": self.problem, "dt": self.dts, "relative_error": self.errors, "order": self.order,
                "asymptotic": self.used, "confirmed": self.confirmed, "exact": self.exact, "reason": self.reason}

    @property
    def local_slopes(self) -> list[float]:
        """log2 of successive error ratios over ``used`` (the step halves between them)."""
        errors = [self.errors[index] for index in self.used]
        return [math.log2(coarse / fine) for coarse, fine in zip(errors, errors[1:])]


def measure_order(integrator: Integrator, system: System, problem: str) -> OrderMeasurement:
    """Halve the step from COARSEST_STEPS per run until the asymptotic range is found (or round-off, or
    FINEST_STEPS), and fit the slope of log error against log dt over it."""
    w = system.test_frequency or 1.0
    duration = ORDER_PERIODS * 2.0 * math.pi / w
    x_exact = system.exact_solution(np.array([duration]))[0][0]
    scale = system.length_scale
    measured = OrderMeasurement(problem)
    steps = COARSEST_STEPS
    while steps <= FINEST_STEPS:
        dt = duration / steps
        state = run(integrator, system, dt, steps)
        error = math.nan if state is None else float(np.max(np.abs(state.x - x_exact))) / scale
        measured.dts.append(dt)
        measured.errors.append(error)
        used = _asymptotic_range(measured.errors)
        if used is not None:
            measured.used, measured.confirmed = used, True
            break
        if math.isfinite(error) and error <= ROUND_OFF_ERROR:
            break
        steps *= 2
    errors = np.array(measured.errors)
    finite = np.isfinite(errors)
    if finite.any() and np.all(errors[finite] <= ROUND_OFF_ERROR):
        measured.exact = True
        return measured
    if not measured.used:  # no range of ASYMPTOTIC_POINTS: the finest points between round-off and saturation
        inside = [index for index, error in enumerate(measured.errors) if ROUND_OFF_ERROR < error < SATURATED_ERROR]
        measured.used = _finest_run(inside)
        if len(measured.used) < 3:
            measured.reason = (f"no asymptotic range: errors {', '.join(f'{error:.2g}' for error in measured.errors)} "
                               f"at {COARSEST_STEPS} to {steps} steps")
            return measured
    measured.order = float(np.polyfit(np.log(np.array(measured.dts)[measured.used]), np.log(errors[measured.used]), 1)[0])
    return measured


def _asymptotic_range(errors: list[float]) -> list[int] | None:
    """The indices of the last ASYMPTOTIC_POINTS errors when they lie between round-off and saturation and their
    local slopes (log2 of successive ratios: the step halves) agree to SLOPE_AGREEMENT; else None."""
    if len(errors) < ASYMPTOTIC_POINTS:
        return None
    last = errors[-ASYMPTOTIC_POINTS:]
    if not all(ROUND_OFF_ERROR < error < SATURATED_ERROR for error in last):
        return None
    slopes = [math.log2(coarse / fine) for coarse, fine in zip(last, last[1:])]
    if max(slopes) - min(slopes) > SLOPE_AGREEMENT:
        return None
    return list(range(len(errors) - ASYMPTOTIC_POINTS, len(errors)))


def _finest_run(indices: list[int]) -> list[int]:
    """The last run of consecutive indices."""
    run_of: list[int] = []
    for index in indices:
        run_of = run_of + [index] if run_of and index == run_of[-1] + 1 else [index]
    return run_of


def order_check(integrator: Integrator, system: System, problem: str) -> tuple[Check, OrderMeasurement | None]:
    name = f"order ({problem})"
    refusal = integrator.refusal(system)
    if refusal is not None:
        return Check(name, None, f"the method refuses this system: {refusal}"), None
    measured = measure_order(integrator, system, problem)
    declared = integrator.order_of_accuracy
    if measured.exact:
        return Check(name, True, f"exact on the {problem}: every error at round-off (<= {ROUND_OFF_ERROR:g} of the "
                                 "length scale), which any order allows"), measured
    if not math.isfinite(measured.order):
        return Check(name, False, measured.reason), measured
    first, last = measured.used[0], measured.used[-1]
    where = (f"over dt = {measured.dts[last]:.3g} ... {measured.dts[first]:.3g} s "
             f"({len(measured.used)} runs, errors {measured.errors[first]:.2g} ... {measured.errors[last]:.2g} of the "
             "length scale)")
    slopes = measured.local_slopes
    falling = 1  # the finest slopes that fall one after the other
    while falling < len(slopes) and slopes[-falling - 1] > slopes[-falling]:
        falling += 1
    slopes = slopes[-falling:]
    if not measured.confirmed and len(slopes) >= 3 and slopes[-1] >= declared - ORDER_TOLERANCE:
        # the error reaches round-off while the slopes still fall toward the order (dopri5 on Kepler: its fifth-order
        # error constant is small beside the sixth-order term down to 1e-11): at least the declared order
        return Check(name, True, f"local slopes {', '.join(f'{slope:.2f}' for slope in slopes)} fall toward the "
                                 f"declared {declared} until round-off {where}: at least order {declared}"), measured
    text = f"observed {measured.order:.2f}, declared {declared} (within {ORDER_TOLERANCE:g}) {where}"
    if not measured.confirmed:
        text += "; no four halvings agreed to 0.1 before round-off: the finest points in range fitted"
    return Check(name, abs(measured.order - declared) <= ORDER_TOLERANCE, text), measured


# -- linearity ----------------------------------------------------------------------------------------------
def _parts(state: State) -> list[np.ndarray]:
    return [np.asarray(state.x, dtype=float), np.asarray(state.v, dtype=float),
            *(np.asarray(part, dtype=float) for part in state.aux)]


def _combined(a: float, first: State, b: float, second: State) -> State:
    x, v, *aux = [a * one + b * two for one, two in zip(_parts(first), _parts(second))]
    return State(first.t, x, v, tuple(aux))


def superposition_error(integrator: Integrator, hw: float, damping_ratio: float = LINEARITY_DAMPING_RATIO) -> float:
    """max |step(a s1 + b s2) - a step(s1) - b step(s2)| over the sum of the terms' magnitudes, on the damped test
    spring at h w; s1, s2 two states after one step (so that a method's carried quantities are filled)."""
    spring = spring_system(damping_ratio)
    solver = CHECK_SOLVER.build()
    states = []
    for x, v in ((1.0, 0.3), (-0.4, 2.0)):
        start = integrator.start(spring, State(0.0, np.array([x]), np.array([v])))
        state, _ = integrator.step(spring, start, hw, solver)
        states.append(State(0.0, state.x, state.v, state.aux))
    a, b = 0.7, -1.3
    combined = _combined(a, states[0], b, states[1])
    ones = [integrator.step(spring, state, hw, solver)[0] for state in states]
    together, _ = integrator.step(spring, combined, hw, solver)
    worst = 0.0
    for part, one, two in zip(_parts(together), _parts(ones[0]), _parts(ones[1])):
        size = float(np.max(np.abs(a * one) + np.abs(b * two))) or 1.0
        worst = max(worst, float(np.max(np.abs(part - (a * one + b * two)))) / size)
    return worst


def linearity_check(integrator: Integrator) -> tuple[Check, bool]:
    """(the check, whether the card may come from the amplification matrix)."""
    if not integrator.linear:
        return Check("linearity", None, "declared nonlinear (linear = False): no amplification matrix; the card is "
                                        "measured from runs of the spring"), False
    errors = {hw: superposition_error(integrator, hw) for hw in LINEARITY_HW}
    worst_hw = max(errors, key=lambda hw: errors[hw] if math.isfinite(errors[hw]) else math.inf)
    worst = errors[worst_hw]
    if math.isfinite(worst) and worst <= LINEARITY_TOLERANCE:
        return Check("linearity", True, f"superposition holds to {worst:.1e} (<= {LINEARITY_TOLERANCE:g}) at h w = "
                                        f"{', '.join(f'{hw:g}' for hw in LINEARITY_HW)}, zeta = "
                                        f"{LINEARITY_DAMPING_RATIO:g}: the amplification matrix exists"), True
    return Check("linearity", False, f"no amplification matrix: the step is not linear in the state (superposition "
                                     f"off by {worst:.2g} of its terms at h w = {worst_hw:g}); declare linear = False if "
                                     "that is meant, and the card is measured from runs"), False


# -- the card -----------------------------------------------------------------------------------------------
@dataclass
class IntegratorCard:
    """What the amplification matrix (or, for a nonlinear method, measured runs) says of a method on the test spring."""

    label: str
    source: str  # "amplification matrix" or "measured runs"
    hw: np.ndarray
    curves: dict[float, dict[str, np.ndarray]]  # damping ratio -> spectral_radius, damping (d/w), period_error
    rho_inf: float  # NaN where measured
    stability_limit: float  # h w; inf: stable over the grid; 0: never stable
    closed_form: np.ndarray | None = None  # the method's own rho(h w) at zeta = 0, where it declares one
    orders: dict[str, OrderMeasurement] = field(default_factory=dict)

    def as_dict(self) -> dict:
        def listed(values):
            return [None if not math.isfinite(value) else value for value in np.asarray(values, dtype=float).tolist()]

        return {"label": self.label, "source": self.source, "hw": listed(self.hw),
                "damping_ratios": list(self.curves),
                "curves": {f"{ratio:g}": {key: listed(values) for key, values in curves.items()}
                           for ratio, curves in self.curves.items()},
                "rho_inf": None if not math.isfinite(self.rho_inf) else self.rho_inf,
                "stability_limit": None if math.isinf(self.stability_limit) else self.stability_limit,
                "stability_limit_text": "none: stable over the grid" if math.isinf(self.stability_limit)
                else f"h w < {self.stability_limit:.6g}",
                "closed_form_spectral_radius": None if self.closed_form is None else listed(self.closed_form),
                "orders": {name: order.as_dict() for name, order in self.orders.items()}}


def card(integrator: Integrator, linear: bool = True) -> IntegratorCard:
    """The integrator card: from the amplification matrix where the step is linear, else from runs."""
    hw = oscillator.hw_grid(*CARD_HW_RANGE, CARD_POINTS_PER_DECADE)
    closed = integrator.closed_form_spectral_radius(hw)
    closed = None if closed is None else np.asarray(closed, dtype=float)
    if not linear:
        return _measured_card(integrator, closed)
    # probed up to h w = 1e9 (rho_inf), where an implicit step's matrix is as ill-conditioned as h w^2: expected
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        prediction = oscillator.predict(integrator, *CARD_HW_RANGE, CARD_POINTS_PER_DECADE)
        curves = {0.0: {"spectral_radius": np.array(prediction.rho), "damping": np.array(prediction.damping),
                        "period_error": np.array(prediction.period_error)}}
        for ratio in CARD_DAMPING_RATIOS[1:]:
            curves[ratio] = _damped_curves(integrator, hw, ratio)
        # an explicit method has no radius at h w -> infinity to speak of: it is unstable long before
        rho_inf = math.nan if integrator.explicit else oscillator.high_frequency_radius(integrator)
    return IntegratorCard(integrator.label, "amplification matrix", hw, curves, rho_inf, prediction.stability_limit,
                          closed)


def _damped_curves(integrator: Integrator, hw: np.ndarray, ratio: float) -> dict[str, np.ndarray]:
    """On q'' + 2 zeta w q' + w^2 q = 0: rho, the damping the method adds to the physical 2 zeta w (as d/w), and the
    period error against the damped period 2 pi / (w sqrt(1 - zeta^2))."""
    matrices = oscillator.amplification_matrices(integrator, hw, np.full(hw.shape, ratio))
    if matrices is None:
        matrices = np.stack([oscillator.amplification_matrix(integrator, 1.0, SpringMassParams(
            stiffness=value * value, mass=1.0, damping_ratio=ratio).build()) for value in hw.tolist()])
    with np.errstate(all="ignore"):
        eigenvalues = list(np.linalg.eigvals(matrices))
        rho = np.array([float(np.max(np.abs(values))) for values in eigenvalues])
        principal = oscillator.principal_eigenvalues(hw, eigenvalues)
        damped = math.sqrt(1.0 - ratio * ratio)
        phase = np.abs(np.angle(principal))
        real = np.abs(principal.imag) <= oscillator.REAL_EIGENVALUE * np.abs(principal)
        period_error = np.where(real | (hw * damped >= oscillator.PERIOD_HW_MAX) | (phase == 0), np.nan,
                                hw * damped / phase - 1.0)
        damping = oscillator.damping_over_frequency(rho, hw) - 2.0 * ratio
    return {"spectral_radius": rho, "damping": damping, "period_error": period_error}


def _measured_card(integrator: Integrator, closed: np.ndarray | None) -> IntegratorCard:
    """A nonlinear method's card: runs of the spring at MEASURED_HW, their energy decay and zero crossings."""
    hw = np.array(MEASURED_HW)
    curves = {}
    limit = math.inf
    for ratio in CARD_DAMPING_RATIOS:
        spring = spring_system(ratio)
        rho, damping, period = (np.full(hw.size, np.nan) for _ in range(3))
        for index, value in enumerate(hw.tolist()):
            steps = max(8, int(math.ceil(MEASURED_PERIODS * 2.0 * math.pi / value)))
            t, x, energy = _sampled_run(integrator, spring, value, steps)
            if energy.size < steps + 1 or not np.isfinite(energy[-1]) or energy[-1] > DIVERGENCE * energy[0]:
                if ratio == 0.0:
                    limit = min(limit, value)
                continue
            fit = oscillator.measure_damping(t, energy, x, 1.0 if ratio == 0.0 else None)
            damping[index] = fit.rate - 2.0 * ratio
            rho[index] = math.exp(-0.5 * fit.rate * value)
            damped = math.sqrt(1.0 - ratio * ratio)
            period[index] = oscillator.measure_period_error(t, x, damped) if value * damped < math.pi else math.nan
        curves[ratio] = {"spectral_radius": rho, "damping": damping, "period_error": period}
    return IntegratorCard(integrator.label, "measured runs", hw, curves, math.nan, limit, closed)


def _sampled_run(integrator: Integrator, system: System, dt: float, steps: int):
    """t (s), x (m) and E (J) at every step of a run, shorter where it stopped (a raise or a non-finite state)."""
    solver = CHECK_SOLVER.build()
    t, x, energy = [0.0], [float(system.x0[0])], [system.total_energy(system.x0, system.v0)]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        try:
            state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
            for number in range(1, steps + 1):
                state, _ = integrator.step(system, state, dt, solver)
                t.append(number * dt)
                x.append(float(state.x[0]))
                energy.append(system.total_energy(state.x, state.v))
                if not math.isfinite(energy[-1]) or energy[-1] > DIVERGENCE * energy[0]:
                    break
        except Exception:  # noqa: BLE001 - a diverging nonlinear step may raise
            pass
    return np.array(t), np.array(x), np.array(energy)


def card_check(method_card: IntegratorCard) -> Check:
    zero = method_card.curves[0.0]
    at = int(np.argmin(np.abs(np.log(method_card.hw / 0.1))))
    measured_runs = method_card.source == "measured runs"
    limit = ("stable at every h w of the grid" if math.isinf(method_card.stability_limit)
             else "never stable" if method_card.stability_limit == 0.0
             else f"diverged from h w = {method_card.stability_limit:.4g} on (the grid's first run that did)"
             if measured_runs else f"stable for h w < {method_card.stability_limit:.4g}")
    rho_inf = "" if not math.isfinite(method_card.rho_inf) else f"rho_inf = {method_card.rho_inf:.3g}; "
    text = (f"from the {method_card.source}: {rho_inf}{limit}; at h w = {method_card.hw[at]:.2g}: "
            f"d/w = {zero['damping'][at]:.3g}, period error {zero['period_error'][at]:.3g}")
    measured = np.isfinite(zero["spectral_radius"])
    if not measured.any():
        return Check("card", False, f"no point of the card could be measured: {text}")
    return Check("card", True, text)


def closed_form_check(method_card: IntegratorCard) -> Check:
    if method_card.closed_form is None:
        return Check("closed form", None, "the method declares no closed_form_spectral_radius")
    measured = method_card.curves[0.0]["spectral_radius"]
    closed = method_card.closed_form
    if closed.shape != measured.shape:
        return Check("closed form", False, f"closed_form_spectral_radius gave shape {closed.shape} for "
                                           f"{measured.size} points of h w")
    with np.errstate(all="ignore"):
        relative = np.abs(measured - closed) / np.maximum(np.abs(closed), np.finfo(float).tiny)
    tolerance = CLOSED_FORM_TOLERANCE if method_card.source == "amplification matrix" else 1e-2
    comparable = np.isfinite(measured) & np.isfinite(closed)
    if not comparable.any():
        return Check("closed form", False, "no point where both the measured and the closed-form radius are finite")
    worst = int(np.argmax(np.where(comparable, relative, -1.0)))
    text = (f"measured rho against the declared closed form at {int(comparable.sum())} points of h w "
            f"{CARD_HW_RANGE[0]:g} ... {CARD_HW_RANGE[1]:g}: worst {relative[worst]:.1e} at h w = "
            f"{method_card.hw[worst]:.3g} (tolerance {tolerance:g})")
    return Check("closed form", bool(relative[worst] <= tolerance), text)


# -- free motion, determinism, refusals ---------------------------------------------------------------------
def free_motion_check(integrator: Integrator) -> Check:
    system = free_square()
    refusal = integrator.refusal(system)
    if refusal is not None:
        return Check("free motion", None, f"the method refuses the free square: {refusal}")
    dt = stable_dt(system)
    start = system.momentum(system.v0)
    size = float(np.sum(system.mass * np.abs(system.v0)))
    solver = CHECK_SOLVER.build()
    worst = 0.0
    with np.errstate(all="ignore"):
        state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
        for _ in range(FREE_STEPS):
            state, _ = integrator.step(system, state, dt, solver)
            change = float(np.max(np.abs(system.momentum(state.v) - start))) / size
            worst = max(worst, change) if math.isfinite(change) else math.inf
    text = (f"{FREE_STEPS} steps of dt = {dt:.3g} s of a free spinning square: |p - p0| <= {worst:.1e} of sum m|v| "
            f"(tolerance {MOMENTUM_TOLERANCE:g})")
    return Check("free motion", worst <= MOMENTUM_TOLERANCE, text if worst <= MOMENTUM_TOLERANCE
                 else f"linear momentum lost: {text}")


def determinism_check(integrator: Integrator) -> Check:
    problems = []
    for name, system, dt in (("spring", spring_system(LINEARITY_DAMPING_RATIO), 0.5),
                             ("free square", free_square(), None)):
        if integrator.refusal(system) is not None:
            continue
        dt = stable_dt(system) if dt is None else dt
        results = []
        for _ in range(2):
            state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
            solver = CHECK_SOLVER.build()
            for _ in range(3):
                state, _ = integrator.step(system, state, dt, solver)
            results.append(b"".join(part.tobytes() for part in _parts(state)))
        if results[0] != results[1]:
            problems.append(f"three steps of the {name} from the same start gave different bytes")
    if problems:
        return Check("determinism", False, "; ".join(problems))
    return Check("determinism", True, "three steps twice from the same start, on the spring and the free square: "
                                      "the same bytes")


def refusal_check(integrator: Integrator) -> Check:
    refused = []
    for name, system in (("test spring", spring_system()), ("free square", free_square())):
        reason = integrator.refusal(system)
        if reason is not None:
            refused.append(f"the {name}: {reason}")
    if refused:
        return Check("not refused", False, "the method refuses " + "; ".join(refused))
    return Check("not refused", True, "refusal() is None for the test spring and the free mass-spring square")


# -- all of them --------------------------------------------------------------------------------------------
@dataclass
class IntegratorReport:
    checks: list[Check]
    card: IntegratorCard | None


def run_checks(integrator: Integrator) -> IntegratorReport:
    """Every check, in the order they are reported; a check that raises is a FAIL naming the error."""
    checks: list[Check] = []

    def attempt(name, function, *arguments):
        """function(*arguments), or None after a FAIL naming what it raised."""
        try:
            return function(*arguments)
        except Exception as error:  # noqa: BLE001 - a user's method may raise anything
            lines = str(error).strip().splitlines()
            checks.append(Check(name, False, f"raised {type(error).__name__}: {lines[0] if lines else ''}"))
            return None

    def add(check: Check | None) -> None:
        if check is not None:
            checks.append(check)

    add(attempt("not refused", refusal_check, integrator))
    orders = {}
    for problem, system in (("spring", spring_system()), ("Kepler", kepler_orbit())):
        result = attempt(f"order ({problem})", order_check, integrator, system, problem)
        if result is not None:
            add(result[0])
            if result[1] is not None:
                orders[problem] = result[1]
    linear = attempt("linearity", linearity_check, integrator)
    if linear is not None:
        add(linear[0])
    method_card = attempt("card", card, integrator, linear is not None and linear[1])
    if method_card is not None:
        method_card.orders = orders
        add(card_check(method_card))
        add(closed_form_check(method_card))
    add(attempt("free motion", free_motion_check, integrator))
    add(attempt("determinism", determinism_check, integrator))
    return IntegratorReport(checks, method_card)
