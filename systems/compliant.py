"""Springs declared as compliant constraints: what position-based integrators (XPBD) need from a system.

A Hookean spring of stiffness k is the constraint C(x) = 0 with compliance alpha = 1/k, since its energy
k/2 C^2 = C^2 / (2 alpha) (Macklin, Mueller & Chentanez, "XPBD: position-based simulation of compliant
constrained dynamics", MIG 2016, eq. 4); a damper of coefficient beta along the spring acts on the rate
grad C . v (their eq. 25). Two kinds of constraint:

- l0 > 0, the distance constraint C = |x_i - x_j| - l0 (one row, grad_i C = n = (x_i - x_j)/|x_i - x_j|);
- l0 = 0, the vector constraint C = x_i - x_j (d rows, each of compliance 1/k): k/2 |x_i - x_j|^2, a
  zero-length spring (the test spring k q^2/2 to the origin, the linear central force of circular motion).

A spring may tie a vertex to a fixed point (an anchor) instead of a second vertex: ``second`` is then
``ANCHORED`` and ``anchor`` holds the point.

A system declares its springs as its ``compliant_form()`` (systems/forms.py): a ``CompliantSprings``, or None
(``NotOffered`` to say why, in a few words) where it has none.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

ANCHORED = -1  # ``second`` of a spring that ties ``first`` to its fixed ``anchor`` point


@dataclass(frozen=True, eq=False)
class CompliantSprings:
    """A system's Hookean springs with their dampers, as compliant constraints (see the module docstring).

    first: (m,) intp, the spring's first vertex i; second: (m,) intp, its second vertex j, or ANCHORED;
    anchor: (m, d) m, the fixed point of anchored springs (rows of two-vertex springs are not read);
    rest_length: (m,) m, l0 >= 0 (0: the vector constraint x_i - x_j); stiffness: (m,) N/m, k >= 0 (0: a
    damper alone); damping: (m,) N s/m, beta >= 0, the damper along the spring, f_i = -beta (grad C . v) grad_i C;
    vertex_count: vertices of the system (dof_count / d); other_forces: whether the system has forces besides
    these springs and its constant ``external_acceleration`` (gravity): penalty contact, damping that is not
    along the springs. Integrators then evaluate them as f(x, v) - ``force(x, v)``; without them, they skip
    that evaluation.
    """

    first: np.ndarray
    second: np.ndarray
    anchor: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    vertex_count: int
    other_forces: bool

    @property
    def dim(self) -> int:
        """Coordinates per vertex, d."""
        return int(self.anchor.shape[1])

    @property
    def spring_count(self) -> int:
        return int(self.first.size)

    @functools.cached_property
    def free(self) -> np.ndarray:
        """(f,) indices of the springs whose second end is a vertex (not an anchor)."""
        return np.flatnonzero(self.second != ANCHORED)

    @functools.cached_property
    def colours(self) -> tuple[np.ndarray, ...]:
        """The springs in groups that share no vertex (a greedy edge colouring; computed once per spring set).

        The constraints of one group touch disjoint vertices, so projecting them all at once is the same
        as projecting them one after another: Gauss-Seidel over the groups, each group one vectorised
        update. Greedy colouring needs at most 2 Delta - 1 colours, Delta the largest number of springs at
        a vertex (the 12x12 cloth: Delta = 12)."""
        used = [0] * self.vertex_count  # per vertex, a bit mask of the colours of its springs so far
        colour = np.empty(self.spring_count, dtype=np.intp)
        for spring, (i, j) in enumerate(zip(self.first.tolist(), self.second.tolist())):
            taken = used[i] | (used[j] if j != ANCHORED else 0)
            lowest_free = (~taken & (taken + 1)).bit_length() - 1  # the lowest bit not set in taken
            colour[spring] = lowest_free
            used[i] |= 1 << lowest_free
            if j != ANCHORED:
                used[j] |= 1 << lowest_free
        count = int(colour.max()) + 1 if colour.size else 0
        return tuple(np.flatnonzero(colour == number) for number in range(count))

    def _ends(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions of the first ends, of the second ends) of every spring, (m, d) each, from the vertex
        positions (n, d): an anchored spring's second end is its anchor."""
        second = self.anchor.copy()
        second[self.free] = positions[self.second[self.free]]
        return positions[self.first], second

    def force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The springs' and their dampers' force (N), shape (n d,), unfiltered:
        f_i = -(k C + beta grad C . (v_i - v_j)) grad_i C per spring, its opposite on j; for l0 = 0 that is
        -k (x_i - x_j) - beta (v_i - v_j). Parameters: x (m) and v (m/s), shape (n d,)."""
        d = self.dim
        positions, velocities = x.reshape(-1, d), v.reshape(-1, d)
        first_x, second_x = self._ends(positions)
        delta = first_x - second_x
        rate = velocities[self.first].copy()
        rate[self.free] -= velocities[self.second[self.free]]
        vector = self.rest_length == 0.0
        spring_force = -(self.stiffness[:, None] * delta + self.damping[:, None] * rate)
        distance = np.flatnonzero(~vector)
        if distance.size:
            length = np.sqrt(np.einsum("ij,ij->i", delta[distance], delta[distance]))
            direction = delta[distance] / np.where(length > 0.0, length, np.inf)[:, None]  # no direction at zero length
            along = (self.stiffness[distance] * (length - self.rest_length[distance])
                     + self.damping[distance] * np.einsum("ij,ij->i", rate[distance], direction))
            spring_force[distance] = -along[:, None] * direction
        force = np.zeros((self.vertex_count, d))
        j = self.second[self.free]
        for component in range(d):  # per component, two bincounts: the scatter onto vertices i and j
            force[:, component] = (np.bincount(self.first, spring_force[:, component], self.vertex_count)
                                   - np.bincount(j, spring_force[self.free, component], self.vertex_count))
        return force.ravel()

    def energy(self, x: np.ndarray) -> float:
        """sum_e k_e/2 |C_e(x)|^2 (J): the springs' potential energy; x (m), shape (n d,)."""
        first_x, second_x = self._ends(x.reshape(-1, self.dim))
        delta = first_x - second_x
        squared_length = np.einsum("ij,ij->i", delta, delta)
        squared = np.where(self.rest_length == 0.0, squared_length, np.square(np.sqrt(squared_length) - self.rest_length))
        return 0.5 * float(np.dot(self.stiffness, squared))


def anchored_springs(stiffness: float, damping: float, dim: int) -> CompliantSprings:
    """One zero-length spring from vertex 0 to the origin (k/2 |x|^2, damper beta along it): the test spring
    and the linear law of circular motion. stiffness k (N/m), damping beta (N s/m), dim d."""
    return CompliantSprings(
        first=np.zeros(1, dtype=np.intp), second=np.full(1, ANCHORED, dtype=np.intp), anchor=np.zeros((1, dim)),
        rest_length=np.zeros(1), stiffness=np.array([float(stiffness)]), damping=np.array([float(damping)]),
        vertex_count=1, other_forces=False)
