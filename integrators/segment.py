"""The problem of the methods that sample the force at several points of the step x_n -> x_{n+1} (the average
vector field, Ascher's BDF2/midpoint mix): ``SegmentPotential``, whose gradient is their residual and whose Hessian
their Jacobian, and which still has a value, so that line-search solvers can use it (integrators/base.py holds the
incremental potential it generalises, and the helpers both share)."""

from __future__ import annotations

import numpy as np

from simrun.systems import System

from .base import add_mass, constrained_start, initial_guess, residual_floor


class SegmentPotential:
    """E(y) = 1/2 (y - y~)^T M (y - y~) + h^2 sum_j c_j P(z_j) / s_j  + damping term,
    with z_j = x_n + s_j (y - x_n) points of the segment from x_n to the unknown y = x_{n+1}.

    Its gradient is the residual of methods that sample the force along the step,
        M (y - y~) - h^2 sum_j c_j f(z_j, v_j),   v_j = (1 - s_j) v_n + s_j v(y),  v(y) = (y - a)/b,
    (each sampled force is the gradient of P(z_j)/s_j in y), and its Hessian is their Jacobian
        M + h^2 sum_j c_j s_j K(z_j) + (h^2 sum_j c_j s_j / b) D.
    Damping f_d = -D v enters with node j's D_j taken at ``damping_at`` (one point for all nodes, or
    one per node), as in ``IncrementalPotential``; the damping term is
    h^2 [v_n^T D_start y + (y - a)^T D_end (y - a) / (2 b)], D_start = sum_j c_j (1 - s_j) D_j, D_end = sum_j c_j s_j D_j.
    A single node s = 1 with weight c gives ``IncrementalPotential`` with scale c h^2.

    Parameters: system; y_tilde (m) and x_start = x_n (m), v_start = v_n (m/s), shape (dof_count,);
    nodes s_j in (0, 1] and weights c_j (dimensionless); dt = h (s); velocity_origin a (m) and
    velocity_divisor b (s); damping_at: positions (m) at which D is taken, an array or one per node.
    """

    def __init__(self, system: System, y_tilde: np.ndarray, x_start: np.ndarray, v_start: np.ndarray,
                 nodes, weights, dt: float, velocity_origin: np.ndarray, velocity_divisor: float,
                 damping_at: np.ndarray | None = None):
        points = damping_at if isinstance(damping_at, (list, tuple)) else [damping_at] * len(nodes)
        kept = [(float(s), float(c), point) for s, c, point in zip(nodes, weights, points) if c != 0.0]
        self.nodes = np.array([s for s, _, _ in kept])
        self.weights = np.array([c for _, c, _ in kept])
        self.system = system
        self.y_tilde = y_tilde
        self.x_start = x_start
        self.v_start = v_start
        self.h2 = dt * dt
        self.fixed_dofs = system.fixed_dofs
        self.sliding = system.sliding
        self.velocity_origin = velocity_origin
        self.velocity_divisor = velocity_divisor
        # D_start and D_end: how the sampled damping forces see v_n and v(y)
        self.damping_start = self.damping_end = None
        if damping_at is not None and system.damping_matrix(x_start) is not None:
            for s, c, point in kept:
                damping = system.damping_matrix(point)
                start, end = (c * (1.0 - s)) * damping, (c * s) * damping
                self.damping_start = start if self.damping_start is None else self.damping_start + start
                self.damping_end = end if self.damping_end is None else self.damping_end + end
        self.residual_floor = residual_floor(system.mass, y_tilde)
        self.step_start = (x_start, v_start, dt)
        self.fraction = 1.0  # the unknown is x_{n+1}
        self._rest_scale = self.h2 * float(np.dot(self.weights, self.nodes))

    projective = False  # forces sampled along the step: not the form projective dynamics minimises

    def initial_guess(self, kind: str) -> np.ndarray:
        """As ``IncrementalPotential.initial_guess``, with c h^2 = h^2 sum_j c_j s_j."""
        return initial_guess(self, kind, self._rest_scale)

    def rest_hessian(self):
        """M + h^2 sum_j c_j s_j K_r (+ (h^2/b) D_end when D does not depend on x): the Hessian's form at rest."""
        form = self.system.projective_form()
        if not form:
            return None
        matrix = self._rest_scale * form.rest_stiffness()
        if self.damping_end is not None and self.system.damping_is_constant:
            matrix = matrix + (self.h2 / self.velocity_divisor) * self.damping_end
        return add_mass(matrix, self.system)

    @property
    def rest_key(self) -> tuple:
        return (id(self.system), self._rest_scale, self.h2 / self.velocity_divisor if self.damping_end is not None else None)

    def _points(self, y: np.ndarray):
        step = y - self.x_start
        return [self.x_start + s * step for s in self.nodes]

    def value(self, y: np.ndarray) -> float:
        offset = y - self.y_tilde
        energy = 0.5 * float(np.dot(self.system.mass_times(offset), offset))
        for s, c, z in zip(self.nodes, self.weights, self._points(y)):
            # P(z_j) whole, not P(z_j) - P(x_n): the constant changes no comparison, and without it |E|
            # keeps the size of its terms, which the line search's round-off allowance is relative to
            energy += self.h2 * c * self.system.potential_energy(z) / s
        if self.damping_end is not None:
            rate = y - self.velocity_origin
            energy += self.h2 * (float(self.v_start @ (self.damping_start @ y))
                                 + 0.5 / self.velocity_divisor * float(rate @ (self.damping_end @ rate)))
        return energy

    def value_magnitude(self, y: np.ndarray) -> float:
        """As ``IncrementalPotential.value_magnitude``: the size of the terms ``value`` sums."""
        offset = y - self.y_tilde
        momentum = np.abs(self.system.mass * offset)
        if self.system.mass_correction is not None:
            momentum += abs(self.system.mass_correction) @ np.abs(offset)
        magnitude = float(momentum @ (0.5 * np.abs(offset) + np.abs(y)))
        for s, c, z in zip(self.nodes, self.weights, self._points(y)):
            magnitude += self.h2 * abs(c) * self.system.potential_magnitude(z) / s
        if self.damping_end is not None:
            rate = y - self.velocity_origin
            magnitude += self.h2 * (abs(float(self.v_start @ (self.damping_start @ y)))
                                    + 0.5 / self.velocity_divisor * abs(float(rate @ (self.damping_end @ rate))))
        return magnitude

    def gradient(self, y: np.ndarray) -> np.ndarray:
        gradient = self.system.mass_times(y - self.y_tilde)
        for c, z in zip(self.weights, self._points(y)):
            gradient += self.h2 * c * self.system.gradient(z)
        if self.damping_end is not None:
            gradient += self.h2 * (self.damping_start @ self.v_start
                                   + self.damping_end @ ((y - self.velocity_origin) / self.velocity_divisor))
        if self.fixed_dofs.size:
            gradient[self.fixed_dofs] = 0.0
        if self.sliding is not None:
            self.sliding.apply(gradient)
        return gradient

    prescribed = None  # the unknown x_{n+1} on the prescribed paths' dofs (base.on_paths), set by the method

    def start_point(self, start: np.ndarray) -> np.ndarray:
        """As ``IncrementalPotential.start_point``."""
        return constrained_start(self.system, start, self.y_tilde, self.prescribed)

    def direction_guess(self, y: np.ndarray) -> np.ndarray:
        return self.y_tilde - y

    def hessian(self, y: np.ndarray, project_spd: bool = False):
        hessian = None
        for s, c, z in zip(self.nodes, self.weights, self._points(y)):
            term = (self.h2 * c * s) * self.system.hessian(z, project_spd=project_spd)
            hessian = term if hessian is None else hessian + term
        if self.damping_end is not None:
            hessian = hessian + (self.h2 / self.velocity_divisor) * self.damping_end
        return add_mass(hessian, self.system)
