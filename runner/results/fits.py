"""Reading the fits of a results file (``Results.fits``): a table with one row per fit, the observations, each
fit's trajectory at the observation times, and the transfer table. Layout: docs/results-format.md, "Fits"."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np


@dataclass
class FitResults:
    """parameters: the fitted config keys; table: one row per fit (pandas DataFrame: fit_id, index, label,
    integrator, dt, status, message, residual_norm, rms_residual, evaluations, iterations, simulations, wall_time,
    jacobian, and per key: ``<key>``, ``<key> stderr``, ``<key> start``, ``<key> predicted``); observed_t (K,),
    observed_positions (K, q) and names (q,); truth: the keys' values that made synthetic data ({} otherwise);
    transfer: pandas DataFrame (fit_id, integrator, dt, relative_error, status)."""

    parameters: list[str]
    table: object
    observed_t: np.ndarray
    observed_positions: np.ndarray
    names: list[str]
    truth: dict
    source: str
    weights: str
    transfer: object
    _fitted: dict

    def fitted(self, fit_id: str) -> np.ndarray:
        """The fit's positions at the observation times (K, q), NaN where it has none."""
        return self._fitted[fit_id]

    @property
    def reference(self):
        """The row of the fit with the system's exact solution (the observed motion's own parameters), or None."""
        rows = self.table[self.table["integrator"] == "exact"]
        return None if rows.empty else rows.iloc[0]

    @property
    def method_fits(self):
        """The rows of the fits with an integrator (not the exact solution), in sweep order."""
        return self.table[self.table["integrator"] != "exact"]


def read_fits(file) -> FitResults | None:
    """The fits of an open h5py file, or None when it holds none."""
    import pandas

    if "fits" not in file:
        return None
    group = file["fits"]
    attrs = group.attrs
    keys = json.loads(_text(attrs["parameters"]))
    rows, fitted = [], {}
    for name, item in group.items():
        if not hasattr(item, "attrs") or "complete" not in item.attrs or not item.attrs["complete"]:
            continue
        a = item.attrs
        row = {"fit_id": name, "index": int(a["index"]), "label": _text(a["label"]), "integrator": _text(a["integrator"]),
               "dt": float(a["dt"]), "status": _text(a["status"]), "message": _text(a["message"])}
        for column in ("residual_norm", "rms_residual", "wall_time"):
            row[column] = float(a[column])
        for column in ("evaluations", "iterations", "simulations"):
            row[column] = int(a[column])
        row["jacobian"] = _text(a["jacobian"])
        values, errors = json.loads(_text(a["values"])), json.loads(_text(a["standard_errors"]))
        starts, predicted = json.loads(_text(a["start"])), json.loads(_text(a["predicted"]))
        for key in keys:
            row[key] = float(values.get(key, np.nan))
            row[f"{key} stderr"] = float(errors.get(key, np.nan))
            row[f"{key} start"] = float(starts.get(key, np.nan))
            row[f"{key} predicted"] = float(predicted.get(key, np.nan))
        rows.append(row)
        fitted[name] = item["fitted_positions"][()]
    table = pandas.DataFrame(rows)
    if not table.empty:
        table = table.sort_values("index").reset_index(drop=True)
    transfer = pandas.DataFrame(columns=["fit_id", "integrator", "dt", "relative_error", "status"])
    if "transfer" in group:
        data = group["transfer"][()]
        transfer = pandas.DataFrame({name: [_text(value) for value in data[name]] if data.dtype[name].kind == "O" else data[name]
                                     for name in data.dtype.names})
    return FitResults(keys, table, group["observed_t"][()], group["observed_positions"][()],
                      json.loads(_text(attrs["names"])), json.loads(_text(attrs["truth"])), _text(attrs["source"]),
                      _text(attrs["weights"]), transfer, fitted)


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


__all__ = ["FitResults", "read_fits"]
