"""MuJoCo's integrators on simrun's systems, stepped by MuJoCo itself: ``{type: mujoco, integrator: Euler | implicit |
implicitfast | RK4 | discrete}`` (the extra ``engines``: pip install '.[engines]').

A step hands the state to MuJoCo (qpos, qvel of a model translated from the system), calls ``mj_step`` once and reads
the state back; simrun's loop records it, so every energy and error is simrun's own system's, the same for every
engine. MuJoCo computes in float64: the state passes through unchanged. A probe of the same step on unit states of the
test spring gives the amplification matrix (runner/analysis/oscillator.py), as for simrun's own methods.

The translation (``TRANSLATIONS``, the first that takes the system; each says what it cannot express):
- **Uncoupled springs:** a potential sum_i k_i q_i^2 / 2 (constant diagonal Hessian, at rest at the origin) with
  constant diagonal damping: the spring, the spring bank of the predictions, circular motion under its linear force.
  One body per dof on a slide joint with the joint's ``stiffness`` k_i (``springref`` 0), ``damping`` d_i and mass m_i.
- **Springs between vertices:** a mass-spring model or the cloth with Hookean springs k/2 (L - l0)^2, damped only along
  them, under uniform gravity. One body per vertex with a slide joint per coordinate; each spring a spatial tendon
  between the two vertices' sites with ``stiffness`` k, ``springlength`` l0 (MuJoCo's tendon spring is -k (L - l0)
  along the tendon: the same energy) and ``damping`` beta on dL/dt (simrun's ``spring`` damping model); pinned
  vertices are sites of the world body.
Anything else (contact, prescribed paths, sliding vertices, consistent masses, other damping models or spring laws,
nonlinear forces MuJoCo has no element for) is refused in one line: no approximation stands in for the system.

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
import weakref
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
import scipy.sparse
from pydantic import Field

from simrun.solvers import EXPLICIT_STEP
from simrun.systems.compliant import ANCHORED
from simrun.systems.forms import NotOffered

from .base import Integrator, State

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


def _dense_diagonal(matrix) -> np.ndarray | None:
    """The diagonal of a matrix that has nothing off it, else None."""
    if matrix is None:
        return None
    if scipy.sparse.issparse(matrix):
        matrix = scipy.sparse.coo_array(matrix)
        off = matrix.row != matrix.col
        if np.any(matrix.data[off] != 0.0):
            return None
        return np.asarray(matrix.diagonal(), dtype=float)
    matrix = np.atleast_2d(np.asarray(matrix, dtype=float))
    diagonal = np.diag(matrix).copy()
    return diagonal if np.array_equal(matrix, np.diag(diagonal)) else None


def _held(system) -> str | None:
    """What of the system's constraints MuJoCo's translation would not hold, or None."""
    if system.mass_correction is not None:
        return "a consistent mass matrix (MuJoCo's point bodies have lumped masses): use mass: lumped"
    constraints = system.constraints
    if system.sliding is not None or (constraints is not None and constraints.moving_dofs.size):
        return "prescribed paths or sliding vertices (no MuJoCo element follows them here)"
    if system.contact_form():
        return "contact (MuJoCo's soft contacts are another model than simrun's penalty or IPC)"
    return None


def uncoupled_springs(system) -> Translation | str:
    """One slide joint per dof with its spring and damper; a reason where the system is not uncoupled springs."""
    if not system.quadratic_potential:
        return "its potential is not quadratic"
    n = system.dof_count
    stiffness = _dense_diagonal(system.hessian(system.x0))
    if stiffness is None:
        return "its springs are coupled (the Hessian has terms off its diagonal)"
    if np.any(system.gradient(np.zeros(n)) != 0.0):
        return "its springs are not at rest at the origin (or a field such as gravity acts)"
    damping = np.zeros(n)
    if system.is_damped:
        damping = _dense_diagonal(system.damping_matrix(system.x0)) if system.damping_is_constant else None
        if damping is None:
            return "its damping is not constant and diagonal"
    if np.asarray(system.fixed_dofs).size:
        return "it holds dofs fixed"
    mass = np.broadcast_to(np.asarray(system.mass, dtype=float), (n,))
    bodies = [f'<body name="q{i}"><joint type="slide" axis="1 0 0" stiffness="{_number(stiffness[i])}" '
              f'damping="{_number(damping[i])}" springref="0"/><inertial pos="0 0 0" mass="{_number(mass[i])}" '
              f'diaginertia="1 1 1"/></body>' for i in range(n)]
    return Translation(_model("0 0 0", "".join(bodies)), np.arange(n), np.zeros(n))


def springs_between_vertices(system) -> Translation | str:
    """A body per vertex, a tendon per spring; a reason where the system is not such springs."""
    form = system.compliant_form()
    if form is None:
        return "it has no springs between vertices"
    if isinstance(form, NotOffered):
        return form.reason
    if form.other_forces:
        return "it has forces besides its springs, their dampers and gravity (damping not along the springs, contact)"
    dim, count = form.dim, form.vertex_count
    if dim not in (2, 3):
        return f"its vertices have {dim} coordinates"
    gravity = np.zeros(3)
    if system.external_acceleration is not None:
        field = np.asarray(system.external_acceleration, dtype=float).reshape(count, dim)
        if not np.all(field == field[0]):
            return "its external field is not one uniform gravity"
        gravity[:dim] = field[0]
    mass = np.asarray(system.mass, dtype=float).reshape(count, dim)
    if not np.all(mass == mass[:, :1]):
        return "its vertices' masses differ between coordinates"
    fixed = np.zeros(count * dim, dtype=bool)
    fixed[np.asarray(system.fixed_dofs, dtype=np.intp)] = True
    held = fixed.reshape(count, dim)
    if np.any(held.any(axis=1) & ~held.all(axis=1)):
        return "some vertices are held in some directions only"
    pinned = held.all(axis=1)
    rest = np.asarray(system.x0, dtype=float).reshape(count, dim)
    position = np.zeros((count, 3))
    position[:, :dim] = rest
    axes = ("1 0 0", "0 1 0", "0 0 1")[:dim]
    world, bodies = [], []
    for vertex in range(count):
        site = f'<site name="s{vertex}" pos="{{}}" size="0.001"/>'
        if pinned[vertex]:
            world.append(site.format(_vector(position[vertex])))
            continue
        joints = "".join(f'<joint type="slide" axis="{axis}"/>' for axis in axes)
        bodies.append(f'<body name="v{vertex}" pos="{_vector(position[vertex])}">{joints}'
                      f'<inertial pos="0 0 0" mass="{_number(mass[vertex, 0])}" diaginertia="1 1 1"/>'
                      f'{site.format("0 0 0")}</body>')
    anchors = []
    tendons = []
    for spring in range(form.spring_count):
        first, second = int(form.first[spring]), int(form.second[spring])
        if second == ANCHORED:
            point = np.zeros(3)
            point[:dim] = form.anchor[spring]
            anchors.append(f'<site name="a{spring}" pos="{_vector(point)}" size="0.001"/>')
            other = f"a{spring}"
        else:
            other = f"s{second}"
        tendons.append(f'<spatial stiffness="{_number(form.stiffness[spring])}" damping="{_number(form.damping[spring])}" '
                       f'springlength="{_number(form.rest_length[spring])}"><site site="s{first}"/>'
                       f'<site site="{other}"/></spatial>')
    free = np.flatnonzero(~fixed)
    body_text = "".join(world) + "".join(anchors) + "".join(bodies)
    return Translation(_model(_vector(gravity), body_text, "".join(tendons)), free, np.asarray(system.x0, float)[free])


def _model(gravity: str, bodies: str, tendons: str = "") -> str:
    """The MJCF of a translation: no contact (the translated systems have none), MuJoCo's options set per run."""
    tendon_block = f"<tendon>{tendons}</tendon>" if tendons else ""
    return (f'<mujoco><option gravity="{gravity}"><flag contact="disable"/></option>'
            f"<worldbody>{bodies}</worldbody>{tendon_block}</mujoco>")


# the translations, in the order they are tried
TRANSLATIONS = (uncoupled_springs, springs_between_vertices)


def translate(system) -> Translation | str:
    """The first translation that takes ``system``, or why none does (each one's reason, in one line)."""
    held = _held(system)
    if held is not None:
        return f"MuJoCo's translation cannot express {held}"
    reasons = []
    for translation in TRANSLATIONS:
        result = translation(system)
        if isinstance(result, Translation):
            return result
        reasons.append(f"not {translation.__name__.replace('_', ' ')}: {result}")
    return "MuJoCo's translation cannot express this system (" + "; ".join(reasons) + ")"


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


# each system's steppers, by (dt, integrator): built on a run's first step, kept while the system lives
_STEPPERS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


class MuJoCo(Integrator):
    """MuJoCo's own integrator, stepping a MuJoCo model translated from the system (module docstring)."""

    name: ClassVar[str] = "mujoco"
    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = True  # every MuJoCo integrator takes the stiffness explicitly: a step limit remains
    fixed_steps_only: ClassVar[bool] = True  # MuJoCo's timestep is a model option
    family: ClassVar[str] = "engines"
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

    def refusal(self, system) -> str | None:
        missing = self.missing()
        if missing is not None:
            return missing
        import mujoco

        name = MUJOCO_INTEGRATORS[self.integrator][0]
        if not hasattr(mujoco.mjtIntegrator, name):
            return f"integrator {self.integrator} is not in MuJoCo {mujoco.__version__} (it has no {name})"
        if getattr(system, "lane_count", None) is not None:
            return "is not stepped as lanes"
        translation = translate(system)
        return translation if isinstance(translation, str) else None

    def engine_description(self) -> str:
        import mujoco

        return f"MuJoCo {mujoco.__version__}, float64, CPU"

    def prepare(self, system, dt: float) -> None:
        self._stepper(system, dt)

    def step(self, system, state, dt, solver):
        return self._stepper(system, dt).step(state), EXPLICIT_STEP

    def _stepper(self, system, dt: float) -> Stepper:
        """The system's MuJoCo model and data for steps of dt with these options: built once, kept with the system."""
        steppers = _STEPPERS.setdefault(system, {})
        key = (float(dt), self.integrator, self.iterations, self.tolerance)
        stepper = steppers.get(key)
        if stepper is None:
            translation = translate(system)
            if isinstance(translation, str):
                raise TypeError(translation)
            stepper = steppers[key] = Stepper(translation, self, float(dt))
        return stepper
