"""`simrun fit CONFIG`: calibrate the config's parameters to observed motion for every integrator x dt of its sweep
(simrun.calibration), write OUTPUT/results.h5 (its ``fits`` group and the fitted runs), then the figures."""

from __future__ import annotations

import sys

from simrun.commands._options import add_executor_options, add_experiment_options, executor_name
from simrun.commands.run import EXIT_INTERRUPTED  # 128 + SIGINT, as for a run


def add_parser(commands) -> None:
    fit = commands.add_parser(
        "fit", help="calibrate parameters to observed motion, per integrator and dt (a config with a fit block)",
        description="Fit the config's `fit.parameters` to the observations `fit.observed` with scipy's least_squares, "
                    "once per integrator x dt of the sweep, and write OUTPUT/results.h5 (a `fits` group, and each "
                    "fit's run) and OUTPUT/figures/. See docs/calibration.md.")
    fit.add_argument("config", help="the experiment's YAML file with a fit block, e.g. configs/calibrate_spring.yaml")
    add_experiment_options(fit, "--set fit.observed.synthetic.noise=0")
    add_executor_options(fit, "fits")
    fit.add_argument("--force", action="store_true", help="start over even if OUTPUT/results.h5 holds other results")
    fit.add_argument("-q", "--quiet", action="store_true", help="print only errors and the final paths")
    fit.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.calibration.pipeline import fit

    try:
        results = fit(args.config, output=args.output, jobs=args.jobs, executor=executor_name(args),
                      scheduler=args.scheduler, force=args.force, progress=not args.quiet,
                      figures=not args.no_plots, svg=args.svg, overrides=args.overrides, command_line=getattr(args, "command_line", None))
    except KeyboardInterrupt:
        print("simrun: interrupted: the finished fits are in the results file; run the same command again to finish "
              "the rest", file=sys.stderr)
        return EXIT_INTERRUPTED
    counts = results.fits.table["status"].value_counts().to_dict() if results.fits is not None else {}
    print(f"results: {results.path}  ({', '.join(f'{count} {status}' for status, count in counts.items())})")
    if not args.no_plots:
        print(f"figures: {results.path.parent / 'figures'}  ({len(results.figure_files)} files)")
    return 0
