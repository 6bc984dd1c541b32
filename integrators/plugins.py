"""An integrator's config name (an entry of ``integrators:``, or its ``type``) resolved to its class: built-in,
plug-in path or entry point.

A name is resolved by the first of these rules that applies:

1. a name of ``INTEGRATORS`` or ``PEERS`` (``backward_euler``, ``solve_ivp``, ...): simrun's own methods;
2. a name with a colon, ``package.module:ClassName``: the module is imported (installed, on ``PYTHONPATH``, or else
   from the current folder) and the class taken from it;
3. a name that an installed distribution registers in the entry-point group ``simrun.integrators``
   (``[project.entry-points."simrun.integrators"]  bathe = "mypackage.bathe:Bathe"`` in its pyproject.toml).

The class must be a concrete subclass of ``Integrator`` that declares ``order`` (a whole number >= 1), ``explicit``
(a bool) and ``summary`` (one line), as the built-ins do (docs/integrators.md, "Writing your own integrator"). Its
``name``, if it declares one, is its label in figures and tables; without one, its path is. A name that is a
built-in's belongs to that built-in. Anything else is an ``IntegratorTypeError``: one line that says what the name is
and what is wrong with it. Resolutions are cached.
"""

from __future__ import annotations

import inspect
from typing import Any

from simrun import plugins as shared

from .base import Integrator


class IntegratorTypeError(ValueError):
    """An integrator name that names no usable method; the message is one line."""


KIND = shared.PluginKind(noun="integrator", base=Integrator, base_name="simrun.integrators.Integrator",
                         group="simrun.integrators", example="mypackage.bathe:Bathe", error=IntegratorTypeError)
ENTRY_POINT_GROUP = KIND.group
# what a plug-in must declare itself (a ClassVar of the contract), with the type it must have
DECLARED = {"order": int, "explicit": bool, "summary": str}

_resolved: dict[str, type[Integrator]] = {}  # plug-in name -> its class (built-in names need no cache)


def resolve(name: Any, current_folder: bool = True) -> type[Integrator]:
    """The class that config name ``name`` stands for (rules in the module docstring).

    current_folder: may a module path be imported from the current folder when Python does not find it? Readers of a
    results file pass False: reading a file must not run code from wherever it is read."""
    return shared.resolve(KIND, name, _built_in(), _resolved, _checked, current_folder)


def names() -> list[str]:
    """Every name a config may give without a path: the built-in methods and peers, then the installed plug-ins."""
    return shared.registered_names(KIND, _built_in())


def installed() -> dict[str, str]:
    """The installed plug-ins: entry-point name -> ``package.module:ClassName`` (not imported)."""
    return {name: entry.value for name, entry in shared.entry_points(KIND).items()}


def is_built_in(method: type[Integrator]) -> bool:
    """Whether ``method`` is one of simrun's registered methods or peers."""
    return _built_in().get(method.name) is method


def provenance(method: type[Integrator]) -> dict[str, str]:
    """Where a method's code is: its class path and the sha256 of its source file, as the results file records them."""
    return {"integrator_class": shared.class_path(method), "integrator_source_sha256": shared.source_digest(method)}


def clear_cache() -> None:
    """Forget every resolved plug-in (a test that installs or removes one)."""
    _resolved.clear()


# -- the rules -----------------------------------------------------------------------------------------
def _built_in() -> dict[str, type[Integrator]]:
    from . import ENGINES, INTEGRATORS, PEERS  # at call time, so that simrun.integrators may import this module

    return INTEGRATORS | ENGINES | PEERS


def _checked(name: str, value: Any) -> type[Integrator]:
    """``value`` if it is a usable method (docs/integrators.md, "Writing your own integrator"), else
    IntegratorTypeError."""
    wrong = shared.not_a_class(KIND, name, value)
    if wrong is not None:
        raise IntegratorTypeError(wrong)
    for attribute, kind in DECLARED.items():
        declared = getattr(value, attribute, None)
        if declared is None:
            raise IntegratorTypeError(f"{name!r}: {value.__name__} does not declare {attribute!r}; give it  "
                                      f"{attribute}: ClassVar[{kind.__name__}] = ...  ({_DECLARATION[attribute]})")
        if not isinstance(declared, kind) or (kind is int and isinstance(declared, bool)):
            raise IntegratorTypeError(f"{name!r}: {value.__name__}.{attribute} is {declared!r}, not a {kind.__name__} "
                                      f"({_DECLARATION[attribute]})")
    if value.order < 1:
        raise IntegratorTypeError(f"{name!r}: {value.__name__}.order is {value.order}; the order of accuracy is a whole "
                                  "number >= 1")
    if inspect.isabstract(value):
        missing = ", ".join(sorted(value.__abstractmethods__))
        raise IntegratorTypeError(f"{name!r}: {value.__name__} does not define {missing}; a method's step is "
                                  "step(system, state, dt, solver) -> (State, SolveStats)")
    known = _built_in().get(value.name)
    if known is not None and known is not value:
        raise IntegratorTypeError(f"{name!r}: {value.__name__}.name is {value.name!r}, which is simrun's own "
                                  f"{known.__name__}; give the plug-in a name of its own")
    return value


_DECLARATION = {"order": "its order of accuracy at the default parameters",
                "explicit": "True when its step solves nothing",
                "summary": "one line saying what the method is"}
