"""NVIDIA Newton's particle solvers on simrun's systems, stepped by Newton itself on Warp's CPU device:
``{type: newton, solver: semi_implicit | xpbd | vbd, iterations: N}`` (the extra ``engines``: pip install
'.[engines]').

A step writes the state into a Newton ``State`` (float32: Newton's particles are Warp ``vec3`` of float32), calls the
solver's ``step(state_in, state_out, control, None, dt)`` once and reads the state back; simrun's loop records it,
so every energy and error is simrun's own system's, the same for every engine. A probe of the same step on unit
states of the test spring gives the amplification matrix (runner/analysis/oscillator.py), as for simrun's own methods.

The translation, from the scenes of integrators/engine_scenes.py (anything else is refused in one line):
- **Springs between vertices:** a particle per vertex (pinned vertices massless: Newton's kinematic particles) and
  a Newton spring per spring: ``ke`` k, ``kd`` beta on dL/dt (Newton's spring damper is along the spring, simrun's
  ``spring`` damping model), the rest length l0 set after ``finalize`` (Newton's builder would take the initial
  distance); anchored springs end at a massless particle at the anchor. A 2-D system lies in the z = 0 plane.
  Newton's spring has no direction at zero length: zero-rest-length springs are refused.
- **Uncoupled springs:** dof i is a particle on the x axis at q_i, tied by a spring of rest length L to a massless
  particle at -L: the force is -k_i q_i while q stays above -L. L is set before every step to ten times the farthest
  the step can move the particle (its reach |q| + h |v| + h^2 (k/m) |q|), so the spring is linear over the whole
  step, and the float32 rounding of (q + L) - L is at most ten float32 ulps of that reach.
Newton's particles have no contact with each other here (radius 0, no hash grid), and its velocity clamp
(``particle_max_velocity``, 1e5 m/s by default) is lifted: a clamp would hide a blow-up.

What Newton's solvers are (newton/_src/solvers; Newton 1.8):
- ``semi_implicit``: symplectic Euler, v' = v + h M^-1 f(x, v), x' = x + h v', every force (spring damper included)
  at the start of the step.
- ``xpbd``: extended position-based dynamics. Predict x* = x + h (v + h g), then ``iterations`` Jacobi sweeps
  over the springs as compliant distance constraints (compliance 1/k, damping gamma = kd / (k h)), the corrections
  summed per particle; v' = (x' - x) / h. On one spring: backward Euler.
- ``vbd``: vertex block descent. The same prediction, then ``iterations`` Gauss-Seidel sweeps over graph-coloured
  vertices, each a Newton step on the vertex's incremental potential (its springs' full Hessian, the damper
  kd/h (L - L_start) along each spring implicit); v' = (x' - x) / h. At convergence: backward Euler.
Newton's own style3d solver steps only its anisotropic cloth (triangles and bending, no springs), which no simrun system
is: it is not offered.
"""

from __future__ import annotations

import importlib.util
import os
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from simrun.systems.compliant import ANCHORED

from .base import State
from .engine import EngineIntegrator
from .engine_scenes import TetSolid, UncoupledSprings, VertexSprings, read_scene

EXTRA = "pip install '.[engines]' (newton, warp-lang)"
# Newton's solver class of each config name
NEWTON_SOLVERS = {"semi_implicit": "SolverSemiImplicit", "xpbd": "SolverXPBD", "vbd": "SolverVBD"}
# the energy each iterative solver gives Newton's tetrahedra (k_mu, k_lambda), where it is not simrun's stable
# neo-Hookean (read from newton/_src/solvers/{xpbd/kernels.py, vbd/particle_vbd_kernels.py})
OTHER_TET_ENERGIES = {
    "xpbd": "two compliant constraints, k_mu/2 (I_C - 3)^2 + k_lambda/2 (J - 1)^2",
    "vbd": "Smith et al.'s energy without its log term, mu/2 (I_C - 3) + (lambda + mu)/2 (J - alpha)^2",
}
# how far the anchor of an uncoupled spring sits, in units of the farthest the step can move its particle
ANCHOR_MARGIN = 10.0
# Newton's velocity clamp, lifted (float32's range is 3.4e38)
NO_VELOCITY_CLAMP = 1e30


def newton_missing() -> str | None:
    """Why Newton cannot be used here (the extra is not installed), or None."""
    found = all(importlib.util.find_spec(name) is not None for name in ("newton", "warp"))
    return None if found else f"needs NVIDIA Newton on Warp: {EXTRA}"


def _warp():
    """Warp, initialised with its log at errors only: its compile lines would fill simrun's output, and so would the
    line its native library writes to stderr when no CUDA driver is found (this engine runs on the CPU device)."""
    import warp

    warp.config.log_level = warp.LOG_ERROR
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            warp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return warp


class Stepper:
    """A translated system's Newton model, solver and states at one step size: a step writes the state into Newton's
    state, calls the solver's step and reads the state back."""

    def __init__(self, scene: UncoupledSprings | VertexSprings | TetSolid, integrator: "Newton", dt: float):
        _warp()
        import newton

        self.dt = dt
        self.vertex_shape = None  # (vertices, coordinates) of a scene of vertices; None for uncoupled springs
        self.frequency_squared = None  # k_i / m_i of uncoupled springs, whose anchors move with every step
        if isinstance(scene, UncoupledSprings):
            builder = self._uncoupled(newton, scene)
        elif isinstance(scene, TetSolid):
            builder = self._tetrahedra(newton, scene)
        else:
            builder = self._vertices(newton, scene)
        if integrator.solver == "vbd":
            builder.color()  # VBD's Gauss-Seidel sweeps go colour by colour
        self.model = builder.finalize(device="cpu")
        self.model.particle_grid = None
        self.model.particle_max_velocity = NO_VELOCITY_CLAMP
        if self.rest_length.size:
            self.model.spring_rest_length.assign(self.rest_length.astype(np.float32))
        options = {} if integrator.solver == "semi_implicit" else {"iterations": integrator.iterations}
        self.solver = getattr(newton.solvers, NEWTON_SOLVERS[integrator.solver])(self.model, **options)
        self.state_in, self.state_out = self.model.state(), self.model.state()
        self.control = self.model.control()

    def _uncoupled(self, newton, scene: UncoupledSprings):
        builder = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        count = scene.stiffness.size
        for k, d, m in zip(scene.stiffness, scene.damping, scene.mass):
            moving = builder.add_particle((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), float(m), radius=0.0)
            anchor = builder.add_particle((-1.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, radius=0.0)
            builder.add_spring(moving, anchor, float(k), float(d), 0.0)
        self.positions = np.zeros((2 * count, 3))
        self.flat = 6 * np.arange(count)  # particle 2 i, coordinate x
        self.dofs = np.arange(count)
        self.rest_length = np.ones(count)
        self.frequency_squared = scene.stiffness / scene.mass
        self.anchors = 2 * np.arange(count) + 1
        return builder

    def _vertices(self, newton, scene: VertexSprings):
        builder = newton.ModelBuilder(gravity=tuple(float(g) for g in scene.gravity))
        for position, mass, pinned in zip(scene.rest, scene.mass, scene.pinned):
            builder.add_particle(tuple(position), (0.0, 0.0, 0.0), 0.0 if pinned else float(mass), radius=0.0)
        positions = [scene.rest]
        for spring, (first, second) in enumerate(zip(scene.first, scene.second)):
            if second == ANCHORED:
                second = builder.add_particle(tuple(scene.anchor[spring]), (0.0, 0.0, 0.0), 0.0, radius=0.0)
                positions.append(scene.anchor[spring][None])
            builder.add_spring(int(first), int(second), float(scene.stiffness[spring]), float(scene.damping[spring]), 0.0)
        self.positions = np.concatenate(positions)
        self._vertex_dofs(scene)
        self.rest_length = scene.rest_length
        return builder

    def _vertex_dofs(self, scene: VertexSprings | TetSolid) -> None:
        vertex, coordinate = np.divmod(scene.free_dofs, scene.dim)
        self.flat = 3 * vertex + coordinate
        self.dofs = scene.free_dofs
        self.vertex_shape = (scene.rest.shape[0], scene.dim)

    def _tetrahedra(self, newton, scene: TetSolid):
        builder = newton.ModelBuilder(gravity=tuple(float(g) for g in scene.gravity))
        for position, mass, pinned in zip(scene.rest, scene.mass, scene.pinned):
            builder.add_particle(tuple(position), (0.0, 0.0, 0.0), 0.0 if pinned else float(mass), radius=0.0)
        for element, mu, lam in zip(scene.elements, scene.mu, scene.lam):
            builder.add_tetrahedron(*(int(vertex) for vertex in element), k_mu=float(mu), k_lambda=float(lam),
                                    k_damp=0.0)
        self.positions = scene.rest.copy()
        self._vertex_dofs(scene)
        self.rest_length = np.zeros(0)
        return builder

    def step(self, state: State) -> State:
        positions, velocities = self.positions.copy(), np.zeros_like(self.positions)
        if self.vertex_shape is not None:  # every vertex where the state has it, pinned ones too (at rest: no velocity)
            count, dim = self.vertex_shape
            positions[:count, :dim] = state.x.reshape(count, dim)
        else:
            positions.ravel()[self.flat] = state.x[self.dofs]
        velocities.ravel()[self.flat] = state.v[self.dofs]
        if self.frequency_squared is not None:
            q, v = state.x[self.dofs], state.v[self.dofs]
            reach = np.abs(q) + self.dt * np.abs(v) + self.dt ** 2 * self.frequency_squared * np.abs(q)
            length = np.where(reach > 0.0, ANCHOR_MARGIN * reach, 1.0)
            positions[self.anchors, 0] = -length
            self.model.spring_rest_length.assign(length.astype(np.float32))
        self.state_in.particle_q.assign(positions.astype(np.float32))
        self.state_in.particle_qd.assign(velocities.astype(np.float32))
        self.state_in.clear_forces()
        self.solver.step(self.state_in, self.state_out, self.control, None, self.dt)
        x, v = state.x.copy(), state.v.copy()
        x[self.dofs] = self.state_out.particle_q.numpy().ravel()[self.flat]
        v[self.dofs] = self.state_out.particle_qd.numpy().ravel()[self.flat]
        return State(state.t + self.dt, x, v)


def translate(system) -> UncoupledSprings | VertexSprings | TetSolid | str:
    """The scene of ``system`` that Newton's particles express, or why there is none (in one line)."""
    scene = read_scene(system, "Newton", "Newton's particle contacts are another model than simrun's penalty or IPC")
    if isinstance(scene, VertexSprings) and np.any(scene.rest_length == 0.0):
        return ("Newton's translation cannot express zero-rest-length springs (Newton's spring has no direction at "
                "zero length)")
    return scene


class Newton(EngineIntegrator):
    """NVIDIA Newton's particle solver, stepping a Newton model translated from the system (module docstring)."""

    name: ClassVar[str] = "newton"
    order: ClassVar[int] = 1
    unit_roundoff: ClassVar[float] = 2.0 ** -24  # Newton's particles are float32
    summary: ClassVar[str] = ("NVIDIA Newton's particle solvers (semi_implicit, xpbd, vbd), stepped by Newton on Warp's "
                              "CPU device in float32 on the system translated to its model (extra: engines)")

    solver: Literal[tuple(NEWTON_SOLVERS)] = Field(  # type: ignore[valid-type]
        "semi_implicit", description="semi_implicit (symplectic Euler) | xpbd (Jacobi XPBD) | vbd (vertex block "
                                     "descent)")
    iterations: int = Field(10, ge=1, description="the xpbd and vbd solvers' iterations per step (semi_implicit has "
                                                  "none)")

    @classmethod
    def missing(cls) -> str | None:
        """Why this engine cannot run here (its extra is not installed), or None."""
        return newton_missing()

    def engine_refusal(self, system) -> str | None:
        if self.solver == "semi_implicit" and "iterations" in self.model_fields_set:
            return "iterations: Newton's semi_implicit solver takes none (it is symplectic Euler)"
        scene = translate(system)
        if isinstance(scene, TetSolid) and self.solver in OTHER_TET_ENERGIES:
            return (f"Newton's {self.solver} solver steps its tetrahedra as {OTHER_TET_ENERGIES[self.solver]}, another "
                    "energy than simrun's stable_neo_hookean (its semi_implicit solver steps simrun's)")
        return scene if isinstance(scene, str) else None

    def unused_parameters(self) -> frozenset[str]:
        return frozenset({"iterations"}) if self.solver == "semi_implicit" else frozenset()

    def engine_description(self) -> str:
        warp = _warp()
        import newton

        return f"Newton {newton.__version__} on Warp {warp.__version__}, float32, CPU"

    def build_stepper(self, system, dt: float) -> Stepper:
        scene = translate(system)
        if isinstance(scene, str):
            raise TypeError(scene)
        return Stepper(scene, self, dt)
