"""`simrun list`: every system, integrator and solver a config may name, with its parameters and defaults."""

from __future__ import annotations


def add_parser(commands) -> None:
    commands.add_parser("list", help="print the systems, integrators and solvers with their parameters",
                        description="Print every system, integrator and solver that a config may name, with parameters and defaults."
                        ).set_defaults(handler=handle)


def _fields(model, skip=("type",)) -> list[str]:
    lines = []
    for key, info in model.model_fields.items():
        if key in skip:
            continue
        default = "" if info.is_required() else f" = {info.default!r}"
        note = f"  # {info.description}" if info.description else ""
        lines.append(f"      {key}{default}{note}")
    return lines


def handle(args) -> int:
    from simrun.integrators import INTEGRATORS
    from simrun.solvers import LINEAR_SOLVERS, SOLVERS, SolverParams
    from simrun.systems import SYSTEMS

    print("systems (system.type):")
    for name, model in SYSTEMS.items():
        print(f"  {name}: {(model.__doc__ or '').strip().splitlines()[0]}")
        print("\n".join(_fields(model)))
    print("\nintegrators (integrators: [name] or [{type: name, param: value}]):")
    for name, cls in INTEGRATORS.items():
        kind = "explicit" if cls.explicit else "implicit"
        print(f"  {name}  (order {cls.order}, {kind}): {cls.summary}")
        print("\n".join(_fields(cls)))
    linear = [name if cls.missing() is None else f"{name} (not installed: make install-cholmod)"
              for name, cls in LINEAR_SOLVERS.items()]
    print("\nsolvers (solver.type): " + ", ".join(SOLVERS) + "; linear solvers (solver.linear_solver): " + ", ".join(linear))
    print("\n".join(_fields(SolverParams)))
    return 0
