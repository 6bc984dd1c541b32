"""MuJoCo's integrators on simrun's systems, stepped by MuJoCo itself: ``{type: mujoco, integrator: Euler | implicit |
implicitfast | RK4 | discrete}`` (the extra ``engines``: pip install '.[engines]').

A step hands the state to MuJoCo (qpos, qvel of a model translated from the system), calls ``mj_step`` once and reads
the state back; simrun's loop records it, so every energy and error is simrun's own system's, the same for every
engine. MuJoCo computes in float64: the state passes through unchanged. A probe of the same step on unit states of the
test spring gives the amplification matrix (runner/analysis/oscillator.py), as for simrun's own methods.

The translation, from the scenes of integrators/engine_scenes.py (anything else is refused in one line):
- **Uncoupled springs:** one body per dof on a slide joint with the joint's ``stiffness`` k_i (``springref`` 0),
  ``damping`` d_i and mass m_i.
- **Springs between vertices:** one body per vertex with a slide joint per coordinate; each spring a spatial tendon
  between the two vertices' sites with ``stiffness`` k, ``springlength`` l0 (MuJoCo's tendon spring is -k (L - l0)
  along the tendon: the same energy) and ``damping`` beta on dL/dt (simrun's ``spring`` damping model); pinned
  vertices are sites of the world body.

What MuJoCo's integrators are (src/engine/engine_forward.c, ``mj_step``), each explicit in the stiffness:
- ``Euler``: semi-implicit, v' = v + h a, x' = x + h v', with the joints' damping implicit, (M + h D_joint) a = f;
  tendon damping explicit. On the undamped spring: symplectic Euler.
- ``implicit``: (M - h df/dv) a = f with every velocity derivative (joint and tendon damping, Coriolis); then as Euler.
- ``implicitfast``: the same without the Coriolis (RNE) derivative, a symmetric matrix.
- ``RK4``: the classical four-stage Runge-Kutta method on (q, v).
- ``discrete`` (MuJoCo 4.0): implicit in the stiffness too (measured: tests/test_mujoco.py).
MuJoCo resets its state where qpos, qvel or qacc exceed 1e10 (its BADQPOS, BADQVEL, BADQACC warnings): such a step
returns NaN, so that the run is diverged, as it is, rather than silently restarted.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from simrun.systems.compliant import ANCHORED

from .base import State
from .engine import EngineIntegrator
from .engine_scenes import UncoupledSprings, VertexSprings, read_scene, springs_between_vertices, uncoupled_springs

EXTRA = "pip install '.[engines]' (mujoco)"
# MuJoCo's name of each integrator, and the order of accuracy it is known by
MUJOCO_INTEGRATORS = {"Euler": ("mjINT_EULER", 1), "implicit": ("mjINT_IMPLICIT", 1),
                      "implicitfast": ("mjINT_IMPLICITFAST", 1), "RK4": ("mjINT_RK4", 4),
                      "discrete": ("mjINT_DISCRETE", 1)}
BAD_STATE_WARNINGS = ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC")


def mujoco_missing() -> str | None:
    """Why MuJoCo cannot be used here (the extra is not installed), or None."""
    return None if importlib.util.find_spec("mujoco") is not None else f"needs MuJoCo: {EXTRA}"


@dataclass(frozen=True)
class Translation:
    """A system as a MuJoCo model: its MJCF text, the system's dofs that are MuJoCo's qpos (in order), and the
    positions those dofs measure their displacement from (the bodies' rest frames)."""

    xml: str
    dofs: np.ndarray
    origin: np.ndarray


def _number(value: float) -> str:
    return repr(float(value))


def _vector(values) -> str:
    return " ".join(_number(value) for value in values)


def _uncoupled_springs(scene: UncoupledSprings) -> Translation:
    """One slide joint per dof with its spring (``springref`` 0) and damper."""
    bodies = [f'<body name="q{i}"><joint type="slide" axis="1 0 0" stiffness="{_number(k)}" '
              f'damping="{_number(d)}" springref="0"/><inertial pos="0 0 0" mass="{_number(m)}" '
              f'diaginertia="1 1 1"/></body>' for i, (k, d, m) in enumerate(zip(scene.stiffness, scene.damping,
                                                                                  scene.mass))]
    n = scene.stiffness.size
    return Translation(_model("0 0 0", "".join(bodies)), np.arange(n), np.zeros(n))


def _springs_between_vertices(scene: VertexSprings) -> Translation:
    """A body per free vertex with a slide joint per coordinate, a spatial tendon per spring; pinned vertices and
    anchors are sites of the world body."""
    axes = ("1 0 0", "0 1 0", "0 0 1")[:scene.dim]
    world, bodies = [], []
    for vertex, position in enumerate(scene.rest):
        site = f'<site name="s{vertex}" pos="{{}}" size="0.001"/>'
        if scene.pinned[vertex]:
            world.append(site.format(_vector(position)))
            continue
        joints = "".join(f'<joint type="slide" axis="{axis}"/>' for axis in axes)
        bodies.append(f'<body name="v{vertex}" pos="{_vector(position)}">{joints}'
                      f'<inertial pos="0 0 0" mass="{_number(scene.mass[vertex])}" diaginertia="1 1 1"/>'
                      f'{site.format("0 0 0")}</body>')
    anchors, tendons = [], []
    for spring, (first, second) in enumerate(zip(scene.first, scene.second)):
        if second == ANCHORED:
            anchors.append(f'<site name="a{spring}" pos="{_vector(scene.anchor[spring])}" size="0.001"/>')
            other = f"a{spring}"
        else:
            other = f"s{second}"
        tendons.append(f'<spatial stiffness="{_number(scene.stiffness[spring])}" '
                       f'damping="{_number(scene.damping[spring])}" springlength="{_number(scene.rest_length[spring])}">'
                       f'<site site="s{first}"/><site site="{other}"/></spatial>')
    body_text = "".join(world) + "".join(anchors) + "".join(bodies)
    free = scene.free_dofs
    origin = scene.rest[:, :scene.dim].ravel()[free]
    return Translation(_model(_vector(scene.gravity), body_text, "".join(tendons)), free, origin)


def _model(gravity: str, bodies: str, tendons: str = "") -> str:
    """The MJCF of a translation: no contact (the translated systems have none), MuJoCo's options set per run."""
    tendon_block = f"<tendon>{tendons}</tendon>" if tendons else ""
    return (f'<mujoco><option gravity="{gravity}"><flag contact="disable"/></option>'
            f"<worldbody>{bodies}</worldbody>{tendon_block}</mujoco>")


def translate(system) -> Translation | str:
    """The system as a MuJoCo model, or why it cannot be one (in one line)."""
    scene = read_scene(system, "MuJoCo", "MuJoCo's soft contacts are another model than simrun's penalty or IPC",
                       (uncoupled_springs, springs_between_vertices))
    if isinstance(scene, str):
        return scene
    return _uncoupled_springs(scene) if isinstance(scene, UncoupledSprings) else _springs_between_vertices(scene)


class Stepper:
    """A translated system's MuJoCo model and data at one step size and integrator: a step sets qpos and qvel from
    the state, calls mj_step and reads them back."""

    def __init__(self, translation: Translation, integrator: "MuJoCo", dt: float):
        import mujoco

        self.mujoco = mujoco
        self.model = mujoco.MjModel.from_xml_string(translation.xml)
        self.model.opt.timestep = dt
        self.model.opt.integrator = getattr(mujoco.mjtIntegrator, MUJOCO_INTEGRATORS[integrator.integrator][0])
        self.model.opt.iterations = integrator.iterations
        self.model.opt.tolerance = integrator.tolerance
        self.data = mujoco.MjData(self.model)
        self.dofs, self.origin = translation.dofs, translation.origin
        self.warnings = [getattr(mujoco.mjtWarning, name) for name in BAD_STATE_WARNINGS]

    def step(self, state: State) -> State:
        data, dofs = self.data, self.dofs
        data.qpos[:] = state.x[dofs] - self.origin
        data.qvel[:] = state.v[dofs]
        data.time = state.t
        before = [data.warning[kind].number for kind in self.warnings]
        self.mujoco.mj_step(self.model, data)
        x, v = state.x.copy(), state.v.copy()
        if any(data.warning[kind].number > count for kind, count in zip(self.warnings, before)):
            x[dofs], v[dofs] = math.nan, math.nan  # MuJoCo reset a state it could not step: the run diverged here
        else:
            x[dofs] = self.origin + data.qpos
            v[dofs] = data.qvel
        return State(state.t + self.model.opt.timestep, x, v)


class MuJoCo(EngineIntegrator):
    """MuJoCo's own integrator, stepping a MuJoCo model translated from the system (module docstring)."""

    name: ClassVar[str] = "mujoco"
    order: ClassVar[int] = 1
    summary: ClassVar[str] = ("MuJoCo's integrators (Euler, implicit, implicitfast, RK4, discrete), stepped by MuJoCo "
                              "on the system translated to its model (extra: engines)")

    integrator: Literal[tuple(MUJOCO_INTEGRATORS)] = Field(  # type: ignore[valid-type]
        "Euler", description="Euler (semi-implicit, joint damping implicit) | implicit | implicitfast (implicit in "
                             "velocity) | RK4 | discrete (MuJoCo 4.0)")
    iterations: int = Field(100, ge=1, description="MuJoCo's opt.iterations (its constraint solver's; the translated "
                                                   "systems have no constraint)")
    tolerance: float = Field(1e-8, ge=0, allow_inf_nan=False, description="MuJoCo's opt.tolerance (the same solver's)")

    @property
    def order_of_accuracy(self) -> int:
        return MUJOCO_INTEGRATORS[self.integrator][1]

    @classmethod
    def missing(cls) -> str | None:
        """Why this engine cannot run here (its extra is not installed), or None."""
        return mujoco_missing()

    def engine_refusal(self, system) -> str | None:
        import mujoco

        name = MUJOCO_INTEGRATORS[self.integrator][0]
        if not hasattr(mujoco.mjtIntegrator, name):
            return f"integrator {self.integrator} is not in MuJoCo {mujoco.__version__} (it has no {name})"
        translation = translate(system)
        return translation if isinstance(translation, str) else None

    def engine_description(self) -> str:
        import mujoco

        return f"MuJoCo {mujoco.__version__}, float64, CPU"

    def build_stepper(self, system, dt: float) -> Stepper:
        translation = translate(system)
        if isinstance(translation, str):
            raise TypeError(translation)
        return Stepper(translation, self, dt)
