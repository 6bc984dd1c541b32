"""`simrun list`: the keys of a config, and every system, integrator and solver it may name, with their
parameters and defaults, written as YAML that could go in a config."""

from __future__ import annotations

INDENT = "  "


def add_parser(commands) -> None:
    commands.add_parser("list", help="print the config's keys, the systems, integrators and solvers with their parameters",
                        description="Print the keys of a config and every system, integrator and solver that a config "
                                    "may name, with parameters, defaults and units, as YAML."
                        ).set_defaults(handler=handle)


def _value(value) -> str:
    """A default as YAML, in flow style: [0.5, 0.5, -0.6], null, linear, 1.0e-10."""
    import yaml
    from pydantic import BaseModel

    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    elif isinstance(value, tuple):
        value = list(value)
    return yaml.safe_dump(value, default_flow_style=True, width=10_000).strip().removesuffix("...").strip()


def _nested_model(annotation):
    """The model class of a field that holds one (possibly optional): its keys are listed below it."""
    import typing

    from pydantic import BaseModel

    candidates = [annotation, *typing.get_args(annotation)]
    models = [item for item in candidates if isinstance(item, type) and issubclass(item, BaseModel)]
    return models[0] if len(models) == 1 else None


def _fields(model, fields: dict | None = None, depth: int = 2, lines_for: dict | None = None, instance=None) -> list[str]:
    """One line per key: ``key: default  # description``; a key that holds a model gets its keys below it.

    lines_for: key -> the text after ``key:`` for keys described elsewhere (the config's system, solver).
    instance: the parent's default value of this model, whose values are the defaults shown (mass: {total: 1.0})."""
    from pydantic import BaseModel

    lines = []
    for key, info in (model.model_fields if fields is None else fields).items():
        if key == "type":
            continue
        if lines_for and key in lines_for:
            lines.append(f"{INDENT * depth}{key}:{lines_for[key]}")
            continue
        nested = _nested_model(info.annotation)
        if nested is not None and nested.model_fields:
            summary = info.description or (nested.__doc__ or "").strip().partition("\n")[0]
            comment = "; ".join(filter(None, ["optional" if info.default is None else "", summary]))
            lines.append(f"{INDENT * depth}{key}:" + (f"  # {comment}" if comment else ""))
            lines += _fields(nested, depth=depth + 1, instance=info.default if isinstance(info.default, BaseModel) else None)
            continue
        value = getattr(instance, key) if instance is not None else info.default
        default = "" if info.is_required() and instance is None else f" {_value(value)}"
        comment = "; ".join(filter(None, ["required" if info.is_required() else "", info.description or ""]))
        lines.append(f"{INDENT * depth}{key}:{default}" + (f"  # {comment}" if comment else ""))
    return lines


def _print(lines: list[str]) -> None:
    if lines:
        print("\n".join(lines))


def handle(args) -> int:
    from simrun.experiment.config import Experiment
    from simrun.integrators import ENGINES, INTEGRATORS, PEERS
    from simrun.solvers import LINEAR_SOLVERS, SOLVER_PARAMS, SolverParams
    from simrun.systems import SYSTEMS

    solver_default = Experiment.model_fields["solver"].default.type
    print("config (the top-level keys of an experiment's YAML file):")
    _print(_fields(Experiment, depth=1, lines_for={
        "system": "  # required: {type: name, parameter: value}, one of the systems below",
        "integrators": "  # required: a list of names or {type: name, parameter: value}, of the integrators below",
        "solver": f" {{type: {solver_default}}}  # the nonlinear solver of the implicit integrators: "
                  "{type: name, option: value}, one of the solvers below",
        "sweep": "  # required: dt (s) and any other dotted key (e.g. system.stiffness), each a list of values, "
                 "{logspace: [start_exp, stop_exp, count]} or {linspace: [start, stop, count]}",
    }))
    print("\nsystems (system.type):")
    for name, model in SYSTEMS.items():
        print(f"  {name}:  # {(model.__doc__ or '').strip().splitlines()[0]}")
        _print(_fields(model))
    from simrun.systems import plugins

    installed = {name: path for name, path in plugins.installed().items() if name not in SYSTEMS}
    print("  # and plug-ins: system.type: package.module:ClassName (docs/systems.md); installed: "
          + (", ".join(f"{name} ({path})" for name, path in installed.items()) or "none"))
    print("\nintegrators (integrators: [name] or [{type: name, parameter: value}]):")
    for name, cls in INTEGRATORS.items():
        kind = "explicit" if cls.explicit else "implicit"
        print(f"  {name}:  # order {cls.order}, {kind}: {cls.summary}")
        _print(_fields(cls))
    from simrun.integrators import plugins as integrator_plugins

    own = {name: path for name, path in integrator_plugins.installed().items() if name not in INTEGRATORS}
    print("  # and plug-ins: package.module:ClassName (docs/integrators.md, \"Writing your own integrator\"); "
          "installed: " + (", ".join(f"{name} ({path})" for name, path in own.items()) or "none"))
    print("  # engines: other codes' integrators, stepping the system translated into their models (docs/engines.md)")
    for name, cls in ENGINES.items():
        print(f"  {name}:  # order {cls.order}, {'explicit' if cls.explicit else 'implicit'}: {cls.summary}")
        _print(_fields(cls))
    print("  # peers: other codes' runs on the same system, named in integrators: like a method")
    for name, cls in PEERS.items():
        print(f"  {name}:  # {cls.summary}")
        _print(_fields(cls))
    linear = [name if cls.missing() is None else f"{name} (not installed: make install-cholmod)"
              for name, cls in LINEAR_SOLVERS.items()]
    print(f"\nsolvers (solver: {{type: name, option: value}}; default type: {solver_default}); options every solver takes:")
    _print(_fields(SolverParams))
    print(f"{INDENT * 2}# linear solvers (solver.linear_solver): " + ", ".join(linear))
    for name, model in SOLVER_PARAMS.items():
        own = model.own_fields()
        default = " (the default)" if name == solver_default else ""
        print(f"  {name}:  # {(model.__doc__ or '').strip().splitlines()[0]}{default}")
        _print(_fields(model, own))
    return 0
