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
cached. A run is sent to its worker process with its parameters, pickled by module path: the workers of the
local pool and of a local Dask cluster start with this process's ``sys.path``, so they import the module too
(a remote Dask cluster needs it installed).
"""

from __future__ import annotations

import difflib
import importlib
import importlib.metadata
import inspect
import os
import sys
from pathlib import Path
from typing import Any

from .base import System, SystemParams

ENTRY_POINT_GROUP = "simrun.systems"
PATH_SEPARATOR = ":"  # package.module:ClassName, as in entry points

_resolved: dict[str, type[SystemParams]] = {}  # plug-in name -> its params model (built-in names need no cache)


class SystemTypeError(ValueError):
    """A ``system.type`` that names no usable system; the message is one line (without the config path)."""


def resolve(name: Any, current_folder: bool = True) -> type[SystemParams]:
    """The parameter model that config name ``name`` stands for (rules in the module docstring).

    current_folder: may a module path be imported from the current folder when Python does not find it
    (a config beside its plug-in)? A results file names a module too, and reading a file must not run code
    from wherever it is read: the readers pass False. Raises SystemTypeError with a one-line message."""
    from . import SYSTEMS  # at call time, so that simrun.systems may import this module

    if isinstance(name, str) and name in SYSTEMS:
        return SYSTEMS[name]
    if isinstance(name, str) and name in _resolved:
        return _resolved[name]
    if not isinstance(name, str) or not name:
        raise SystemTypeError(_unknown(str(name)))
    if PATH_SEPARATOR in name:
        model = _checked(name, _import_path(name, current_folder))
    else:
        entry = _entry_points().get(name)
        if entry is None:
            raise SystemTypeError(_unknown(name))
        model = _checked(name, _load_entry_point(name, entry))
    _resolved[name] = model
    return model


def find(name: Any) -> type[SystemParams] | None:
    """``resolve(name)``, or None where it fails (for code that only describes an error)."""
    try:
        return resolve(name)
    except SystemTypeError:
        return None


def names() -> list[str]:
    """Every name a config may give without a path: the built-in systems, then the installed plug-ins."""
    from . import SYSTEMS

    return [*SYSTEMS, *(name for name in _entry_points() if name not in SYSTEMS)]


def installed() -> dict[str, str]:
    """The installed plug-ins: entry-point name -> ``package.module:ClassName`` (not imported)."""
    return {name: entry.value for name, entry in _entry_points().items()}


def clear_cache() -> None:
    """Forget every resolved plug-in (a test that installs or removes one)."""
    _resolved.clear()


# -- the rules -----------------------------------------------------------------------------------------
def _unknown(name: str) -> str:
    known = names()
    close = difflib.get_close_matches(name, known, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return (f"unknown system {name!r}{hint}; valid: " + ", ".join(known)
            + ", or a plug-in as package.module:ClassName")


def _import_path(name: str, current_folder: bool = True) -> Any:
    """The object that ``package.module:Attribute.Path`` names."""
    module_name, _, attribute = name.partition(PATH_SEPARATOR)
    if not _dotted(module_name) or not _dotted(attribute):
        raise SystemTypeError(f"{name!r} is not a plug-in path; write package.module:ClassName (e.g. mypackage.rope:RopeParams)")
    module = _import_module(module_name, name, current_folder)
    return _attribute(module, attribute, name)


def _dotted(text: str) -> bool:
    return bool(text) and all(part.isidentifier() for part in text.split("."))


def _import_module(module_name: str, name: str, current_folder: bool = True):
    """Import a plug-in's module; where Python does not find it, in the current folder too (as ``python -m`` would)."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        here = os.getcwd()
        if not current_folder or not _is_the_module(error, module_name) or not _beside(here, module_name) \
                or here in (_absolute(entry) for entry in sys.path):
            raise SystemTypeError(_import_failed(module_name, name, error)) from None
    except Exception as error:  # noqa: BLE001 - a user's module may raise anything while it is imported
        raise SystemTypeError(_import_failed(module_name, name, error)) from None
    sys.path.append(here)
    try:
        return importlib.import_module(module_name)
    except Exception as error:  # noqa: BLE001
        raise SystemTypeError(_import_failed(module_name, name, error)) from None


def _beside(folder: str, module_name: str) -> bool:
    """Whether ``folder`` holds the top package (or the module) of ``module_name``."""
    top = module_name.split(".")[0]
    return (Path(folder) / f"{top}.py").is_file() or (Path(folder) / top).is_dir()


def _is_the_module(error: ModuleNotFoundError, module_name: str) -> bool:
    """Whether the module missing is the plug-in's own (or a package above it), not one that it imports."""
    parts = module_name.split(".")
    return error.name in {".".join(parts[:count]) for count in range(1, len(parts) + 1)}


def _import_failed(module_name: str, name: str, error: BaseException) -> str:
    """One line: the module, and the first line of what its import raised (with the error's type where that is
    not plainly "not found")."""
    lines = str(error).strip().splitlines()
    reason = lines[0] if lines else type(error).__name__
    if isinstance(error, ModuleNotFoundError):
        advice = "; install it, or put its folder on PYTHONPATH" if _is_the_module(error, module_name) else ""
        return f"{name!r}: cannot import module {module_name!r}: {reason}{advice}"
    return f"{name!r}: cannot import module {module_name!r}: {type(error).__name__}: {reason}"


def _attribute(module, attribute: str, name: str) -> Any:
    value = module
    for part in attribute.split("."):
        if not hasattr(value, part):
            defined = sorted(key for key, item in vars(module).items()
                             if isinstance(item, type) and issubclass(item, SystemParams) and item is not SystemParams
                             and item.__module__ == module.__name__)
            where = f"module {module.__name__!r}" if value is module else getattr(value, "__name__", repr(value))
            close = difflib.get_close_matches(part, defined, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            offer = f"; its SystemParams classes: {', '.join(defined)}" if defined else "; it defines no SystemParams class"
            raise SystemTypeError(f"{name!r}: {where} has no attribute {part!r}{hint}{offer}")
        value = getattr(value, part)
    return value


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    """The entry points of group ``simrun.systems``, by name (the first distribution's where two share a name)."""
    found: dict[str, importlib.metadata.EntryPoint] = {}
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(entry.name, entry)
    return found


def _load_entry_point(name: str, entry: importlib.metadata.EntryPoint) -> Any:
    distribution = getattr(entry, "dist", None)
    source = f" of {distribution.name} {distribution.version}" if distribution is not None else ""
    try:
        return _import_path(entry.value)
    except SystemTypeError as error:
        raise SystemTypeError(f"{name!r} (entry point{source}: {ENTRY_POINT_GROUP} {name} = {entry.value!r}) -> "
                              f"{error}") from None


def _checked(name: str, value: Any) -> type[SystemParams]:
    """``value`` if it is a usable parameter model (docs/systems.md, "The contract"), else SystemTypeError."""
    if not isinstance(value, type):
        kind = ("a module" if inspect.ismodule(value) else "a function" if inspect.isroutine(value)
                else f"an object of type {type(value).__name__}")
        raise SystemTypeError(f"{name!r} names {kind}, not a class; give a subclass of simrun.systems.SystemParams")
    if not issubclass(value, SystemParams):
        raise SystemTypeError(f"{name!r} names the class {value.__name__}, which is not a subclass of "
                              "simrun.systems.SystemParams")
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


def _absolute(entry: str) -> str:
    return os.path.abspath(entry or os.curdir)
