"""The energy line search shared by Newton, projected Newton, L-BFGS, gradient descent and Jacobi-Chebyshev.

Rules (``line_search``): ``none`` takes the full step (cut, as every rule's first trial, to the fraction that
crosses no contact surface where the problem filters its steps: IPC); ``backtracking`` halves the step until
E(y + a p) <= E(y); ``armijo`` halves it until E(y + a p) <= E(y) + c a g^T p (sufficient decrease,
Nocedal & Wright, "Numerical Optimization", sec. 3.1). Near the solution the change of E drops
below the round-off of E itself (|dE| ~ |g|^2 / H), and that round-off is relative to the size of the
terms E sums (the problem's ``value_magnitude``: springs near their rest length have energies far
below their round-off eps |dW/dL| L), not to |E|. A change that E cannot resolve is judged by the
gradient instead (accepted when it lowers |g|_inf), or, for the Newton family (``within_roundoff``),
accepted as it is: its full step near the solution is the best there is. E therefore never increases
by more than its own round-off.
"""

from __future__ import annotations

import numpy as np

from .base import Advance, Iterate, max_norm
from .dofs import FreeDofs

LINE_SEARCHES = ("none", "backtracking", "armijo")
# Armijo's sufficient-decrease constant; 1e-4 is the customary choice (Nocedal & Wright, sec. 3.1).
ARMIJO_C = 1e-4
# Halvings before a line search gives up: 2^-40 ~ 1e-12 of the trial step changes nothing of use.
MAX_LINE_SEARCH = 40
# E sums many terms of both signs; a change below this fraction of |E| is within its round-off.
ENERGY_ROUNDOFF = 1024 * np.finfo(float).eps


def judge(rule: str, energy: float, candidate_energy: float, predicted: float, magnitude=None) -> bool | None:
    """True: acceptable; False: not; None: the change is below the round-off of E (judge by the gradient).

    ``predicted`` is g^T (y_candidate - y), the first-order change; a non-negative prediction never
    licenses an increase. ``magnitude``: the size of the terms E sums (its round-off is relative to it,
    not to |E|, where they cancel), or a callable giving it (asked only when E did not clearly fall);
    max(|E|, |E_candidate|) when the problem does not say."""
    if not np.isfinite(candidate_energy):
        return False
    limit = energy + (ARMIJO_C * min(predicted, 0.0) if rule == "armijo" else 0.0)
    if candidate_energy <= limit:
        return True
    if callable(magnitude):
        magnitude = magnitude()
    scale = max(abs(energy), abs(candidate_energy), magnitude or 0.0)
    if abs(candidate_energy - energy) <= ENERGY_ROUNDOFF * scale:
        return None
    return False


def accept(problem, free: FreeDofs, current: Iterate, rule: str, candidate: np.ndarray,
           candidate_energy: float, within_roundoff: bool = False) -> tuple[bool, np.ndarray | None]:
    """Is ``candidate`` an acceptable next iterate? Returns (verdict, its gradient if it was computed).

    ``within_roundoff``: a change of E below its round-off is accepted as it is (Newton's full step near
    the solution, where E cannot tell and the residual is at its own noise), not judged by the gradient."""
    verdict = judge(rule, current.energy, candidate_energy, float(current.gradient @ (candidate - current.y)),
                    lambda: value_magnitude(problem, candidate))
    if verdict is None and within_roundoff:
        return True, None
    if verdict is None:
        gradient = free.zero_fixed(np.array(problem.gradient(candidate), dtype=float))
        return bool(max_norm(gradient) < current.residual), gradient
    return verdict, None


def line_search(problem, free: FreeDofs, current: Iterate, direction: np.ndarray, rule: str,
                within_roundoff: bool = False) -> Advance:
    """y + a p for the first a = a0, a0/2, a0/4, ... that ``rule`` accepts; a0 = 1, or for a problem that filters
    its steps (IPC contact) the collision-free fraction of p (``collision_free``); a step of a0 for ``none`` or
    for a problem without a value. A direction that is not a descent direction (g^T p >= 0) fails.
    ``within_roundoff``: see ``accept``."""
    step = collision_free(problem, current.y, direction)
    if rule == "none" or current.energy is None:
        return Advance(current.y + step * direction if step < 1.0 else current.y + direction)
    slope = float(current.gradient @ direction)
    if not slope < 0.0 or not step > 0.0:
        return Advance(current.y, ok=False)
    for reductions in range(MAX_LINE_SEARCH + 1):
        candidate = current.y + step * direction
        energy = problem.value(candidate)
        ok, gradient = accept(problem, free, current, rule, candidate, energy, within_roundoff)
        if ok:
            return Advance(candidate, gradient, energy, reductions)
        step *= 0.5
    return Advance(current.y, line_search_steps=MAX_LINE_SEARCH, ok=False)


def collision_free(problem, y: np.ndarray, direction: np.ndarray) -> float:
    """The fraction of the step y -> y + direction that crosses no contact surface (``problem.max_step``, IPC's
    continuous collision detection), 1 for problems without contact filtering."""
    if not getattr(problem, "requires_step_filter", False):
        return 1.0
    return min(1.0, problem.max_step(y, direction))


def value_magnitude(problem, y: np.ndarray) -> float | None:
    """The problem's ``value_magnitude(y)`` (the size of E's terms), or None where it offers none."""
    magnitude = getattr(problem, "value_magnitude", None)
    return magnitude(y) if magnitude is not None else None


def has_value(problem) -> bool:
    return callable(getattr(problem, "value", None))
