"""`simrun show RESULTS`: the summary table in the terminal, or as CSV."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from simrun.commands._options import load_results


def add_parser(commands) -> None:
    show = commands.add_parser("show", help="print the summary table of a results file (or write it as CSV)",
                               description="Print one row per run: status, drift, error, iterations, cost, "
                                           "and measured against predicted artificial damping.")
    show.add_argument("results", help="a results file, e.g. results/quickstart/results.h5")
    show.add_argument("--csv", nargs="?", const="-", metavar="FILE",
                      help="write the table as CSV to FILE (to standard output without FILE)")
    show.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.figures import figure_data
    from simrun.tables import format_table, summary_rows, write_csv

    results = load_results(args.results)
    with results.opened():
        rows = summary_rows(figure_data(results))
    if args.csv is not None:
        if args.csv == "-":
            _to_stdout(lambda: write_csv(rows, sys.stdout))
        else:
            target = Path(args.csv)
            target.parent.mkdir(parents=True, exist_ok=True)
            with open(target, "w", newline="") as stream:
                write_csv(rows, stream)
            print(f"summary: {target}  ({len(rows)} runs)")
        return 0
    _to_stdout(lambda: print(format_table(rows, results.name)))
    return 0


def _to_stdout(write) -> None:
    """Write to standard output; a reader that stops early (`simrun show ... | head`) is not an error."""
    try:
        write()
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
