"""The runs of a results file as every reader after the file sees them: each run with what follows from its
series (``RunData``: damping, period, h w, its integrator), the runs grouped by the settings of their swept keys
(``RunSet``), and the predictions for the integrators they name. Figures, tables and findings all read these.

The measured and predicted numbers come from ``simrun.analysis.oscillator``, imported on first use: reading a
file loads no integrator, system or solver; a prediction does (it probes the integrators named in the file, never
the runs).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from simrun.format.record import run_attribute
from simrun.analysis.reference import ReferenceErrors
from simrun.format.summary import Status
from simrun.results import Results, StoredRun

if TYPE_CHECKING:
    from simrun.analysis import oscillator


@dataclasses.dataclass(eq=False)
class RunData:
    """One run as the figures, tables and findings read it: the stored run, and what follows from its series."""

    stored: StoredRun
    group: str  # JSON of the swept parameters other than dt and integrator.*
    reference_error: float = math.nan  # m, at the error time against a reference (run_set), for runs without an exact solution
    error_from_reference: bool = False

    # -- the stored description -----------------------------------------------------------------
    @property
    def run_id(self) -> str:
        return self.stored.run_id

    @property
    def index(self) -> int:
        return self.stored.index

    @property
    def label(self) -> str:
        return self.stored.label

    @property
    def integrator(self) -> str:
        return self.stored.integrator

    @property
    def integrator_params(self) -> dict:
        return self.stored.integrator_params

    @property
    def dt(self) -> float:
        return self.stored.dt

    @property
    def status(self) -> Status:
        return self.stored.status

    @property
    def explicit(self) -> bool:
        return self.stored.explicit

    @property
    def order(self) -> int:
        return self.stored.order

    @property
    def steps(self) -> int:
        return self.stored.steps

    @property
    def wall_time(self) -> float:
        return self.stored.wall_time

    @property
    def frequency(self) -> float | None:
        """w (rad/s) when the run is the undamped test equation, else None (the system's declaration)."""
        return self.stored.test_frequency

    @property
    def explicit_frequency(self) -> float | None:
        """rad/s: the frequency that bounds the run's stable step, off the test equation (0: no bound)."""
        return self.stored.explicit_frequency

    @functools.cached_property
    def length_scale(self) -> float:
        return self.stored.length_scale

    # -- series, read on first use ------------------------------------------------------------
    @functools.cached_property
    def t(self) -> np.ndarray:
        return self.stored.series("t")

    @functools.cached_property
    def energy(self) -> np.ndarray:
        return self.stored.series("energy")

    @functools.cached_property
    def energy_ref(self) -> float:
        """E_ref (J): the run's energy reference as its system declared it (``StoredRun.energy_reference``;
        format 1: |E0|, or |KE0| + |PE0| when E0 = 0). Every energy figure divides by it, never by E0 alone:
        a cloth at rest has E0 = 0 (or round-off)."""
        return float(self.stored.energy_reference)

    @property
    def energy_reference_name(self) -> str:
        """What E_ref is, e.g. "E0 (initial energy)" or "max(M |g| L, |KE0| + |PE0|)"."""
        return str(self.stored.energy_reference_name)

    @property
    def duration(self) -> float:
        """s: the run's planned duration (format 1, which did not store it: its last sample's time)."""
        if "duration" in self.stored.attrs:
            return float(self.stored.attrs["duration"])
        t = self.t[np.isfinite(self.t)]
        return float(t[-1]) if t.size else math.nan

    @property
    def error(self) -> float:
        """m: the run's error at its error time (``StoredRun.error``), or, for a run without an exact solution,
        its error against the reference that run_set was given."""
        return self.reference_error if self.error_from_reference else self.stored.error

    @property
    def error_time(self) -> float:
        """s: when ``error`` was measured (``StoredRun.error_time``)."""
        return self.stored.error_time

    @functools.cached_property
    def newton_iterations(self) -> np.ndarray:
        return self.stored.series("newton_iterations")

    @functools.cached_property
    def nonlinear_iterations(self) -> float:
        """Newton (nonlinear) iterations of the whole run, rejected tries of a step-controlled run included; NaN for
        a peer (scipy does not report its own) and a run kept without series."""
        if self.stored.attrs.get("integrator") == "solve_ivp" or not self.newton_iterations.size:
            return math.nan if self.steps else 0.0
        return float(np.sum(self.newton_iterations))

    @property
    def function_evaluations(self) -> float:
        """Force evaluations of the whole run (``function_evaluations``); NaN in files from before they were counted."""
        return float(run_attribute(self.stored.attrs, "function_evaluations"))

    @property
    def tolerance(self) -> float:
        """The tolerance of a step-controlled run (NaN for a run of fixed steps)."""
        return float(self.stored.params.get("step_control.tolerance", math.nan))

    @functools.cached_property
    def positions(self) -> np.ndarray:
        """(samples, dof) m, or (0, 0) when the run keeps frames instead."""
        positions = self.stored.series("positions")
        return positions if positions.ndim == 2 else np.empty((0, 0))

    @property
    def xy(self) -> np.ndarray:
        """(samples, 2) m: the trajectory in the x-y plane of a planar run's body."""
        positions = self.positions
        return positions[:, :2] if positions.shape[1] >= 2 else np.empty((0, 2))

    @property
    def coordinate(self) -> np.ndarray | None:
        """(samples,) m, the first coordinate of a test-equation run (for its zero crossings)."""
        if self.frequency is None or self.positions.shape[0] == 0:
            return None
        return self.positions[:, 0]

    # -- what follows from them -------------------------------------------------------------------
    @property
    def hw(self) -> float:
        """h w of the run (NaN when it is not the test equation)."""
        return self.dt * self.frequency if self.frequency else math.nan

    @functools.cached_property
    def method(self):
        """The integrator object (from its name and parameters) for its predictions, or None where there is none to
        make: a method this simrun does not know, a whole-run peer, or a method whose step is not linear."""
        from simrun.analysis import oscillator

        try:
            return oscillator.integrator_from_params(self.integrator, self.integrator_params, self.stored.integrator_class)
        except Exception:  # another version's file, a plug-in that does not import here: no prediction, the rest draws
            return None

    @functools.cached_property
    def damping_fit(self):
        """The measured artificial damping (``oscillator.DampingFit``, energy decay) of an undamped linear run
        that did not stop early; None otherwise."""
        if self.frequency is None or self.status.stopped or not self.has_change:
            return None
        from simrun.analysis import oscillator

        return oscillator.measure_damping(self.t, self.energy, self.coordinate, self.frequency)

    @functools.cached_property
    def period_error(self) -> float:
        """T / T_exact - 1 measured from the zero crossings of the first coordinate (NaN where not measurable)."""
        if self.frequency is None or self.coordinate is None or self.status.stopped:
            return math.nan
        from simrun.analysis import oscillator

        return oscillator.measure_period_error(self.t, self.coordinate, self.frequency)

    @property
    def has_series(self) -> bool:
        """At least one finite energy sample: something to draw."""
        return int(np.count_nonzero(np.isfinite(self.energy))) >= 1

    @property
    def has_change(self) -> bool:
        """At least two finite energy samples: a drift or growth can be measured."""
        return int(np.count_nonzero(np.isfinite(self.energy))) >= 2

    @property
    def energy_change(self) -> np.ndarray:
        """(E - E0) / E_ref over the run: 0 where the energy is conserved (every system, whatever the sign of E0)."""
        energy = self.energy
        if energy.size == 0 or not np.isfinite(energy[0]):
            return np.full(energy.shape, np.nan)
        return (energy - energy[0]) / self.energy_ref

    def status_note(self) -> str:
        return {Status.DIVERGED: " (diverged)", Status.FAILED: " (failed)",
                Status.NOT_CONVERGED: " (solver not converged)"}.get(self.status, "")


@dataclasses.dataclass
class RunSet:
    """Every run of a results file, grouped by its swept parameters other than dt (``groups``: one entry per setting
    of all of them, in config order), with the integrator labels in config order and a name per dt."""

    name: str
    runs: list[RunData]
    groups: list[tuple[str, list[RunData]]]  # (title, runs) per setting of every swept key, in config order
    labels: list[str]  # integrator labels in config order
    dt_names: dict[float, str]  # dt (s) -> the shortest text that tells it from the other dts
    results: Results  # the file, for series that only one reader needs
    # the reference the errors of runs without an exact solution are measured against, with its estimated accuracy
    # (None: no reference solved, or the errors handed in as a plain dict)
    reference: ReferenceErrors | None = None

    @property
    def path(self) -> Path:
        return self.results.path


def run_set(results: Results, reference_errors: dict[str, float] | None = None) -> RunSet:
    """The runs of ``results``; ``reference_errors`` (run id -> m) stand in for a NaN error."""
    runs = []
    for stored in results.runs.values():
        group = json.dumps(stored.swept, sort_keys=True)
        if reference_errors and stored.run_id in reference_errors and not np.isfinite(stored.error):
            runs.append(RunData(stored, group, reference_errors[stored.run_id], error_from_reference=True))
        else:
            runs.append(RunData(stored, group))
    grouped: dict[str, list[RunData]] = {}
    for run in runs:
        grouped.setdefault(run.group, []).append(run)
    groups = [(settings_title(members[0].stored.swept), members) for members in grouped.values()]
    labels = list(dict.fromkeys(run.label for run in runs))
    reference = reference_errors if isinstance(reference_errors, ReferenceErrors) else None
    return RunSet(results.name, runs, groups, labels, _dt_names(sorted({run.dt for run in runs})), results, reference)


def test_equation_runs(data: RunSet) -> list[RunData]:
    """The runs on the undamped test equation (spring, linear circular motion): h w is defined for them."""
    return [run for run in data.runs if run.frequency is not None]


def predictions_for(data: RunSet, runs: list[RunData] | None = None) -> dict[str, "oscillator.Prediction"]:
    """label -> predicted curves for each label whose integrator this simrun knows, over oscillator.HW_RANGE
    widened to cover the runs' h w."""
    from simrun.analysis import oscillator  # on first use: reading a file loads no integrator

    runs = test_equation_runs(data) if runs is None else runs
    xs = [run.hw for run in runs if np.isfinite(run.hw) and run.hw > 0]
    low = min([oscillator.HW_RANGE[0]] + [0.5 * min(xs)] if xs else [oscillator.HW_RANGE[0]])
    high = max([oscillator.HW_RANGE[1]] + [2.0 * max(xs)] if xs else [oscillator.HW_RANGE[1]])
    # a decade boundary keeps the grid (and so the cache key) the same for similar files
    low, high = 10.0 ** math.floor(math.log10(low)), 10.0 ** math.ceil(math.log10(high))
    methods = {}
    for run in data.runs:
        if run.label not in methods and run.method is not None:
            methods[run.label] = run.method
    return {label: oscillator.predict(method, low, high) for label, method in methods.items()}


def explicit_prediction(method) -> "oscillator.Prediction":
    """The test-equation prediction of ``method``'s explicit form (the method itself, or an IMEX method with nothing
    implicit), whose stability limit over the run's ``explicit_frequency`` bounds its step."""
    from simrun.analysis import oscillator

    return oscillator.predict(method.explicit_form())


# What a solver's iterations are called in the tables: the solver's own name for its iteration.
SOLVER_ITERATION_NAMES = {"newton": "Newton", "projected_newton": "Newton", "lbfgs": "L-BFGS",
                          "gradient_descent": "gradient descent", "jacobi_chebyshev": "Jacobi-Chebyshev",
                          "projective_dynamics": "local-global", "vbd": "VBD sweep"}


def solver_text(solver: dict) -> str:
    """A run's solver type and its fallbacks, e.g. "newton+projected_newton"."""
    fallbacks = [item.get("type", "") if isinstance(item, dict) else str(item) for item in solver.get("fallback") or []]
    return "+".join(filter(None, [str(solver.get("type", ""))] + fallbacks))


def run_iteration_names(runs) -> dict[str, str]:
    """What the solver iterations of these runs (implicit ones) count, by solver type: {"newton": "Newton",
    "lbfgs": "L-BFGS", ...} (fallbacks included): a figure names them rather than call every iteration Newton's."""
    kinds = {kind for run in runs if not run.explicit for kind in solver_text(run.stored.solver).split("+") if kind}
    return {kind: SOLVER_ITERATION_NAMES.get(kind, kind) for kind in sorted(kinds)}


def settings_title(swept: dict, width: int | None = None) -> str:
    """"key = value, ..."; with ``width``, broken into lines of at most that many characters between settings
    (a panel's title: three swept solver keys side by side run into the neighbouring panels' titles)."""
    parts = [f"{name} = {format_value(value)}" for name, value in swept.items()]
    if width is None:
        return ", ".join(parts)
    lines = [""]
    for part in parts:
        if lines[-1] and len(lines[-1]) + 2 + len(part) > width:
            lines[-1] += ","
            lines.append(part)
        else:
            lines[-1] += (", " if lines[-1] else "") + part
    return "\n".join(lines)


def format_value(value) -> str:
    """A swept value as the figures write it: floats in %g, anything else as str."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def _dt_names(dts: list[float]) -> dict[float, str]:
    """Three significant digits (logspace sweeps), more only where two time steps would read alike."""
    for digits in range(3, 18):
        names = [f"{dt:.{digits}g}" for dt in dts]
        if len(set(names)) == len(names):
            break
    return dict(zip(dts, names))
