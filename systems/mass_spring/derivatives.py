"""Exact parameter derivatives of a mass-spring system, for the forward sensitivities of a calibration.

The potential's gradient is linear in the per-spring stiffness, and the damping matrix in each damper's
coefficients (k_d; alpha and beta of Rayleigh damping). A config value selects some of those numbers (the
stiffness of every stretch spring, one damper's coefficient), so moving the value by Delta moves each of them by
Delta or by nothing: comparing the system built at theta + Delta with this one gives the selection, and with it
d(grad P)/dtheta and dD/dtheta exactly (``MassSpring.parameter_derivative``). Spring damping also moves with x
(its directions are the springs'): ``damping_derivative`` is its derivative along a change of x.
"""

from __future__ import annotations

import numpy as np

from ..base import ParameterDerivative

# what must be equal for a change of config value to be a change of coefficients only
SAME_ARRAYS = ("first", "second", "rest_length", "vertex_masses", "x0", "v0", "gravity", "fixed_dofs")


def parameter_derivative(system, changed, change: float) -> ParameterDerivative | None:
    """d(grad P)/dtheta and dD/dtheta of ``system`` from ``changed`` (theta moved by ``change``), or None."""
    if type(changed) is not type(system) or changed.law is not system.law or system.contact is not None \
            or changed.contact is not None or system.sliding is not None:
        return None
    if any(not np.array_equal(getattr(system, name), getattr(changed, name)) for name in SAME_ARRAYS):
        return None
    if [term.model for term in system.damping_terms] != [term.model for term in changed.damping_terms]:
        return None  # a damper switched on or off (a zero coefficient drops it): not a linear change
    stiffness_rate = (changed.stiffness - system.stiffness) / change
    if np.any(stiffness_rate) and any(term.model == "rayleigh" and term.beta != 0.0 for term in system.damping_terms):
        return None  # Rayleigh's beta K_rest moves with the stiffness too: finite differences follow it
    rates = [(term.model, (moved.coefficient - term.coefficient) / change, (moved.alpha - term.alpha) / change,
              (moved.beta - term.beta) / change) for term, moved in zip(system.damping_terms, changed.damping_terms)]
    rates = [rate for rate in rates if any(rate[1:])]

    def gradient(x: np.ndarray) -> np.ndarray:
        geometry = system._springs(x)
        factor = system.law.unit_gradient_factor(system, geometry) * stiffness_rate
        return (system._incidence @ (geometry.delta * factor[:, None])).ravel()

    def damping(x: np.ndarray):
        return system.pattern_matrix(damping_data(system, rates, x))

    return ParameterDerivative(gradient=gradient, damping=damping if rates else None)


def damping_data(system, terms: list[tuple[str, float, float, float]], x: np.ndarray) -> np.ndarray:
    """The pattern data of sum of the dampers (model, coefficient, alpha, beta) at x, assembled as
    ``MassSpring.damping_matrix`` assembles the system's own."""
    d = system.dim
    data = np.zeros(system.hessian_pattern.nnz)
    for model, coefficient, alpha, beta in terms:
        if model == "spring":
            direction = system._springs(x).direction
            data += system._scatter_blocks(coefficient * direction[:, :, None] * direction[:, None, :])
        elif model == "relative":
            data += system._scatter_blocks(np.broadcast_to(coefficient * system.identity, (system.spring_count, d, d)))
        elif model == "drag":
            data += system._scatter_blocks(np.zeros((system.spring_count, d, d)),
                                           np.broadcast_to(coefficient * system.identity, (system.vertex_count, d, d)))
        elif model == "rayleigh":
            part = beta * system._spring_hessian_data(system._geometry_at(system.rest.ravel()), project_spd=True)
            part[system.diagonal_positions] += alpha * system.mass
            data += part
    return data


def spring_damping_derivative(system, x: np.ndarray, dx: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """d/de D(x + e dx) w of the spring dampers, D = sum_e k_d u u^T on (v_i - v_j): with l = x_i - x_j, L = |l|,
    du = (I - u u^T) dl / L and d(u u^T) w_e = du (u . w_e) + u (du . w_e). dx and w: (dof_count,) or (dof_count, p)."""
    coefficient = sum(term.coefficient for term in system.damping_terms if term.model == "spring")
    if coefficient == 0.0:
        return None
    d = system.dim
    geometry = system._springs(x)
    u, length = geometry.direction, geometry.length
    columns = dx.reshape(dx.shape[0], -1)
    weights = np.broadcast_to(w.reshape(w.shape[0], -1), columns.shape)
    result = np.empty(columns.shape)
    for column in range(columns.shape[1]):
        dl = (np.take(columns[:, column], system._first_dofs) - np.take(columns[:, column], system._second_dofs)).reshape(-1, d)
        we = (np.take(weights[:, column], system._first_dofs) - np.take(weights[:, column], system._second_dofs)).reshape(-1, d)
        du = (dl - u * np.einsum("ij,ij->i", u, dl)[:, None]) / length[:, None]
        per_spring = coefficient * (du * np.einsum("ij,ij->i", u, we)[:, None] + u * np.einsum("ij,ij->i", du, we)[:, None])
        result[:, column] = (system._incidence @ per_spring).ravel()
    return result.reshape(dx.shape)
