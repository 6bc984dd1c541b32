"""Options and steps that several subcommands share: the reference option, the results file, and the
outputs they write (checked before any work, written so that a failure leaves nothing half-written)."""

from __future__ import annotations

from pathlib import Path


def add_experiment_options(parser, example: str) -> None:
    """What `simrun run` and `simrun fit` both take after the config: ``--set`` (``example``: a use of it),
    ``--output``, ``--no-plots`` and ``--svg``."""
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help=f"override a config key, value in YAML (repeatable), e.g. {example}")
    parser.add_argument("--output", help="output folder (default: the config's `output`, else results/<name>)")
    parser.add_argument("--no-plots", action="store_true", help="write the results file only")
    add_svg_option(parser)


def add_executor_options(parser, what: str) -> None:
    """Where ``what`` (runs, fits) are done and how many at once: ``-j``, ``--executor`` and ``--scheduler``, which
    ``executor_options`` turns into the one object the executors take."""
    from simrun.execution.workers import EXECUTOR_ALIASES, EXECUTORS

    parser.add_argument("-j", "--jobs", type=int,
                        help=f"{what} at once: local processes or Dask workers (default: the number of cores; 1 = serial)")
    parser.add_argument("--executor", choices=(*EXECUTORS, *EXECUTOR_ALIASES), default="process",
                        help="process: a process pool on this machine (default; `local` is the same); "
                             "dask: a Dask cluster (pip install 'simrun[dask]')")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="with --executor dask: an existing scheduler, e.g. tcp://host:8786 (default: a local cluster)")


def executor_name(args) -> str:
    """The executor the command line names (an alias as its executor)."""
    from simrun.execution.workers import EXECUTOR_ALIASES

    return EXECUTOR_ALIASES.get(args.executor, args.executor)


def add_svg_option(parser) -> None:
    """``--svg``: every figure as SVG too (PNG alone by default)."""
    parser.add_argument("--svg", action="store_true", help="write each figure as SVG too, a vector copy for papers "
                                                          "(default: PNG only, what the report shows)")


def add_reference_option(parser, default: str = "none") -> None:
    """``--reference METHOD_OR_RUN``: what the error of runs without an exact solution (the cloth) is measured
    against. It always takes a value, so that it never takes the results file for one."""
    from simrun.analysis.reference import REFERENCE_CHOICES, REFERENCE_RTOL

    parser.add_argument(
        "--reference", default=default, metavar="METHOD_OR_RUN",
        help="reference for the convergence of runs without an exact solution (the cloth): dop853 (scipy solve_ivp "
             f"with DOP853 at rtol {REFERENCE_RTOL:g}), another method, a run_id of the file (e.g. the smallest dt), "
             f"or none; one of {REFERENCE_CHOICES} (default: {default})")


def field_overrides(overrides: list[str], section: str, argument: str, metavar: str, example: str) -> dict:
    """``{section: {type: argument}}`` (the command's first argument, shown as ``metavar``) with each ``--set FIELD=VALUE`` of a check command applied (the value in YAML, as
    a config's ``--set``; ``section.FIELD`` taken too): ConfigError in one line for an assignment that is not one, or
    that sets the type, which is the command's own argument."""
    from simrun.errors import ConfigError
    from simrun.experiment.config import apply_override

    raw = {section: {"type": argument}}
    for assignment in overrides:
        key, sep, value = assignment.partition("=")
        key = key.strip().removeprefix(f"{section}.")
        if not sep or not key:
            raise ConfigError(f"--set {assignment}: expected field=value, e.g. {example}")
        if key == "type":
            raise ConfigError(f"--set {assignment}: the {section} is the {metavar} argument; give it there")
        apply_override(raw, f"{section}.{key}={value}")
    return raw


def load_results(text: str):
    """The results file named on the command line (``simrun.results.load``: one line for anything else)."""
    from simrun.results import load

    return load(Path(text))


def writable_output(path: str | Path, field: str, *, kind: str = "file") -> Path:
    """The output ``path`` that option ``field`` names, refused before any work when it cannot be written.

    kind: "file" (a file to write: not a folder, and its folder can be created or written in) or
    "folder" (a folder to write into). Raises ConfigError ``field: ...`` (one line, exit status 2)."""
    from simrun.results.lock import check_writable

    path = Path(path)
    check_writable(path, field, kind=kind)
    return path


def writing_file(path: str | Path, field: str):
    """``with writing_file(path, field) as temporary:`` write ``temporary`` (same suffix as path); it
    replaces ``path`` at once at the end, and is removed on any error. An OSError (disk full,
    permission) becomes ConfigError ``field: cannot write 'path': reason``."""
    from simrun.results.lock import replacing

    return replacing(Path(path), field)


def writing_folder(path: str | Path, field: str):
    """``with writing_folder(folder, field) as temporary:`` write files into the empty folder
    ``temporary``; at the end they move into ``folder`` (created if needed); on any error nothing
    is left. An OSError becomes ConfigError ``field: cannot write 'folder': reason``."""
    from simrun.results.lock import filling

    return filling(Path(path), field)


def say(text: str) -> None:
    """Progress for the user, on standard error (standard output carries the command's result)."""
    import sys

    print(text, file=sys.stderr, flush=True)


__all__ = ["add_experiment_options", "add_reference_option", "field_overrides", "load_results", "say", "writable_output", "writing_file", "writing_folder"]
