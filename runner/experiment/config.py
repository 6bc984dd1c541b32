"""The experiment config: YAML in, validated models out, every error one line that names its field.

Loading never builds Python objects from YAML tags (safe loading only). Validation is pydantic's;
this module turns its errors into ``ConfigError`` messages of the form ``field.path: what is allowed``.
``system.type`` names a built-in system, a plug-in ``package.module:ClassName`` or an installed plug-in's
entry point (``simrun.systems.plugins``, docs/systems.md); the rest of the mapping is that model's parameters.
"""

from __future__ import annotations

import re

import copy
import difflib
import math
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import numpy as np
import yaml
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, SerializeAsAny, TypeAdapter, ValidationError,
                      field_validator, model_validator)
from pydantic_core import PydanticCustomError, PydanticKnownError

from simrun.errors import ConfigError
from simrun.experiment.fit import FitParams
from simrun.experiment.step_control import StepControlParams
from simrun.integrators import Integrator
from simrun.integrators import plugins as integrator_plugins
from simrun.solvers import SOLVER_PARAMS, NewtonParams, SolverField, SolverOptionError
from simrun.systems import SystemParams, plugins
from simrun.systems.vertex.files import SEARCH_FOLDERS as MODEL_SEARCH_FOLDERS

# A config's errors reported at once, one line each: enough to fix a file in one go, few enough to read.
MAX_REPORTED_ERRORS = 5
# record.error_time: auto measures the error after this many periods of the test frequency: long enough
# for the phase and amplitude errors to build up, short enough that the damped methods' errors at the
# sweep's larger steps are not yet saturated (the whole amplitude), so that an order can be fitted; an
# eighth of a period past a whole one, because at whole (or quarter) periods x = cos(w t) is at a turning
# point (or a zero), where the position error hides the phase (or the amplitude) error.
ERROR_PERIODS = 2.125


# -- integrators: a name, or a mapping with `type` and the method's parameters --------------------
def build_integrator(value: Any) -> Integrator:
    """The method that ``value`` names (a name or path, or a mapping with ``type`` and its parameters), validated by
    its own model; a plug-in's type is resolved by simrun.integrators.plugins."""
    if isinstance(value, Integrator):
        return value
    if isinstance(value, str):
        value = {"type": value}
    if not isinstance(value, dict):
        raise ValueError("expected an integrator name or a mapping with 'type' and its parameters")
    params = dict(value)
    name = params.pop("type", None)
    if name is None:
        raise ValueError("a mapping needs 'type': one of " + ", ".join(integrator_plugins.names())
                         + ", or a plug-in as package.module:ClassName")
    try:
        method = integrator_plugins.resolve(name)
    except integrator_plugins.IntegratorTypeError as error:
        raise ValueError(str(error)) from None
    try:
        return method.model_validate(params)
    except ValidationError as error:
        raise ValueError(f"{name}: " + _describe(error.errors()[0], method.model_fields)) from None
    except Exception as error:  # a plug-in's own validator that raised something else: still one line
        raise ValueError(f"{name}: {type(error).__name__}: {error}") from None


IntegratorField = Annotated[Integrator, BeforeValidator(build_integrator)]


# -- the system: a mapping whose `type` names a built-in system, a plug-in path or an installed plug-in --
SYSTEM_TYPE_ERROR = "system_type"  # the error type of a `type` that names no system (described as system.type: ...)


def _build_system(value: Any) -> SystemParams:
    """The parameter model that ``value["type"]`` resolves to (simrun.systems.plugins), validated with ``value``.

    Its errors keep their paths below ``system`` (``system.mass``); the type is stored as written, so that
    the config's hash and provenance are those of the file."""
    if isinstance(value, SystemParams):
        return value
    if not isinstance(value, dict):
        raise PydanticKnownError("model_attributes_type")
    if "type" not in value:
        raise _type_error("missing; valid: " + ", ".join(plugins.names()), None)
    try:
        model = plugins.resolve(value["type"])
    except plugins.SystemTypeError as error:
        raise _type_error(str(error), value["type"]) from None
    try:
        return model.model_validate(value)  # a ValidationError keeps its locations, below `system`
    except (ValueError, AssertionError):  # pydantic's own errors (a ValidationError is a ValueError)
        raise
    except Exception as error:  # a plug-in's own validator that raised something else: still one line
        raise ValueError(f"{value['type']}: {type(error).__name__}: {error}") from None


def _type_error(message: str, given: Any) -> ValidationError:
    return ValidationError.from_exception_data("system", [{
        "type": PydanticCustomError(SYSTEM_TYPE_ERROR, "{message}", {"message": message}), "loc": ("type",), "input": given}])


# Any SystemParams subclass, dumped with its own fields (SerializeAsAny), found by its `type`
SystemField = Annotated[SerializeAsAny[SystemParams], BeforeValidator(_build_system)]


# -- sweep values: a list, or {logspace: [start_exp, stop_exp, count]}, or {linspace: [a, b, n]} --
def _expand_values(value: Any) -> list:
    if isinstance(value, dict):
        if len(value) != 1 or next(iter(value)) not in ("logspace", "linspace"):
            raise ValueError("expected a list, {logspace: [start_exp, stop_exp, count]} or {linspace: [start, stop, count]}")
        (kind, spec), = value.items()
        if (not isinstance(spec, list) or len(spec) != 3
                or not all(isinstance(item, (int, float)) and not isinstance(item, bool) for item in spec)
                or not all(math.isfinite(item) for item in spec)):
            raise ValueError(f"{kind} takes three finite numbers [start, stop, count]")
        if not float(spec[2]).is_integer() or spec[2] < 1:
            raise ValueError(f"{kind} count must be a whole number >= 1, got {spec[2]}")
        make = np.logspace if kind == "logspace" else np.linspace
        return [float(item) for item in make(spec[0], spec[1], int(spec[2]))]
    if not isinstance(value, list):
        value = [value]
    if not value:
        raise ValueError("an empty sweep runs nothing: give at least one value")
    return value


SweepValues = Annotated[list[Any], BeforeValidator(_expand_values)]


class RecordParams(BaseModel):
    """What is kept of each run: every k-th step, or at most max_samples evenly spaced samples."""

    model_config = ConfigDict(extra="forbid")
    every: int | None = Field(None, ge=1, description="record every k-th step (the last step is always recorded)")
    max_samples: int = Field(10_000, ge=2, description="used when `every` is not given: record at most this many samples per run")
    series: bool = Field(True, description="keep the recorded series (samples, per-step solver counts, frames); false keeps "
                                          "only the summary's numbers and each run's scalars: a map of thousands of runs")

    max_wall_time: float | None = Field(None, gt=0, description="a run's budget of wall time (s): a run still stepping "
                                        "after it stops there, not_converged, with what it recorded so far (a run "
                                        "stepped alone: runs with a budget are not stepped as lanes). Its outcome "
                                        "depends on the machine: for the real-time question only; max_steps and "
                                        "max_solver_iterations bound a run the same on every machine")
    max_steps: int | None = Field(None, ge=1, description="a run's budget of steps (Hairer's NMAX): a run that has taken "
                                  "this many steps short of its end stops there, not_converged (step-controlled runs "
                                  "count their accepted steps; scipy's peers theirs)")
    max_solver_iterations: int | None = Field(None, ge=1, description="a run's budget of solver iterations, summed "
                                              "over its steps (Newton's, L-BFGS's, a sweep's): a run that has used them "
                                              "up short of its end stops there, not_converged; explicit methods and "
                                              "scipy's peers iterate no simrun solver")

    @property
    def budgeted(self) -> bool:
        """Some budget bounds each run: it is stepped alone (lanes step together)."""
        return self.max_wall_time is not None or self.max_steps is not None or self.max_solver_iterations is not None

    def used_up(self, steps: int, solver_iterations: int = 0, elapsed: float = 0.0) -> str | None:
        """What of its budgets a run has used up after ``steps`` steps, ``solver_iterations`` solver iterations and
        ``elapsed`` seconds of wall time short of its end, as its message says it; None while it has some left. The
        budgets of work (max_steps, max_solver_iterations) come first: they stop a run the same on every machine."""
        if self.max_steps is not None and steps >= self.max_steps:
            return f"{steps} steps, record.max_steps {self.max_steps}"
        if self.max_solver_iterations is not None and solver_iterations >= self.max_solver_iterations:
            return f"{solver_iterations} solver iterations, record.max_solver_iterations {self.max_solver_iterations}"
        if self.max_wall_time is not None and elapsed > self.max_wall_time:
            return f"{elapsed:.3g} s of wall time, over record.max_wall_time {self.max_wall_time:g} s"
        return None
    frames_every: int | None = Field(None, ge=1, description="cloth: keep the vertex positions every k-th step")
    max_frames: int = Field(200, ge=2, description="cloth, when `frames_every` is not given: at most this many frames per run")
    error_time: float | Literal["auto"] = Field(
        "auto", description="time (s) at which each run's error is measured, the same for every run of the sweep (at its "
                            f"nearest step): convergence is measured there; auto: {ERROR_PERIODS} periods of the system's "
                            "test frequency, else the end of the run (never past it)")

    @field_validator("error_time")
    @classmethod
    def _positive_time(cls, value):
        if value != "auto" and not (math.isfinite(value) and value > 0):
            raise ValueError(f"expected 'auto' or a time > 0 (s), got {value!r}")
        return value

    def error_step(self, dt: float, step_count: int, test_frequency: float | None) -> int:
        """The step at whose end the run's error is measured: the nearest to error_time (auto: ERROR_PERIODS
        periods 2 pi / w of the system's test frequency, else the whole run), within the run."""
        time = self.error_at(test_frequency)
        if time is None:
            return step_count
        return min(step_count, max(1, round(time / dt)))

    def error_at(self, test_frequency: float | None) -> float | None:
        """The time (s) of error_time (auto: ERROR_PERIODS periods of the test frequency), None: the run's end."""
        if self.error_time == "auto":
            return None if test_frequency is None else ERROR_PERIODS * 2.0 * math.pi / test_frequency
        return self.error_time

    def stride(self, step_count: int) -> int:
        if self.every is not None:
            return self.every
        return max(1, math.ceil(step_count / (self.max_samples - 1)))

    def frame_stride(self, step_count: int) -> int:
        if self.frames_every is not None:
            return self.frames_every
        return max(1, math.ceil(step_count / (self.max_frames - 1)))


class DivergenceParams(BaseModel):
    """When a run counts as diverged."""

    model_config = ConfigDict(extra="forbid")
    energy_factor: float = Field(1e6, gt=1, allow_inf_nan=False, description="diverged when |E - E0| exceeds this factor times the initial energy scale |KE0| + |PE0|, or E is not finite")
    check_every: int = Field(1, ge=1, description="test the energy every k-th step")


class Experiment(BaseModel):
    """A whole experiment as written in the YAML file (sweep values expanded, not yet multiplied out)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*$", max_length=100, description="names the output folder")
    system: SystemField
    integrators: list[IntegratorField] = Field(min_length=1, description="names, or mappings with 'type' and parameters")
    solver: SolverField = NewtonParams()
    duration: float = Field(10.0, gt=0, allow_inf_nan=False, description="simulated time per run (s)")
    sweep: dict[str, SweepValues] = Field(default_factory=dict, description="dt (s) and any other dotted key, each a list of values; with "
                                                      "step_control, no dt (step_control.tolerance is the axis)")
    step_control: StepControlParams | None = Field(None, description="adaptive steps by a local error estimate "
                                                                     "(docs/integrators.md); none: fixed steps of dt")
    record: RecordParams = RecordParams()
    divergence: DivergenceParams = DivergenceParams()
    output: str | None = Field(None, description="output folder; default results/<name>")
    fit: FitParams | None = Field(None, description="`simrun fit`: what was observed and which parameters to fit (docs/calibration.md)")

    @field_validator("sweep")
    @classmethod
    def _sweep_has_valid_dt(cls, sweep: dict[str, list]) -> dict[str, list]:
        for dt in sweep.get("dt", ()):
            if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0:
                raise ValueError(f"dt must be finite numbers > 0, got {dt!r}")
        return sweep

    @model_validator(mode="after")
    def _steps_are_fixed_or_controlled(self) -> "Experiment":
        if self.step_control is None and "dt" not in self.sweep:
            raise ValueError("sweep: needs 'dt': a list of time steps (s), or a step_control block")
        if self.step_control is not None and "dt" in self.sweep:
            raise ValueError("sweep.dt: step_control chooses every step; give step_control.dt_initial for the first, or "
                             "drop step_control for fixed steps")
        return self

    @property
    def steps(self) -> list[float]:
        """The fixed steps of the sweep (s); one NaN (no fixed step) where step_control chooses them."""
        return list(self.sweep["dt"]) if self.step_control is None else [math.nan]

    @property
    def output_dir(self) -> Path:
        return Path(self.output) if self.output else Path("results") / self.name


class Run(BaseModel):
    """One run: a fully resolved experiment with one integrator and one dt."""

    model_config = ConfigDict(frozen=True)
    run_id: str
    index: int
    system: SystemField
    integrator: IntegratorField
    solver: SolverField
    dt: float
    duration: float
    record: RecordParams
    divergence: DivergenceParams
    swept: dict[str, Any]  # the swept keys other than dt that this run uses, with this run's values
    # the integrator's label in its config: with the parameters its family varies (expand_runs); None: integrator.label
    label: str | None = None
    # adaptive steps (dt is then NaN: no fixed step), or None
    step_control: StepControlParams | None = None

    @property
    def integrator_label(self) -> str:
        """The integrator's name and parameters as the run id and the results file show them."""
        return self.label or self.integrator.label

    @property
    def step_count(self) -> int:
        """Steps of dt that fit in the duration: every run of a sweep ends within one dt before it, never past it;
        a step-controlled run's first estimate (one step: its count is known only once it ran)."""
        if self.step_control is not None:
            return 1
        return max(1, math.floor(self.duration / self.dt + 1e-9))

    @property
    def params(self) -> dict[str, Any]:
        """Every swept and method parameter of this run (stored as JSON in the results file): dt, or the tolerance of
        its step control (the rest of the block is in the stored config, and among the swept keys where swept)."""
        steps = {"dt": self.dt} if self.step_control is None else {"step_control.tolerance": self.step_control.tolerance}
        return {**steps, **self.swept, **{f"integrator.{key}": value for key, value in self.integrator.model_dump().items()}}


# -- loading ---------------------------------------------------------------------------------------
def config_file_of(config) -> Path | None:
    """The config's file, when it was given as a path (not YAML text or a dict)."""
    if isinstance(config, Path) or (isinstance(config, str) and "\n" not in config and ": " not in config):
        return Path(config)
    return None


def load_yaml(path: str | Path) -> tuple[dict, str]:
    """Read a config file safely; returns (raw mapping, text)."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"config: file {str(path)!r} does not exist")
    if path.is_dir():
        raise ConfigError(f"config: {str(path)!r} is a folder; give a YAML file such as configs/quickstart.yaml")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"config: cannot read {str(path)!r}: {error}") from None
    return parse_yaml(text, str(path)), text


def parse_yaml(text: str, source: str = "config") -> dict:
    try:
        raw = yaml.safe_load(text)
    except yaml.constructor.ConstructorError as error:
        mark = error.problem_mark
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        raise ConfigError(f"{source}{where}: YAML tags that build objects are not allowed; write plain values") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ConfigError(f"{source}:{where}: malformed YAML: {problem}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping with name, system, integrators and sweep at the top level")
    return raw


def apply_override(raw: dict, assignment: str) -> None:
    """Apply one ``--set key.path=value`` (value parsed as YAML) to the raw config, in place; under ``sweep.`` the rest
    of the path is one swept key (``sweep.system.stiffness=[10, 100]``)."""
    key, sep, text = assignment.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--set {assignment}: expected key.path=value, e.g. system.stiffness=1000")
    value = parse_yaml(f"value: {text}", f"--set {key}")["value"]
    parts = key.split(".")
    if parts[0] == "sweep" and len(parts) > 2:  # a swept key is a dotted path itself: sweep.system.stiffness=[1, 2]
        parts = ["sweep", ".".join(parts[1:])]
    set_path(raw, parts, value, f"--set {key}")


def set_path(raw: dict, parts: list[str], value: Any, source: str) -> None:
    node = raw
    for part in parts[:-1]:
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ConfigError(f"{source}: {part!r} is not a mapping, so it has no key {parts[-1]!r}")
        node = child
    node[parts[-1]] = value


def validate_experiment(raw: dict) -> Experiment:
    raw = _base_system_from_sweep(raw)
    try:
        return Experiment.model_validate(raw)
    except ValidationError as error:
        raise ConfigError(describe_error(error, raw)) from None


def _base_system_from_sweep(raw: dict) -> dict:
    """A config that sweeps whole systems (``sweep.system: [{...}, {...}]``) may leave out ``system``: the first swept
    one, without its label, is then the base, so that no model is written out twice."""
    sweep = raw.get("sweep")
    swept = sweep.get("system") if isinstance(sweep, dict) else None
    if "system" in raw or not isinstance(swept, list) or not swept or not isinstance(swept[0], dict):
        return raw
    return {**raw, "system": {key: value for key, value in swept[0].items() if key != "label"}}


_SYSTEM_ALONE = TypeAdapter(SystemField)


def validate_system(raw: Any) -> SystemParams:
    """A config's ``system`` mapping on its own (``simrun check-system``); errors as in a config (``system.mass: ...``)."""
    try:
        return _SYSTEM_ALONE.validate_python(raw)
    except ValidationError as error:
        raise ConfigError(describe_error(error, {"system": raw}, within=("system",))) from None


def load_experiment(source: str | Path | dict, overrides: list[str] = ()) -> tuple[Experiment, str]:
    """Load, override and validate a config; returns the experiment and its resolved YAML text.

    source: a path to a YAML file, YAML text (a string with a line break or a ``key: value``), or a
    dict of the same content (as ``simrun.run`` accepts)."""
    if isinstance(source, dict):
        raw, text = copy.deepcopy(source), yaml.safe_dump(source, sort_keys=False)
    elif isinstance(source, str) and ("\n" in source or ": " in source):
        raw, text = parse_yaml(source), source
    elif isinstance(source, (str, Path)):
        raw, text = load_yaml(source)
    else:
        raise ConfigError(f"config: expected a path, YAML text or a dict, got {type(source).__name__}")
    if overrides:
        for assignment in overrides:
            apply_override(raw, assignment)
        text = yaml.safe_dump(raw, sort_keys=False)
    folders = (Path(source).resolve().parent,) if isinstance(source, Path) or (isinstance(source, str) and "\n" not in source
                                                                           and ": " not in source) else ()
    token = MODEL_SEARCH_FOLDERS.set(folders)  # relative model paths: the current folder, then the config's
    try:
        return validate_experiment(raw), text
    finally:
        MODEL_SEARCH_FOLDERS.reset(token)


# -- describing validation errors ------------------------------------------------------------------
def _did_you_mean(word: str, choices) -> str:
    close = difflib.get_close_matches(str(word), list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


# "field: message", "field[2].sub: message": a message that names a field of the model it was raised for
FIELD_PREFIX = re.compile(r"^([a-z_]+(?:\[\d+\])?(?:\.[a-z_]+(?:\[\d+\])?)*): (.*)$", re.DOTALL)


def _describe(error: dict, fields: dict | None = None) -> str:
    """One pydantic error as 'path: message'."""
    location = ".".join(str(part) for part in error["loc"])
    kind, message = error["type"], error["msg"]
    if kind == "extra_forbidden":
        name = str(error["loc"][-1])
        message = f"unknown key{_did_you_mean(name, fields or {})}"
        if fields:
            message += "; allowed: " + ", ".join(fields)
    elif kind == "value_error":
        message = message.removeprefix("Value error, ")
        # a model's own check that names one of its fields ("pinned: vertex 99 does not exist", raised where
        # the whole model is known): that field's path, system.pinned, rather than system: pinned
        named = FIELD_PREFIX.match(message)
        if named and fields and named.group(1).split("[")[0].split(".")[0] in fields:
            location = f"{location}.{named.group(1)}" if location else named.group(1)
            message = named.group(2)
    elif "input" in error and kind not in ("missing",) and not isinstance(error["input"], (dict, list)):
        message = f"{message} (got {error['input']!r})"
    return f"{location}: {message}" if location else message


def describe_error(error: ValidationError, raw: dict, within: tuple[str, ...] = ()) -> str:
    """Up to MAX_REPORTED_ERRORS errors of a config, one line each (``field.path: what is allowed``).

    within: the config path of what was validated, when it was a part of a config (``("system",)``)."""
    lines: dict[str, list[str]] = {}  # config path -> its messages (the alternatives of a union are one error)
    for item in error.errors():
        path, line = _describe_one({**item, "loc": within + tuple(item["loc"])}, raw)
        if path not in lines and len(lines) == MAX_REPORTED_ERRORS:
            break
        if line not in lines.setdefault(path, []):
            lines[path].append(line)
    # a line break inside a message (a key or value with one) would look like a second error
    return "\n".join(_joined_alternatives(path, messages).replace("\n", "\\n") for path, messages in lines.items())


def _describe_one(item: dict, raw: dict) -> tuple[str, str]:
    """One pydantic error as (its config path, its line)."""
    location = [part for part in item["loc"]]
    cause = item.get("ctx", {}).get("error")
    if isinstance(cause, SolverOptionError):  # it names the option inside the field: solver.history, not solver
        location += list(cause.path)
        item = {**item, "msg": cause.reason}
    # ... and the member of a plain union that did not match (record.error_time.float): one error per field
    location = _without_union_member(location, raw)
    item = {**item, "loc": tuple(location)}
    path = ".".join(str(part) for part in location)
    if item["type"] == SYSTEM_TYPE_ERROR:
        return path, f"{path}: {item['msg']}"
    if item["type"] == "value_error":  # raised by the model at this path: its own fields may be named
        line = _describe(item, _fields_at(location, raw))
        return line.split(": ", 1)[0], line
    return path, _describe(item, _fields_at(location[:-1], raw))


def _joined_alternatives(path: str, lines: list[str]) -> str:
    """'path: a' and 'path: b' (the members of a union) as 'path: a, or b'."""
    prefix = f"{path}: "
    if len(lines) == 1 or not path or not all(line.startswith(prefix) for line in lines):
        return lines[0]
    messages = [line.removeprefix(prefix) for line in lines]
    got = messages[-1][messages[-1].rfind(" (got "):] if " (got " in messages[-1] else None
    if got and all(message.endswith(got) for message in messages):  # the input once, at the end
        messages = [message.removesuffix(got) for message in messages[:-1]] + messages[-1:]
    return prefix + ", or ".join(messages)


def _without_union_member(location: list, raw: dict) -> list:
    """An error location cut where pydantic names the member of a union that failed: the config's path."""
    node: Any = Experiment
    for number, part in enumerate(location):
        node = _unwrap(node)
        if node is SystemParams:  # the system's fields are those of the model its type names
            node = _system_model(raw)
        if isinstance(node, type) and issubclass(node, BaseModel):
            if part not in node.model_fields:
                return location  # an unknown key, or a path below a validator's own: as it is
            node = node.model_fields[part].annotation
        elif get_origin(node) in (list, tuple, dict):
            arguments = get_args(node)
            node = arguments[-1] if arguments else None
        elif get_origin(node) in (Union, UnionType):
            # a union of models (the systems) continues in the member that has the key; any other union's
            # next part names the member that failed
            models = [member for member in get_args(node) if isinstance(member, type) and issubclass(member, BaseModel)]
            if not models:
                return location[:number] if isinstance(part, str) else location
            owner = next((model for model in models if part in model.model_fields), None)
            if owner is None:
                return location  # an unknown key of a model
            node = owner.model_fields[part].annotation
        else:
            return location
    return location


def _unwrap(node: Any) -> Any:
    """The type inside Annotated[X, ...] and X | None."""
    while True:
        if get_origin(node) is Annotated:
            node = get_args(node)[0]
            continue
        if get_origin(node) in (Union, UnionType):
            members = [member for member in get_args(node) if member is not type(None)]
            if len(members) == 1:
                node = members[0]
                continue
        return node


def _system_model(raw: dict) -> type[SystemParams] | None:
    """The parameter model that the config's system.type names, if it names one."""
    system = raw.get("system") if isinstance(raw, dict) else None
    return plugins.find(system.get("type")) if isinstance(system, dict) else None


def _fields_at(location: list, raw: dict) -> dict:
    """The model fields allowed at a config path (to suggest names for an unknown key)."""
    model: type[BaseModel] | None = Experiment
    for part in location:
        if model is None:
            return {}
        if part == "system":
            model = _system_model(raw)
            continue
        if part == "solver":
            solver_type = raw["solver"].get("type", "newton") if isinstance(raw.get("solver"), dict) else None
            model = SOLVER_PARAMS.get(solver_type) if isinstance(solver_type, str) else None
            continue
        field = model.model_fields.get(str(part))
        annotation = _unwrap(getattr(field, "annotation", None))
        model = annotation if isinstance(annotation, type) and issubclass(annotation, BaseModel) else None
    return model.model_fields if model is not None else {}
