"""What one run, or one chunk of runs stepped together as lanes, produced: the rows the stepping code hands to the
writer. A chunk's table and summary rows (``lane_table``, ``lane_summary``) are built where it ran, so that the
single writer stores a handful of datasets per chunk (docs/results-format.md, "Lane chunks")."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import h5py
import numpy as np

from simrun.experiment.config import Run
from simrun.format.layout import ERROR_NORMS
from simrun.format.summary import SUMMARY_DTYPE, Status, real_time_factor, wall_time_per_frame
from simrun.integrators import plugins as integrator_plugins


@dataclass
class RunResult:
    """Everything one run produced: outcome, recorded samples and per-step solver statistics."""

    run_id: str
    status: Status
    steps: int  # steps taken (fewer than planned when the run stopped early)
    wall_time: float  # s, the stepping loop alone
    samples: dict[str, np.ndarray]  # one row per recorded sample: t, energies, positions, ...
    per_step: dict[str, np.ndarray]  # one row per step: newton_iterations, linear_iterations, ...
    t_diverged: float | None = None
    message: str = ""
    attrs: dict = field(default_factory=dict)
    model: dict[str, np.ndarray] = field(default_factory=dict)  # the drawn topology: model_edges, model_triangles


@dataclass
class LaneBatch:
    """The runs of one chunk, column by column (one row per run), as the writer stores them (docs/results-format.md,
    /lanes). ``results()`` gives each run as the RunResult that ``simulate`` would have returned."""

    runs: list[Run]
    status: list[Status]
    steps: np.ndarray  # (lanes,) steps taken
    wall_time: np.ndarray  # (lanes,) s: the chunk's stepping time shared equally among its lanes
    t_diverged: np.ndarray  # (lanes,) s, NaN where the run did not diverge
    message: list[str]
    attrs: list[dict]
    samples: dict[str, np.ndarray] = field(default_factory=dict)  # key -> (lanes, samples, ...), NaN past a lane's count
    sample_count: np.ndarray | None = None  # (lanes,)
    per_step: dict[str, np.ndarray] = field(default_factory=dict)  # key -> (lanes, steps), zero past a lane's steps
    error_positions: np.ndarray | None = None  # (lanes, dofs), NaN where the run ended before its error time
    results_alone: list[RunResult] | None = None  # the chunk failed as lanes: its runs, each stepped alone
    table: tuple | None = None  # (shared attributes, a row per run): lane_table, built where the chunk ran
    summary: np.ndarray | None = None  # the runs' summary rows: lane_summary, likewise

    @property
    def run_ids(self) -> list[str]:
        return [run.run_id for run in self.runs]

    def results(self) -> list[RunResult]:
        if self.results_alone is not None:
            return self.results_alone
        return [self.result(lane) for lane in range(len(self.runs))]

    def result(self, lane: int) -> RunResult:
        samples = {}
        if self.sample_count is not None:
            count = int(self.sample_count[lane])
            samples = {key: np.ascontiguousarray(values[lane, :count]) for key, values in self.samples.items()}
            if not math.isnan(self.attrs[lane].get("error_time", math.nan)):
                samples["error_positions"] = self.error_positions[lane].copy()
        steps = int(self.steps[lane])
        per_step = {key: values[lane, :steps].copy() for key, values in self.per_step.items()}
        t_diverged = None if math.isnan(self.t_diverged[lane]) else float(self.t_diverged[lane])
        return RunResult(run_id=self.runs[lane].run_id, status=self.status[lane], steps=steps,
                         wall_time=float(self.wall_time[lane]), samples=samples, per_step=per_step,
                         t_diverged=t_diverged, message=self.message[lane], attrs=dict(self.attrs[lane]))


def lane_summary(runs: list[Run], batch: LaneBatch, series: dict[str, np.ndarray]) -> np.ndarray:
    """The summary rows of a chunk's runs (SUMMARY_DTYPE), as ``summary_row`` computes them from each run's group;
    ``series``: results.series_summary's numbers per lane."""
    rows = np.empty(len(runs), dtype=SUMMARY_DTYPE)
    rows["run_id"] = [run.run_id for run in runs]
    rows["integrator"] = [run.integrator_label for run in runs]
    rows["dt"] = [run.dt for run in runs]
    rows["status"] = [str(status) for status in batch.status]
    rows["steps"] = batch.steps
    for key, values in series.items():
        rows[key] = values
    for key in ("final_error", "error_time", "error", *ERROR_NORMS):
        rows[key] = [attrs.get(key, math.nan) for attrs in batch.attrs]
    rows["wall_time"] = batch.wall_time
    rows["real_time_factor"] = [real_time_factor(steps, run.dt, wall) for steps, run, wall in
                                zip(batch.steps.tolist(), runs, batch.wall_time.tolist())]
    rows["wall_time_per_frame"] = [wall_time_per_frame(steps, run.dt, wall) for steps, run, wall in
                                   zip(batch.steps.tolist(), runs, batch.wall_time.tolist())]
    return rows


def lane_table(runs: list[Run], batch: LaneBatch) -> tuple[dict, np.ndarray]:
    """A chunk's attributes as the writer stores them: (the attributes its runs share, a table with a row per run and a
    field per other attribute), each what a run's own group would hold. Built by the worker that stepped the chunk."""
    first = runs[0]
    shared = {"system": first.system.type, "integrator": first.integrator.name,
              "integrator_label": first.integrator_label, **integrator_plugins.provenance(type(first.integrator)),
              "order": first.integrator.order,
              "explicit": first.integrator.explicit, "solver": json.dumps(first.solver.model_dump(mode="json")),
              "planned_steps": first.step_count}
    columns = {"run_id": [run.run_id for run in runs], "index": [run.index for run in runs],
               "system_params": [json.dumps(run.system.model_dump(mode="json")) for run in runs],
               "dt": [run.dt for run in runs], "duration": [run.duration for run in runs],
               "status": [str(status) for status in batch.status], "steps": batch.steps.tolist(),
               "wall_time": batch.wall_time.tolist(), "params": [json.dumps(run.params) for run in runs],
               "message": batch.message, "t_diverged": batch.t_diverged.tolist()}
    for key in dict.fromkeys(key for attrs in batch.attrs for key in attrs):
        values = [attrs.get(key, math.nan) for attrs in batch.attrs]
        if isinstance(values[0], np.ndarray):  # array attributes (frame_shape) are the system's: one per chunk
            shared[key] = values[0]
        else:
            columns[key] = values
    # one table, a row per run and a field per attribute: one dataset however many attributes (each costs a write)
    table = np.empty(len(runs), dtype=[(key, h5py.string_dtype() if isinstance(values[0], str) else np.asarray(values).dtype)
                                       for key, values in columns.items()])
    for key, values in columns.items():
        table[key] = values
    return shared, table
