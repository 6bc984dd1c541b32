"""`simrun show RESULTS`: the summary table in the terminal, or as CSV.

    simrun show results.h5                      # the table, fitted to 100 columns
    simrun show results.h5 --wide               # every column
    simrun show --csv results.h5                # CSV on standard output (every column, units in the headers)
    simrun show results.h5 --output table.csv   # CSV into a file (written whole or not at all)
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from simrun.commands._options import load_results, writable_output, writing_file


def add_parser(commands) -> None:
    show = commands.add_parser("show", help="print the summary table of a results file (or write it as CSV)",
                               description="Print one row per run: status, drift, error, solver iterations, cost, "
                                           "and measured against predicted artificial damping.")
    show.add_argument("results", help="a results file, e.g. results/quickstart/results.h5")
    show.add_argument("--wide", action="store_true",
                      help="every column (by default the table is fitted to a 100-character terminal)")
    show.add_argument("--csv", action="store_true",
                      help="write the table as CSV (every column, full precision, units in the headers: dt_s, "
                           "wall_time_s, error_m, ...) to standard output, or to --output")
    show.add_argument("--output", "-o", metavar="FILE",
                      help="write the CSV to FILE instead (implies --csv); the file is replaced whole, or not at all")
    show.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.analysis.rows import summary_rows
    from simrun.figures import figure_data
    from simrun.report.summary_table import format_table, write_csv

    output = getattr(args, "output", None)
    target = writable_output(Path(output), "--output") if output else None  # refused before any work
    results = load_results(args.results)
    with results.opened():
        rows = summary_rows(figure_data(results))
    if target is not None:
        with writing_file(target, "--output") as temporary, open(temporary, "w", newline="") as stream:
            write_csv(rows, stream)
        print(f"summary: {target}  ({len(rows)} runs)")
        return 0
    if getattr(args, "csv", False):
        _to_stdout(lambda: write_csv(rows, sys.stdout))
        return 0
    _to_stdout(lambda: print(format_table(rows, results.name, wide=getattr(args, "wide", False))))
    return 0


def _to_stdout(write) -> None:
    """Write to standard output; a reader that stops early (`simrun show ... | head`) is not an error."""
    try:
        write()
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
