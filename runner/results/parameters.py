"""The summary's parameter columns: one per swept key and per method parameter, named by the key, typed.

A run's ``params`` attribute holds what sets it apart: the swept keys it reads (``system.stiffness``, ``solver.type``),
its step control's tolerance, and its integrator's parameters (``integrator.order``). Each becomes one column of
``results.summary``, ``simrun show --csv`` and the report's runs table, so that runs group by them without their ids:

    summary.groupby(["system.label", "step_control.tolerance", "integrator"])["error"].min()

A key swept over whole mappings (a labelled ``system``, a ``solver``) is named ``<key>.label`` and holds each mapping's
name as the run ids show it. A run that does not read a key (``solver.linear_solver`` of L-BFGS, ``integrator.order``
of a method without one) has it missing: NaN, or pandas' NA in integer and boolean columns. ``dt`` is the summary's
own column already. Like the reader, this module does not import the library.
"""

from __future__ import annotations

import json
import math
from typing import Any

# keys of ``params`` that the summary has as columns of its own
OWN_COLUMNS = ("dt",)
# the column of a key swept over whole mappings: the mapping's name (its label)
LABEL_SUFFIX = ".label"


def column_name(key: str, mapping_keys: set[str]) -> str:
    return key + LABEL_SUFFIX if key in mapping_keys else key


def mapping_keys(config: dict) -> set[str]:
    """The swept keys whose values are mappings (a whole ``system`` or ``solver``): their runs carry the mapping's name."""
    sweep = config.get("sweep") or {}
    return {key for key, values in sweep.items() if isinstance(values, list) and any(isinstance(value, dict) for value in values)}


def parameter_columns(params: list[dict[str, Any]], config: dict) -> dict[str, list]:
    """Column name -> one value per run (None where the run does not read the key), in the order the keys first
    appear: the swept keys in the config's order, then the step control's tolerance, then the integrators'
    parameters."""
    swept = [key for key in (config.get("sweep") or {}) if key not in OWN_COLUMNS]
    seen: dict[str, None] = dict.fromkeys(swept)
    for run in params:
        seen.update(dict.fromkeys(key for key in run if key not in OWN_COLUMNS))
    present = [key for key in seen if any(key in run for run in params)]
    present.sort(key=lambda key: (key.startswith("integrator."), key not in swept))  # stable: the order above
    mappings = mapping_keys(config)
    return {column_name(key, mappings): [_plain(run.get(key)) for run in params] for key in present}


def _plain(value):
    """A stored value as a cell: lists as tuples (hashable, so that pandas groups by them), mappings as JSON."""
    if isinstance(value, list):
        return tuple(_plain(item) for item in value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True)
    return value


def column_kind(values: list) -> str:
    """How a column is typed: "bool", "int", "float" or "object" (text and anything else), from its present values."""
    present = [value for value in values if value is not None]
    if present and all(isinstance(value, bool) for value in present):
        return "bool"
    if present and all(isinstance(value, int) and not isinstance(value, bool) for value in present):
        return "int"
    if present and all(isinstance(value, (int, float)) and not isinstance(value, bool) for value in present):
        return "float"
    return "object"


def typed_series(values: list):
    """A pandas Series of one parameter column: bool and int columns nullable ("boolean", "Int64") where a run lacks
    the key, float columns NaN there, the rest as objects (None there)."""
    import pandas

    kind = column_kind(values)
    missing = any(value is None for value in values)
    if kind == "bool":
        return pandas.Series(values, dtype="boolean" if missing else bool)
    if kind == "int":
        return pandas.Series(values, dtype="Int64" if missing else "int64")
    if kind == "float":
        return pandas.Series([math.nan if value is None else float(value) for value in values], dtype="float64")
    return pandas.Series(values, dtype=object)


__all__ = ["column_kind", "column_name", "mapping_keys", "parameter_columns", "typed_series"]
