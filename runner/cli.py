"""The `simrun` command: parse the command line and dispatch to one module of simrun.commands per subcommand.

Light imports only: `main` starts the worker pool's fork server before the simulation's own imports
(numpy, scipy, pydantic, h5py), so that the two run side by side; each subcommand imports what it
needs when it runs.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from simrun import __version__
from simrun.commands import COMMANDS
from simrun.errors import ConfigError
from simrun.workers import may_use_local_pool, start_worker_server

EXIT_CONFIG_ERROR = 2


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


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in COMMANDS and not argv[0].startswith("-"):
        argv.insert(0, "run")  # `simrun CONFIG.yaml`
    if argv and argv[0] == "run" and may_use_local_pool(argv):
        start_worker_server()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return args.handler(args)
    except ConfigError as error:  # config errors, a locked output folder, an unreadable results file
        print(f"simrun: error: {error}", file=sys.stderr)
        return EXIT_CONFIG_ERROR


if __name__ == "__main__":
    sys.exit(main())
