"""`simrun list`: every system, integrator and solver a config may name, with its parameters and defaults."""

from __future__ import annotations


def add_parser(commands) -> None:
    commands.add_parser("list", help="print the systems, integrators and solvers with their parameters",
                        description="Print every system, integrator and solver that a config may name, with parameters and defaults."
                        ).set_defaults(handler=handle)


def _fields(model, fields: dict | None = None) -> list[str]:
    lines = []
    for key, info in (model.model_fields if fields is None else fields).items():
        if key == "type":
            continue
        default = "" if info.is_required() else f" = {info.default!r}"
        note = f"  # {info.description}" if info.description else ""
        lines.append(f"      {key}{default}{note}")
    return lines


def handle(args) -> int:
    from simrun.integrators import INTEGRATORS
    from simrun.solvers import LINEAR_SOLVERS, SOLVER_PARAMS, SolverParams
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
    print("\nsolvers (solver: {type: name, option: value}); options every solver takes:")
    print("\n".join(_fields(SolverParams)))
    print("    linear solvers (solver.linear_solver): " + ", ".join(linear))
    for name, model in SOLVER_PARAMS.items():
        own = model.own_fields()
        print(f"  {name}: {(model.__doc__ or '').strip().splitlines()[0]}")
        if own:
            print("\n".join(_fields(model, own)))
    return 0
