"""The run record, declared once: every attribute a run stores, every per-step column, and how a run's status is
decided.

Every producer of runs (the stepping loop in ``simulate``, lanes, scipy's peers) fills these names and no others
(the writer's ``check_record`` holds them to it), and every reader takes a missing attribute's value from here
(``run_attribute``): a new per-run field is declared in RUN_FIELDS and filled by its producer. docs/results-format.md
lists the same names and types (tests/test_record.py compares them). Like the reader, this module imports numpy only.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from collections.abc import Mapping

import numpy as np


class Status(str, enum.Enum):
    """How a run ended (the ``status`` attribute); a ``str``, so ``Status.OK == "ok"``."""

    OK = "ok"  # reached the end time
    DIVERGED = "diverged"  # energy non-finite or beyond the bound (``t_diverged`` says when)
    NOT_CONVERGED = "not_converged"  # some step's solver hit max_iterations
    FAILED = "failed"  # an exception; its message is stored

    def __str__(self) -> str:
        return self.value

    @property
    def stopped(self) -> bool:
        """The run did not reach its end time with data to trust (diverged or failed)."""
        return self in (Status.DIVERGED, Status.FAILED)


# the summary's numbers that come from a run's series; a run recorded without them (record.series: false) stores
# them as attributes instead
SERIES_SUMMARY_KEYS = ("max_rel_energy_drift", "final_rel_energy_drift", "max_rel_energy_remainder",
                       "final_rel_dissipated_energy", "mean_newton_iterations", "mean_linear_iterations")

# the paths of a sparse factorisation, as simrun.solvers.linear names them (a test holds the two equal; the format
# names them itself so that reading a file imports no solver)
FACTORISATION_PATHS = ("symmetric", "threshold", "colamd")
REQUIRED = object()  # a field every run has, in every format version: no default


@dataclass(frozen=True)
class RunField:
    """One per-run attribute (``/runs/<run_id>``'s, or a field of a lane chunk's table)."""

    type: type  # int, float, str, bool or np.ndarray
    unit: str  # SI unit, "" for counts, names and flags
    doc: str  # one line; docs/results-format.md says the rest
    default: object = REQUIRED  # what a run that lacks it reads (older files, or runs it does not apply to)


@dataclass(frozen=True)
class StepColumn:
    """One per-step dataset (``/runs/<run_id>/<name>``, one row per step)."""

    dtype: type  # the numpy type it is stored as
    stats_field: str | None  # the solver's SolveStats field it records, None where the loop fills it
    unit: str
    doc: str


_F, _I, _S, _B = float, int, str, bool
NAN = math.nan

RUN_FIELDS: dict[str, RunField] = {
    # what the run was (the writer, from the config's run)
    "index": RunField(_I, "", "position in the expanded sweep"),
    "system": RunField(_S, "", "the system's type as the config names it"),
    "system_params": RunField(_S, "", "JSON of the system's parameters, defaults filled in"),
    "integrator": RunField(_S, "", "the integrator's name (a plug-in's declared name, else its path)"),
    "integrator_label": RunField(_S, "", "name plus non-default parameters"),
    "integrator_class": RunField(_S, "", "the method's class as package.module:ClassName", ""),
    "integrator_source_sha256": RunField(_S, "", "sha256 of the file that defines the method's class", ""),
    "order": RunField(_I, "", "the method's order of accuracy"),
    "explicit": RunField(_B, "", "whether the method is explicit"),
    "solver": RunField(_S, "", "JSON of the solver's parameters"),
    "dt": RunField(_F, "s", "time step; a step-controlled run's mean accepted step"),
    "duration": RunField(_F, "s", "simulated time asked for"),
    "params": RunField(_S, "", "JSON of every swept and method parameter"),
    "planned_steps": RunField(_I, "", "steps the run would take to the end"),
    # how it ended (every producer)
    "status": RunField(_S, "", "ok, diverged, not_converged or failed (decide_status)"),
    "steps": RunField(_I, "", "steps taken"),
    "wall_time": RunField(_F, "s", "time spent in the stepping loop"),
    "message": RunField(_S, "", "why a run is not ok", ""),
    "t_diverged": RunField(_F, "s", "when the energy left the bound (diverged runs only)", NAN),
    "final_error": RunField(_F, "m", "max |x - x_exact| at the last sample", NAN),
    "final_velocity_error": RunField(_F, "m/s", "max |v - v_exact| at the last sample", NAN),
    "max_error": RunField(_F, "m", "max |x - x_exact| over the stored samples", NAN),
    "max_velocity_error": RunField(_F, "m/s", "max |v - v_exact| over the stored samples", NAN),
    "error_time": RunField(_F, "s", "when the run's error is measured", NAN),
    "error": RunField(_F, "m", "distance from the exact solution at error_time", NAN),
    "not_converged_steps": RunField(_I, "", "steps whose solver did not converge, accepted ones included", 0),
    "first_not_converged_step": RunField(_I, "", "the first of them, 1-based; 0: none", 0),
    "diverged_step": RunField(_I, "", "the step at whose end the energy left the bound; 0: none", 0),
    "safeguard_steps": RunField(_I, "", "steps in which any solver safeguard fired", 0),
    **{f"factorisations_{path}": RunField(_I, "", f"sparse LU factorisations that took the {path} path", 0)
       for path in FACTORISATION_PATHS},
    "min_contact_distance": RunField(_F, "m", "the smallest signed contact distance over the steps", NAN),
    "max_active_contacts": RunField(_I, "", "the most contacts acting in one step", 0),
    "friction_work": RunField(_F, "J", "the energy friction took out over the run", NAN),
    "decay_per_period": RunField(_F, "", "an oscillator's measured amplitude factor per period", NAN),
    "explicit_frequency": RunField(_F, "rad/s", "the largest frequency an explicit method steps stably at dt", NAN),
    # NaN where a run does not count them (fixed steps)
    "function_evaluations": RunField(_I, "", "force evaluations of a step-controlled run or a peer", NAN),
    "jacobian_evaluations": RunField(_I, "", "Hessian or Jacobian evaluations of the same", NAN),
    "factorisations": RunField(_I, "", "every factorisation of a step-controlled run (a peer: scipy's nlu)", NAN),
    "accepted_steps": RunField(_I, "", "a step-controlled run's steps kept", NAN),
    "rejected_steps": RunField(_I, "", "a step-controlled run's tries taken again smaller", 0),
    "not_converged_attempts": RunField(_I, "", "rejected tries whose solve did not converge", 0),
    "threads": RunField(_I, "", "threads of the run's compiled kernels", 1),
    "trajectory_metadata": RunField(_S, "", "a recorded trajectory's free-form metadata, as JSON", ""),
    "engine": RunField(_S, "", "the engine that took the steps, its version, precision and device", ""),
    # the system's capabilities (systems/capabilities.py, Capabilities.as_attrs)
    "test_frequency": RunField(_F, "rad/s", "w of the undamped test equation; NaN otherwise", NAN),
    "length_scale": RunField(_F, "m", "the scale of position errors", 1.0),
    "energy_scale": RunField(_F, "J", "the energy reference E_ref of drifts and the divergence bound", NAN),
    "energy_reference_name": RunField(_S, "", "what E_ref is", "the system's energy scale"),
    "frame_shape": RunField(np.ndarray, "", "the vertex grid of a frame (rows, columns); empty off a grid",
                            np.zeros(0, dtype=np.int64)),
    # files before it: 0, and the reader takes the frames' own shape
    "vertex_dim": RunField(_I, "", "coordinates per vertex of frames; 0 without frames", 0),
    "planar": RunField(_B, "", "one body moving in the x-y plane", False),
    "dof_count": RunField(_I, "", "degrees of freedom of the system", 0),
    "natural_frequency": RunField(_F, "rad/s", "w0 of a linear oscillator; NaN for other systems", NAN),
    "damping_ratio": RunField(_F, "", "zeta of the same oscillator; NaN for other systems", NAN),
    # record.series: false keeps the summary's series numbers instead of the series
    **{key: RunField(_F, "", "the summary's number, for a run kept without series", NAN) for key in SERIES_SUMMARY_KEYS},
    # the writer's mark of a run written whole
    "complete": RunField(_B, "", "the run's group was written to the end", False),
}

# the solver's statistics of each step (SolveStats), in every implicit run and in lanes
SOLVER_STEP_COLUMNS: dict[str, StepColumn] = {
    "newton_iterations": StepColumn(np.int32, "iterations", "", "nonlinear iterations"),
    "linear_iterations": StepColumn(np.int32, "linear_iterations", "", "linear solver iterations summed over the step"),
    "line_search_steps": StepColumn(np.int32, "line_search_steps", "", "line-search reductions in the step"),
    "residual": StepColumn(np.float64, "residual", "", "the solver's final residual"),
    "solver_index": StepColumn(np.int8, "solver_index", "", "which solver of the fallback chain finished the step"),
    "safeguards": StepColumn(np.uint8, "safeguards", "", "bits of the safeguards that fired in the step"),
}
# sparse systems whose solver factors with `direct` or `cholesky`
FACTORISATION_STEP_COLUMNS = {
    "factorisation_path": StepColumn(np.int8, None, "", "the furthest path a sparse LU factorisation took; 0: none"),
}
# systems with contact
CONTACT_STEP_COLUMNS = {
    "contact_distance": StepColumn(np.float64, None, "m", "the smallest signed contact distance at the step's end"),
    "active_contacts": StepColumn(np.int32, None, "", "the contacts acting at the step's end"),
    "friction_work": StepColumn(np.float64, None, "J", "the energy friction took out in the step"),
}
# step-controlled runs (a peer records dt alone)
CONTROL_STEP_COLUMNS = {
    "dt": StepColumn(np.float64, None, "s", "the accepted step's size"),
    "error_estimate": StepColumn(np.float64, None, "", "its error estimate's scaled norm (<= 1: within the tolerance)"),
    "rejected_attempts": StepColumn(np.int16, None, "", "the tries rejected before it"),
}
STEP_COLUMNS: dict[str, StepColumn] = {**SOLVER_STEP_COLUMNS, **FACTORISATION_STEP_COLUMNS, **CONTACT_STEP_COLUMNS,
                                       **CONTROL_STEP_COLUMNS}


def check_record(attrs: Mapping) -> None:
    """Every name in a producer's attributes is declared in RUN_FIELDS: a producer that stores an undeclared field
    is a programming error, caught where the run is made rather than by a reader that cannot know its default."""
    undeclared = [key for key in attrs if key not in RUN_FIELDS]
    if undeclared:
        raise KeyError(f"run attributes not declared in simrun.format.record.RUN_FIELDS: {', '.join(undeclared)}")


def run_attribute(attrs: Mapping, name: str):
    """A run's attribute ``name`` as stored, else its declared default (a file or a run without it)."""
    if name in attrs:
        return attrs[name]
    default = RUN_FIELDS[name].default
    if default is REQUIRED:
        raise KeyError(f"run attribute {name!r} is required and missing")
    return default


def decide_status(*, failed: bool, diverged: bool, over_budget: bool, not_converged_steps: int,
                  accept_not_converged: bool) -> Status:
    """How a run ended, the one rule for every producer: failed (an exception, or a step controller's end) and
    diverged (the energy left the bound) as they happened; else not_converged where the run stopped at
    record.max_wall_time, or where some step's solve did not converge and solver.on_not_converged is not accept (a
    real-time budget's steps are what it bought); else ok."""
    if failed:
        return Status.FAILED
    if diverged:
        return Status.DIVERGED
    if over_budget or (not_converged_steps and not accept_not_converged):
        return Status.NOT_CONVERGED
    return Status.OK


def not_converged_message(not_converged_steps: int, steps: int, time_budget: bool = False) -> str:
    """The message of a run left not_converged by its solves (and no other message)."""
    limits = "max_iterations" + (" or time_budget" if time_budget else "")
    return f"{not_converged_steps} of {steps} steps did not converge within {limits}"
