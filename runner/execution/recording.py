"""What a run keeps of its samples and frames: the preallocated rows of ``Recorder``, and ``SampleCadence``, when a
step-controlled run (or a peer, which chooses its own steps too) keeps them. Shared by simulate.py and peers.py."""

from __future__ import annotations

import math

import numpy as np

from simrun.systems.forms import has_friction

from .measures import moving_dofs

# a step-controlled run's rows at first where their count is not known ahead (doubled when full)
STEP_ROWS = 1024


class Recorder:
    """Preallocated rows for the samples of a run: one float table, one row per sample.

    A row holds the observables (``system.observable_layout``, written by ``system.write_observables``
    without a dictionary), then t and the dissipated energy (and, for systems with prescribed paths, the
    work the paths did), then, for small systems, x and v. Systems of vertices (mass-spring models) keep
    the vertex positions as ``frames`` (frames x vertices x d) at their own, sparser cadence instead.
    """

    def __init__(self, system, sample_count: int, frame_count: int):
        self.write_observables = system.write_observables
        self.with_state = system.records_state_per_sample
        columns = list(system.observable_layout) + [("t", ()), ("dissipated_energy", ())]
        self.with_work = moving_dofs(system).size > 0
        if self.with_work:
            columns.append(("prescribed_work", ()))
        self.with_friction = has_friction(system)
        if self.with_friction:
            columns.append(("friction_dissipated", ()))
        if self.with_state:
            columns += [("positions", (system.dof_count,)), ("velocities", (system.dof_count,))]
        self.columns: dict[str, tuple[slice, tuple[int, ...]]] = {}
        start = 0
        for key, shape in columns:
            self.columns[key] = (slice(start, start + math.prod(shape)), shape)
            start += math.prod(shape)
        self.table = np.empty((sample_count, start))
        self.t_column = self.columns["t"][0].start
        self.dissipated_column = self.columns["dissipated_energy"][0].start
        if self.with_state:
            self.positions, self.velocities = self.columns["positions"][0], self.columns["velocities"][0]
        self.count = 0
        self.frame_count = 0
        self.work_column = self.columns["prescribed_work"][0].start if self.with_work else None
        self.friction_column = self.columns["friction_dissipated"][0].start if self.with_friction else None
        dim = system.vertex_dim
        self.frames = None if self.with_state else np.empty((frame_count, system.dof_count // dim, dim))
        self.frame_t = None if self.with_state else np.empty(frame_count)

    def record(self, t: float, x: np.ndarray, v: np.ndarray, dissipated_energy: float, work: float = 0.0,
               friction: float = 0.0) -> float:
        """One sample at time t (s) of (x, v); returns its total energy (J), for the divergence check.
        dissipated_energy, work, friction: the physical damping's loss, the prescribed paths' work and the
        friction's loss (J) up to t."""
        if self.count == self.table.shape[0]:  # only a step-controlled run's sample count is not known ahead
            self.table = np.concatenate([self.table, np.empty_like(self.table)])
        row = self.table[self.count]
        energy = self.write_observables(x, v, row)
        row[self.t_column] = t
        row[self.dissipated_column] = dissipated_energy
        if self.work_column is not None:
            row[self.work_column] = work
        if self.friction_column is not None:
            row[self.friction_column] = friction
        if self.with_state:
            row[self.positions] = x
            row[self.velocities] = v
        self.count += 1
        return energy

    def record_frame(self, t: float, x: np.ndarray) -> None:
        if self.frame_count == self.frames.shape[0]:
            self.frames = np.concatenate([self.frames, np.empty_like(self.frames)])
            self.frame_t = np.concatenate([self.frame_t, np.empty_like(self.frame_t)])
        self.frames[self.frame_count] = x.reshape(self.frames.shape[1:])
        self.frame_t[self.frame_count] = t
        self.frame_count += 1

    def result(self) -> dict[str, np.ndarray]:
        """The samples by name (t first), each a contiguous array of shape (samples,) + its shape."""
        count = self.count
        order = ["t", *(key for key in self.columns if key != "t")]
        arrays = {key: np.ascontiguousarray(self.table[:count, self.columns[key][0]]).reshape((count,) + self.columns[key][1])
                  for key in order}
        if self.frames is not None:
            arrays["frames"] = self.frames[: self.frame_count]
            arrays["frame_t"] = self.frame_t[: self.frame_count]
        return arrays


class SampleCadence:
    """When a step-controlled run keeps a sample (and a frame): every k-th accepted step where record.every
    (record.frames_every) says so, else at the first step that reaches each of record.max_samples (max_frames) even
    times of the duration."""

    def __init__(self, record, duration: float):
        self.every, self.frames_every = record.every, record.frames_every
        self.sample_spacing = duration / (record.max_samples - 1)
        self.frame_spacing = duration / (record.max_frames - 1)
        self.next_sample, self.next_frame = self.sample_spacing, self.frame_spacing
        self.sample_rows = STEP_ROWS if self.every is not None else record.max_samples + 2
        self.frame_rows = STEP_ROWS if self.frames_every is not None else record.max_frames + 2

    def sample_due(self, steps: int, t: float) -> bool:
        return self._due(steps, t, self.every, "sample")

    def frame_due(self, steps: int, t: float) -> bool:
        return self._due(steps, t, self.frames_every, "frame")

    def _due(self, steps: int, t: float, every: int | None, kind: str) -> bool:
        """Every k-th accepted step, else the first step at or past the next even time of ``kind`` (then the one after)."""
        if every is not None:
            return steps % every == 0
        spacing = self.sample_spacing if kind == "sample" else self.frame_spacing
        if t < getattr(self, f"next_{kind}") * (1.0 - 1e-12):
            return False
        setattr(self, f"next_{kind}", (math.floor(t / spacing + 1e-9) + 1) * spacing)
        return True
