"""The fits in the results file (docs/results-format.md, "Fits"): the observations, one group per fit (committed
whole, ``complete`` last, so that a killed calibration resumes), and the transfer table. ``simrun.results.fits``
reads them back."""

from __future__ import annotations

import json

import h5py
import numpy as np

FITS = "fits"
TRANSFER_DTYPE = np.dtype([("fit_id", h5py.string_dtype()), ("integrator", h5py.string_dtype()), ("dt", "f8"),
                           ("relative_error", "f8"), ("status", h5py.string_dtype())])


def begin(file: h5py.File, fit, observations, keys: list[str]) -> None:
    """The /fits group with the observations and what every fit shares, unless a resumed file has it; incomplete
    fit groups (a killed calibration's) are removed."""
    if FITS in file:
        group = file[FITS]
        for name in [name for name, item in group.items() if isinstance(item, h5py.Group) and not item.attrs.get("complete", False)]:
            del group[name]
        return
    group = file.create_group(FITS)
    attrs = group.attrs
    attrs["parameters"] = json.dumps(keys)
    attrs["weights"] = fit.weights
    attrs["sensitivities"] = fit.sensitivities
    attrs["source"] = observations.source
    attrs["truth"] = json.dumps(observations.truth)
    attrs["names"] = json.dumps(observations.names)
    attrs["dofs"] = observations.dofs.astype(np.int64)
    attrs["velocity_scale"] = observations.velocity_scale
    attrs["starts"] = json.dumps({key: spec.start for key, spec in fit.parameters.items()})
    attrs["bounds"] = json.dumps({key: list(spec.bounds) for key, spec in fit.parameters.items()})
    group.create_dataset("observed_t", data=observations.t)
    group.create_dataset("observed_positions", data=observations.positions)
    if observations.velocities is not None:
        group.create_dataset("observed_velocities", data=observations.velocities)
    file.flush()


def completed(file: h5py.File) -> set[str]:
    if FITS not in file:
        return set()
    return {name for name, item in file[FITS].items() if isinstance(item, h5py.Group) and item.attrs.get("complete", False)}


def write_fit(file: h5py.File, task, outcome) -> None:
    """One fit's group: what was fitted, with what, and what came out; ``complete`` last."""
    group = file[FITS].create_group(task.fit_id)
    attrs = group.attrs
    keys = task.keys
    attrs["index"] = task.index
    attrs["label"] = task.label
    attrs["integrator"] = "exact" if task.integrator is None else task.integrator.name
    attrs["integrator_params"] = json.dumps({} if task.integrator is None else task.integrator.model_dump(mode="json"))
    attrs["dt"] = task.dt
    attrs["status"] = outcome.status
    attrs["message"] = outcome.message
    attrs["values"] = json.dumps(dict(zip(keys, map(float, outcome.values))))
    attrs["standard_errors"] = json.dumps(dict(zip(keys, map(float, outcome.standard_errors))))
    attrs["start"] = json.dumps(dict(zip(keys, map(float, task.start))))
    attrs["predicted"] = json.dumps({})
    for name in ("residual_norm", "rms_residual", "evaluations", "iterations", "simulations", "wall_time", "jacobian"):
        attrs[name] = getattr(outcome, name)
    group.create_dataset("fitted_positions", data=outcome.fitted_positions)
    if outcome.fitted_velocities is not None:
        group.create_dataset("fitted_velocities", data=outcome.fitted_velocities)
    attrs["complete"] = True
    file.flush()


def write_predicted(file: h5py.File, predicted: dict[str, dict[str, float]]) -> None:
    """Each fit's predicted values (fit id -> key -> value; see simrun.calibration.predicted)."""
    for fit_id, values in predicted.items():
        file[FITS][fit_id].attrs["predicted"] = json.dumps(values)
    file.flush()


def write_transfer(file: h5py.File, rows: list[tuple]) -> None:
    """The transfer table (fit id, integrator label, dt, relative error, status), replacing an older one."""
    group = file[FITS]
    if "transfer" in group:
        del group["transfer"]
    group.create_dataset("transfer", data=np.array(rows, dtype=TRANSFER_DTYPE))
    file.flush()


__all__ = ["FITS", "TRANSFER_DTYPE", "begin", "completed", "write_fit", "write_predicted", "write_transfer"]
