"""Contact handling within a Newton iteration: a 64 x 64 cloth with self-contact on, resting on a
sphere under IPC with friction, one backward Euler step (dt = 0.01 s) with projected Newton (IPC's solver: the raw
Hessian of a cloth bent over a sphere is indefinite, and the default Newton's raw steps are cut short by CCD).

Every contact evaluation is timed where it happens (systems/contact: the colliders' barrier, energy, gradient
and Hessian; ipctk's collision candidates, distances, barrier and CCD for self-contact; friction's lag, value,
gradient and Hessian; the line search's collision-free fraction); the rest of the step (springs, inertia, the
linear solves, the line search's arithmetic) is the step's wall time minus that. Target: contact <= 2x the rest.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from simrun.integrators import INTEGRATORS, State
from simrun.solvers import solver_params
from simrun.systems import ClothParams
from simrun.systems.contact import friction, mesh_contact, model

RESOLUTION = 64
DHAT = 1.0e-3  # m
RADIUS = 1.0  # m: the cloth (1 m square) rests on the top of this sphere
DT = 0.01  # s

# what is timed as contact, by part: (owner, method names)
CONTACT_PARTS = {
    "colliders (barrier)": (model.ContactModel, ("point_terms",)),
    "self-contact (ipctk: candidates, barrier)": (mesh_contact.MeshContact, ("barrier_energy", "barrier_gradient",
                                                                             "barrier_hessian")),
    "CCD (collision-free step)": (model.ContactModel, ("max_step",)),
    "friction": (model.ContactModel, ("friction_lag",)),
    "friction terms": (friction.FrictionTerm, ("value", "gradient", "vertex_blocks", "point_matrix", "mesh_hessian")),
}


class _Clock:
    """Inclusive wall time of the wrapped methods, per part; a call inside another timed call is not counted
    twice (the outermost timed call holds the clock)."""

    def __init__(self):
        self.seconds = dict.fromkeys(CONTACT_PARTS, 0.0)
        self.depth = 0
        self.saved = []

    def __enter__(self):
        for part, (owner, names) in CONTACT_PARTS.items():
            for name in names:
                original = getattr(owner, name)
                self.saved.append((owner, name, original))
                setattr(owner, name, self._timed(part, original))
        return self

    def __exit__(self, *exc):
        for owner, name, original in reversed(self.saved):
            setattr(owner, name, original)

    def _timed(self, part, function):
        @functools.wraps(function)
        def timed(*args, **kwargs):
            if self.depth:
                return function(*args, **kwargs)
            self.depth += 1
            began = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds[part] += time.perf_counter() - began
                self.depth -= 1
        return timed


def _resting_cloth():
    """(system, x): the cloth with IPC against the sphere, self-contact and friction; x its vertices laid on the
    sphere's top at dhat/2 (every vertex within the barrier's reach)."""
    params = ClothParams(resolution=(RESOLUTION, RESOLUTION), size=(1.0, 1.0), mass=1.0, pinned=[], damping=0.0,
                         contact={"method": "ipc", "dhat": DHAT, "self": True, "friction": {"mu": 0.3, "epsv": 1e-3},
                                  "colliders": [{"shape": "sphere", "center": [0.5, 0.5, -RADIUS - 0.5 * DHAT],
                                                 "radius": RADIUS}]})
    system = params.build()
    positions = system.x0.reshape(-1, 3).copy()
    planar = np.square(positions[:, 0] - 0.5) + np.square(positions[:, 1] - 0.5)
    center = np.array([0.5, 0.5, -RADIUS - 0.5 * DHAT])
    positions[:, 2] = center[2] + np.sqrt(RADIUS ** 2 - planar) + 0.5 * DHAT
    return system, positions.ravel()


def rows() -> list[tuple[str, float, str, str]]:
    system, x = _resting_cloth()
    v = np.zeros_like(x)
    system.contact_form().begin_run(DT, x)
    system.contact_form().begin_step(0.0, DT, x)
    solver = solver_params(type="projected_newton", tolerance=1e-6, max_iterations=100).build()
    with _Clock() as clock:
        began = time.perf_counter()
        _, stats = INTEGRATORS["backward_euler"]().step(system, State(0.0, x, v), DT, solver)
        total = time.perf_counter() - began
    contact = sum(clock.seconds.values())
    rest = total - contact
    split = ", ".join(f"{part} {1e3 * seconds / max(stats.iterations, 1):.0f}" for part, seconds in clock.seconds.items())
    active = system.contact.active_count(x)
    return [(f"cloth {RESOLUTION}x{RESOLUTION} on a sphere, IPC + self + friction: contact / rest of Newton",
             contact / rest, "<= 2",
             f"{stats.iterations} iterations, {active} contacts; per iteration: contact {1e3 * contact / max(stats.iterations, 1):.0f} ms "
             f"({split} ms), rest {1e3 * rest / max(stats.iterations, 1):.0f} ms")]
