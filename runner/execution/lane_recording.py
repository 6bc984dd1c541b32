"""What lanes keep while they are stepped (runner/execution/lanes.py): every sample and step (``LaneSeries``), or only what the
summary and the run's scalars need (``LaneSummary``, for ``record.series: false``).

Both take a sample of every lane at once and are told which lanes are still running (a stopped lane keeps the
sample of the step it stopped at, as ``simulate``'s ``record_stop``). Their numbers are ``simulate``'s for each run:
the series row for row; the summary's energy drift, mean iterations and safeguarded steps from the same samples and
steps, accumulated as they come instead of read back from the series.
"""

from __future__ import annotations

import math

import numpy as np

from simrun.execution.measures import DECAY_FLOOR, decay_per_period
from simrun.format.record import SOLVER_STEP_COLUMNS


class LaneSeries:
    """Every sample (one array per key, samples first while stepping) and every step's solver counts."""

    def __init__(self, layout: dict[str, tuple], sample_rows: int, lanes: int, step_count: int, modal_energy,
                 energy_scale: np.ndarray, exact=None):
        self.modal_energy = modal_energy  # the lane system's: what the decay per period is measured from
        self.exact = exact  # the lane system's exact_states (None: no exact solution), for the error norms
        self.energy_scale = energy_scale  # E_ref per lane: the energy drift's unit
        self.series = {key: np.full((sample_rows, lanes) + shape, np.nan) for key, shape in layout.items()}
        self.per_step = {key: np.zeros((step_count, lanes), dtype=column.dtype) for key, column in SOLVER_STEP_COLUMNS.items()}
        self.per_step_count = step_count
        self.counts = np.zeros(lanes, dtype=np.int64)
        self.row = 0  # the next regular sample's row
        self.stop_rows: dict[str, np.ndarray] | None = None  # samples of lanes that stopped off the regular cadence
        self.off_cadence = np.zeros(lanes, dtype=bool)

    def sample(self, observed: dict, t, dissipated, x, v, running: np.ndarray | None) -> None:
        """A regular sample: every lane's row (a stopped lane's is overwritten, then dropped: its count stays)."""
        _write(self.series, self.row, observed, t, dissipated, x, v)
        self.row += 1
        if running is None:
            self.counts[:] = self.row
        else:
            self.counts[running] = self.row

    def stop_sample(self, stopping: np.ndarray, observed: dict, t, dissipated, x, v) -> None:
        """The sample of the step at which ``stopping`` lanes stop, off the regular cadence: one more row of their own."""
        if self.stop_rows is None:
            self.stop_rows = {key: np.full((1,) + values.shape[1:], np.nan) for key, values in self.series.items()}
        taken = {key: np.empty_like(values) for key, values in self.stop_rows.items()}
        _write(taken, 0, observed, t, dissipated, x, v)
        for key, values in taken.items():
            self.stop_rows[key][0, stopping] = values[0, stopping]
        self.off_cadence |= stopping
        self.counts[stopping] = self.row + 1

    def solver_step(self, n: int, stats, running) -> None:
        for key, column in SOLVER_STEP_COLUMNS.items():
            value = getattr(stats, column.stats_field)
            if value.flags.writeable or value.any():  # the solver's shared zeros: the record is zero already
                self.per_step[key][n] = value

    def finish(self, steps: np.ndarray) -> dict:
        """The recorded data by lane: samples (lanes, samples, ...) NaN past each lane's count, per-step (lanes, steps)."""
        samples = {key: np.ascontiguousarray(np.moveaxis(values, 0, 1)) for key, values in self.series.items()}
        samples = {"t": samples.pop("t"), **samples}
        # lanes that stopped: their rows past the stop go, and a stop off the regular cadence takes its own row back
        # (a lane may stop with as many rows as the others, or one more, when the loop ended with it)
        short = np.flatnonzero((self.counts < self.row) | self.off_cadence).tolist()
        for lane in short:
            count = self.counts[lane]
            for key, values in samples.items():
                values[lane, count:] = np.nan
                if self.off_cadence[lane]:
                    values[lane, count - 1] = self.stop_rows[key][0, lane]
        per_step = {key: np.ascontiguousarray(values.T) for key, values in self.per_step.items()}
        for lane in np.flatnonzero(steps < self.per_step_count).tolist():  # stopped lanes were stepped on, unrecorded
            for values in per_step.values():
                values[lane, steps[lane]:] = 0
        last = self.counts - 1
        every = np.arange(last.size)
        norms = self._error_norms(samples, last)
        series_summary = self._series_summary(samples["energy"], samples["dissipated_energy"], per_step, steps)
        energy = self.modal_energy(samples["energy"], samples["positions"], samples["velocities"])
        usable = np.isfinite(energy) & (energy > DECAY_FLOOR * energy[:, :1])  # NaN past a lane's count: not usable
        latest = energy.shape[1] - 1 - np.argmax(usable[:, ::-1], axis=1)
        latest = np.where(usable.any(axis=1), latest, 0)
        return {"samples": samples, "sample_count": self.counts, "per_step": per_step,
                "last_t": samples["t"][every, last], "last_positions": samples["positions"][every, last],
                "safeguard_steps": np.count_nonzero(per_step["safeguards"], axis=1),
                "decay_energies": (energy[:, 0], energy[every, latest], samples["t"][every, latest]),
                "series_summary": series_summary, "error_norms": norms}

    def _error_norms(self, samples: dict, last: np.ndarray) -> dict[str, np.ndarray]:
        """measures.error_norms per lane (NaN: not stored), from each lane's own samples (those before its count)."""
        if self.exact is None:
            return {}
        t = samples["t"]
        position_error = np.full(t.shape, -np.inf)  # max over the dofs, per lane and sample; -inf past a lane's count
        velocity_error = np.full(t.shape, -np.inf)
        kept = np.arange(t.shape[1])[None, :] <= last[:, None]
        for column in range(t.shape[1]):
            inside = kept[:, column]
            q, p = self.exact(np.where(inside, t[:, column], 0.0))
            position_error[inside, column] = np.max(np.abs(samples["positions"][:, column] - q[:, None]), axis=1)[inside]
            velocity_error[inside, column] = np.max(np.abs(samples["velocities"][:, column] - p[:, None]), axis=1)[inside]
        every = np.arange(t.shape[0])
        return {"final_velocity_error": velocity_error[every, last], "max_error": np.max(position_error, axis=1),
                "max_velocity_error": np.max(velocity_error, axis=1)}

    def _series_summary(self, energy: np.ndarray, dissipated: np.ndarray, per_step: dict, steps: np.ndarray
                        ) -> dict[str, np.ndarray]:
        """results.series_summary for every lane at once: the largest and the last energy drift over the finite samples,
        relative to the first finite one, the budget's remainder and the dissipated energy (summary.energy_remainder),
        and the mean iterations per step (the same operations, lane by lane)."""
        finite = np.isfinite(energy)
        every = np.arange(energy.shape[0])
        first = np.argmax(finite, axis=1)
        last = energy.shape[1] - 1 - np.argmax(finite[:, ::-1], axis=1)
        drift = (energy - energy[every, first][:, None]) / self.energy_scale[:, None]
        with np.errstate(invalid="ignore", over="ignore"):  # a diverged lane's last samples: inf - inf
            budget = energy + dissipated
            remainder = np.abs(budget - budget[every, first][:, None]) / self.energy_scale[:, None]
        some = finite.any(axis=1)
        largest = np.max(np.where(finite, np.abs(drift), -np.inf), axis=1)
        largest_remainder = np.max(np.where(finite, remainder, -np.inf), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            means = {key: np.where(steps > 0, per_step[key].sum(axis=1, dtype=np.float64) / np.maximum(steps, 1), 0.0)
                     for key in ("newton_iterations", "linear_iterations")}
        return {"max_rel_energy_drift": np.where(some, largest, np.nan),
                "final_rel_energy_drift": np.where(some, drift[every, last], np.nan),
                "max_rel_energy_remainder": np.where(some, largest_remainder, np.nan),
                "final_rel_dissipated_energy": np.where(some, dissipated[every, last] / self.energy_scale, np.nan),
                "mean_newton_iterations": means["newton_iterations"], "mean_linear_iterations": means["linear_iterations"]}


class LaneSummary:
    """record.series: false. The summary's series numbers (results.series_summary) accumulated per lane: the largest
    and the last finite energy drift over the samples, the solver iterations summed over the steps, the safeguarded
    steps counted; the last sample's t, x and v (the final errors) and the largest errors over the samples
    (measures.error_norms)."""

    def __init__(self, energy_scale: np.ndarray, lanes: int, dofs: int, modal_energy, exact=None):
        self.scale = energy_scale
        self.modal_energy = modal_energy
        self.exact = exact  # the lane system's exact_states (None: no exact solution)
        self.max_error = np.full(lanes, -np.inf)  # max |x - x_exact| over the samples so far (NaN propagates, as np.max)
        self.max_velocity_error = np.full(lanes, -np.inf)
        self.last_velocities = np.zeros((lanes, dofs))
        self.first_energy: np.ndarray | None = None
        self.max_drift = np.full(lanes, math.nan)
        self.final_drift = np.full(lanes, math.nan)
        self.first_budget: np.ndarray | None = None  # E0 + the dissipated energy at the first sample
        self.max_remainder = np.full(lanes, math.nan)
        self.final_dissipated = np.full(lanes, math.nan)
        self.newton = np.zeros(lanes, dtype=np.int64)
        self.linear = np.zeros(lanes, dtype=np.int64)
        self.safeguard_steps = np.zeros(lanes, dtype=np.int64)
        self.last_t = np.zeros(lanes)
        self.last_positions = np.zeros((lanes, dofs))
        self.decay_energy = np.full(lanes, math.nan)  # the last sample usable for the decay (measures.measured_decay)
        self.decay_t = np.zeros(lanes)

    def sample(self, observed: dict, t, dissipated, x, v, running: np.ndarray | None) -> None:
        energy = observed["energy"]
        modal = self.modal_energy(energy, x, v)
        if self.first_energy is None:  # results.energy_drift: relative to the first finite sample, E at t = 0 (finite: x0 is)
            self.first_energy = energy.copy()
            self.first_budget = energy + dissipated
            self.first_modal = self.decay_energy = modal
        self._add(np.ones(energy.shape, dtype=bool) if running is None else running, energy, modal, t, dissipated, x, v)

    def stop_sample(self, stopping: np.ndarray, observed: dict, t, dissipated, x, v) -> None:
        self._add(stopping, observed["energy"], self.modal_energy(observed["energy"], x, v), t, dissipated, x, v)

    def _add(self, recorded: np.ndarray, energy: np.ndarray, modal: np.ndarray, t, dissipated, x, v) -> None:
        """A sample of the ``recorded`` lanes: its drift and the budget's remainder count where the energy is finite
        (results.energy_drift, energy_remainder), its t and x are the lane's last sample whatever they are
        (measures.final_error)."""
        drift = (energy - self.first_energy) / self.scale
        size = np.abs(drift)
        finite = recorded & np.isfinite(energy)
        self.max_drift = np.where(finite & ~(size <= self.max_drift), size, self.max_drift)  # NaN max: none yet
        self.final_drift = np.where(finite, drift, self.final_drift)
        with np.errstate(invalid="ignore", over="ignore"):  # a diverged lane: inf - inf
            remainder = np.abs(energy + dissipated - self.first_budget) / self.scale
        self.max_remainder = np.where(finite & ~(remainder <= self.max_remainder), remainder, self.max_remainder)
        self.final_dissipated = np.where(finite, dissipated / self.scale, self.final_dissipated)
        self.last_t = np.where(recorded, t, self.last_t)
        self.last_positions = np.where(recorded[:, None], x, self.last_positions)
        self.last_velocities = np.where(recorded[:, None], v, self.last_velocities)
        if self.exact is not None:
            q, p = self.exact(np.broadcast_to(t, recorded.shape))
            position_error = np.max(np.abs(x - q[:, None]), axis=1)
            velocity_error = np.max(np.abs(v - p[:, None]), axis=1)
            self.max_error = np.where(recorded, np.maximum(self.max_error, position_error), self.max_error)
            self.max_velocity_error = np.where(recorded, np.maximum(self.max_velocity_error, velocity_error),
                                               self.max_velocity_error)
        usable = recorded & np.isfinite(modal) & (modal > DECAY_FLOOR * self.first_modal)
        self.decay_energy = np.where(usable, modal, self.decay_energy)
        self.decay_t = np.where(usable, t, self.decay_t)

    def solver_step(self, n: int, stats, running) -> None:
        if running is None:
            self.newton += stats.iterations
            self.linear += stats.linear_iterations
            self.safeguard_steps += stats.safeguards != 0
        else:
            self.newton += np.where(running, stats.iterations, 0)
            self.linear += np.where(running, stats.linear_iterations, 0)
            self.safeguard_steps += running & (stats.safeguards != 0)

    def finish(self, steps: np.ndarray) -> dict:
        with np.errstate(invalid="ignore", divide="ignore"):
            newton = np.where(steps > 0, self.newton / np.maximum(steps, 1), 0.0)
            linear = np.where(steps > 0, self.linear / np.maximum(steps, 1), 0.0)
        norms = {}
        if self.exact is not None:
            _, p = self.exact(self.last_t)
            norms = {"final_velocity_error": np.max(np.abs(self.last_velocities - p[:, None]), axis=1),
                     "max_error": self.max_error, "max_velocity_error": self.max_velocity_error}
        return {"samples": {}, "sample_count": None, "per_step": {}, "last_t": self.last_t,
                "last_positions": self.last_positions, "safeguard_steps": self.safeguard_steps, "error_norms": norms,
                "decay_energies": (self.first_modal, self.decay_energy, self.decay_t),
                "series_summary": {"max_rel_energy_drift": self.max_drift, "final_rel_energy_drift": self.final_drift,
                                   "max_rel_energy_remainder": self.max_remainder,
                                   "final_rel_dissipated_energy": self.final_dissipated,
                                   "mean_newton_iterations": newton, "mean_linear_iterations": linear}}


def _write(into: dict, row: int, observed: dict, t, dissipated, x, v) -> None:
    for key, value in observed.items():
        into[key][row] = value
    into["t"][row] = t
    into["dissipated_energy"][row] = dissipated
    into["positions"][row] = x
    into["velocities"][row] = v


def lane_final_error(system, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """measures.final_error per lane: max |x - x_exact| at the last sample (NaN without an exact solution)."""
    exact = getattr(system, "exact_states", None)
    if exact is None:
        return np.full(t.shape, math.nan)
    q, _ = exact(t)
    return np.max(np.abs(x - q[:, None]), axis=1)


def lane_errors(system, t: np.ndarray, x: np.ndarray, v: np.ndarray, frequency: np.ndarray) -> np.ndarray:
    """measures.error_at per lane: the phase-space distance sqrt(|x - x_e|^2 + |v - v_e|^2 / w^2) where the lane is
    the test equation, else max |x - x_e|; NaN where the lane has no error time or no exact solution."""
    exact = getattr(system, "exact_states", None)
    if exact is None:
        return np.full(t.shape, math.nan)
    reached = ~np.isnan(t)
    q, p = exact(np.where(reached, t, 0.0))
    position_error, velocity_error = x - q[:, None], v - p[:, None]
    squared_frequency = np.array([value ** 2 for value in frequency.tolist()])  # Python's pow, as simulate takes it
    phase = np.sqrt(np.sum(position_error ** 2, axis=1) + np.sum(velocity_error ** 2, axis=1) / squared_frequency)
    errors = np.where(np.isnan(frequency), np.max(np.abs(position_error), axis=1), phase)
    return np.where(reached, errors, math.nan)


def lane_decays(decay_energies, frequencies: np.ndarray) -> list[float]:
    """measures.measured_decay per lane, from (V(0), V at the last usable sample, its t), V the modal energy: NaN where
    V(0) is not positive or no sample after t = 0 is usable."""
    first, energy, t = (values.tolist() for values in decay_energies)
    return [decay_per_period(e0, e, time, w) if e0 > 0.0 and time > 0.0 else math.nan
            for e0, e, time, w in zip(first, energy, t, frequencies.tolist())]
