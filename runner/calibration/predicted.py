"""What a fit on the mass on a spring should find, from theory alone: the (k, d) at which the method's own step has
the observed motion's eigenvalue.

The observed motion m q'' + d q' + k q = 0 has the eigenvalue lambda = -d/(2m) + i sqrt(k/m - d^2/(4 m^2)); sampled
at the step h, it advances by exp(lambda h) per step. A method with parameters (k', d') advances by the principal
eigenvalue mu(k', d') of its amplification matrix, probed by stepping the unit states (``simrun.analysis.oscillator``, no
formula of its own). A fit over many periods matches the motion's decay and phase per step, so it should land where
log mu(k', d') = lambda h: two real equations (modulus and phase) in two unknowns, solved here by a 2-D root-find.
With d alone fitted, the phase error would leak into d; with k and d together, k absorbs the period error and d
the artificial damping (negative where the method damps more than the motion: it must pump energy back in).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.optimize

# the root-find's residual (in units of |lambda h|) below which the equations count as solved
ROOT_TOLERANCE = 1e-8
KEYS = ("system.stiffness", "system.damping")


def continuous_eigenvalue(mass: float, stiffness: float, damping: float) -> complex:
    """lambda of m q'' + d q' + k q = 0 with Im >= 0 (the oscillating root; real when overdamped)."""
    rate = -damping / (2.0 * mass)
    discriminant = stiffness / mass - rate * rate
    return complex(rate, math.sqrt(discriminant)) if discriminant >= 0 else complex(rate + math.sqrt(-discriminant), 0.0)


def principal_log(matrix: np.ndarray, target: complex) -> complex:
    """log of the eigenvalue of ``matrix`` (with Im >= 0) nearest to exp(target) in the log plane."""
    eigenvalues = np.linalg.eigvals(matrix)
    logs = [complex(np.log(abs(value)), abs(np.angle(value))) for value in eigenvalues if abs(value) > 0]
    if not logs:
        return complex(-np.inf, 0.0)
    return min(logs, key=lambda value: abs(value - target))


def observed_eigenvalue(mass: float, stiffness: float, damping: float, data_method: tuple | None = None) -> complex:
    """lambda of the observed motion: the continuous one, or, for data that a method made at its step h_d
    (``data_method`` = (integrator, h_d)), that method's own, log(mu_d) / h_d."""
    rate = continuous_eigenvalue(mass, stiffness, damping)
    if data_method is None:
        return rate
    from simrun.analysis.oscillator import amplification_matrix
    from simrun.systems import SpringMassParams

    integrator, step = data_method
    system = SpringMassParams(mass=mass, stiffness=stiffness, damping=damping).build()
    with np.errstate(all="ignore"):
        return principal_log(amplification_matrix(integrator, step, system), rate * step) / step


def predicted_fit(integrator, dt: float, mass: float, stiffness: float, damping: float,
                  data_method: tuple | None = None) -> tuple[float, float]:
    """(k', d') at which ``integrator`` at step ``dt`` has the eigenvalue exp(lambda h) of the motion with (k, d) (as
    ``data_method`` made it, if one did: ``observed_eigenvalue``); (NaN, NaN) where no such parameters exist (the
    phase per step is past pi, or the root-find does not meet it)."""
    from simrun.analysis.oscillator import amplification_matrix
    from simrun.systems import SpringMassParams

    target = observed_eigenvalue(mass, stiffness, damping, data_method) * dt
    if target.imag == 0.0 or target.imag >= math.pi:
        return math.nan, math.nan
    scale = abs(target)

    def mismatch(parameters):
        k, d = parameters
        system = SpringMassParams(mass=mass, stiffness=float(k), damping=float(d)).build()
        with np.errstate(all="ignore"):
            value = principal_log(amplification_matrix(integrator, dt, system), target)
        if not np.isfinite(value.real):
            return np.array([1e3, 1e3])
        return np.array([value.real - target.real, value.imag - target.imag]) / scale

    damping_scale = max(abs(damping), 0.01 * math.sqrt(stiffness * mass))
    try:
        result = scipy.optimize.least_squares(mismatch, [stiffness, damping], bounds=([1e-12 * stiffness, -np.inf], np.inf),
                                              x_scale=[stiffness, damping_scale], xtol=1e-14, ftol=1e-14, gtol=1e-14,
                                              max_nfev=400)
    except (ValueError, np.linalg.LinAlgError):
        return math.nan, math.nan
    if not np.all(np.isfinite(result.fun)) or np.max(np.abs(result.fun)) > ROOT_TOLERANCE:
        return math.nan, math.nan
    return float(result.x[0]), float(result.x[1])


def predicted_values(keys: list[str], system_mapping: dict, integrator, dt: float, truth: dict,
                     data_method: tuple | None = None) -> dict[str, float]:
    """The predicted fitted values of a spring fit of stiffness and damping, from the motion's own ``truth``
    ({key: value}) and the method that made the data, if one did; {} for other systems or other parameters."""
    if system_mapping.get("type") != "spring_mass" or sorted(keys) != sorted(KEYS) or not all(key in truth for key in KEYS):
        return {}
    stiffness, damping = predicted_fit(integrator, dt, float(system_mapping["mass"]), float(truth[KEYS[0]]),
                                       float(truth[KEYS[1]]), data_method)
    return {KEYS[0]: stiffness, KEYS[1]: damping}


__all__ = ["continuous_eigenvalue", "observed_eigenvalue", "predicted_fit", "predicted_values"]
