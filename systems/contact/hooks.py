"""What a system with a ``contact`` (a ContactModel or None) answers the runner, the problems and the line search:
written once for every system of vertices that takes a contact block (mass_spring, fem).

The system provides ``contact``, ``fixed_dofs``, ``sliding``, ``_elastic_gradient(x)`` (dP/dx without contact,
what IPC's stiffness estimate balances the barrier against), and for its Hessian ``hessian_data`` (its elements' and
contact's vertex blocks in the fixed pattern) and ``_vertex_positions`` ((n, d, d): where each vertex block's entries
sit in the pattern's data array).
"""

from __future__ import annotations

import numpy as np

from ..patterns import add_keeping_pattern


class ContactHooks:
    contact = None

    @property
    def has_contact(self) -> bool:
        return self.contact is not None

    @property
    def has_friction(self) -> bool:
        return self.contact is not None and self.contact.friction is not None

    @property
    def contact_needs_step_filter(self) -> bool:
        """IPC's barrier: every step of a solve cut short of a collision (System.contact_needs_step_filter)."""
        return self.contact is not None and self.contact.requires_step_filter

    def vertex_step_fractions(self, x: np.ndarray, vertices: np.ndarray, steps: np.ndarray) -> np.ndarray | None:
        """IPC's step filter for each vertex moving alone by steps (k, d): the fraction (k,) of its step that stops
        short of the first collider it would reach (ContactModel.point_step_fractions); None without IPC
        (System.vertex_step_fractions). The mesh contacts couple vertices: vertex block descent refuses them."""
        if not self.contact_needs_step_filter:
            return None
        return self.contact.point_step_fractions(x.reshape(-1, self.dim)[vertices], steps)

    def contact_energy(self, x: np.ndarray) -> float:
        return 0.0 if self.contact is None else self.contact.energy(x)

    def hessian(self, x, project_spd=False):
        """The pattern's matrix of ``hessian_data``, plus the mesh contacts' coupling outside the pattern."""
        matrix = self.pattern_matrix(self.hessian_data(x, project_spd))
        coupling = self.off_pattern_hessian(x, project_spd)
        return matrix if coupling is None else add_keeping_pattern(matrix, coupling)

    def add_vertex_blocks(self, data: np.ndarray, vertices: np.ndarray, blocks: np.ndarray) -> None:
        """Adds blocks (k, d, d) at the vertices (k,) (repeats summed) into the pattern's data array, in place."""
        np.add.at(data, self._vertex_positions[vertices], blocks)

    def off_pattern_hessian(self, x, project_spd=False):
        """The Hessian of the mesh contacts (IPC through ipctk), which couples vertices that no element of the model
        joins and so lies outside ``hessian_pattern``; None without them (System.off_pattern_hessian)."""
        return None if self.contact is None else self.contact.coupling_hessian(x, project_spd)

    def contact_start(self, x: np.ndarray) -> np.ndarray:
        """x with the vertices near moving IPC colliders carried along over the step (ContactModel.carried), the
        move filtered as every solver step is (pins stay, sliding vertices stay on their planes and lines)."""
        if not self.contact_needs_step_filter:
            return x
        carried = self.contact.carried(x)
        if carried is x:
            return x
        move = carried - x
        if self.fixed_dofs.size:
            move[self.fixed_dofs] = 0.0
        if self.sliding is not None:
            self.sliding.apply(move)
        return x + move

    def begin_run(self, dt: float, x: np.ndarray) -> None:
        if self.contact is not None:
            self.contact.begin_run(dt, x, self._elastic_gradient)

    def begin_step(self, t: float, dt: float, x: np.ndarray) -> None:
        if self.contact is not None:
            self.contact.begin_step(t, dt, x, self._elastic_gradient)

    def friction_term(self, x_start: np.ndarray, velocity_origin: np.ndarray, velocity_divisor: float,
                      time: float | None = None):
        if self.contact is None:
            return None
        return self.contact.friction_term(x_start, velocity_origin, velocity_divisor, time)

    def contact_record(self, x_start: np.ndarray, x: np.ndarray, v: np.ndarray, dt: float) -> tuple[float, int, float]:
        """(smallest signed distance (m), active contacts, friction work (J)) of the step x_start -> (x, v)."""
        contact = self.contact
        return contact.minimum_distance(x), contact.active_count(x), contact.friction_work(x_start, x, v)
