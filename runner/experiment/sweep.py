"""The sweep of an experiment expanded into runs: the cartesian product of the swept values and the
integrators, every run validated before any starts, and the hash that tells one experiment from another.

A swept key a run does not use (a linear-solver key for a solver without linear solves, any solver key
for an explicit method) does not multiply it; integrators of one type that differ in a parameter (a
family) are labelled with that parameter in every member.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
from typing import Any

import yaml
from pydantic import ValidationError

from simrun.errors import ConfigError
from simrun.experiment.config import Experiment, Run, describe_error, set_path
from simrun.experiment.step_control import estimate_refusal
from simrun.integrators import Integrator
from simrun.integrators.labels import parameter_text
from simrun.solvers import SOLVERS, SOLVER_PARAMS, NonlinearSolver, SolverParams
from simrun.systems.forms import contact_needs_step_filter

# A sweep bigger than this is almost certainly a typo in a logspace/linspace count.
MAX_RUNS = 100_000


def expand_runs(experiment: Experiment) -> list[Run]:
    """The cartesian product of the sweep x integrators, every run validated before any starts.

    A swept solver key that a run does not use (``solver.linear_solver`` for L-BFGS, any solver key for
    an explicit method) does not multiply that run: it is run once, with the key's first value, and
    its run id does not name the key."""
    swept = {key: [_without_label(value) for value in values] for key, values in experiment.sweep.items() if key != "dt"}
    names = {key: _value_names(key, values) for key, values in experiment.sweep.items() if key != "dt"}
    combinations = [dict(zip(swept, values)) for values in _product(list(swept.values()))]
    # the same, as runs name them: a swept mapping (a whole system, say) by its label
    shown = [dict(zip(names, values)) for values in _product(list(names.values()))]
    steps = experiment.steps  # the fixed steps, or one NaN where step_control chooses them
    total = len(combinations) * len(experiment.integrators) * len(steps)
    if total > MAX_RUNS:
        raise ConfigError(f"sweep: {total} runs exceed the limit of {MAX_RUNS}; shorten the sweep")
    base = experiment.model_dump(exclude={"sweep", "output", "name", "fit"}, mode="python")
    # the solver as written (its defaults filled in again per run), so that sweeping solver.type does not
    # carry the base solver's own options to a solver that does not take them
    base["solver"] = experiment.solver.model_dump(exclude_unset=True, mode="python")
    base["integrators"] = list(experiment.integrators)
    labels = family_labels(experiment.integrators)
    runs = []
    systems: dict[str, Any] = {}  # built systems by their config, for the solvers' refusals
    seen = set()  # (integrator's position, the swept keys it uses) already expanded
    swept_solvers = tuple(swept.get("solver.type", ()))
    for assignment, named in zip(combinations, shown):
        resolved = _resolve(base, assignment, swept_solvers)
        for number, integrator in enumerate(resolved.integrators):
            used = {key: named[key] for key in assignment if uses_swept_key(key, integrator, resolved.solver, swept_solvers)}
            identity = (number, json.dumps(used, sort_keys=True, default=str))
            if identity in seen:
                continue
            seen.add(identity)
            _check_method_fits(resolved, integrator, systems)
            try:
                given = integrator.given_steps(resolved.duration)  # a recorded trajectory's own times: one run
            except ValueError as error:
                raise ConfigError(f"integrators: {integrator.label}: {error}") from None
            if resolved.step_control is None and integrator.whole_run and given is None:
                raise ConfigError(f"integrators: {integrator.label} chooses its own steps by a tolerance: give a "
                                  "step_control block (its tolerance and bounds are the peer's rtol, atol, first_step "
                                  "and max_step)")
            if resolved.step_control is not None:
                reason = estimate_refusal(resolved.step_control, integrator)
                if reason is not None:
                    raise ConfigError(f"step_control.estimate: {reason}")
            duration, step_control = resolved.duration, resolved.step_control
            if given is not None and used:
                key = next(iter(used))
                raise ConfigError(f"sweep.{key}: {integrator.label} was computed for one system, and the sweep varies "
                                  f"{key}: measure a trajectory with a config of its own system (--set sweep.{key}=[...] "
                                  "with its one value)")
            if given is not None:
                (dt_given, duration), step_control = given, None
            for dt in (steps if given is None else [dt_given]):
                if dt > resolved.duration:
                    raise ConfigError(f"sweep.dt: {dt:g} is longer than duration {resolved.duration:g}; a step must fit in the run")
                index = len(runs)
                # every part is validated already (the resolved experiment): a map builds 10^4 runs here
                runs.append(Run.model_construct(
                    run_id=_run_id(index, labels[number], dt, used), index=index, system=resolved.system,
                    integrator=integrator, solver=resolved.solver, dt=float(dt), duration=duration,
                    record=resolved.record, divergence=resolved.divergence, swept=used, label=labels[number],
                    step_control=step_control,
                ))
    return runs


def _without_label(value: Any) -> Any:
    """A swept value as the config takes it: a mapping without its ``label`` (which only names it)."""
    return {key: item for key, item in value.items() if key != "label"} if isinstance(value, dict) else value


def _value_names(key: str, values: list) -> list:
    """Each swept value as run ids, tables and figures show it: a mapping (a whole ``system``, a ``solver``) by its
    ``label``, else its ``type`` where that tells it from the others, else its type (or the key) and its place,
    "fem#2"; any other value as it is. Labels must tell the values apart."""
    if not any(isinstance(value, dict) for value in values):
        return list(values)
    types = [value.get("type") if isinstance(value, dict) else None for value in values]
    names = []
    for number, value in enumerate(values):
        if not isinstance(value, dict):
            names.append(value)
        elif "label" in value:
            names.append(str(value["label"]))
        elif types[number] is not None and types.count(types[number]) == 1:
            names.append(str(types[number]))
        else:
            names.append(f"{types[number] or key.split('.')[-1]}#{number + 1}")
    repeated = sorted({str(name) for name in names if names.count(name) > 1})
    if repeated:
        raise ConfigError(f"sweep.{key}: two values are named {repeated[0]!r}; give each mapping its own label")
    return names


# the swept solver keys that only a linear solver reads (solvers/params.py: LINEAR_SOLVER_FIELDS and the solver's name)
LINEAR_SOLVER_KEYS = ("solver.linear_solver", "solver.linear_tolerance", "solver.linear_max_iterations", "solver.mpcg_start")


def uses_swept_key(key: str, integrator: Integrator, solver, swept_solvers: tuple = ()) -> bool:
    """Whether a run of ``integrator`` with ``solver`` reads the swept config key ``key``.

    An explicit method reads no solver key; a linear-solver key is read by the solvers whose
    directions are linear solves (Newton's family: ``uses_linear_solver``), in the chain of the
    solver and its fallbacks, and by the methods that take one Newton step with the main solver's linear solver
    whatever the solver (problem_kind newton_step: solver.newton_step)."""
    if not key.startswith("solver."):
        return True
    if integrator.explicit:
        return False
    if _foreign_solver_key(key, solver.type, swept_solvers):
        return False
    if key not in LINEAR_SOLVER_KEYS:
        return True
    return integrator.problem_kind == "newton_step" or any(SOLVERS[name].uses_linear_solver for name in solver.chain_names())


def _read_parameters(integrator: Integrator) -> dict:
    unused = integrator.unused_parameters()
    return {key: value for key, value in integrator.model_dump().items() if key not in unused}


def family_labels(integrators: list[Integrator]) -> list[str]:
    """Each integrator's label in this config: its name and the parameters that differ from their defaults,
    and, when integrators of the same type differ in a parameter (a family: generalized_alpha at several
    rho_inf), that parameter in every label of the family, so that the default member is named too:
    ``generalized_alpha[rho_inf=0.5]`` beside ``generalized_alpha[rho_inf=0]``."""
    values_by_type: dict[str, dict[str, set]] = {}
    for integrator in integrators:
        for key, value in _read_parameters(integrator).items():
            values_by_type.setdefault(integrator.name, {}).setdefault(key, set()).add(json.dumps(value, default=str))
    labels = []
    for integrator in integrators:
        if type(integrator).label is not Integrator.label:
            # a method that names itself (a trajectory by its source: trajectories of one source at several steps are
            # one method's runs, as a convergence study)
            labels.append(integrator.label)
            continue
        defaults = type(integrator).model_fields
        varied = values_by_type.get(integrator.name, {})
        named = [(key, value) for key, value in _read_parameters(integrator).items()
                 if value != defaults[key].default or len(varied.get(key, ())) > 1]
        if not any(len(values) > 1 for values in varied.values()):
            labels.append(integrator.label)  # no family: the label as everywhere else
            continue
        parts = [parameter_text(key, value) for key, value in named]
        labels.append(f"{integrator.name}[{','.join(parts)}]" if parts else integrator.name)
    return labels


def config_hash(experiment: Experiment) -> str:
    """sha256 of the validated experiment (defaults filled in), so equal configs hash equally."""
    document = resolved_document(experiment)
    del document["output"]
    files = experiment.system.input_files()
    if files:  # the content of the model files the system reads (absent for systems that read none)
        document["system_files"] = files
    return hashlib.sha256(json.dumps(document, sort_keys=True).encode()).hexdigest()


def resolved_document(experiment: Experiment) -> dict:
    """The validated experiment with every default filled in, as plain data (JSON types): a config that
    gives the same runs. Integrators are mappings with their ``type``."""
    document = experiment.model_dump(mode="json")
    document["integrators"] = [{"type": item.name, **item.model_dump(mode="json")} for item in experiment.integrators]
    return document


def resolved_config(experiment: Experiment) -> str:
    """``resolved_document`` as YAML text (stored in the results file as ``resolved_config``)."""
    return yaml.safe_dump(resolved_document(experiment), sort_keys=False)


def _check_method_fits(resolved: Experiment, integrator: Integrator, systems: dict[str, Any]) -> None:
    """An integrator that cannot step this system (XPBD without compliant springs), or a solver that cannot solve
    the integrator's problems on it (projective dynamics on squared-length springs, VBD on forces sampled along
    the step, ...), is refused in one line before any run starts."""
    kind = integrator.problem_kind
    # the solvers' classes decide whether any of them can refuse: most sweeps build no solver here (a map has 10^4 runs)
    classes = [SOLVERS[name] for name in resolved.solver.chain_names()] if kind is not None else []
    if kind == "newton_step" and not classes[0].takes_newton_step:  # the chain's first solver takes the step
        raise ConfigError(f"solver.type: {classes[0].name} iterates on the incremental potential, and {integrator.label} "
                          "takes exactly one Newton step (with the linear solver): use newton or projected_newton")
    can_refuse = kind != "newton_step" and any(cls.refusal is not NonlinearSolver.refusal for cls in classes)
    contact = getattr(resolved.system, "contact", None)
    with_contact = contact is not None and contact.active
    if not can_refuse and type(integrator).refusal is Integrator.refusal and not with_contact:
        return  # nothing here refuses anything: no system to build
    chain = []
    if kind is not None:
        solver = resolved.solver.build()
        chain = list(getattr(solver, "solvers", (solver,)))
    refusing = [member for member in chain if type(member).refusal is not NonlinearSolver.refusal] if kind != "newton_step" else []
    key = json.dumps(resolved.system.model_dump(mode="json"), sort_keys=True)
    if key not in systems:
        systems[key] = resolved.system.build()
    reason = integrator.refusal(systems[key])
    if reason is not None:
        raise ConfigError(f"integrators: {integrator.label}: {reason}")
    if contact_needs_step_filter(systems[key]) and kind != "newton_step":
        for member in chain:
            if not type(member).filters_steps:
                raise ConfigError(f"solver.type: {member.name} takes steps without a line search, which IPC contact needs "
                                  f"to cut each step short of a collision (integrator {integrator.label}): use newton, "
                                  "projected_newton, lbfgs or gradient_descent")
    for member in refusing:
        reason = member.refusal(systems[key], kind)
        if reason is not None:
            raise ConfigError(f"solver.type: {reason} (integrator {integrator.label})")


def _foreign_solver_key(key: str, solver_type: Any, swept_solvers: tuple) -> bool:
    """Is ``key`` (solver.<option>) the own option of another of the swept solver types (``swept_solvers``, the
    values of sweep's solver.type), not one that ``solver_type`` takes? Sweeping solver.type with
    solver.chebyshev_rho then gives the solvers with that option each value, and the others one run without it.
    Otherwise the key is set and validated as any: an option that no swept solver takes is refused."""
    option = key.split(".", 1)[1] if key.startswith("solver.") else ""
    if not option or "." in option or option in SolverParams.model_fields or solver_type not in SOLVER_PARAMS:
        return False
    return option not in SOLVER_PARAMS[solver_type].model_fields and any(
        option in SOLVER_PARAMS[name].model_fields for name in swept_solvers if name in SOLVER_PARAMS)


def _resolve(base: dict, assignment: dict[str, Any], swept_solvers: tuple = ()) -> Experiment:
    raw = copy.deepcopy({key: value for key, value in base.items() if key != "integrators"})
    raw["integrators"] = base["integrators"]
    solver_type = assignment.get("solver.type", (raw.get("solver") or {}).get("type", "newton"))
    for key, value in assignment.items():
        if _foreign_solver_key(key, solver_type, swept_solvers):
            continue  # an option of the other swept solvers: this one does not take it
        parts = key.split(".")
        if parts[0] not in Experiment.model_fields or parts[0] in ("sweep", "name", "output", "integrators"):
            allowed = ", ".join(k for k in Experiment.model_fields if k not in ("sweep", "name", "output", "integrators"))
            raise ConfigError(f"sweep.{key}: cannot sweep {parts[0]!r}; sweepable sections: dt, {allowed}")
        set_path(raw, parts, value, f"sweep.{key}")
    raw.update(name="run", sweep={"dt": [1.0]} if raw.get("step_control") is None else {})
    try:
        return Experiment.model_validate(raw)
    except ValidationError as error:
        raise ConfigError("\n".join("sweep: " + line for line in describe_error(error, raw).splitlines())) from None


def _product(lists: list[list]) -> list[tuple]:
    result: list[tuple] = [()]
    for values in lists:
        result = [prefix + (value,) for prefix in result for value in values]
    return result


def _run_id(index: int, label: str, dt: float, assignment: dict[str, Any]) -> str:
    parts = [f"{index:04d}", label] + ([] if math.isnan(dt) else [f"dt={dt:.6g}"])
    parts += [f"{key}={value:.6g}" if isinstance(value, float) else f"{key}={value}" for key, value in assignment.items()]
    return "-".join(parts).replace("/", "_")
