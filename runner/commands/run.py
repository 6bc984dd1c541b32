"""`simrun run CONFIG` (or `simrun CONFIG`): every run of the sweep, the results file, then the figures."""

from __future__ import annotations

import sys
from collections import Counter

from simrun.commands._options import add_executor_options, add_experiment_options, executor_name

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report Ctrl-C
DEFAULT_MAX_SIZE_GB = 50.0  # = simrun.results.writer.DEFAULT_MAX_SIZE_GB (the writer is not imported before a run)


def add_parser(commands) -> None:
    run = commands.add_parser("run", help="run an experiment: every run of its sweep, then its figures",
                              description="Run every run of CONFIG's sweep, write OUTPUT/results.h5 and draw OUTPUT/figures/.")
    run.add_argument("config", help="the experiment's YAML file, e.g. configs/quickstart.yaml")
    add_experiment_options(run, "--set system.stiffness=1000 --set sweep.dt=[0.01,0.02]")
    add_executor_options(run, "runs")
    run.add_argument("--lanes", choices=("auto", "off"), default="auto",
                     help="auto: step many small runs of one kind (the spring's maps) together as lanes of one array, "
                          "each run's data what it would be alone (default); off: every run alone")
    run.add_argument("--force", action="store_true", help="start over even if OUTPUT/results.h5 holds other results, removing "
                                                          "its old figures and report first (default: resume an unchanged config)")
    run.add_argument("--max-size", type=float, default=DEFAULT_MAX_SIZE_GB, metavar="GB",
                     help=f"refuse a sweep whose results would exceed this size (default {DEFAULT_MAX_SIZE_GB:g} GB)")
    run.add_argument("-q", "--quiet", action="store_true", help="print only errors and the final paths")
    run.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.pipeline import Interrupted, run

    try:
        results = run(args.config, output=args.output, jobs=args.jobs,
                      executor=executor_name(args), scheduler=args.scheduler,
                      force=args.force, progress=not args.quiet, figures=not args.no_plots, svg=args.svg,
                      overrides=args.overrides, max_size_gb=args.max_size,
                      command_line=getattr(args, "command_line", None), lanes=args.lanes)
    except Interrupted as interrupted:
        print(f"simrun: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED
    print_written(results, figures=not args.no_plots)
    return 0


def print_written(results, figures: bool) -> None:
    """The final lines: the results file with its runs counted, and the figures' folder where they were drawn."""
    print(f"results: {results.path}  ({counts_text(results)})")
    if figures:
        print(f"figures: {results.path.parent / 'figures'}  ({len(results.figure_files)} files)")


def counts_text(results) -> str:
    """The file's runs by status, then what this invocation ran where that was not all of them (a resume):
    "336 runs in the file: 1 diverged, 55 not_converged, 280 ok; this invocation ran 17 not_converged, 38 ok"."""
    def counted(counts: dict) -> str:
        return ", ".join(f"{count} {status}" for status, count in sorted(counts.items()))

    in_file = Counter(str(run.status) for run in results.runs.values())
    ran = sum(results.ran.values())
    if ran == len(results.runs):
        return counted(in_file)
    this = f"this invocation ran {counted(results.ran)}" if ran else "nothing left to run"
    return f"{len(results.runs)} runs in the file: {counted(in_file)}; {this}"
