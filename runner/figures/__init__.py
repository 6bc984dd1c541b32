"""simrun.figures (folder runner/figures/): the figures of an experiment, drawn from its results file alone.

Data flows one way: the figures read the file through ``simrun.results`` and nothing else, so they
can be redrawn without re-running (``simrun plot results.h5``). One module per family (energy,
stability, solver work, theory curves, convergence, orbits, frames, calibration); this module holds the registry.

A figure is a function plus an entry in ``FIGURES``: the function takes the file's runs as
``FigureData`` and returns a matplotlib Figure, a list of (file name, Figure) pairs (one per run),
or None when the file holds nothing it could show. The entry carries its caption (the report prints
it under the figure) and what it needs from a results file (the report says so when it is not
drawn); ``simrun plot --list``, the report and the tests all read the registry.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from pathlib import Path

from simrun.analysis.runs import RunData
from simrun.figures import _layout as layout
from simrun.figures._data import FigureData, figure_data
from simrun.figures.calibration import fitted_parameters_vs_dt, observed_vs_fitted, transfer_errors
from simrun.figures.contact import contact_distance
from simrun.figures.volume import volume_ratio
from simrun.figures.convergence import convergence, work_precision
from simrun.figures.cost import cost_vs_accuracy
from simrun.figures.damping_map import damping_map
from simrun.figures.energy import energy_budget, energy_drift_vs_dt, energy_over_time
from simrun.figures.frames import SNAPSHOT_PREFIX, snapshots
from simrun.figures.orbits import orbits
from simrun.figures.solver_work import newton_iterations_vs_dt, wall_time_per_step_vs_dt
from simrun.figures.stability import stability_map
from simrun.figures.theory import artificial_damping, spectral_radius_and_period
from simrun.results import Results, load


CALIBRATION = "a calibration (simrun fit)"
# Figures drawn at once, at most: each worker reads the file and builds its figure data itself, so more than a few
# spend more on that than they save on drawing.
MAX_FIGURE_WORKERS = 4


@dataclass(frozen=True)
class Figure:
    """A registered figure: its name (the file stem), how to draw it, what it shows and what it needs."""

    name: str
    draw: Callable[[FigureData], object]
    caption: str  # what to look for, shown under the figure in the report
    needs: str  # what a results file must hold for it to be drawn
    dpi: int = layout.PNG_DPI
    # what the figure adds for runs on the undamped test equation (h w, predicted limits): the report shows it
    # only for files with such runs
    test_equation_caption: str = ""
    # drawn from the runs' recorded series (energy, frames): not drawn from a file whose runs kept none (record.series:
    # false, a map of thousands of runs), whose figures come from the runs' scalars
    from_series: bool = False
    # drawn against dt, a panel per setting of the other swept keys: not drawn for a sweep of one dt over more settings
    # than its panels show (a map, which has its own figure), where it would be single points in the first few panels
    against_dt: bool = False


FIGURES: dict[str, Figure] = {figure.name: figure for figure in (
    Figure("energy_over_time", energy_over_time,
           "The energy change (E − E₀)/E_ref against time (0: conserved; E_ref is the energy scale the system "
           "declares, named on the axis), one panel per time step, a row per setting of the swept keys (and per "
           "family of methods when there are many). Look for growth (an explicit method past its stability limit), "
           "decay towards −E₀/E_ref (the damped implicit methods) and a bounded oscillation about 0 (symplectic and "
           "energy-conserving methods). An ✕ ends a run that diverged; a note says which time steps are shown.",
           "runs with recorded energy", from_series=True),
    Figure("energy_drift_vs_dt", energy_drift_vs_dt,
           "The largest energy change max |E − E₀|/E_ref over each run against dt (log-log). Look for the slope (the "
           "drift shrinks like dt^p) and for methods at round-off (energy-conserving on this problem).",
           "runs with recorded energy", from_series=True, against_dt=True),
    Figure("stability_map", stability_map,
           "Integrators × dt (and swept settings), every run a cell, coloured by the largest energy change in decades "
           "on a scale symmetric about 0 (blue: lost, red: gained). On other systems a black bar marks the stability "
           "limit predicted at the start shape where a method has one: an explicit method's from the system's "
           "stiffest frequency, IMEX Euler's from the stiffest frequency of its explicit minus its implicit terms.",
           "runs with recorded energy",
           test_equation_caption="A black bar in a row marks the predicted stability limit dt = (h w)*/w from the "
                                 "amplification matrix: cells right of it should be red or diverged (✕), cells left of it not.", from_series=True),
    Figure("newton_iterations_vs_dt", newton_iterations_vs_dt,
           "Mean (solid) and largest (dotted) solver iterations per step of the implicit methods. Look for the growth "
           "with dt: larger steps start the solver farther from the solution.",
           "implicit methods", from_series=True, against_dt=True),
    Figure("orbits", orbits,
           "Trajectories of a body moving in the x-y plane against the circle through its start (the exact orbit of "
           "circular motion). Look for orbits that spiral out (energy gained), spiral in (energy lost) or stay on a "
           "(slightly deformed) closed curve.",
           "a planar system (one body in the x-y plane, e.g. circular motion)", from_series=True),
    Figure("artificial_damping", artificial_damping,
           "d_method/w = −2 ln ρ/(h w) against h w (Ascher's damping curves). Lines: predicted from the probed "
           "amplification matrix of each method; markers: measured from each run's energy decay (hollow where the "
           "run is too short to resolve it). Look for markers on their lines, first-order methods damping ~ h w at "
           "small steps, second-order methods damping only at large h w, and parameter families ordered by their "
           "parameter.",
           "runs on the undamped test equation (a system that declares a test frequency: spring without damping, "
           "linear circular motion)"),
    Figure("damping_map", damping_map,
           "The amplitude's decay per period over the step h w and the damping ratio ζ, a panel per method, every run a "
           "cell coloured by what it measured (log₁₀ of the factor per period 2π/w: 0 keeps the amplitude, −1 loses 90 % "
           "of it each period; red: growth, hatched: diverged). White contours: measured; black dashed: predicted from "
           "the method's amplification matrix at each point; thick red: the predicted stability boundary ρ = 1; orange "
           "dots: the exact motion's e^(−2πζ). Look for measured contours on the predicted ones, and for where a method's decay departs from "
           "the dotted physics: to the right of it the method's own damping dominates the model's.",
           "runs of a linear oscillator (the spring) over at least 3 step sizes h w and 2 damping ratios per method"),
    Figure("spectral_radius_and_period", spectral_radius_and_period,
           "Top: the spectral radius ρ(h w); ρ < 1 damps, ρ > 1 grows (a hollow circle marks a stability limit). "
           "Bottom: the relative period error T_h/T − 1 of the principal eigenvalue (up to h w = π), with the periods "
           "measured from the runs' zero crossings. A curve identical to an earlier one is dashed over it. Look for "
           "methods with ρ = 1 that still lag in phase.",
           "runs on the undamped test equation"),
    Figure("convergence", convergence,
           "Each run's error at its error time (a fixed time for the whole sweep, named on the axis) against dt "
           "(log-log), with the least-squares slope over the smallest time steps (dashed) in the legend, or why no "
           "slope could be fitted. Look for slopes equal to each method's order; runs at round-off are exact on this "
           "problem, saturated ones (error ~ the length scale) are left out of the fit.",
           "runs with an exact solution, or a reference (systems without one: --reference)", against_dt=True),
    Figure("work_precision", work_precision,
           "The same error against the wall time of each run. Lower left is better: a higher-order or cheaper method "
           "reaches a given accuracy sooner.",
           "runs with an exact solution, or a reference (systems without one: --reference)", against_dt=True),
    Figure("cost_vs_accuracy", cost_vs_accuracy,
           "What each method buys for its wall time per 1/60 s frame (the dotted line: real time), at the dt the "
           "methods share: left, the distance max |x − x_ref| of its positions from the fastest Newton run whose every "
           "step converged (★, drawn at the floor: distance 0), at the error time; right, its largest energy change, "
           "the artificial damping (or gain) it adds. The runs and numbers are the report's cost findings'. Look for "
           "the methods below and left of the others, and for the distance a real-time budget leaves.",
           "a sweep of solver.type with two methods at one dt, one of them implicit"),
    Figure("wall_time_per_step_vs_dt", wall_time_per_step_vs_dt,
           "Wall time per step against dt, one line per method (or per swept solver setting), one panel per setting "
           "of the other swept keys. Look for implicit methods getting dearer at large dt (more solver iterations).",
           "runs that took at least one step", against_dt=True),
    Figure("energy_budget", energy_budget,
           "Where the energy goes, at one time step: kinetic and potential energy (each potential term), the work "
           "done by the physical damping and by friction, stacked, over E_ref; the grey gap up to the initial energy "
           "(dashed) is the "
           "integrator's own numerical dissipation, an orange band above it a numerical gain. With damping 0 the gap "
           "is all of the drift; with damping it separates the model's loss from the method's.",
           "runs with at least two samples", from_series=True),
    Figure("contact_distance", contact_distance,
           "The smallest signed distance to the colliders (and between the model's own triangles, with self-contact) "
           "at every step, in mm; shaded below 0, where a vertex is inside. Look for a penalty's penetration, deeper "
           "the softer its stiffness, against IPC's positive gap (which never reaches 0), and for the landing steps.",
           "runs with contact", from_series=True),
    Figure("volume_ratio", volume_ratio,
           "The volume ratio J = det F of the finite elements, smallest and largest over the elements at every "
           "sample, a band per run; shaded below 0, where an element is inverted. Look for neo-Hookean elements "
           "that stay well above 0, co-rotated or StVK ones that invert, and volume lost or gained with the step.",
           "finite-element runs", from_series=True),
    Figure("snapshots", snapshots,
           "The model at four times of the run (from its stored frames), with the contact colliders drawn in grey "
           "(translucent, beneath the model) where they are at each time; the title names anything not drawn.",
           "runs that keep frames on a vertex grid (the cloth)", dpi=110, from_series=True),
    Figure("fitted_parameters_vs_dt", fitted_parameters_vs_dt,
           "Each fitted parameter against dt (log), a line per integrator with its standard errors, the predicted "
           "value (where the method's own step has the observed eigenvalue) dashed in the same colour, the truth (or "
           "the exact-solution fit) as a grey line; the top axis gives dt × w on the spring. Look for lines that "
           "leave the grey line as dt grows (the fit absorbs the method's error into the parameters), damping pushed "
           "below zero (the method damps more than the motion: the fit pumps energy in) or far above it (the method "
           "damps less, or gains), and solid lines that part from their dashed prediction.",
           CALIBRATION),
    Figure("observed_vs_fitted", observed_vs_fitted,
           "The observed positions (grey dots) against each fit's trajectory at the observation times, a panel per "
           "integrator, a line per dt, over the first and the last tenth of the observations. Look for fits that "
           "match the decay but start with an offset in amplitude or phase, and for large steps whose best "
           "trajectory still misses the dots.",
           CALIBRATION),
    Figure("transfer_errors", transfer_errors,
           "Each fit's parameters simulated with another integrator and dt (the columns), coloured by the relative rms "
           "error against the observations (log). Look for parameters that only work with the method and dt they were "
           "fitted with: small errors on the diagonal of a method with itself, large ones elsewhere.",
           CALIBRATION),
)}


def figures_for(data: FigureData) -> list[Figure]:
    """The registered figures to try on ``data``: all, but those drawn from series when no run kept any, and those
    drawn against dt when the file is a map (one dt, more settings than a figure's panels show)."""
    kept_series = any(run.stored.datasets for run in data.runs)
    a_map = len({run.dt for run in data.runs}) == 1 and len(data.sections) > layout.MAX_SUMMARY_PANELS
    return [entry for entry in FIGURES.values()
            if not ((entry.from_series and not kept_series) or (entry.against_dt and a_map))]


def render_figures(results: Results | str | Path, reference_errors: dict[str, float] | None = None,
                   names: Collection[str] | None = None) -> Iterator[tuple[Figure, str, object]]:
    """Yield (registry entry, file name, matplotlib Figure) for every figure the file supports (of ``names``, the
    registry's names, where given); the caller closes each.

    reference_errors (run_id -> error at the end time, m) stand in for the stored ``final_error`` where it is
    NaN (no exact solution); ``simrun.analysis.reference.reference_errors`` computes them on request.
    """
    results = results if isinstance(results, Results) else load(results)
    if not results.runs:
        return
    with results.opened():  # one file handle for every series the figures read
        data = figure_data(results, reference_errors)
        for entry in figures_for(data):
            if names is not None and entry.name not in names:
                continue
            drawn = entry.draw(data)
            if drawn is None:
                continue
            for name, figure in drawn if isinstance(drawn, list) else [(entry.name, drawn)]:
                yield entry, name, figure


def draw_figures(results: Results | str | Path, out_dir: str | Path,
                 reference_errors: dict[str, float] | None = None, jobs: int = 1, svg: bool = False) -> list[Path]:
    """Draw every figure the results file supports into out_dir as PNG (and SVG too, with ``svg``); returns the paths
    written.

    ``jobs`` > 1: the figures are shared out among that many worker processes (round robin over the registry, so
    that the costly ones spread), each reading the file itself; the files are the same as drawn in one process."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = results.path if isinstance(results, Results) else Path(results)
    names = list(FIGURES)
    jobs = min(jobs, MAX_FIGURE_WORKERS)
    formats = layout.VECTOR_FORMATS if svg else layout.FORMATS
    if jobs <= 1:
        return _draw_share(path, names, out_dir, reference_errors, formats,
                           results if isinstance(results, Results) else None)
    from simrun.execution.workers import process_pool, stop_workers

    # a figure registered in this process only (a user's own, added to FIGURES at run time) is drawn here: a worker
    # knows the figures of simrun's registry
    here = [name for name in names if not FIGURES[name].draw.__module__.startswith("simrun.")]
    shared = [name for name in names if name not in here]
    shares = [shared[start::jobs] for start in range(jobs)]
    pool = process_pool(jobs)
    finished = False
    try:
        futures = [pool.submit(_draw_share, path, share, out_dir, reference_errors, formats) for share in shares]
        written = _draw_share(path, here, out_dir, reference_errors, formats) if here else []
        written += [file for future in futures for file in future.result()]
        finished = True
    finally:
        if not finished:  # Ctrl-C or a figure that failed: no worker is left drawing
            stop_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)
    order = {name: number for number, name in enumerate(names)}
    return sorted(written, key=lambda file: (order.get(_entry_of(file.stem), len(order)), file.name))


def _draw_share(path: Path, names: list[str], out_dir: Path, reference_errors, formats: tuple[str, ...],
                results: Results | None = None) -> list[Path]:
    """The figures of ``names`` (registry names) of the file at ``path``, drawn and saved into out_dir."""
    import matplotlib.pyplot as plt

    written: list[Path] = []
    for entry, name, figure in render_figures(results if results is not None else path, reference_errors, names):
        try:
            written += layout.save_figure(figure, out_dir / name, dpi=entry.dpi, formats=formats)
        finally:
            plt.close(figure)
    return written


def _entry_of(stem: str) -> str:
    """The registry name a figure file belongs to (the snapshots' files are one per run, ``frames_<run>``)."""
    if stem.startswith(SNAPSHOT_PREFIX):
        return "snapshots"
    return next((name for name in FIGURES if stem == name or stem.startswith(f"{name}_")), stem)


__all__ = ["CALIBRATION", "FIGURES", "Figure", "FigureData", "RunData", "draw_figures", "figure_data", "figures_for",
           "render_figures"]
