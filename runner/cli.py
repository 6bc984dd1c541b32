"""The `simrun` command: parse the command line and dispatch to one module of simrun.commands per subcommand.

Light imports only: `main` starts the worker pool's fork server before the simulation's own imports
(numpy, scipy, pydantic, h5py), so that the two run side by side; each subcommand imports what it
needs when it runs.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import os
import shlex
import sys
import warnings
from pathlib import Path

from simrun.commands import COMMANDS
from simrun.commands.run import EXIT_INTERRUPTED
from simrun.errors import ConfigError
from simrun.execution.workers import may_use_local_pool, start_worker_server
from simrun.version import __version__

EXIT_CONFIG_ERROR = 2
CONFIG_FOLDER = Path("configs")  # where `simrun NAME` looks for NAME.yaml to suggest
CONFIG_SUFFIXES = (".yaml", ".yml")
# the subcommands that run work in the local pool (runs, fits, figures): their fork server starts first
POOL_COMMANDS = ("run", "fit", "measure", "plot")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="simrun",
        description="Batch experiments with the time integrators of physics-based animation. "
                    "`simrun CONFIG.yaml` is short for `simrun run CONFIG.yaml`.",
    )
    parser.add_argument("--version", action="version", version=f"simrun {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in COMMANDS.values():
        importlib.import_module(f"simrun.commands.{module}").add_parser(subparsers)
    return parser


def _warning_line(message, category, filename, lineno, line=None) -> str:
    """A warning meant for the user (its category says ``one_line``: a model mended on loading) as one line; any
    other as Python writes it."""
    if getattr(category, "one_line", False):
        return f"simrun: warning: {message}\n"
    return _python_warning_line(message, category, filename, lineno, line)


_python_warning_line = warnings.formatwarning


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    warnings.formatwarning = _warning_line
    command_line = shlex.join(["simrun", *argv])
    if not argv:  # a command is needed: say which there are
        build_parser().print_help(sys.stderr)
        return EXIT_CONFIG_ERROR
    if argv[0] not in COMMANDS and not argv[0].startswith("-"):
        if not _may_be_config(argv[0]):
            return _error(ConfigError(_unknown_command(argv[0])))
        argv.insert(0, "run")  # `simrun CONFIG.yaml`
    if argv and argv[0] in POOL_COMMANDS and may_use_local_pool(argv):
        start_worker_server()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_CONFIG_ERROR
    args.command_line = command_line  # the provenance of a run
    try:
        return args.handler(args)
    except ConfigError as error:  # config errors, a locked output folder, an unreadable results file, an unwritable output
        return _error(error)
    except KeyboardInterrupt as interrupt:  # Ctrl-C: one line, saying what is complete (files are written whole)
        said = str(interrupt) or (f"interrupted: nothing {args.command} writes is left half-written; run the same "
                                  "command again")
        print(f"simrun: {said}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # a reader that stopped early (`simrun list | head`) is not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 0
    except OSError as error:  # one the command did not name (it names its outputs itself)
        where = f"{error.filename}: " if error.filename else ""
        return _error(ConfigError(f"{where}{error.strerror or error}"))


def _error(error: ConfigError) -> int:
    """``simrun: error: field: ...``, one line per error (a config reports up to a handful at once)."""
    for line in str(error).splitlines() or [""]:
        print(f"simrun: error: {line}", file=sys.stderr)
    return EXIT_CONFIG_ERROR


def _may_be_config(word: str) -> bool:
    """Whether the first argument is meant as a config file (`simrun CONFIG.yaml`): it exists, or looks like one."""
    path = Path(word)
    return path.exists() or path.suffix.lower() in CONFIG_SUFFIXES or "/" in word


def _unknown_command(word: str) -> str:
    """'unknown command ...' with the closest subcommand or shipped config, and what is valid."""
    message = f"unknown command {word!r}"
    configs = {}
    if CONFIG_FOLDER.is_dir():
        configs = {path.stem: path for path in sorted(CONFIG_FOLDER.iterdir()) if path.suffix.lower() in CONFIG_SUFFIXES}
    # a config's own name first (`simrun quickstart`), then a misspelt command (`simrun runn`), then a misspelt config
    suggestions = ([str(configs[word])] if word in configs else []) + difflib.get_close_matches(word, list(COMMANDS), n=1) \
        + [str(configs[name]) for name in difflib.get_close_matches(word, list(configs), n=1)]
    if suggestions:
        message += f" (did you mean {suggestions[0]!r}?)"
    return message + f"; give a command ({', '.join(COMMANDS)}) or a config file such as configs/quickstart.yaml"


if __name__ == "__main__":
    sys.exit(main())
