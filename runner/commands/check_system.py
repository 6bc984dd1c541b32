"""`simrun check-system SYSTEM`: the contract checks of tests/test_systems.py on one system, for its author.

    simrun check-system mypackage.rope:RopeParams                # a plug-in, at its default parameters
    simrun check-system rope --set count=2 --set hardening=0     # an installed plug-in (entry point), two overrides
    simrun check-system cloth                                    # a built-in system

One line per check (PASS, FAIL or SKIP, with what was measured against which tolerance); exit status 0 when
every check passes, 1 when one fails, 2 when the system cannot be resolved or its parameters are invalid.
"""

from __future__ import annotations


def add_parser(commands) -> None:
    check = commands.add_parser(
        "check-system", help="check a system (a plug-in) against the contract: derivatives, damping, pins, observables",
        description="Build a system from its parameters (defaults plus --set) and check it against the System contract "
                    "(docs/systems.md): gradient and Hessian against finite differences, the SPD projection, damping, "
                    "forces on pinned dofs, observables, capabilities, the energy reference and a short run. "
                    "Exit status 0: all pass; 1: a check fails; 2: the system cannot be resolved or built.")
    check.add_argument("system", metavar="SYSTEM",
                       help="what a config's system.type may name: package.module:ClassName, an installed plug-in's "
                            "name, or a built-in system")
    check.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                       help="a parameter of the system, value in YAML (repeatable), e.g. --set count=5 "
                            "(system.count=5 works too)")
    check.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.commands._options import field_overrides
    from simrun.experiment.config import validate_system
    from simrun.contracts.system import run_checks

    params = validate_system(field_overrides(args.overrides, "system", args.system, "SYSTEM", "count=5")["system"])
    checks = run_checks(params)
    failed = [check for check in checks if check.passed is False]
    print(f"{args.system}: {len(checks)} checks of the System contract (docs/systems.md)")
    for check in checks:
        print(check)
    print(f"{len(failed)} of {len(checks)} checks failed" if failed else
          f"all {sum(check.passed is True for check in checks)} checks that apply passed")
    return 1 if failed else 0
