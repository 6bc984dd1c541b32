"""The summary table of a results file and what it is computed from: the run's status, its energy drift
relative to the system's energy reference, and its cost per simulated second and per frame.

Every stage reads these definitions: the stepping code (a lane's summary rows, a run kept without series), the
writer (a run's row), the reader (a resumed or older file's rows) and the tables. Like the reader, this module
imports h5py and numpy only.
"""

from __future__ import annotations

import math

import h5py
import numpy as np

from simrun.format.layout import ERROR_NORMS
from simrun.format.record import SERIES_SUMMARY_KEYS, Status, run_attribute

__all__ = ["SERIES_SUMMARY_KEYS", "SUMMARY_COLUMNS", "SUMMARY_DTYPE", "Status", "energy_drift", "energy_reference",
           "energy_remainder", "real_time_factor", "series_summary", "summary_row", "summary_row_of", "wall_time_per_frame"]


# -- energy drift: the one definition ---------------------------------------------------------------
def energy_reference(attrs, energy: np.ndarray, kinetic: np.ndarray, potential: np.ndarray) -> tuple[float, str]:
    """A run's energy reference E_ref (J) and what it is: every drift, energy figure and table divides by it.

    Format 2: what the run's system declared (attributes ``energy_scale``, ``energy_reference_name``),
    e.g. E0 for the spring and M |g| L for a cloth at rest, whose E0 is round-off. Format 1 did not store
    it: its drifts were relative to ``drift_scale``, which stays its reference."""
    if "energy_scale" in attrs:
        return float(attrs["energy_scale"]), as_text(run_attribute(attrs, "energy_reference_name"))
    return drift_scale(energy, kinetic, potential), "|E0| (format 1)"


def energy_drift(energy: np.ndarray, scale: float) -> tuple[float, float]:
    """(max |E - E0|, final E - E0) over the finite samples, both divided by ``scale`` (J); NaN without samples."""
    energy = energy[np.isfinite(energy)]
    if energy.size == 0:
        return math.nan, math.nan
    drift = (energy - energy[0]) / scale
    return float(np.max(np.abs(drift))), float(drift[-1])


def energy_remainder(energy: np.ndarray, dissipated: np.ndarray, work: np.ndarray, scale: float) -> tuple[float, float]:
    """The energy budget split in two (J / ``scale``): (max |E + E_dissipated - W - E0|, E_dissipated at the end).

    The first is what the integrator itself removed or added, the remainder of the budget E0 + W (W: the work of the
    vertices on prescribed paths) once the physical losses E_dissipated (damping and friction, as the run recorded
    them) are counted; the second is those losses. Over the samples where E is finite; NaN without any."""
    finite = np.isfinite(energy)
    if not finite.any():
        return math.nan, math.nan
    with np.errstate(invalid="ignore", over="ignore"):  # a diverged run's last samples: inf - inf
        remainder = (energy + dissipated - work)[finite]
        return float(np.max(np.abs(remainder - remainder[0]))) / scale, float(dissipated[finite][-1]) / scale


# the sample series of the energy that left the system physically: damping's work and friction's (J, from t = 0)
DISSIPATED_SERIES = ("dissipated_energy", "friction_dissipated")


# -- the summary table ------------------------------------------------------------------------------
SUMMARY_DTYPE = np.dtype([
    ("run_id", h5py.string_dtype()),
    ("integrator", h5py.string_dtype()),
    ("dt", "f8"),
    ("status", h5py.string_dtype()),
    ("steps", "i8"),
    ("max_rel_energy_drift", "f8"),
    ("final_rel_energy_drift", "f8"),
    ("max_rel_energy_remainder", "f8"),
    ("final_rel_dissipated_energy", "f8"),
    ("final_error", "f8"),
    ("error_time", "f8"),
    ("error", "f8"),
    ("final_velocity_error", "f8"),
    ("max_error", "f8"),
    ("max_velocity_error", "f8"),
    ("mean_newton_iterations", "f8"),
    ("mean_linear_iterations", "f8"),
    ("wall_time", "f8"),
    ("real_time_factor", "f8"),
    ("wall_time_per_frame", "f8"),
])


SUMMARY_COLUMNS = SUMMARY_DTYPE.names


# the frame of real-time animation, simulated seconds: wall_time_per_frame is the wall time per 1/60 s
FRAME_TIME = 1.0 / 60.0


def real_time_factor(steps: int, dt: float, wall_time: float) -> float:
    """Simulated time over wall time (> 1: faster than real time); NaN when either is zero or unknown."""
    simulated = steps * dt
    return simulated / wall_time if simulated > 0.0 and wall_time > 0.0 else math.nan


def wall_time_per_frame(steps: int, dt: float, wall_time: float) -> float:
    """Wall time (s) per FRAME_TIME of simulated time: real time needs it below FRAME_TIME."""
    simulated = steps * dt
    return wall_time * FRAME_TIME / simulated if simulated > 0.0 else math.nan




def series_summary(attrs, read) -> dict[str, float]:
    """SERIES_SUMMARY_KEYS of one run: from its attributes where it kept no series, else from ``read(key)`` (its
    recorded dataset, or an empty array)."""
    if SERIES_SUMMARY_KEYS[0] in attrs:
        return {key: float(attrs[key]) if key in attrs else math.nan for key in SERIES_SUMMARY_KEYS}  # older: fewer
    series = {key: read(key) for key in ("energy", "kinetic_energy", "potential_energy")}
    scale = energy_reference(attrs, *series.values())[0]
    max_drift, final_drift = energy_drift(series["energy"], scale)
    count = series["energy"].size
    dissipated, work = np.zeros(count), np.zeros(count)
    for key in DISSIPATED_SERIES:
        values = read(key)
        dissipated = dissipated + (values[:count] if values.size >= count else 0.0)
    prescribed = read("prescribed_work")
    if prescribed.size >= count:
        work = prescribed[:count]
    remainder, lost = energy_remainder(series["energy"], dissipated, work, scale)
    newton, linear = read("newton_iterations"), read("linear_iterations")
    return {"max_rel_energy_drift": max_drift, "final_rel_energy_drift": final_drift,
            "max_rel_energy_remainder": remainder, "final_rel_dissipated_energy": lost,
            "mean_newton_iterations": float(newton.mean()) if newton.size else 0.0,
            "mean_linear_iterations": float(linear.mean()) if linear.size else 0.0}


def summary_row(run_id: str, group: h5py.Group) -> tuple:
    """One summary row, computed from a run's group alone (the writer's row, and a resumed file's rebuild)."""
    return summary_row_of(run_id, group.attrs, lambda key: group[key][()] if key in group else np.empty(0))


def summary_row_of(run_id: str, attrs, read) -> tuple:
    """One summary row from a run's attributes and ``read(key)``, its datasets (an empty array where it has none)."""
    series = series_summary(attrs, read)
    steps, dt, wall_time = int(attrs["steps"]), float(attrs["dt"]), float(attrs["wall_time"])
    return (
        run_id, as_text(attrs["integrator_label"]), dt, as_text(attrs["status"]), steps,
        series["max_rel_energy_drift"], series["final_rel_energy_drift"], series["max_rel_energy_remainder"],
        series["final_rel_dissipated_energy"], float(run_attribute(attrs, "final_error")),
        float(run_attribute(attrs, "error_time")), float(run_attribute(attrs, "error")),
        *(float(run_attribute(attrs, key)) for key in ERROR_NORMS), series["mean_newton_iterations"], series["mean_linear_iterations"], wall_time,
        real_time_factor(steps, dt, wall_time), wall_time_per_frame(steps, dt, wall_time),
    )


# -- format 1: the drift reference --------------------------------------------------------------------
def drift_scale(energy: np.ndarray, kinetic: np.ndarray, potential: np.ndarray) -> float:
    """Format 1's drift reference (J): |E0|, else |KE0| + |PE0| (E0 = 0), else 1 J."""
    if energy.size and np.isfinite(energy[0]) and energy[0] != 0:
        return abs(float(energy[0]))
    if kinetic.size and potential.size:
        scale = abs(float(kinetic[0])) + abs(float(potential[0]))
        if np.isfinite(scale) and scale > 0:
            return scale
    return 1.0


# -- attributes as Python ------------------------------------------------------------------------------
def as_text(value) -> str:
    """An attribute as text: h5py gives bytes for some strings."""
    return value.decode() if isinstance(value, bytes) else str(value)


def attribute_value(value):
    """An HDF5 attribute as Python: str for strings, int/float/bool for numpy scalars, arrays as they are."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value
