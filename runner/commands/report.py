"""`simrun report RESULTS`: the results file as one self-contained HTML page (simrun.report.page)."""

from __future__ import annotations

from pathlib import Path

from simrun.commands._options import add_reference_option, load_results, say, writable_output, writing_file
from simrun.results.lock import REPORT_NAME  # beside the results file, unless --output says otherwise


def add_parser(commands) -> None:
    report = commands.add_parser(
        "report", help=f"write OUTPUT/{REPORT_NAME}: config, provenance, summary table and every figure in one page",
        description="Write one self-contained HTML page (figures embedded, no external files) from a results file: "
                    "config, provenance, summary of the runs, observed orders, stability limits, determinants, "
                    "and every figure with a caption.")
    report.add_argument("results", help="a results file, e.g. results/damping_curves/results.h5")
    report.add_argument("--output", help=f"the HTML file (default: {REPORT_NAME} beside the results file)")
    add_reference_option(report, default="dop853")
    report.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.report.page import write_report

    results = load_results(args.results)  # refuses anything but a results file before any work
    field = "--output" if args.output else "output"
    output = writable_output(Path(args.output) if args.output else results.path.parent / REPORT_NAME, field)
    with writing_file(output, field) as page:
        write_report(results.path, page, reference=args.reference, say=say)
    print(f"report: {output}")
    return 0
