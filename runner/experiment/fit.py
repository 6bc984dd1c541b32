"""The ``fit`` block of a config: what was observed, which markers, which parameters (with bounds and a start),
how residuals are weighted and how the Jacobian is formed. Checked as any config section is, one line per
error naming its path (``fit.parameters.system.stiffness.bounds: ...``); what needs the system (a key that
names no numeric system parameter, a marker out of range) is checked by ``simrun.calibration.keys.check_parameters``."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator, model_validator


class ParameterSpec(BaseModel):
    """One fitted parameter: its start and bounds, in the config key's own units."""

    model_config = ConfigDict(extra="forbid")
    start: float = Field(allow_inf_nan=False, description="the first iterate")
    bounds: tuple[float, float] = Field((-math.inf, math.inf), description="[lower, upper]; .inf / -.inf: unbounded")

    @model_validator(mode="after")
    def _start_within(self) -> "ParameterSpec":
        lower, upper = self.bounds
        if math.isnan(lower) or math.isnan(upper):
            raise ValueError("bounds: NaN is not a bound; give [lower, upper] (.inf for none)")
        if not lower < upper:
            raise ValueError(f"bounds: [{lower:g}, {upper:g}] is inverted or empty; give [lower, upper] with lower < upper")
        if not lower <= self.start <= upper:
            raise ValueError(f"start: {self.start:g} lies outside bounds [{lower:g}, {upper:g}]")
        return self


class Synthetic(BaseModel):
    """Observations made on the fly: the experiment's system with ``system`` overrides (the truth), stepped by
    ``integrator`` (``exact``: the system's exact solution, the spring's) at ``dt``, kept every ``every``-th
    step, with Gaussian noise of standard deviation ``noise`` (m) drawn from ``seed``."""

    model_config = ConfigDict(extra="forbid")
    system: dict[str, Any] = Field({}, description="system keys of the truth (the rest as the experiment's system)")
    integrator: Union[str, dict[str, Any]] = Field("exact", description="exact (the exact solution), or any integrator name or mapping")
    dt: float = Field(gt=0, allow_inf_nan=False, description="the step (s) of the data (exact: the sample spacing before `every`)")
    noise: float = Field(0.0, ge=0, allow_inf_nan=False, description="standard deviation of the noise added to every observed value (m)")
    every: int = Field(1, ge=1, description="keep every k-th step")
    seed: int = Field(0, ge=0, description="of the noise")
    duration: float | None = Field(None, gt=0, allow_inf_nan=False, description="s; default: the experiment's duration")


class StoredRun(BaseModel):
    """Observations taken from a run of a simrun results file."""

    model_config = ConfigDict(extra="forbid")
    results: str = Field(description="path of a results.h5")
    run: str | None = Field(None, description="run id (default: the file's only run)")


class Transfer(BaseModel):
    """The transfer table: every fit's parameters simulated with these integrators at these steps."""

    model_config = ConfigDict(extra="forbid")
    integrators: list[Union[str, dict[str, Any]]] | None = Field(None, description="default: the experiment's integrators")
    dt: list[float] | None = Field(None, description="s; default: the sweep's smallest dt")

    @field_validator("dt")
    @classmethod
    def _positive(cls, values):
        if values is not None:
            if not values:
                raise ValueError("give at least one time step, or leave it out")
            for value in values:
                if not (math.isfinite(value) and value > 0):
                    raise ValueError(f"time steps must be finite numbers > 0, got {value!r}")
        return values


def _observed_source(value: Any):
    """A CSV path, {results, run} or {synthetic: {...}}, told apart by their shape first, so that an error in one
    is reported as that one's (one line), not as every member of the union failing."""
    if isinstance(value, (str, StoredRun)):
        return value
    if isinstance(value, dict) and "synthetic" in value:
        if len(value) != 1:
            raise ValueError("synthetic: give it alone, as {synthetic: {...}}")
        synthetic = value["synthetic"]
        return {"synthetic": synthetic if isinstance(synthetic, Synthetic) else _member(Synthetic, synthetic, "synthetic.")}
    if isinstance(value, dict) and "results" in value:
        return _member(StoredRun, value, "")
    raise ValueError("expected a CSV file's path, {results: FILE.h5, run: RUN_ID} or {synthetic: {...}}")


def _member(model: type[BaseModel], value: Any, prefix: str):
    """``model`` validated from ``value``; its first error as one ValueError line ``prefix + field: message``."""
    try:
        return model.model_validate(value)
    except ValidationError as error:
        item = error.errors()[0]
        where = prefix + ".".join(str(part) for part in item["loc"])
        message = (f"unknown key; allowed: {', '.join(model.model_fields)}" if item["type"] == "extra_forbidden"
                   else item["msg"].removeprefix("Value error, "))
        if "input" in item and not isinstance(item["input"], (dict, list)) and item["type"] not in ("missing", "extra_forbidden"):
            message += f" (got {item['input']!r})"
        raise ValueError(f"{where.rstrip('.')}: {message}" if where.rstrip(".") else message) from None


class FitParams(BaseModel):
    """The ``fit`` block (docs/calibration.md)."""

    model_config = ConfigDict(extra="forbid")
    observed: Annotated[Any, BeforeValidator(_observed_source)] = Field(
        description="a CSV file (t, then one column per observed dof), {results: file.h5, run: id}, or {synthetic: {...}}")
    markers: list[int] | None = Field(None, description="observed vertices (every dof when omitted); spring_mass: its one position")
    parameters: dict[str, ParameterSpec] = Field(min_length=1, description="config keys (system.*) with start and bounds")
    weights: Literal["position", "position_and_velocity"] = Field(
        "position", description="position: sum of squared position errors; position_and_velocity: velocities too, "
                                "scaled by the observed motion's time scale rms(x)/rms(v)")
    compare: Literal["steps", "interpolated"] = Field(
        "steps", description="steps: only the observations at a run's steps enter its residual (a method has no motion "
                             "between its steps); interpolated: every observation, with the run's motion interpolated "
                             "(cubic Hermite on x and v) in each step")
    sensitivities: Literal["auto", "exact", "finite_differences"] = Field(
        "auto", description="auto: exact forward sensitivities where the method and parameter have them, else finite "
                            "differences; exact: refuse a fit that would need finite differences")
    max_evaluations: int = Field(100, ge=2, description="per fit, the least-squares solver's budget of residual evaluations "
                                                        "(max_nfev; a finite-difference Jacobian costs one more simulation per parameter)")
    tolerance: float = Field(1e-10, gt=0, lt=1, description="ftol, xtol and gtol of scipy.optimize.least_squares")
    transfer: Transfer = Transfer()

    @field_validator("markers")
    @classmethod
    def _markers(cls, markers):
        if markers is not None:
            if not markers:
                raise ValueError("give at least one vertex, or leave markers out to observe every dof")
            if any(marker < 0 for marker in markers):
                raise ValueError(f"vertex indices are >= 0, got {min(markers)}")
            if len(set(markers)) != len(markers):
                raise ValueError("a vertex is listed twice")
        return markers

    @field_validator("parameters")
    @classmethod
    def _system_keys(cls, parameters):
        for key in parameters:
            if not key.startswith("system.") or any(not part for part in key.split(".")[1:]) or key == "system.":
                raise ValueError(f"{key!r}: fitted parameters are system keys (the model's), e.g. system.stiffness")
            if key == "system.type":
                raise ValueError("'system.type' is not a number")
        return parameters
