"""The incremental potential of one step of many lanes at once (systems/lanes.py): IncrementalPotential per row.

    E_l(y_l) = 1/2 (y_l - y~_l)^T M_l (y_l - y~_l) + s_l [P_l(y_l) + 1/(2 b_l) (y_l - a_l)^T D_l (y_l - a_l)]

for every lane l, each with its own predictor, scale and velocity map (its own dt). Built by ``StepPlan.problem``
when the system is a lane system, so the methods' ``potential_step`` needs no change; solved by
``solvers.lanes.LaneNewton``. Gradient and Hessian repeat IncrementalPotential's sums in the same order, so each
lane's numbers are its run's.
"""

from __future__ import annotations

import numpy as np

# IncrementalPotential's residual floor: 64 eps |M y~|_inf + 64 subnormal spacings (integrators/base.py)
RESIDUAL_ULPS = 64.0 * np.finfo(float).eps
RESIDUAL_SUBNORMALS = 64.0 * np.finfo(float).smallest_subnormal


class LaneIncrementalPotential:
    """One incremental potential per lane; arrays (lanes, dofs), scalars per lane (lanes, 1). Quadratic only."""

    def __init__(self, system, y_tilde, scale, velocity_origin, velocity_divisor, damping_at, step_start, fraction=1.0):
        if not system.quadratic_potential:
            raise TypeError("lanes step only systems with a quadratic potential (one Newton step is the minimiser)")
        self.system = system
        self.y_tilde = y_tilde
        self.scale = scale
        self.velocity_origin = velocity_origin
        self.velocity_divisor = velocity_divisor
        self.step_start = step_start
        self.fraction = fraction
        self.damped = damping_at is not None and system.is_damped
        self.damping_weight = scale / velocity_divisor
        self.quadratic = True
        # per lane: the residual below which the inertia term's own round-off hides further progress
        inertia = np.abs(system.mass * y_tilde)
        self.residual_floor = RESIDUAL_ULPS * (inertia[:, 0] if inertia.shape[1] == 1 else np.max(inertia, axis=1)) + RESIDUAL_SUBNORMALS

    def start_point(self, start):
        return start  # lane systems have no prescribed paths, pins or contact

    def gradient(self, y):
        """M (y - y~) + s dP/dy + (s/b) D (y - a), summed in IncrementalPotential.gradient's order (in place: it runs at
        every iteration of every step)."""
        gradient = np.subtract(y, self.y_tilde)
        gradient *= self.system.mass
        force = self.system.gradient(y)
        force *= self.scale
        gradient += force
        if self.damped:
            damping = self.system.damping_times(y - self.velocity_origin)
            damping *= self.damping_weight
            gradient += damping
        return gradient

    def hessian(self, y):
        """M + s K + (s/b) D per lane, shape (lanes, dofs, dofs)."""
        return self.system.hessian_blocks(self.scale, self.damping_weight if self.damped else None)
