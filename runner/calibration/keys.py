"""Fitted parameters are config keys of the system (``system.stiffness``, ``system.stiffness.stretch``,
``system.damping.0.coefficient``): dotted paths into the system's mapping, a whole number indexing a list. A trial
value is set on the mapping and validated as the config would be, so every model's own rules hold for the fit."""

from __future__ import annotations

import difflib
import math
from typing import Any

from simrun.errors import ConfigError
from simrun.experiment.config import validate_system


def key_parts(key: str) -> list[str | int]:
    """'system.damping.0.coefficient' -> ['damping', 0, 'coefficient']."""
    return [int(part) if part.isdigit() else part for part in key.split(".")[1:]]


def get_value(node: Any, parts: list) -> Any:
    for part in parts:
        if isinstance(part, int) and isinstance(node, list) and part < len(node):
            node = node[part]
        elif isinstance(part, str) and isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise KeyError(part)
    return node


def set_value(node: Any, parts: list, value: Any) -> None:
    for part in parts[:-1]:
        node = node[part]
    node[parts[-1]] = value


def numeric_keys(node: Any, prefix: str = "system") -> list[str]:
    """Every key below ``node`` whose value is a real number (the keys a fit can name; whole-number settings such as
    a grid's resolution are not fitted)."""
    if isinstance(node, dict):
        return [key for name, child in node.items() for key in numeric_keys(child, f"{prefix}.{name}")]
    if isinstance(node, list):
        return [key for number, child in enumerate(node) for key in numeric_keys(child, f"{prefix}.{number}")]
    return [prefix] if isinstance(node, float) else []


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def system_mapping(system) -> dict:
    """The system's config with every default filled in (JSON types)."""
    return system.model_dump(mode="json")


def system_at(system, keys: list[str], values) -> Any:
    """The system's parameters with ``keys`` set to ``values``: validated, so a value the model refuses raises
    ValueError (one line)."""
    mapping = system_mapping(system)
    for key, value in zip(keys, values):
        set_value(mapping, key_parts(key), float(value))
    try:
        return validate_system(mapping)
    except ConfigError as error:
        raise ValueError(str(error)) from None


def check_parameters(system, parameters: dict) -> None:
    """Each fitted key names a number of the system; its start and finite bounds are values the system takes.
    ConfigError ``fit.parameters.<key>...: ...`` otherwise."""
    mapping = system_mapping(system)
    numbers = numeric_keys(mapping)
    for key, spec in parameters.items():
        where = f"fit.parameters.{key}"
        try:
            value = get_value(mapping, key_parts(key))
        except KeyError:
            close = difflib.get_close_matches(key, numbers, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(f"{where}: the system ({mapping.get('type')}) has no key {key.removeprefix('system.')!r}"
                              f"{hint}; numeric keys: {', '.join(numbers) or 'none'}") from None
        if not isinstance(value, float):
            what = "a whole-number setting" if _is_number(value) else "not a number"
            raise ConfigError(f"{where}: {key} is {value!r}, {what}; numeric keys: {', '.join(numbers) or 'none'}")
        for name, trial in (("start", spec.start), ("bounds", spec.bounds[0]), ("bounds", spec.bounds[1])):
            if not math.isfinite(trial):
                continue
            try:
                system_at(system, [key], [trial])
            except ValueError as error:
                raise ConfigError(f"{where}.{name}: {trial:g} is not a value of {key}: {_reason(str(error))}") from None


def _reason(message: str) -> str:
    """The model's own complaint without its leading field path."""
    return message.split(": ", 1)[1] if ": " in message else message


__all__ = ["check_parameters", "get_value", "key_parts", "numeric_keys", "set_value", "system_at", "system_mapping"]
