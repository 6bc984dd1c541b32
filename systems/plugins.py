"""A system's config name (``system.type``) resolved to its parameter model: built-in, plug-in path or entry point.

A name is resolved by the first of these rules that applies:

1. a name of ``SYSTEMS`` (``spring_mass``, ``cloth``, ...): simrun's own systems;
2. a name with a colon, ``package.module:ClassName``: the module is imported (as Python imports it:
   installed, on ``PYTHONPATH``, or else from the current folder) and the class taken from it;
3. a name that an installed distribution registers in the entry-point group ``simrun.systems``
   (``[project.entry-points."simrun.systems"]  rope = "mypackage.rope:RopeParams"`` in its pyproject.toml).

The class must be a subclass of ``SystemParams`` with a ``type`` field (``type: str``), a ``dof_count``
and a ``system_class`` that is a subclass of ``System`` (docs/systems.md). Anything else is a
``SystemTypeError``: one line that says what the name is and what is wrong with it. Resolutions are
cached. Importing, entry points and their messages are every kind of plug-in's (simrun.plugins). A run is sent to
its worker process with its parameters, pickled by module path: the workers of the local pool and of a local Dask
cluster start with this process's ``sys.path``, so they import the module too (a remote Dask cluster needs it
installed).
"""

from __future__ import annotations

from typing import Any

from simrun import plugins as shared

from .base import System, SystemParams


class SystemTypeError(ValueError):
    """A ``system.type`` that names no usable system; the message is one line (without the config path)."""


KIND = shared.PluginKind(noun="system", base=SystemParams, base_name="simrun.systems.SystemParams",
                         group="simrun.systems", example="mypackage.rope:RopeParams", error=SystemTypeError)
ENTRY_POINT_GROUP = KIND.group

_resolved: dict[str, type[SystemParams]] = {}  # plug-in name -> its params model (built-in names need no cache)


def resolve(name: Any, current_folder: bool = True) -> type[SystemParams]:
    """The parameter model that config name ``name`` stands for (rules in the module docstring).

    current_folder: may a module path be imported from the current folder when Python does not find it
    (a config beside its plug-in)? A results file names a module too, and reading a file must not run code
    from wherever it is read: the readers pass False. Raises SystemTypeError with a one-line message."""
    from . import SYSTEMS  # at call time, so that simrun.systems may import this module

    return shared.resolve(KIND, name, SYSTEMS, _resolved, _checked, current_folder)


def find(name: Any) -> type[SystemParams] | None:
    """``resolve(name)``, or None where it fails (for code that only describes an error)."""
    try:
        return resolve(name)
    except SystemTypeError:
        return None


def names() -> list[str]:
    """Every name a config may give without a path: the built-in systems, then the installed plug-ins."""
    from . import SYSTEMS

    return shared.registered_names(KIND, SYSTEMS)


def installed() -> dict[str, str]:
    """The installed plug-ins: entry-point name -> ``package.module:ClassName`` (not imported)."""
    return {name: entry.value for name, entry in shared.entry_points(KIND).items()}


def clear_cache() -> None:
    """Forget every resolved plug-in (a test that installs or removes one)."""
    _resolved.clear()


# -- the rules -----------------------------------------------------------------------------------------
def _checked(name: str, value: Any) -> type[SystemParams]:
    """``value`` if it is a usable parameter model (docs/systems.md, "The contract"), else SystemTypeError."""
    wrong = shared.not_a_class(KIND, name, value)
    if wrong is not None:
        raise SystemTypeError(wrong)
    if "type" not in value.model_fields:
        raise SystemTypeError(f"{name!r}: {value.__name__} has no field 'type'; declare  type: str = {name!r}")
    if not hasattr(value, "dof_count") and "dof_count" not in value.model_fields:
        raise SystemTypeError(f"{name!r}: {value.__name__} has no dof_count; give it a property dof_count "
                              "(the number of degrees of freedom)")
    system_class = getattr(value, "system_class", None)
    if system_class is None:
        raise SystemTypeError(f"{name!r}: {value.__name__} has no system_class; set  {value.__name__}.system_class = "
                              "YourSystem  (a subclass of simrun.systems.System)")
    if not (isinstance(system_class, type) and issubclass(system_class, System)):
        raise SystemTypeError(f"{name!r}: {value.__name__}.system_class is {system_class!r}, not a subclass of "
                              "simrun.systems.System")
    return value
