"""The exact motion of the damped oscillator m q'' + d q' + k q = 0 near critical damping, shared by the spring's runs
(systems/spring_mass.py) and its lanes (systems/lanes.py)."""

from __future__ import annotations

import numpy as np


# the roots of m l^2 + d l + k of a damped oscillator count as distinct when they differ by this fraction of their size:
# the two-exponential form of its exact motion (the spring's, one run or lanes) then loses at most eps / DISTINCT_ROOTS
# of its digits (about 1e-13)
DISTINCT_ROOTS = 1e-3


def near_critical_states(m, k, d, q0, p0, t):
    """(q, p) at t of m q'' + d q' + k q = 0 from (q0, p0), where the roots nearly coincide: the propagator exp(t A),
    A = [[0, 1], [-k/m, -d/m]], in closed form, e^{s t} (cosh(delta t) I + sinh(delta t)/delta (A - s I)) with s =
    -d/(2m) and delta^2 = s^2 - k/m (complex for an oscillation), sinh(z)/z taken as 1 at z = 0: no digits lost as
    delta goes to 0, where the two-exponential form loses them. Arrays that broadcast (lanes, or times), where scipy's
    expm takes one 2 x 2 matrix at a time and would be most of the damping map's stepping (docs/performance.md,
    "Lockstep lanes")."""
    s = -d / (2.0 * m)
    delta = np.sqrt((s * s - k / m).astype(complex))
    z = delta * t
    at_zero = z == 0.0
    sinh_over_delta = np.where(at_zero, 1.0, np.sinh(z) / np.where(at_zero, 1.0, z)) * t
    cosh, grow = np.cosh(z), np.exp(s * t)
    q = grow * (cosh * q0 + sinh_over_delta * (p0 - s * q0))
    p = grow * (cosh * p0 + sinh_over_delta * (s * p0 - (k / m) * q0))
    return q.real, p.real
