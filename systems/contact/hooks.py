"""A system's contact block as the runner, the problems, the line search and vertex block descent see it: the
``ContactForm`` a system with a ``contact`` (a ContactModel) returns from ``contact_form()``, and ``WithContact``,
what such a system inherits. Written once for every system of vertices that takes a contact block (mass_spring,
fem).

The system provides ``contact``, ``dim``, ``fixed_dofs``, ``sliding``, ``_elastic_gradient(x)`` (dP/dx without
contact, what IPC's stiffness estimate balances the barrier against), and for its Hessian ``hessian_data`` (its
elements' and contact's vertex blocks in the fixed pattern) and ``_vertex_positions`` ((n, d, d): where each vertex
block's entries sit in the pattern's data array).
"""

from __future__ import annotations

import numpy as np

from ..patterns import add_keeping_pattern


class ContactForm:
    """The contact of ``system`` (its ContactModel is ``model``): see the module docstring."""

    def __init__(self, system):
        self.system = system
        self.model = system.contact

    @property
    def needs_step_filter(self) -> bool:
        """Whether every step of a solve must be cut short of a collision (IPC's barrier): the integrators that cannot
        cut theirs (explicit ones, forces sampled along the step) and the solvers without a filtered line search
        refuse such a system."""
        return self.model.requires_step_filter

    @property
    def has_friction(self) -> bool:
        return self.model.friction is not None

    def begin_run(self, dt: float, x: np.ndarray) -> None:
        self.model.begin_run(dt, x, self.system._elastic_gradient)

    def begin_step(self, t: float, dt: float, x: np.ndarray) -> None:
        self.model.begin_step(t, dt, x, self.system._elastic_gradient)

    def start(self, x: np.ndarray) -> np.ndarray:
        """x with the vertices near moving IPC colliders carried along over the step (ContactModel.carried), the
        move filtered as every solver step is (pins stay, sliding vertices stay on their planes and lines)."""
        if not self.needs_step_filter:
            return x
        carried = self.model.carried(x)
        if carried is x:
            return x
        move = carried - x
        system = self.system
        if system.fixed_dofs.size:
            move[system.fixed_dofs] = 0.0
        if system.sliding is not None:
            system.sliding.apply(move)
        return x + move

    def friction_term(self, x_start: np.ndarray, velocity_origin: np.ndarray, velocity_divisor: float,
                      time: float | None = None):
        """The friction potential of a step from x_start (colliders at ``time``, default the step's start) for the
        velocity map v(y) = (y - a)/b (an object with value, gradient and hessian in y), or None without friction
        (contact/model.py, FrictionTerm)."""
        return self.model.friction_term(x_start, velocity_origin, velocity_divisor, time)

    def coupling_hessian(self, x: np.ndarray, project_spd=False):
        """The Hessian of the mesh contacts (IPC through ipctk), which couples vertices that no element of the model
        joins and so lies outside the system's ``hessian_pattern`` (N/m); None without them. The system's
        ``hessian`` includes it, its ``hessian_data`` does not."""
        return self.model.coupling_hessian(x, project_spd)

    def add_vertex_blocks(self, data: np.ndarray, vertices: np.ndarray, blocks: np.ndarray) -> None:
        """Adds blocks (k, d, d) at the vertices (k,) (repeats summed) into the pattern's data array, in place."""
        np.add.at(data, self.system._vertex_positions[vertices], blocks)

    def point_step_fractions(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray | None:
        """IPC's step filter for each vertex moving alone by steps (k, d): the fraction (k,) of its step that stops
        short of the first collider it would reach (ContactModel.point_step_fractions); None without IPC. The mesh
        contacts couple vertices: vertex block descent refuses them."""
        if not self.needs_step_filter:
            return None
        return self.model.point_step_fractions(x.reshape(-1, self.system.dim)[vertices], steps)

    def record(self, x_start: np.ndarray, x: np.ndarray, v: np.ndarray, dt: float) -> tuple[float, int, float]:
        """(smallest signed distance (m), active contacts, friction work (J)) of the step x_start -> (x, v)."""
        model = self.model
        return model.minimum_distance(x), model.active_count(x), model.friction_work(x_start, x, v)


class WithContact:
    """What a system of vertices with a ``contact`` block inherits: its ``contact_form()``, the contact's energy, and
    a Hessian that holds the mesh contacts' coupling outside the fixed pattern."""

    contact = None

    def contact_form(self) -> ContactForm | None:
        return None if self.contact is None else ContactForm(self)

    def contact_energy(self, x: np.ndarray) -> float:
        return 0.0 if self.contact is None else self.contact.energy(x)

    def hessian(self, x, project_spd=False):
        """The pattern's matrix of ``hessian_data``, plus the mesh contacts' coupling outside the pattern."""
        matrix = self.pattern_matrix(self.hessian_data(x, project_spd))
        coupling = None if self.contact is None else self.contact.coupling_hessian(x, project_spd)
        return matrix if coupling is None else add_keeping_pattern(matrix, coupling)
