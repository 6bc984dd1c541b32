"""Options that several subcommands share."""

from __future__ import annotations

from pathlib import Path


def add_reference_option(parser, default: str | None = None) -> None:
    """``--reference``: what the error of runs without an exact solution (the cloth) is measured against."""
    from simrun.reference import REFERENCE_CHOICES, REFERENCE_RTOL

    parser.add_argument(
        "--reference", nargs="?", const="dop853", default=default, metavar="METHOD_OR_RUN",
        help="reference for the convergence of runs without an exact solution (the cloth): scipy solve_ivp with "
             f"DOP853 at rtol {REFERENCE_RTOL:g} (default{' here' if default else ' with the bare option'}), another method, "
             f"a run_id of the file (e.g. the smallest dt), or none; one of {REFERENCE_CHOICES}")


def load_results(text: str):
    """The results file named on the command line (``simrun.results.load``: one line for anything else)."""
    from simrun.results import load

    return load(Path(text))


def say(text: str) -> None:
    """Progress for the user, on standard error (standard output carries the command's result)."""
    import sys

    print(text, file=sys.stderr, flush=True)


__all__ = ["add_reference_option", "load_results", "say"]
