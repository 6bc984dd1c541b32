"""What a system tells the runner and the figures about itself (``System.capabilities``), stored with every run."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class Capabilities:
    """What a system tells the runner and the figures about itself; stored as attributes of every run (results format 2)."""

    test_frequency: float | None  # w (rad/s) when the system is the undamped test equation q'' + w^2 q = 0 (or uncoupled copies of it), else None
    length_scale: float  # m, the scale of position errors: max |x0| (1 when x0 = 0)
    energy_scale: float  # J, the run's energy reference E_ref: drift, divergence and every energy figure are relative to it
    frame_shape: tuple[int, ...] | None  # the vertex grid of one stored frame, e.g. (ny, nx) for the cloth (rows of the grid, vertices per row, as frames reshape to (ny, nx, 3)); None for systems that record x and v in every sample
    planar: bool  # one body whose motion stays in the x-y plane: its trajectory is drawn as an orbit
    dof_count: int
    energy_reference_name: str = "|KE0| + |PE0|"  # what energy_scale is, for axis labels and tables
    vertex_dim: int = 0  # coordinates per vertex of a stored frame (2 or 3); 0 for systems that keep no frames
    # (w0 rad/s, zeta) of a linear oscillator q'' + 2 zeta w0 q' + w0^2 q = 0, damped or not (the damping map's axes); None
    oscillator: tuple[float, float] | None = None

    @classmethod
    def attribute_names(cls) -> set[str]:
        """The names ``as_attrs`` stores: the fields', the oscillator's two (natural_frequency, damping_ratio) for it."""
        return {field.name for field in fields(cls)} - {"oscillator"} | {"natural_frequency", "damping_ratio"}

    def as_attrs(self) -> dict:
        """The capabilities as HDF5 attributes, under the field names: test_frequency (float, NaN for None),
        length_scale and energy_scale (floats), frame_shape (int64 array, empty for None), planar (bool),
        dof_count (int)."""
        return {
            "test_frequency": math.nan if self.test_frequency is None else float(self.test_frequency),
            "length_scale": float(self.length_scale),
            "energy_scale": float(self.energy_scale),
            "frame_shape": np.array(self.frame_shape or (), dtype=np.int64),
            "planar": bool(self.planar),
            "dof_count": int(self.dof_count),
            "energy_reference_name": str(self.energy_reference_name),
            "vertex_dim": int(self.vertex_dim),
            "natural_frequency": math.nan if self.oscillator is None else float(self.oscillator[0]),
            "damping_ratio": math.nan if self.oscillator is None else float(self.oscillator[1]),
        }
