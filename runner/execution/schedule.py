"""When a run steps, samples and measures its error: fixed steps of dt, or the steps a step controller chooses.

``simulate`` runs one loop for both; the schedule is what differs. Both answer the same questions: the next step
(``next_step``), whether the step just taken is sampled (``sample_due``), drawn as a frame (``frame_due``), the
one at which the run's error is measured (``at_error_time``), the last (``done``), and what the run stores of its
steps (``attrs``).
"""

from __future__ import annotations

import math

from simrun.integrators import State
from simrun.solvers.linear import FactorisationLog

from .recording import STEP_ROWS, SampleCadence
from .step_control import StepController

# the per-step columns a step-controlled run adds (simrun.format.record.CONTROL_STEP_COLUMNS)
CONTROL_COLUMNS = ("dt", "error_estimate", "rejected_attempts")


class FixedSteps:
    """run.step_count steps of run.dt; samples every ``stride``-th step, frames every ``frame_stride``-th, the
    error at the end of step ``error_step``; the last step is always sampled and framed."""

    controlled = False
    log_columns: tuple[str, ...] = ()

    def __init__(self, run, system):
        self.step_count, self.dt = run.step_count, run.dt
        self.stride = run.record.stride(self.step_count)
        self.frame_stride = run.record.frame_stride(self.step_count)
        self.error_step = run.record.error_step(self.dt, self.step_count, system.capabilities.test_frequency)
        self.sample_rows = self.step_count // self.stride + 2
        self.frame_rows = self.step_count // self.frame_stride + 2
        self.log_rows = self.step_count
        self.steps, self.t = 0, 0.0
        self.factorisations = None  # a fixed-step run counts only its sparse factorisations, by path

    def first_size(self, system, state: State) -> float:
        return self.dt

    @property
    def done(self) -> bool:
        return self.steps == self.step_count

    def next_step(self, system, state: State, step, solver, log) -> tuple[State, object]:
        """Step n + 1 from t = n dt: the colliders moved to its end first; the loop owns t (no accumulated
        round-off, whatever state.t says)."""
        n = self.steps
        contact = system.contact_form()
        if contact:  # colliders move to the step's end; IPC's stiffness is estimated and updated
            contact.begin_step(self.dt * n, self.dt, state.x)
        state, stats = step(system, state, self.dt, solver)
        self.steps = n + 1
        self.t = self.dt * self.steps
        return state, stats

    def sample_due(self) -> bool:
        return self.steps % self.stride == 0 or self.done

    def frame_due(self) -> bool:
        return self.steps % self.frame_stride == 0 or self.done

    def at_error_time(self) -> bool:
        return self.steps == self.error_step

    def changed(self, system) -> None:
        """The system changed at a release of prescribed paths: nothing to follow."""

    def where(self) -> str:
        return f"step {self.steps} of {self.step_count}"

    def attrs(self) -> dict:
        return {}


class ControlledSteps:
    """The steps a StepController chooses to run.duration, landing on the error time and the releases of prescribed
    paths; samples and frames at SampleCadence's even times (or every k-th step). Every try of a step is counted,
    its evaluations and factorisations too: work-precision's currency."""

    controlled = True
    log_columns = CONTROL_COLUMNS

    def __init__(self, run, system, integrator):
        error_time = run.record.error_at(system.capabilities.test_frequency)
        self.error_time = run.duration if error_time is None else min(error_time, run.duration)
        release_stops = list(system.constraints.release_times) if system.constraints is not None else []
        self.controller = StepController(run.step_control, integrator, system,
                                         [run.duration, self.error_time, *release_stops])
        self.cadence = SampleCadence(run.record, run.duration)
        self.sample_rows, self.frame_rows = self.cadence.sample_rows, self.cadence.frame_rows
        self.log_rows = STEP_ROWS  # the rows grow as the steps come
        self.steps, self.t, self.dt = 0, 0.0, math.nan
        # every factorisation, sparse or dense, its solver's or its method's own (Radau IIA's blocks); a fixed-step
        # run's solver log joins it (simulate)
        self.factorisations = FactorisationLog()

    def first_size(self, system, state: State) -> float:
        return self.controller.step_size(system, state)

    @property
    def done(self) -> bool:
        return self.controller.done

    def next_step(self, system, state: State, step, solver, log) -> tuple[State, object]:
        """One accepted step (its tries before it rejected); its size, error estimate and rejected tries go to the
        log. Raises StepTooSmall below dt_min."""
        controller = self.controller
        cost, rejected = None, 0

        def prepare(t: float, size: float, x) -> None:
            """Before each try: the colliders move to its end (the system as released so far)."""
            contact = system.contact_form()
            if contact:
                contact.begin_step(t, size, x)

        while True:
            size = controller.step_size(system, state)
            new, stats, error = controller.attempt(system, state, size, solver, prepare)
            cost = stats if cost is None else cost.followed_by(stats)
            if controller.judge(size, error, stats.converged):
                break
            rejected += 1
        row = self.steps
        log.grow_to(row + 1)
        log.put(row, dt=size, error_estimate=error, rejected_attempts=rejected)
        self.steps, self.dt = row + 1, size
        self.t = controller.t  # every stop (the duration, the error time, a release) reached exactly
        return new, cost._replace(residual=stats.residual, converged=stats.converged)

    def sample_due(self) -> bool:
        return self.cadence.sample_due(self.steps, self.t) or self.done

    def frame_due(self) -> bool:
        return self.cadence.frame_due(self.steps, self.t) or self.done

    def at_error_time(self) -> bool:
        return self.t == self.error_time

    def changed(self, system) -> None:
        self.controller.changed(system)

    def where(self) -> str:
        return f"step {self.steps}"

    def attrs(self) -> dict:
        """The stored dt is the mean accepted step; the controller's counts; every factorisation."""
        controller, steps = self.controller, self.steps
        return {"dt": controller.t / steps if controller.t > 0 and steps else math.nan, "planned_steps": steps,
                "accepted_steps": controller.accepted_steps, "rejected_steps": controller.rejected_steps,
                "not_converged_attempts": controller.failed_solves, "factorisations": self.factorisations.total}


def schedule_of(run, system, integrator):
    """The run's schedule: its step controller's steps, else fixed steps of dt."""
    return FixedSteps(run, system) if run.step_control is None else ControlledSteps(run, system, integrator)
