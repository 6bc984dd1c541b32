"""A trajectory computed by any code, measured as a run: the ``recorded`` integrator (``simrun measure``).

simrun does not step it. The trajectory file holds the states another code computed for the config's system, and
runner/execution/recorded.py evaluates that system's energies, momenta and errors on them, so that every figure,
finding and table reads the run as it reads simrun's own. The file (docs/results-format.md, "Trajectory files"):

- ``.npz`` (numpy) or HDF5 (``.h5``, ``.hdf5``) with the arrays ``t`` (n,) s, strictly increasing from 0, ``x``
  (n, dof_count) m and optionally ``v`` (n, dof_count) m/s, in the system's dof order; anything else in the file
  (arrays, HDF5 attributes) is free metadata.
- Without ``v``, velocities are the positions' central differences (second order, at uneven times too), and the
  run's label says so ("[v=central_differences]"), so that every number that uses them (kinetic energy, the budget,
  the damping fitted to the energy) carries it.
"""

from __future__ import annotations

import functools
import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from simrun.systems.vertex.errors import ModelError
from simrun.systems.vertex.files import find_file

from .base import Integrator

# the file kinds a trajectory is read from, by suffix
TRAJECTORY_SUFFIXES = {".npz": "npz", ".h5": "hdf5", ".hdf5": "hdf5"}
# how far the trajectory's first state may lie from the system's initial state (relative to its length and velocity
# scales) and still be the same start: single precision's round-off, with room
START_TOLERANCE = 1e-5


@dataclass(frozen=True)
class Trajectory:
    """A trajectory as read and checked: t (n,) s, x (n, dof) m, v (n, dof) m/s (None: not recorded), the file's sha256."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray | None
    sha256: str

    @property
    def velocities(self) -> np.ndarray:
        """v as recorded, else the central differences of x in t (np.gradient, second order at the ends too)."""
        if self.v is not None:
            return self.v
        if self.t.size < 3:
            return np.gradient(self.x, self.t, axis=0)
        return np.gradient(self.x, self.t, axis=0, edge_order=2)


def read_trajectory(path: Path) -> Trajectory:
    """The trajectory in ``path``, checked: ValueError naming the array (``trajectory.t``, ``trajectory.x``, ...) and
    what is allowed, for a file that is not one."""
    return _read_cached(path, _digest(path))


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@functools.lru_cache(maxsize=8)  # a sweep reads the same file for its validation and each run
def _read_cached(path: Path, sha256: str) -> Trajectory:
    kind = TRAJECTORY_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"trajectory: {path.name!r} is not a trajectory file; allowed: "
                         + ", ".join(TRAJECTORY_SUFFIXES) + " (numpy's savez, or HDF5)")
    arrays = _arrays(path, kind)
    for key in ("t", "x"):
        if key not in arrays:
            raise ValueError(f"trajectory.{key}: missing from {path.name} (it holds {', '.join(sorted(arrays)) or 'nothing'}); "
                             "a trajectory has t (n,) and x (n, dof_count), and optionally v (n, dof_count)")
    t, x, v = arrays["t"], arrays["x"], arrays.get("v")
    for key, array in (("t", t), ("x", x), ("v", v)):
        if array is not None and not np.issubdtype(array.dtype, np.number):
            raise ValueError(f"trajectory.{key}: expected numbers, got {array.dtype}")
    t, x = t.astype(float), x.astype(float)
    v = v.astype(float) if v is not None else None
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"trajectory.t: expected the times of at least 2 states, shape (n,), got shape {t.shape}")
    if x.ndim != 2 or x.shape[0] != t.size:
        raise ValueError(f"trajectory.x: expected shape ({t.size}, dof_count), one row per time, got {x.shape}")
    if v is not None and v.shape != x.shape:
        raise ValueError(f"trajectory.v: expected x's shape {x.shape}, got {v.shape}")
    for key, array in (("t", t), ("x", x), ("v", v)):
        if array is not None and not np.all(np.isfinite(array)):
            where = np.argwhere(~np.isfinite(array))[0]
            raise ValueError(f"trajectory.{key}: holds {array[tuple(where)]} at index {tuple(int(i) for i in where)}; "
                             "every value must be finite")
    steps = np.diff(t)
    if np.any(steps <= 0):
        index = int(np.argmax(steps <= 0))
        raise ValueError(f"trajectory.t: not increasing at index {index + 1} (t = {t[index]:.9g} s, then {t[index + 1]:.9g} s); "
                         "times must increase strictly")
    if abs(t[0]) > 1e-12 * t[-1]:
        raise ValueError(f"trajectory.t: starts at {t[0]:.9g} s; a trajectory starts at t = 0 from the system's initial state")
    for array in (t, x, v):
        if array is not None:
            array.setflags(write=False)
    return Trajectory(t, x, v, sha256)


def _arrays(path: Path, kind: str) -> dict[str, np.ndarray]:
    """The file's arrays by name (npz: every array; HDF5: the root's datasets)."""
    try:
        if kind == "npz":
            with np.load(path, allow_pickle=False) as file:
                return {key: np.asarray(file[key]) for key in file.files}
        import h5py

        with h5py.File(path, "r") as file:
            return {key: np.asarray(file[key]) for key in file if isinstance(file[key], h5py.Dataset)}
    except (OSError, ValueError, EOFError) as error:
        raise ValueError(f"trajectory: {path.name} cannot be read as {kind}: {error}") from None


class Recorded(Integrator):
    """A trajectory computed by other code for the config's system, measured as a run (``simrun measure``)."""

    name: ClassVar[str] = "recorded"
    order: ClassVar[int] = 1  # unknown: the code that computed it is not here; its card is measured from the run
    explicit: ClassVar[bool] = True  # takes no simrun solver: solver keys do not multiply it
    family: ClassVar[str] = "recorded"
    summary: ClassVar[str] = "a trajectory computed by any code, measured on the config's system (simrun measure)"
    whole_run: ClassVar[bool] = True
    linear: ClassVar[bool] = False  # nothing here steps it: it has no amplification matrix of its own

    trajectory: str = Field(description="the trajectory file (.npz or HDF5: t, x and optionally v), as an absolute path "
                                        "once read")
    source: str = Field("", pattern=r"^[A-Za-z0-9._+-]*$", max_length=60,
                        description="the label of the code that computed it: the run is named recorded:<source> "
                                    "(default: the file's name without its suffix)")
    sha256: str = Field("", description="the file's sha256 (filled in when read; given, the file must have it)")
    velocities: Literal["recorded", "central_differences"] = Field(
        "recorded", description="where v comes from: the file, or the central differences of x (filled in when read)")

    @model_validator(mode="before")
    @classmethod
    def _read_the_file(cls, data):
        """The file found (beside the config, then in the current folder), read and checked; its path, digest, label
        and velocity source filled in, so that the config hash changes with the file's content."""
        if not isinstance(data, dict) or not isinstance(data.get("trajectory"), (str, Path)):
            return data
        data = dict(data)
        try:
            path = find_file(str(data["trajectory"]), "trajectory")
        except ModelError as error:
            raise ValueError(str(error)) from None
        recorded = read_trajectory(path)
        given = data.get("sha256") or ""
        if given and given != recorded.sha256:
            raise ValueError(f"sha256: {path.name} has sha256 {recorded.sha256}, not the {given} the config names")
        data.update(trajectory=str(path), sha256=recorded.sha256,
                    velocities="recorded" if recorded.v is not None else "central_differences")
        if not data.get("source"):
            data["source"] = "".join(c if c.isalnum() or c in "._+-" else "_" for c in path.stem)[:60] or "trajectory"
        return data

    def read(self) -> Trajectory:
        return read_trajectory(Path(self.trajectory))

    @property
    def label(self) -> str:
        """recorded:<source>, and "[v=central_differences]" where the velocities were not recorded."""
        label = f"recorded:{self.source}"
        return label + "[v=central_differences]" if self.velocities == "central_differences" else label

    @property
    def order_of_accuracy(self) -> int:
        return self.order

    def given_steps(self, duration: float) -> tuple[float, float]:
        """The trajectory's mean step and its span within ``duration`` (s)."""
        t = self.read().t
        kept = t[t <= duration * (1.0 + 1e-12)]
        if kept.size < 2:
            raise ValueError(f"trajectory.t: its first step ends at {t[1]:.6g} s, past the config's duration {duration:g} s")
        return float((kept[-1] - kept[0]) / (kept.size - 1)), float(kept[-1])

    def step(self, system, state, dt, solver):
        raise TypeError("a recorded trajectory is read, not stepped (runner/execution/recorded.py)")

    def refusal(self, system) -> str | None:
        """Why the trajectory cannot be measured on ``system`` (its dof count, friction, energy it cannot evaluate, its
        first state), or None."""
        recorded = self.read()
        dofs = recorded.x.shape[1]
        if dofs != system.dof_count:
            return (f"trajectory.x has {dofs} columns, and the config's system has {system.dof_count} dofs: the "
                    "trajectory must be computed for the config's system, in its dof order")
        contact = system.contact_form()
        if contact and contact.has_friction:
            return ("friction's loss is booked from simrun's own steps (their lagged normal forces), which a recorded "
                    "trajectory has not: measure it on the system without friction")
        try:
            energy = system.total_energy(recorded.x[0], recorded.velocities[0])
        except NotImplementedError as error:
            return f"the system cannot evaluate its energy ({error or 'potential_energy is not implemented'})"
        if not math.isfinite(energy):
            return f"the system's energy at the trajectory's first state is {energy}: it cannot be measured"
        offset = float(np.max(np.abs(recorded.x[0] - system.x0))) if dofs else 0.0
        if offset > START_TOLERANCE * max(system.length_scale, float(np.max(np.abs(system.x0), initial=0.0))):
            return (f"trajectory.x[0] lies {offset:.3g} m from the system's initial positions: it was computed for "
                    "another start (or another system)")
        if recorded.v is not None:
            speed = max(float(np.max(np.abs(system.v0), initial=0.0)), system.length_scale * (system.test_frequency or 0.0))
            offset = float(np.max(np.abs(recorded.v[0] - system.v0)))
            if offset > START_TOLERANCE * speed and offset > 1e-12:
                return (f"trajectory.v[0] differs by {offset:.3g} m/s from the system's initial velocities: it was "
                        "computed for another start (or another system)")
        return None
