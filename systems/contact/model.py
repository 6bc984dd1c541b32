"""Contact of a mass-spring model: colliders given as signed distance fields (penalty or IPC barrier), obstacle
meshes and self-contact (IPC through ipctk, mesh_contact.py), and lagged smoothed Coulomb friction.

Potentials (added to the system's P, so every incremental-potential method gets them through its problem):
- penalty, per vertex i and collider c with signed distance phi = phi_c(x_i) (m):
      P = k_c/2 min(phi, 0)^2,   f = -k_c min(phi, 0) grad phi,   H = k_c (n n^T + phi Hess phi)   (phi < 0),
  and contact damping f = -k_d (v . n) n while phi < 0 (a damping matrix D = k_d n n^T, taken where D is);
- IPC (Li et al., "Incremental Potential Contact", SIGGRAPH 2020), the barrier on the distance, in the units of
  ipctk's physical barrier (``BarrierPotential(dhat, kappa, use_physical_barrier=True)``, so that one stiffness
  kappa serves the colliders and the meshes):
      P = kappa B(phi),  B(phi) = b(phi^2; dhat^2) / dhat^3,  b(s; s^) = -(s - s^)^2 ln(s / s^) for s < s^, else 0,
  which grows without bound as phi -> 0: a step that a line search cuts to the collision-free fraction
  (``max_step``) never crosses a surface.

Friction (IPC's lagged, smoothed Coulomb friction) is a dissipative potential of the method's velocity map
v(y) = (y - a)/b: with the normal force lambda and the tangent projector T = I - n n^T of each contact taken at
the step's start x_n (lagged), and w = T (y - a - b v_c) (v_c the collider's velocity),
      Psi(y) = sum mu lambda f0(|w|; epsv b),   -dPsi/dy = -mu lambda f1(|w|) w/|w|,
f0, f1 IPC's mollifier (f1 rises from 0 at rest to 1 at the sliding speed epsv): the Coulomb force opposing the
tangential velocity w/b, static below epsv. ``FrictionTerm`` is that potential for one step.
"""

from __future__ import annotations

import math

import numpy as np

from .friction import FrictionLag, FrictionTerm
from .pose import ColliderContact

# A line-search step goes at most this fraction short of the first time of impact along it: a point that heads
# straight for a collider keeps a tenth of its distance (IPC scales its CCD's time of impact the same way), so
# distances stay positive in floating point and the barrier finite.
CCD_MARGIN = 0.1


def barrier(distance: np.ndarray, dhat: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B, dB/dphi, d^2B/dphi^2) of the physical IPC barrier at distances 0 < phi < dhat (m), vectorised:
    B = b(s; s^)/dhat^3 with s = phi^2, s^ = dhat^2, b = -(s - s^)^2 ln(s/s^) (ipctk's ClampedLogBarrier on squared
    distances); B is in m, so kappa B is an energy for kappa in N."""
    s = np.square(distance)
    s_hat = dhat * dhat
    r = s - s_hat
    log = np.log(s / s_hat)
    value = -np.square(r) * log
    first = -2.0 * r * log - np.square(r) / s
    second = -2.0 * log - 4.0 * r / s + np.square(r / s)
    scale = 1.0 / (dhat * dhat * dhat)
    return scale * value, scale * 2.0 * distance * first, scale * (4.0 * s * second + 2.0 * first)


class ContactOvertaken(RuntimeError):
    """A moving collider reached a vertex within one step, so that no start of the step is collision-free."""


class ContactModel:
    """All contact of one mass-spring model; see the module docstring.

    Parameters: method "penalty" | "ipc"; colliders: ColliderContact list; dim, vertex_count; dhat (m); stiffness:
    the IPC barrier stiffness kappa (N), or None for IPC's estimate and update (``begin_step``); damping: the
    penalty's k_d (N s/m); friction: (mu, epsv in m/s) or None; mesh: a MeshContact (obstacle meshes and
    self-contact, ipc) or None; masses: (n,) kg (the stiffness estimate uses their mean); friction_relags: how many
    times a step re-lags its friction at its solution and solves again (integrators/base.py solve_step)."""

    def __init__(self, *, method: str, colliders: list[ColliderContact], dim: int, vertex_count: int, dhat: float,
                 stiffness: float | None, damping: float, friction: tuple[float, float] | None, mesh=None,
                 masses: np.ndarray | None = None, friction_relags: int = 0):
        self.method = method
        self.colliders = tuple(colliders)
        self.dim = dim
        self.vertex_count = vertex_count
        self.dhat = dhat
        self.kappa = stiffness
        self.kappa_auto = method == "ipc" and stiffness is None
        self.max_kappa = math.inf
        self.damping = damping
        self.friction = friction
        self.friction_relags = friction_relags  # solves more per step, friction lagged at the last solution
        self.mesh = mesh
        self.masses = masses
        self.time = 0.0  # the colliders are where they are at this time (s): the end of the step being solved
        self._previous_distance = math.inf
        self._step = 0.0  # dt of the step being solved (s)
        self._lag: tuple[np.ndarray, FrictionLag, tuple] | None = None  # (x, lag, (time, kappa))
        if self.kappa_auto:
            self.kappa = 1.0  # until the first step's estimate

    # -- what the system and the runner ask ------------------------------------------------------
    @property
    def requires_step_filter(self) -> bool:
        """IPC: every step a solver takes must be cut to its collision-free fraction (``max_step``)."""
        return self.method == "ipc"

    @property
    def couples_vertices(self) -> bool:
        """Mesh contact couples vertices that no spring joins: its Hessian lies outside the springs' pattern."""
        return self.mesh is not None

    @property
    def is_damped(self) -> bool:
        return self.damping > 0.0


    @property
    def step_start_time(self) -> float:
        """t_n (s), where the colliders stood at the start of the step being solved."""
        return self.time - self._step

    # -- per point: the colliders (penalty and IPC) -------------------------------------------------
    def _reach(self) -> float:
        return 0.0 if self.method == "penalty" else self.dhat

    def point_terms(self, positions: np.ndarray, gradient: np.ndarray | None = None, hessian: np.ndarray | None = None,
                    project_spd=False) -> float:
        """The collider potentials at the points ``positions`` (k, d): returns their energy (J) and adds their
        gradient (N) to ``gradient`` (k, d) and, when given, their Hessian blocks (N/m) to ``hessian`` (k, d, d), in
        place: each point on its own (collider contact is separable per vertex). inf where a point is on or inside
        a collider with IPC."""
        energy = 0.0
        time = self.time
        for contact in self.colliders:
            if self.method == "penalty":
                energy += self._penalty(contact, positions, time, gradient, hessian, project_spd)
                continue
            distance = contact.signed_distance(positions, time)
            near = np.flatnonzero(distance < self.dhat)
            if not near.size:
                continue
            if np.any(distance[near] <= 0.0):
                return math.inf
            phi, normal, _ = contact.derivatives(positions[near], time)
            value, first, second = barrier(phi, self.dhat)
            energy += self.kappa * float(value.sum())
            if gradient is not None:
                gradient[near] += (self.kappa * first)[:, None] * normal
            if hessian is not None:
                outer = normal[:, :, None] * normal[:, None, :]
                # kappa (B'' n n^T + B' Hess phi): B'' > 0 always; B' < 0, so the curvature term is negative where
                # the collider is convex (a clamp drops it, abs mirrors it)
                bend = contact.scaled_hessian(positions[near], self.kappa * first, project_spd, time)
                hessian[near] += (self.kappa * second)[:, None, None] * outer + bend
        return energy

    def _penalty(self, contact: ColliderContact, positions, time, gradient, hessian, project_spd) -> float:
        """k/2 min(phi, 0)^2 at all points, with the same operations for every vertex (touching or not), as the
        penalty of the ground and the sphere always was computed (the cloth's recorded results depend on it)."""
        stiffness = contact.stiffness
        phi, normal = contact.distance_and_normal(positions, time)
        depth = np.maximum(-phi, 0.0)
        if gradient is not None:
            gradient -= stiffness * depth[:, None] * normal
        if hessian is not None:
            touching = depth > 0
            if touching.any():
                n = normal[touching]
                outer = n[:, :, None] * n[:, None, :]
                bend = contact.scaled_hessian(positions[touching], -depth[touching], project_spd, time)
                hessian[touching] += stiffness * (outer + bend)
        return 0.5 * stiffness * float(np.dot(depth, depth))

    def point_energy_changes(self, positions: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The change (k,) (J) of the collider potentials when each point moves by steps (k, d) on its own; the
        penalty's as k/2 (d' - d)(d' + d), without the cancellation of a difference of energies."""
        changes = np.zeros(positions.shape[0])
        moved = positions + steps
        for contact in self.colliders:
            before = contact.signed_distance(positions, self.time)
            after = contact.signed_distance(moved, self.time)
            if self.method == "penalty":
                depth, moved_depth = np.maximum(-before, 0.0), np.maximum(-after, 0.0)
                changes += 0.5 * contact.stiffness * (moved_depth - depth) * (moved_depth + depth)
            else:
                changes += self.kappa * (self._barrier_values(after) - self._barrier_values(before))
        return changes

    def _barrier_values(self, phi: np.ndarray) -> np.ndarray:
        values = np.where(phi <= 0.0, math.inf, 0.0)
        near = (phi > 0.0) & (phi < self.dhat)
        values[near] = barrier(phi[near], self.dhat)[0]
        return values

    # -- the whole model ---------------------------------------------------------------------------
    def energy(self, x: np.ndarray) -> float:
        energy = 0.0
        if self.colliders:
            energy = self.point_terms(x.reshape(-1, self.dim))
        if self.mesh is not None:
            energy += self.kappa * self.mesh.barrier_energy(x)
        return energy

    def add_gradient(self, gradient: np.ndarray, x: np.ndarray) -> None:
        """Adds the contact forces' negative, dP/dx (N), to ``gradient`` (n d,) in place."""
        if self.colliders:
            self.point_terms(x.reshape(-1, self.dim), gradient.reshape(-1, self.dim))
        if self.mesh is not None:
            gradient += self.kappa * self.mesh.barrier_gradient(x)

    def add_vertex_hessian(self, blocks: np.ndarray, x: np.ndarray, project_spd=False) -> None:
        """Adds the colliders' Hessian blocks per vertex (N/m) to ``blocks`` (n, d, d) in place."""
        if self.colliders:
            self.point_terms(x.reshape(-1, self.dim), None, blocks, project_spd)

    def coupling_hessian(self, x: np.ndarray, project_spd=False):
        """The mesh contacts' Hessian (CSR, n d x n d, N/m), which couples vertices no spring joins; None without."""
        if self.mesh is None:
            return None
        return self.kappa * self.mesh.barrier_hessian(x, project_spd)

    def damping_blocks(self, x: np.ndarray) -> np.ndarray | None:
        """Contact damping D = k_d n n^T per penetrating vertex (n, d, d) (N s/m), or None without it."""
        if not self.damping > 0.0:
            return None
        positions = x.reshape(-1, self.dim)
        blocks = np.zeros(positions.shape + (self.dim,))
        for contact in self.colliders:
            phi, normal = contact.distance_and_normal(positions, self.time)
            touching = phi < 0.0
            n = normal[touching]
            blocks[touching] += self.damping * n[:, :, None] * n[:, None, :]
        return blocks

    # -- what the runner records -------------------------------------------------------------------
    def minimum_distance(self, x: np.ndarray, time: float | None = None) -> float:
        """The smallest signed distance (m) of a vertex to a collider (where the colliders are at ``time``, by default
        the end of the step), and of the mesh pairs within dhat (their distance is unsigned: IPC keeps them apart);
        inf when nothing is near."""
        smallest = math.inf
        positions = x.reshape(-1, self.dim)
        for contact in self.colliders:
            phi = contact.signed_distance(positions, self.time if time is None else time)
            smallest = min(smallest, float(np.min(phi)))
        if self.mesh is not None:
            smallest = min(smallest, self.mesh.minimum_distance(x))
        return smallest

    def active_count(self, x: np.ndarray) -> int:
        """Contacts acting at x: vertex-collider pairs inside the reach (penetrating, for the penalty; within dhat,
        for IPC) and mesh pairs within dhat."""
        positions = x.reshape(-1, self.dim)
        reach = self._reach()
        count = sum(int(np.count_nonzero(contact.signed_distance(positions, self.time) < reach))
                    for contact in self.colliders)
        if self.mesh is not None:
            count += self.mesh.active_count(x)
        return count

    def intersection(self, x: np.ndarray) -> str | None:
        """What already intersects at x, in one line, or None: a vertex on or inside a collider (IPC needs a
        positive distance), or mesh elements that cross or touch."""
        positions = x.reshape(-1, self.dim)
        if self.method == "ipc":
            for number, contact in enumerate(self.colliders):
                phi = contact.signed_distance(positions, self.time)
                inside = np.flatnonzero(phi <= 0.0)
                if inside.size:
                    first = int(inside[np.argmin(phi[inside])])
                    return (f"vertex {first} starts {'inside' if phi[first] < 0 else 'on'} collider {number} "
                            f"({contact.collider.shape}; signed distance {phi[first]:.3g} m): IPC needs every distance > 0")
        if self.mesh is not None:
            return self.mesh.initial_check(x)
        return None

    # -- IPC: the line search's filter and the stiffness ---------------------------------------------
    def max_step(self, x: np.ndarray, direction: np.ndarray) -> float:
        """The largest fraction a in (0, 1] of the step x -> x + direction that keeps every distance positive:
        each vertex stops short of a collider at CCD_MARGIN of its distance at x (exact times of impact for the
        plane and the sphere, conservative advancement for the others), and ipctk's CCD for the meshes."""
        fraction = 1.0
        if self.colliders:
            fraction = float(self.point_step_fractions(x.reshape(-1, self.dim), direction.reshape(-1, self.dim)).min())
        if self.mesh is not None and fraction > 0.0:
            fraction = min(fraction, self.mesh.collision_free_step(x, x + fraction * direction) * fraction)
        return max(fraction, 0.0)

    def point_step_fractions(self, positions: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The largest fraction (k,) of each point's move positions (k, d) -> positions + steps that stops it
        CCD_MARGIN of the way short of the first collider it would reach (``max_step``'s filter, each point on its
        own: what vertex block descent cuts a vertex's step to); 1 where it reaches none."""
        fractions = np.ones(len(positions))
        length = np.sqrt(np.einsum("ij,ij->i", steps, steps))
        for contact in self.colliders:
            phi = contact.signed_distance(positions, self.time)
            # a point moving less than its distance cannot reach the collider (phi is L-Lipschitz)
            reaching = np.flatnonzero(contact.collider.lipschitz * length >= phi)
            if not reaching.size:
                continue
            start = positions[reaching]
            impact = contact.time_of_impact(start, start + steps[reaching], self.time)
            hit = impact <= 1.0
            fractions[reaching[hit]] = np.minimum(fractions[reaching[hit]], (1.0 - CCD_MARGIN) * impact[hit])
        return fractions

    def carried(self, x: np.ndarray) -> np.ndarray:
        """The step's start x_n (flat, m) as IPC's solvers may begin from it: each vertex within reach of a moving
        collider at t_n (the first such collider: moves are not summed) moved with it over the step, so that at
        t_n + dt it keeps the distance it had at t_n, where x_n itself could lie inside the collider's new place. A
        carried vertex that would end on or inside another collider stays; the moves are cut to ipctk's collision-free
        fraction for the meshes. ContactOvertaken where the start still lies on or inside a collider at t_n + dt: a
        step too long for that collider's speed. A new array where anything moved; the filters (pins, sliding) are
        the caller's to apply to the move."""
        moving = [contact for contact in self.colliders if contact.moves]
        if self.method != "ipc" or not moving or not self._step:
            return x
        positions = x.reshape(-1, self.dim)
        shift = np.zeros_like(positions)
        claimed = np.zeros(positions.shape[0], dtype=bool)
        start = self.step_start_time
        for contact in moving:
            travel = contact.reach_speed * self._step
            phi = contact.signed_distance(positions, start)
            near = np.flatnonzero((phi < self.dhat + contact.collider.lipschitz * travel) & ~claimed)
            shift[near] = contact.carry(positions[near], start, self.time) - positions[near]
            claimed[near] = True
        if claimed.any():
            moved = positions + shift
            for contact in self.colliders:  # a carried vertex must not land on or in another collider
                blocked = claimed & (contact.signed_distance(moved, self.time) <= 0.0)
                shift[blocked] = 0.0
                claimed &= ~blocked
        carried = x + shift.ravel() if claimed.any() else x
        if carried is not x and self.mesh is not None:
            carried = x + self.mesh.collision_free_step(x, carried) * (carried - x)
        for number, contact in enumerate(self.colliders):
            phi = contact.signed_distance(carried.reshape(-1, self.dim), self.time)
            if np.any(phi <= 0.0):
                vertex = int(np.argmin(phi))
                raise ContactOvertaken(
                    f"collider {number} ({contact.collider.shape}) overtook vertex {vertex} within the step from "
                    f"t = {self.step_start_time:.6g} s (signed distance {phi[vertex]:.3g} m at its end): a smaller dt")
        return carried

    def begin_step(self, t: float, dt: float, x: np.ndarray, elastic_gradient) -> None:
        """Before the step from t (s) of size dt (s) at positions x: the colliders move to t + dt, and IPC's
        barrier stiffness (when auto) is estimated at the first step (ipctk.initial_barrier_stiffness, from the
        gradient of the rest of the energy, ``elastic_gradient(x)``) and raised while the distances shrink below
        1e-9 of the scene's size (ipctk.update_barrier_stiffness). ipctk states both in the IPC paper's units,
        where the barrier is not multiplied by dt^2; our barrier is part of P, which the methods scale by c dt^2."""
        self.time = t + dt
        self._step = dt
        if not self.kappa_auto:
            return
        import ipctk  # only IPC runs need it

        if not math.isfinite(self.max_kappa):
            self.begin_run(dt, x, elastic_gradient)
        scale = self._ipc_units(dt)
        distance = self.minimum_distance(x, t)  # x is where the step starts: the colliders as they were then
        # ipctk compares squared distances (as IPC does), against 1e-9 of the scene's diagonal
        self.kappa = ipctk.update_barrier_stiffness(self._previous_distance ** 2, distance ** 2, self.max_kappa / scale,
                                                    self.kappa / scale, self._scene_diagonal(x)) * scale
        self._previous_distance = distance

    def _ipc_units(self, dt: float) -> float:
        """kappa here over kappa in ipctk's stiffness functions: those state it in the IPC paper's energy,
        1/2 |x - x~|_M^2 + dt^2 Psi + kappa b(d^2; dhat^2), where our barrier, kappa b / dhat^3, is part of P
        and so multiplied by dt^2 (the methods' c dt^2: 1 for backward Euler)."""
        return self.dhat ** 3 / (dt * dt)

    def begin_run(self, dt: float, x: np.ndarray, elastic_gradient) -> None:
        """Before a run of steps dt (s) from x: IPC's barrier stiffness, when auto, from ipctk's estimate
        (initial_barrier_stiffness: the stiffness that balances the barrier's gradient against the rest of the
        energy's, at least a floor set by the masses and the scene's size), so that the energies recorded at the
        start already hold the stiffness the steps use."""
        if not self.kappa_auto:
            return
        import ipctk  # only IPC runs need it

        h2 = dt * dt
        self.kappa = 1.0
        barrier_gradient = np.zeros(x.size)
        self.add_gradient(barrier_gradient, x)
        average_mass = float(np.mean(self.masses)) if self.masses is not None else 1.0
        # both gradients in the paper's energy: dt^2 grad P, and the barrier b = dhat^3 B
        kappa, max_kappa = ipctk.initial_barrier_stiffness(
            self._scene_diagonal(x), ipctk.ClampedLogBarrier(), self.dhat, average_mass, h2 * elastic_gradient(x),
            self.dhat ** 3 * barrier_gradient)
        scale = self._ipc_units(dt)
        self.kappa, self.max_kappa = kappa * scale, max_kappa * scale
        self._previous_distance = self.minimum_distance(x)

    def _scene_diagonal(self, x: np.ndarray) -> float:
        positions = x.reshape(-1, self.dim)
        lower, upper = positions.min(axis=0), positions.max(axis=0)
        for contact in self.colliders:
            box = contact.bounding_box(self.time)
            if box is not None:
                lower, upper = np.minimum(lower, box[0]), np.maximum(upper, box[1])
        return float(np.linalg.norm(upper - lower))

    # -- friction ----------------------------------------------------------------------------------
    def friction_lag(self, x: np.ndarray, time: float | None = None) -> FrictionLag | None:
        """The normal forces and tangent bases at x with the colliders where they are at ``time`` (s; default the
        start of the step being solved, which x is); the last one asked is kept (keyed by x, time and kappa)."""
        if self.friction is None:
            return None
        time = self.step_start_time if time is None else time
        key = (time, self.kappa)
        if self._lag is not None and self._lag[2] == key and np.array_equal(self._lag[0], x):
            return self._lag[1]
        positions = x.reshape(-1, self.dim)
        vertices, forces, normals, velocities = [], [], [], []
        for contact in self.colliders:
            phi = contact.signed_distance(positions, time)
            near = np.flatnonzero((phi < 0.0) if self.method == "penalty" else (phi < self.dhat) & (phi > 0.0))
            if not near.size:
                continue
            phi, normal, _ = contact.derivatives(positions[near], time)
            if self.method == "penalty":
                force = contact.stiffness * np.maximum(-phi, 0.0)
            else:
                force = -self.kappa * barrier(phi, self.dhat)[1]
            vertices.append(near)
            forces.append(force)
            normals.append(normal)
            velocities.append(contact.velocity_at(positions[near], time))
        mesh_lag = None
        if self.mesh is not None:
            mesh_lag = self.mesh.lag_friction(x, self.kappa, self.friction[0])
        empty = np.zeros((0, self.dim))
        lag = FrictionLag(
            vertices=np.concatenate(vertices) if vertices else np.zeros(0, dtype=np.intp),
            normal_force=np.concatenate(forces) if forces else np.zeros(0),
            normals=np.concatenate(normals) if normals else empty,
            velocities=np.concatenate(velocities) if velocities else empty, mesh=mesh_lag)
        self._lag = (x.copy(), lag, key)
        return lag

    def friction_term(self, x_start: np.ndarray, velocity_origin: np.ndarray, velocity_divisor: float,
                      time: float | None = None):
        """The friction potential of one step (``FrictionTerm``), lagged at x_start (the colliders at ``time``: by
        default the step's start), for the velocity map v(y) = (y - velocity_origin)/velocity_divisor; None without
        friction or without contacts at x_start."""
        lag = self.friction_lag(x_start, time)
        if lag is None or (not lag.vertices.size and (lag.mesh is None or not self.mesh.friction_count(lag.mesh))):
            return None
        return FrictionTerm(self.friction, self.dim, self.mesh, lag, velocity_origin, velocity_divisor)

    def friction_work(self, x_start: np.ndarray, x_end: np.ndarray, v_end: np.ndarray) -> float:
        """The energy (J) friction took out of the model in the step x_start -> x_end that ended with velocity v_end:
        -f . (x_end - x_start), f the step's (lagged) friction force at v_end, the method's own v(y) = (y - a)/b
        (backward Euler, BDF2, Newmark): the work of the force the step applied along the step it took, what the
        energy budget adds as dissipated by friction."""
        if self.friction is None:
            return 0.0
        # the lag the step's last solve used: x_start's, or its solution's where friction is re-lagged
        if self.friction_relags and self._lag is not None:
            term = self.friction_term(self._lag[0], np.zeros_like(v_end), 1.0, self._lag[2][0])
        else:
            term = self.friction_term(x_start, np.zeros_like(v_end), 1.0)
        if term is None:
            return 0.0
        return float(term.gradient(v_end) @ (x_end - x_start))
