"""`simrun analyze`: the predicted damping, spectral radius, period error and stability limit of integrators, no runs."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from simrun.commands._options import add_svg_option, writable_output, writing_folder
from simrun.errors import ConfigError

DEFAULT_OUTPUT = Path("results") / "analysis"
TABLE_NAME = "predicted.csv"


def add_parser(commands) -> None:
    analyze = commands.add_parser(
        "analyze", help="predicted damping, spectral radius, period error and stability limits of integrators (no runs)",
        description="Probe each integrator's amplification matrix on the test spring q'' + w^2 q = 0 and draw its "
                    "artificial damping, spectral radius and period error against h w; no runs needed.")
    analyze.add_argument("--integrators", nargs="+", metavar="SPEC",
                         help="names, with parameters as name:key=value[,key=value] or name[key=value], e.g. "
                              "backward_euler implicit_midpoint 'generalized_alpha:rho_inf=0.5' (default: every integrator)")
    analyze.add_argument("--range", nargs=2, type=float, metavar=("LOW", "HIGH"), default=None,
                         help="the h w range of the curves (default: 0.01 100)")
    analyze.add_argument("--output", help=f"folder for the figures and {TABLE_NAME} (default: {DEFAULT_OUTPUT})")
    add_svg_option(analyze)
    analyze.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.analysis import oscillator as analysis
    from simrun.integrators import INTEGRATORS
    from simrun.report.summary_table import csv_number

    integrators = []
    for spec in args.integrators or list(INTEGRATORS):
        try:
            integrators.append(analysis.parse_integrator(spec))
        except ValueError as error:
            raise ConfigError(f"--integrators: {error}") from None
    low, high = args.range if args.range else analysis.HW_RANGE
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low < high):
        raise ConfigError(f"--range: expected 0 < LOW < HIGH, got {low:g} {high:g}")
    if math.log10(high / low) > 12:
        raise ConfigError(f"--range: at most 12 decades, got {low:g} to {high:g}")
    field = "--output" if args.output else "output"
    output = writable_output(Path(args.output) if args.output else DEFAULT_OUTPUT, field, kind="folder")
    predictions = {}
    for integrator in integrators:
        predictions.setdefault(integrator.label, analysis.predict(integrator, low, high))
    with writing_folder(output, field) as folder:  # the figures and the table, or nothing
        written = draw_predicted_figures(predictions, folder, svg=args.svg)
        with open(folder / TABLE_NAME, "w", newline="") as stream:
            writer = csv.writer(stream)
            writer.writerow(["integrator", "hw", "spectral_radius", "damping_over_w", "relative_period_error"])
            for label, prediction in predictions.items():
                for row in zip(prediction.hw, prediction.rho, prediction.damping, prediction.period_error):
                    writer.writerow([label] + [csv_number(value) for value in row])
    print(format_predictions(predictions))
    print(f"figures: {output}  ({len(written)} files); curves: {output / TABLE_NAME}")
    return 0


def draw_predicted_figures(predictions: dict, output: Path, svg: bool = False) -> list[Path]:
    """The damping and the spectral radius/period figures of predictions alone, as PNG (and SVG, with ``svg``)."""
    import matplotlib.pyplot as plt

    from simrun.figures import _layout as layout
    from simrun.figures._style import label_colours, label_markers
    from simrun.figures.theory import damping_figure, spectral_figure

    labels = list(predictions)
    colours = label_colours(labels)
    markers = label_markers(labels)
    figures = {
        "artificial_damping": damping_figure(predictions, colours, markers, "predicted artificial damping"),
        "spectral_radius_and_period": spectral_figure(predictions, colours, markers, "predicted spectral radius and period error"),
    }
    written = []
    for name, figure in figures.items():
        try:
            written += layout.save_figure(figure, output / name,
                                          formats=layout.VECTOR_FORMATS if svg else layout.FORMATS)
        finally:
            plt.close(figure)
    return written


def format_predictions(predictions: dict) -> str:
    """One line per integrator: order, stability limit, rho as h w -> infinity (implicit methods) and d/w at three h w."""
    from simrun.analysis import oscillator as analysis
    from simrun.analysis.units import damping_text

    lines = [f"{'integrator':<36} {'order':>5}  {'stability limit h w':>20}  {'rho(inf)':>8}  "
             f"{'d/w at h w = 0.1':>16}  {'1':>9}  {'10':>9}"]
    for label, prediction in predictions.items():
        limit = prediction.stability_limit
        limit_text = (f"none ≤ {prediction.hw[-1]:g}" if math.isinf(limit)
                      else (analysis.growth_phrase(prediction) if limit == 0 else f"{limit:.6g}"))
        # the limit map of an explicit method is not defined (it grows without bound), nor cheap for the exponential one
        radius = "–" if prediction.integrator.explicit else damping_text(analysis.high_frequency_radius(prediction.integrator))
        damping = [prediction.at(hw)[1] for hw in (0.1, 1.0, 10.0)]
        lines.append(f"{label:<36} {prediction.integrator.order_of_accuracy:>5}  {limit_text:>20}  {radius:>8}  "
                     f"{damping_text(damping[0]):>16}  {damping_text(damping[1]):>9}  {damping_text(damping[2]):>9}")
    return "\n".join(lines)
