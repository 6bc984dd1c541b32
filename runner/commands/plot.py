"""`simrun plot RESULTS`: redraw every registered figure the file supports (PNG; SVG too on request), from the file
alone."""

from __future__ import annotations

from pathlib import Path

from simrun.commands._options import (add_reference_option, add_svg_option, load_results, say, writable_output,
                                     writing_folder)
from simrun.results.lock import FIGURES_NAME


def add_parser(commands) -> None:
    plot = commands.add_parser("plot", help="redraw the figures from a results file alone",
                               description="Draw every figure that RESULTS supports into its folder's figures/ (PNG; with --svg, SVG too).")
    plot.add_argument("results", nargs="?", help="a results file, e.g. results/quickstart/results.h5")
    plot.add_argument("--output", help=f"figure folder (default: {FIGURES_NAME}/ beside the results file)")
    plot.add_argument("--list", action="store_true", help="list the figures simrun draws, with what each needs, and exit")
    add_reference_option(plot, default="auto")  # simrun plot RESULTS --reference auto|dop853|...|none|RUN_ID
    plot.add_argument("-j", "--jobs", type=int, help="figures drawn at once (default: the number of cores, at most 4; 1: "
                                                    "in this process)")
    add_svg_option(plot)
    plot.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.figures import FIGURES, draw_figures

    if args.list:
        for name, entry in FIGURES.items():
            print(f"{name}: needs {entry.needs}")
        return 0
    if args.results is None:
        from simrun.errors import ConfigError

        raise ConfigError("results: give a results file, e.g. simrun plot results/quickstart/results.h5 (or --list)")
    from simrun.execution.workers import default_jobs

    jobs = default_jobs() if args.jobs is None else args.jobs
    if jobs < 1:
        from simrun.errors import ConfigError

        raise ConfigError(f"--jobs: must be >= 1, got {jobs}")
    results = load_results(args.results)
    field = "--output" if args.output else "output"
    out = writable_output(Path(args.output) if args.output else results.path.parent / FIGURES_NAME, field, kind="folder")
    errors = None
    reference = args.reference
    if reference is not None and reference.lower() == "auto":
        from simrun.analysis.reference import automatic_reference

        reference = automatic_reference(results)
    if reference is not None and reference.lower() != "none":
        from simrun.analysis.reference import reference_errors

        errors = reference_errors(results, reference, say=say)
    with writing_folder(out, field) as folder:
        written = draw_figures(results, folder, reference_errors=errors, jobs=jobs, svg=args.svg)
    print(f"figures: {out}  ({len(written)} files)")
    return 0
