"""Every figure of every shipped config names what it draws: each integrator label and each swept value of the file
appears in each figure that draws that kind of data (in a legend, a panel title, a table's tick labels or a row
header), or the figure says in a note how much it shows ("4 of 21 ...").

Each shipped config (configs/*.yaml, found by glob: a new config is tested without editing this file) runs with
shortened settings (fewer and larger time steps, a shorter duration, a coarser cloth) serially into tmp_path; the
figures are drawn through ``simrun.figures.render_figures``, as ``simrun plot`` and the report draw them.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
import yaml
from matplotlib.text import Text

from conftest import config_params
from simrun.analysis.reference import reference_errors
from simrun.analysis.rows import summary_rows
from simrun.analysis.runs import format_value
from simrun.cli import main
from simrun.figures import figure_data, render_figures
from simrun.findings.cost import solver_cost
from simrun.results import load

CONFIGS = sorted((Path(__file__).parents[1] / "configs").glob("*.yaml"))
CLOTH = ["system.resolution=[4,4]"]
# per config: --set overrides that keep every integrator and every swept value but cut the work
SHORT = {
    "quickstart": ["duration=1.0", "sweep.dt=[0.01,0.1,0.25]"],
    "spring_stability": ["duration=1.0", "sweep.dt=[0.01,0.19,0.25]"],
    "circular_orbits": ["duration=3.0", "sweep.dt=[0.1,0.3]"],
    "damping_curves": ["duration=12.0", "sweep.dt=[0.3,1.0,3.0]"],
    "xpbd_damping": ["duration=12.0", "sweep.dt=[0.3,1.0,3.0]"],
    "engine_cards": ["duration=12.0", "sweep.dt=[0.1,1.0,2.5]"],
    "engine_cloth": [*CLOTH, "duration=0.04", "sweep.dt=[0.002,0.008]"],
    "engine_beam": ["duration=0.01", "sweep.dt=[0.0005,0.002]"],
    "cloth_hang": [*CLOTH, "duration=0.06", "sweep.dt=[0.02,0.03]"],
    "cloth_sphere": [*CLOTH, "duration=0.04", "sweep.dt=[0.01,0.02]"],
    "cloth_convergence": [*CLOTH, "duration=0.04", "sweep.dt=[0.01,0.02]"],
    # the point Jacobi iteration diverges on the cloth: its runs use every iteration they are given
    "solver_comparison": [*CLOTH, "duration=0.04", "sweep.dt=[0.01,0.02]", "solver.max_iterations=20",
                          "solver.linear_max_iterations=50"],
    "course_square": ["duration=0.05", "sweep.dt=[0.004,0.002]"],
    "rope": ["duration=0.02"],
    "mixed_stiffness": ["duration=0.02", "sweep.dt=[0.005,0.01]"],
    "curtain": ["system.model={grid: {resolution: [6, 5], size: [1.0, 0.8]}}", "duration=0.03"],
    "twist": ["duration=0.05", "sweep.dt=[0.005,0.01]"],
    "slope": ["duration=0.05"],
    "cloth_drop": [*CLOTH, "duration=0.04", "sweep.dt=[0.01,0.02]"],
    "spot_drop": ["duration=0.04"],  # lands at t = 0.03 s
    "penalty_vs_ipc": [*CLOTH, "duration=0.04"],
    "fem_square": ["duration=0.05", "sweep.dt=[0.005,0.01]"],
    "soft_drop": ["duration=0.12"],  # lands at t = 0.1 s
    "twisted_bar": ["duration=0.6", "sweep.dt=[0.01,0.02]"],  # released at t = 0.5 s
    "cloth_fem": ["duration=0.3", "sweep.dt=[0.004]"],  # lands at t = 0.25 s
    "high_order_kepler": ["sweep.dt=[0.1,0.05]"],
    "high_order_fem": ["duration=0.01", "sweep.step_control.tolerance=[1.0e-1,1.0e-2]", "record.max_steps=200"],
    "imex_cloth": [*CLOTH, "duration=0.04", "sweep.dt=[0.0005,0.01]"],
    "work_precision": ["duration=0.05", "sweep.step_control.tolerance=[1.0e-2,1.0e-4]"],
    # three sizes as the config has, smaller (its 64x64 Newton runs take seconds a frame)
    "realtime_solvers": ["duration=0.05", "sweep.system.resolution=[[4, 4], [6, 6], [8, 8]]"],
    "realtime_fem": ["duration=0.05", "sweep.system.model.box.cells=[[2, 1, 1], [4, 1, 1]]"],
    # calibrations (`simrun fit`): every integrator at two steps, observations every 10 ms of a short motion
    # the map: every integrator at 4 step sizes h w x 3 damping ratios (its sweep has 100 x 60)
    "damping_map": ["duration=1.0", "sweep.system.stiffness={logspace: [0.0, 6.0, 4]}",
                    "sweep.system.damping_ratio=[0.0, 0.3, 1.0]"],
    "calibrate_spring": ["duration=1.0", "sweep.dt=[0.01,0.05]", "fit.observed.synthetic.dt=0.01",
                         "fit.transfer.dt=[0.01]", "fit.max_evaluations=20"],
    "calibrate_soft_body": ["duration=0.1", "sweep.dt=[0.01,0.02]", "fit.observed.synthetic.dt=0.001",
                            "fit.transfer.dt=[0.01]", "fit.max_evaluations=6"],
    "calibrate_cloth": [*CLOTH, "duration=0.1", "sweep.dt=[0.01,0.02]", "fit.observed.synthetic.dt=0.002",
                        "fit.markers=[0,5]", "fit.transfer.dt=[0.01]", "fit.max_evaluations=6"],
}
DEFAULT_SHORT = ["duration=0.1"]  # a config added without an entry above: at least not its full length

# figure name -> which runs it draws (default: every run) and whether it tells the swept settings apart
THEORY = {"artificial_damping", "spectral_radius_and_period"}  # per integrator, in h w: no settings
MAPS = {"damping_map"}  # per integrator over (h w, zeta): the settings are its axes, every run a cell


def draws(name: str, run, cost_runs: set) -> bool:
    if name == "cost_vs_accuracy":  # the runs of the cost findings
        return run.run_id in cost_runs
    if name == "newton_iterations_vs_dt":
        return not run.explicit and run.newton_iterations.size > 0
    if name in ("convergence", "work_precision"):
        return not run.status.stopped and np.isfinite(run.error)
    if name in THEORY:
        return run.frequency is not None
    if name in MAPS:
        return np.isfinite(run.stored.attrs.get("natural_frequency", np.nan))
    if name == "orbits":
        return run.stored.planar
    if name.startswith("frames_"):  # one snapshot figure per run
        return name == f"frames_{run.run_id}"
    return True


# a note that says how much the figure shows: "12 of 45 runs", "4 of 21 time steps"
PART_SHOWN = re.compile(r"\b\d+ of \d+\b")


def texts(figure) -> list[str]:
    """Every text of a figure: legends (and their titles), titles, axis and tick labels, notes."""
    return [artist.get_text() for artist in figure.findobj(Text) if artist.get_visible() and artist.get_text()]


def named(value: str, text: str) -> bool:
    """`value` occurs in `text` as a whole name: "cg" not inside "pcg", "newton" not inside "projected_newton"."""
    return re.search(r"(?<![\w.\[=])" + re.escape(value) + r"(?![\w\[])", text) is not None


def shortened(config: Path) -> list[str]:
    return [argument for override in SHORT.get(config.stem, DEFAULT_SHORT) for argument in ("--set", override)]


@pytest.mark.parametrize("config", config_params(CONFIGS))
def test_every_figure_names_every_integrator_and_swept_value(config, tmp_path):
    output = tmp_path / config.stem
    command = "fit" if "fit" in yaml.safe_load(config.read_text()) else "run"  # a calibration is fitted
    assert main([command, str(config), "--output", str(output), "-q", "--no-plots", "-j", "1", *shortened(config)]) == 0
    results = load(output / "results.h5")
    # systems without an exact solution: errors against a reference, so that convergence is drawn (and checked) too
    errors = reference_errors(results, "dop853")
    data = figure_data(results, errors)
    runs = data.runs
    cost_runs = {method["run_id"] for finding in solver_cost(data, summary_rows(data)) if "methods" in finding.evidence
                 for method in finding.evidence["methods"].values()}
    missing = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no figure may warn
        for entry, name, figure in render_figures(results, errors or None):
            try:
                drawn = [run for run in runs if draws(name, run, cost_runs)]
                words = "\n".join(texts(figure))
                wanted = {run.label for run in drawn}
                if entry.name not in THEORY | MAPS:
                    wanted |= {format_value(value) for run in drawn for value in run.stored.swept.values()}
                absent = sorted(value for value in wanted if not named(value, words))
                if absent and not PART_SHOWN.search(words):
                    missing[name] = absent
            finally:
                plt.close(figure)
    assert not missing, f"{config.stem}: figures that leave out integrators or swept values without saying so: {missing}"
