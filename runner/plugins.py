"""Plug-ins: a class that a config names by its path, ``package.module:ClassName``, or by the name an installed
distribution registers it under in an entry-point group, and the code it came from.

What is shared by every kind of plug-in (systems: simrun.systems.plugins; integrators: simrun.integrators.plugins):
importing the module, following the path to the class, reading the entry points, the one-line messages when any of
that fails, and the sha256 of the file that defines a class (so that a result can be traced to the code that made
it). Each kind checks its own contract on the class it gets.

A module path is imported as Python imports it: installed, or on ``sys.path`` (PYTHONPATH), or else, where the caller
allows it, from the current folder (a config beside its plug-in, as ``python -m`` would find it). Workers of the
local pool and of a local Dask cluster start with this process's ``sys.path``, so they import the module too.
"""

from __future__ import annotations

import difflib
import functools
import hashlib
import importlib
import importlib.metadata
import inspect
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

PATH_SEPARATOR = ":"  # package.module:ClassName, as in entry points


@dataclass(frozen=True)
class PluginKind:
    """What a kind of plug-in is called in messages and where it is registered."""

    noun: str  # "system", "integrator"
    base: type  # what the class must subclass
    base_name: str  # its public name: "simrun.systems.SystemParams"
    group: str  # the entry-point group
    example: str  # a path in the messages: "mypackage.rope:RopeParams"
    error: type[ValueError]  # what a failure raises, with a one-line message


def is_path(name: str) -> bool:
    """Whether a config name is a plug-in path (it has the colon) rather than a registered name."""
    return PATH_SEPARATOR in name


def import_path(kind: PluginKind, name: str, current_folder: bool = True) -> Any:
    """The object that ``package.module:Attribute.Path`` names; ``kind.error`` with one line where it cannot be had."""
    module_name, _, attribute = name.partition(PATH_SEPARATOR)
    if not _dotted(module_name) or not _dotted(attribute):
        raise kind.error(f"{name!r} is not a plug-in path; write package.module:ClassName (e.g. {kind.example})")
    module = _import_module(kind, module_name, name, current_folder)
    return _attribute(kind, module, attribute, name)


def entry_points(kind: PluginKind) -> dict[str, importlib.metadata.EntryPoint]:
    """The entry points of the kind's group, by name (the first distribution's where two share a name)."""
    found: dict[str, importlib.metadata.EntryPoint] = {}
    for entry in importlib.metadata.entry_points(group=kind.group):
        found.setdefault(entry.name, entry)
    return found


def load_entry_point(kind: PluginKind, name: str, entry: importlib.metadata.EntryPoint, check=None) -> Any:
    """What entry point ``name`` names, passed through ``check(path, value)`` (the kind's contract) where given; its
    errors said with the distribution that registers it."""
    distribution = getattr(entry, "dist", None)
    source = f" of {distribution.name} {distribution.version}" if distribution is not None else ""
    try:
        value = import_path(kind, entry.value)
        return value if check is None else check(entry.value, value)
    except kind.error as error:
        raise kind.error(f"{name!r} (entry point{source}: {kind.group} {name} = {entry.value!r}) -> {error}") from None


def resolve(kind: PluginKind, name: Any, built_in: dict, resolved: dict, check, current_folder: bool = True) -> Any:
    """The class that config name ``name`` stands for: a built-in's (``built_in``: name -> class), a plug-in resolved
    before (``resolved``, the kind's cache, filled here), else one imported by its path or by its entry point and passed
    through ``check(path, value)`` (the kind's contract); current_folder: as ``import_path``."""
    if isinstance(name, str) and name in built_in:
        return built_in[name]
    if isinstance(name, str) and name in resolved:
        return resolved[name]
    if not isinstance(name, str) or not name:
        raise kind.error(unknown_name(kind, str(name), built_in))
    if is_path(name):
        found = check(name, import_path(kind, name, current_folder))
    else:
        entry = entry_points(kind).get(name)
        if entry is None:
            raise kind.error(unknown_name(kind, name, built_in))
        found = load_entry_point(kind, name, entry, check)
    resolved[name] = found
    return found


def registered_names(kind: PluginKind, built_in: dict) -> list[str]:
    """Every name a config may give without a path: the built-ins, then the installed plug-ins."""
    return [*built_in, *(name for name in entry_points(kind) if name not in built_in)]


def unknown_name(kind: PluginKind, name: str, built_in: dict) -> str:
    """One line for a name that is neither a built-in nor an installed plug-in: the closest name, and every valid one."""
    known = registered_names(kind, built_in)
    close = difflib.get_close_matches(name, known, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"unknown {kind.noun} {name!r}{hint}; valid: " + ", ".join(known) + ", or a plug-in as package.module:ClassName"


def not_a_class(kind: PluginKind, name: str, value: Any) -> str | None:
    """Why ``value`` is not a subclass of the kind's base, in one line; None when it is one."""
    base = kind.base_name
    if not isinstance(value, type):
        what = ("a module" if inspect.ismodule(value) else "a function" if inspect.isroutine(value)
                else f"an object of type {type(value).__name__}")
        return f"{name!r} names {what}, not a class; give a subclass of {base}"
    if not issubclass(value, kind.base):
        return f"{name!r} names the class {value.__name__}, which is not a subclass of {base}"
    return None


def class_path(cls: type) -> str:
    """``package.module:ClassName``: the path a config names ``cls`` by."""
    return f"{cls.__module__}{PATH_SEPARATOR}{cls.__qualname__}"


@functools.cache
def source_digest(cls: type) -> str:
    """The sha256 (hex) of the file that defines ``cls``, "" where it has none (a class made at run time)."""
    try:
        file = inspect.getsourcefile(cls)
    except (TypeError, OSError):
        return ""
    if file is None or not os.path.isfile(file):
        return ""
    return hashlib.sha256(Path(file).read_bytes()).hexdigest()


# -- the path's parts ---------------------------------------------------------------------------------
def _dotted(text: str) -> bool:
    return bool(text) and all(part.isidentifier() for part in text.split("."))


def _import_module(kind: PluginKind, module_name: str, name: str, current_folder: bool = True):
    """Import a plug-in's module; where Python does not find it, in the current folder too (as ``python -m`` would)."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        here = os.getcwd()
        if not current_folder or not _is_the_module(error, module_name) or not _beside(here, module_name) \
                or here in (_absolute(entry) for entry in sys.path):
            raise kind.error(_import_failed(module_name, name, error)) from None
    except Exception as error:  # noqa: BLE001 - a user's module may raise anything while it is imported
        raise kind.error(_import_failed(module_name, name, error)) from None
    sys.path.append(here)
    try:
        return importlib.import_module(module_name)
    except Exception as error:  # noqa: BLE001
        raise kind.error(_import_failed(module_name, name, error)) from None


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


def _attribute(kind: PluginKind, module, attribute: str, name: str) -> Any:
    value = module
    for part in attribute.split("."):
        if not hasattr(value, part):
            defined = sorted(key for key, item in vars(module).items()
                             if isinstance(item, type) and issubclass(item, kind.base) and item is not kind.base
                             and item.__module__ == module.__name__)
            where = f"module {module.__name__!r}" if value is module else getattr(value, "__name__", repr(value))
            close = difflib.get_close_matches(part, defined, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            noun = kind.base.__name__
            offer = f"; its {noun} classes: {', '.join(defined)}" if defined else f"; it defines no {noun} class"
            raise kind.error(f"{name!r}: {where} has no attribute {part!r}{hint}{offer}")
        value = getattr(value, part)
    return value


def _absolute(entry: str) -> str:
    return os.path.abspath(entry or os.curdir)
