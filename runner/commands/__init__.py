"""simrun.commands (folder runner/commands/): one module per subcommand, each with ``add_parser(subparsers)``
and ``handle(args) -> exit status``. Each module imports only light modules at the top (argparse and
simrun.errors/workers): the heavy imports happen in ``handle``, so that ``simrun --help`` is quick and the
worker pool's fork server starts before them.
"""

# subcommand -> module of simrun.commands, in the order of `simrun --help`
COMMANDS = {
    "run": "run",
    "fit": "fit",
    "plot": "plot",
    "report": "report",
    "show": "show",
    "analyze": "analyze",
    "animate": "animate",
    "measure": "measure",
    "list": "list_",
    "check-system": "check_system",
    "check-integrator": "check_integrator",
}
