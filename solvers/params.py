"""The nonlinear solvers as config: one small pydantic model per solver, found by its name.

A solver's model is its schema: the options every solver shares live in ``SolverParams``, and each
solver's model adds the keyword arguments of its own constructor, so an option that a solver does
not use is refused instead of ignored (``solver: {type: newton, history: 8}``). ``build()`` hands
the fields to the class as keyword arguments; a fallback entry gives only the fallback's own
options, and takes the shared ones from the main solver.

Adding a solver: write its class (``solvers/base.py`` has the contract), a model here with
``type: Literal["<name>"] = "<name>"`` and the constructor's own arguments as fields, and register
both at the bottom of this module.
"""

from __future__ import annotations

import difflib
import os
import warnings
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, SerializeAsAny, ValidationError, field_validator, model_validator
from typing_extensions import TypeAliasType

from .base import INITIAL_GUESSES, STEP_MODES, TOLERANCE_MODES, NonlinearSolver
from .descent import INITIAL_HESSIANS, LBFGS, GradientDescent, JacobiChebyshev
from .fallback import FallbackChain
from .line_search import LINE_SEARCHES
from .linear import LINEAR_SOLVERS
from .newton import DEFAULT_REFACTOR_RATE, REFACTOR_MODES, SPD_PROJECTIONS, Newton, ProjectedNewton
from .projective import CHEBYSHEV_RHO_AUTO, ProjectiveDynamics
from .vbd import VBD_SPD_PROJECTIONS, VertexBlockDescent

# Fields that are not arguments of the solver's constructor: `type` picks the class, the runner reads
# the others; linear_tolerance and linear_max_iterations go to the linear solver's.
RUNNER_FIELDS = ("type", "fallback", "on_not_converged", "threads")
LINEAR_SOLVER_FIELDS = ("linear_tolerance", "linear_max_iterations", "mpcg_start")


class ThreadsWarning(UserWarning):
    """solver.threads above the machine's cores, capped: printed as one line by the command line (``one_line``)."""

    one_line = True


class SolverOptionError(ValueError):
    """A solver option that cannot be used: one line, ``path: reason``.

    ``path`` is the option's place within the solver's mapping (``("history",)``,
    ``("fallback", 0, "tolerance")``), so that the config can name it in full: ``solver.history``."""

    def __init__(self, path: tuple = (), reason: str = ""):
        self.path = tuple(path)
        self.reason = reason
        super().__init__(f"{'.'.join(map(str, self.path))}: {reason}" if self.path else reason)


def _did_you_mean(word: Any, choices) -> str:
    close = difflib.get_close_matches(str(word), list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _option_error(error: ValidationError) -> SolverOptionError:
    """The first error of a model validation as one SolverOptionError (the config reports one error)."""
    first = error.errors()[0]
    path, kind, message = first["loc"], first["type"], first["msg"]
    cause = first.get("ctx", {}).get("error")
    if isinstance(cause, SolverOptionError):  # ours, raised below this path: keep its own path
        return SolverOptionError((*path, *cause.path), cause.reason)
    if kind == "value_error":
        message = message.removeprefix("Value error, ")
    elif "input" in first and kind != "missing" and not isinstance(first["input"], (dict, list)):
        message = f"{message} (got {first['input']!r})"
    return SolverOptionError(path, message)


def _model_named(name: Any, path: tuple) -> type[SolverParams]:
    if not isinstance(name, str) or name not in SOLVER_PARAMS:
        raise SolverOptionError(path, f"unknown solver {name!r}{_did_you_mean(name, SOLVER_PARAMS)}; valid: "
                                + ", ".join(SOLVER_PARAMS))
    return SOLVER_PARAMS[name]


def _fallback_entry(entry: Any) -> dict[str, Any]:
    """One solver of the fallback chain as {type, each of its own options}: from a name or a mapping."""
    if isinstance(entry, str):
        return {"type": entry, **_own_defaults(_model_named(entry, ()))}
    if not isinstance(entry, dict):
        raise SolverOptionError((), "expected a solver name or a mapping {type: name, its own option: value}")
    if "type" not in entry:
        raise SolverOptionError((), "a mapping needs 'type': one of " + ", ".join(SOLVER_PARAMS))
    model = _model_named(entry["type"], ("type",))
    own = model.own_fields()
    for key in entry:
        if key == "type" or key in own:
            continue
        takes = f"its entry takes: {', '.join(['type', *own])}"
        if key in SolverParams.model_fields:
            raise SolverOptionError((key,), f"a fallback takes {key} from the main solver; {takes}")
        raise SolverOptionError((key,), f"{model.solver_name()} does not use {key!r}{_did_you_mean(key, own)}; {takes}")
    try:
        validated = model.model_validate(entry)
    except ValidationError as error:
        raise _option_error(error) from None
    return {"type": validated.type, **{key: getattr(validated, key) for key in own}}


def _own_defaults(model: type[SolverParams]) -> dict[str, Any]:
    return {key: info.default for key, info in model.own_fields().items()}


# A fallback is stored with every own option filled in, so that `[lbfgs]` and `[{type: lbfgs, history: 8}]`
# are the same config (and hash alike).
FallbackEntry = Annotated[dict[str, Any], BeforeValidator(_fallback_entry)]


class SolverParams(BaseModel):
    """The options every nonlinear solver takes; each solver's model (SOLVER_PARAMS) adds its own.

    Not built directly: ``solver_params(type=..., option=...)`` or ``SOLVER_PARAMS[name](...)``
    gives the model of one solver. Its fields other than RUNNER_FIELDS are the keyword arguments of
    the solver's constructor (the linear solver built from linear_solver, linear_tolerance and
    linear_max_iterations)."""

    model_config = ConfigDict(extra="forbid")
    type: str = Field(description="nonlinear solver")
    tolerance: float = Field(1e-10, gt=0, allow_inf_nan=False, description="residual mode: stop when |residual|_inf <= tolerance * |initial residual|_inf (< 1); absolute: when |residual|_inf <= tolerance (kg m for an incremental potential); step mode: when |p|_inf <= tolerance * |first p|_inf (< 1); velocity: when |p|_inf / b <= tolerance (m/s)")
    tolerance_mode: Literal[TOLERANCE_MODES] = Field("residual", description="residual or absolute (every solver); step or velocity (newton, projected_newton: the Newton step relative to the first one, or as a velocity |p|_inf / h, the lectures' rule; the step that meets it is applied)")  # type: ignore[valid-type]
    initial_guess: Literal[INITIAL_GUESSES] = Field("start", description="where each step's solve starts: start (x_n) | inertial (x_n + theta h v_n, theta h the time from t_n to the unknown) | predictor (the method's y~) | adaptive (y~ + c h^2 times the acceleration along gravity, clamped: the VBD paper's)")  # type: ignore[valid-type]
    max_iterations: int = Field(50, ge=1, description="nonlinear iterations per step (per solver of the fallback chain) before the step counts as not converged")
    linear_solver: Literal[tuple(LINEAR_SOLVERS)] = Field("direct", description="linear solver for Newton directions: " + " | ".join(LINEAR_SOLVERS))  # type: ignore[valid-type]
    linear_tolerance: float = Field(1e-10, gt=0, lt=1, allow_inf_nan=False, description="iterative linear solvers: stop when |b - A p|_2 <= linear_tolerance * |b|_2")
    linear_max_iterations: int = Field(1000, ge=1, description="iterative linear solvers: iterations per linear solve")
    mpcg_start: Literal["zero", "filtered"] = Field("zero", description="mpcg: start from p0 = z (Baraff & Witkin) or from p0 = S g + (I - S) z with g the step to the inertial predictor (Ascher & Boxerman)")
    fallback: list[FallbackEntry] = Field([], description="solvers tried in turn when the previous one does not converge on a step (from its best iterate): names, or mappings {type: name, its own option: value}; the shared options are this solver's")
    on_not_converged: Literal["continue", "stop", "accept"] = Field("continue", description="go on after a step that did not converge (status not_converged at the end), stop the run there, or accept it (a real-time budget: max_iterations is the work per step; the run stays ok and counts the steps)")
    threads: Optional[int] = Field(None, ge=1, description="threads of the compiled kernels (vbd's colour sweep): default the cores of the run's worker (with -j N the sweep divides the cores); more than the machine has are capped, with a warning line")

    @field_validator("threads")
    @classmethod
    def _cap_threads(cls, value: int | None) -> int | None:
        cores = os.cpu_count() or 1
        if value is not None and value > cores:
            warnings.warn(ThreadsWarning(f"solver.threads: {value} is more than this machine's {cores} cores; using {cores}"),
                          stacklevel=2)
            return cores
        return value

    @classmethod
    def solver_name(cls) -> str:
        return cls.model_fields["type"].default

    @classmethod
    def own_fields(cls) -> dict:
        """The fields of this solver beyond the shared ones (name -> pydantic FieldInfo)."""
        return {key: info for key, info in cls.model_fields.items() if key not in SolverParams.model_fields}

    @model_validator(mode="before")
    @classmethod
    def _only_its_own_options(cls, data: Any) -> Any:
        if cls is SolverParams:
            raise SolverOptionError((), "SolverParams holds the shared options only; build a solver's model with "
                                        "solver_params(type=name, option=value) or SOLVER_PARAMS[name]")
        if isinstance(data, dict):
            for key in data:
                if key not in cls.model_fields:
                    raise SolverOptionError((key,), cls._not_used(key, data[key], data.get("fallback")))
        return data

    @classmethod
    def _not_used(cls, key: Any, value: Any, fallback: Any) -> str:
        """'newton does not use 'history'; it takes: ...', with the fallback entry to write where one takes it."""
        # a misspelling gets a suggestion; another solver's option is named as it is
        known = any(key in model.model_fields for model in SOLVER_PARAMS.values())
        options = [name for name in cls.model_fields if name != "type"]
        message = f"{cls.solver_name()} does not use {key!r}{'' if known else _did_you_mean(key, options)}; it takes: {', '.join(options)}"
        names = [entry.get("type") if isinstance(entry, dict) else entry for entry in (fallback if isinstance(fallback, list) else [])]
        users = [name for name in names if isinstance(name, str) and name in SOLVER_PARAMS and key in SOLVER_PARAMS[name].own_fields()]
        if users:
            message += f"; to set it for the fallback {users[0]}, give it in its entry: fallback: [{{type: {users[0]}, {key}: {value}}}]"
        return message

    @field_validator("linear_solver")
    @classmethod
    def _installed(cls, name: str) -> str:
        missing = LINEAR_SOLVERS[name].missing()
        if missing is not None:
            raise ValueError(missing)
        return name

    @model_validator(mode="after")
    def _consistent_chain(self) -> "SolverParams":
        if self.tolerance_mode in ("residual", "step") and not self.tolerance < 1.0:
            raise SolverOptionError(("tolerance",), f"in {self.tolerance_mode} mode the tolerance is a fraction of the first "
                                    f"{'residual' if self.tolerance_mode == 'residual' else 'step'}: it must be < 1 (got {self.tolerance:g})")
        chain = self.chain_names()
        budgeted = [entry["type"] for entry in [{"type": self.type, "time_budget": getattr(self, "time_budget", None)},
                                                *self.fallback] if entry.get("time_budget") is not None]
        if budgeted and len(chain) > 1:
            raise SolverOptionError(("fallback",), f"a time budget ({', '.join(budgeted)}) ends a solve when its time is spent, "
                                    "and a fallback would then run past it: give time_budget or fallback, not both")
        if len(set(chain)) != len(chain):
            raise SolverOptionError(("fallback",), f"each solver may appear once in the chain {chain}; a repeat would redo the same attempt")
        if self.tolerance_mode in STEP_MODES:
            unsupported = [name for name in chain if not SOLVERS[name].supports_step_test]
            if unsupported:
                newton_type = ", ".join(name for name, cls in SOLVERS.items() if cls.supports_step_test)
                raise SolverOptionError(("tolerance_mode",), f"{self.tolerance_mode} needs Newton-type solvers ({newton_type}), not "
                                        f"{', '.join(unsupported)}: their steps do not estimate the error")
        return self

    def chain_names(self) -> list[str]:
        """This solver's name, then its fallbacks'."""
        return [self.type, *(entry["type"] for entry in self.fallback)]

    def chain(self) -> list["SolverParams"]:
        """This model, then each fallback's: its own options from its entry, the shared ones from this model."""
        shared = {key: getattr(self, key) for key in SolverParams.model_fields if key not in ("type", "fallback")}
        return [self, *(SOLVER_PARAMS[entry["type"]](**shared, **entry) for entry in self.fallback)]

    def constructor_arguments(self) -> dict[str, Any]:
        """The keyword arguments of SOLVERS[type]: every field but RUNNER_FIELDS, the linear solver built."""
        arguments = {key: getattr(self, key) for key in type(self).model_fields if key not in RUNNER_FIELDS}
        linear_tolerance, linear_max_iterations, mpcg_start = (arguments.pop(key) for key in LINEAR_SOLVER_FIELDS)
        linear_options = {"start": mpcg_start} if self.linear_solver == "mpcg" else {}
        arguments["linear_solver"] = LINEAR_SOLVERS[self.linear_solver](linear_tolerance, linear_max_iterations, **linear_options)
        return arguments

    def build_one(self) -> NonlinearSolver:
        """This solver alone, without its fallbacks."""
        return SOLVERS[self.type](**self.constructor_arguments())

    def build(self) -> NonlinearSolver | FallbackChain:
        """The configured solver, or a FallbackChain when ``fallback`` names more."""
        solvers = [params.build_one() for params in self.chain()]
        return solvers[0] if len(solvers) == 1 else FallbackChain(solvers)


# -- each solver's own options: the keyword arguments of its constructor beyond the shared ones -----
LineSearch = Annotated[Literal[LINE_SEARCHES], Field(description="none | backtracking (halve the step until the energy decreases) | armijo (until it decreases enough)")]  # type: ignore[valid-type]
SpdProjection = Literal[SPD_PROJECTIONS]  # type: ignore[valid-type]
Refactor = Annotated[Literal[REFACTOR_MODES], Field(description="every (factorise the Newton matrix at every iteration) | adaptive (keep the last factorisation across iterations and steps, and refactor when an iteration cuts the residual by less than refactor_rate or its direction does not descend: solvers/lagged.py) | preconditioner (PCG on the current matrix preconditioned by the kept factorisation, refactored when PCG needs more than 15 iterations)")]  # type: ignore[valid-type]
RefactorRate = Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False, description="refactor adaptive: the residual reduction per iteration below which the lagged factorisation is renewed")]


# The real-time solvers' budget (not Newton's: a sweep of solver.type keeps its Newton runs converged, the reference
# the budgeted ones are measured against)
TimeBudget = Annotated[Optional[float], Field(gt=0, allow_inf_nan=False, description="seconds of wall time per step's solve (factorisations included): it stops, unconverged, before an iteration that would end past them (the next taken as long as the last; the first is always taken): a frame's budget, as real-time practice sets it (with on_not_converged: accept the run stays ok); null: no limit. The iterations it buys depend on the machine and its load, so budgeted runs do not repeat bit for bit")]


class NewtonParams(SolverParams):
    """Newton with the raw Hessian, a line search, and safeguards where the raw direction does not descend.

    The safeguards: the abs-projected Hessian's direction, then M added until the solve descends."""

    type: Literal["newton"] = "newton"
    line_search: LineSearch = "backtracking"
    refactor: Refactor = "every"
    refactor_rate: RefactorRate = DEFAULT_REFACTOR_RATE
    spd_projection: SpdProjection = Field("none", description="the Newton matrix: none (raw Hessian; the projected one only where a safeguard needs it) | clamp (the system's own projection) | abs (block eigenvalues mirrored) | eigen (whole-matrix clamp, dense problems) | adaptive (abs while far from the solution, raw once its quadratic model is trusted)")


class ProjectedNewtonParams(SolverParams):
    """Newton on the incremental potential: SPD-projected Hessian and a line search."""

    type: Literal["projected_newton"] = "projected_newton"
    line_search: LineSearch = "backtracking"
    refactor: Refactor = "every"
    refactor_rate: RefactorRate = DEFAULT_REFACTOR_RATE
    spd_projection: SpdProjection = Field("clamp", description="none | clamp (the system's own projection) | abs (block eigenvalues mirrored: Chen et al. 2024) | eigen (whole-matrix eigenvalue clamp for dense problems; clamp for sparse ones) | adaptive (abs while far from the solution, raw once its quadratic model is trusted)")


class LBFGSParams(SolverParams):
    """Limited-memory BFGS directions with a line search."""

    type: Literal["lbfgs"] = "lbfgs"
    line_search: LineSearch = "backtracking"
    history: int = Field(8, ge=1, le=1000, description="number of (s, dg) pairs kept")
    initial_hessian: Literal[INITIAL_HESSIANS] = Field("step", description="H_0 of the two-loop recursion: step (the abs-projected Hessian at the step's inertial guess, factorised once per step: the default, which converges where the others need thousands of iterations) | scalar ((s^T dg / dg^T dg) I: no factorisation) | rest (A^{-1}, A = M + h^2 K_r the rest-shape matrix, factorised once per run: Liu, Bouaziz & Kavan 2017) | scaled_rest ((s^T dg / dg^T A^{-1} dg) A^{-1}); rest and scaled_rest need a system with a rest stiffness")  # type: ignore[valid-type]
    time_budget: TimeBudget = None


class GradientDescentParams(SolverParams):
    """Steepest descent with Barzilai-Borwein step lengths and a line search."""

    type: Literal["gradient_descent"] = "gradient_descent"
    line_search: LineSearch = "backtracking"
    time_budget: TimeBudget = None


class JacobiChebyshevParams(SolverParams):
    """Jacobi-preconditioned descent with Chebyshev acceleration, checked against the energy."""

    type: Literal["jacobi_chebyshev"] = "jacobi_chebyshev"
    line_search: LineSearch = "backtracking"
    chebyshev_rho: float = Field(0.99, ge=0, lt=1, allow_inf_nan=False, description="estimated spectral radius rho of the Jacobi iteration")
    relaxation: float = Field(0.9, gt=0, le=1, allow_inf_nan=False, description="under-relaxation gamma of each Jacobi step (halved when a plain step raises the energy)")
    spd_projection: Literal["none", "clamp", "eigen"] = Field("clamp", description="the Hessian whose diagonal is D: none (raw) | clamp (the system's own projection) | eigen (as clamp: a diagonal has no whole-matrix clamp)")
    time_budget: TimeBudget = None


# chebyshev_rho of projective dynamics: a number, or "auto" (computed: the linearised iteration's spectral radius). A named alias, so
# that the schema and its readers see one type rather than a union of a bounded float and a literal.
ChebyshevRho = TypeAliasType("ChebyshevRho", Union[float, Literal[CHEBYSHEV_RHO_AUTO]])  # type: ignore[valid-type]


class ProjectiveDynamicsParams(SolverParams):
    """Projective dynamics (Hookean springs, incremental potentials) with optional Chebyshev acceleration."""

    type: Literal["projective_dynamics"] = "projective_dynamics"
    chebyshev_rho: ChebyshevRho = Field(0.0, description="estimated spectral radius rho of the PD iteration (dimensionless, [0, 1)): 0 plain PD | a number | auto (computed once per run: 1 - gamma lambda_min of H v = lambda A v, by LAPACK up to 200 free dofs, else Lanczos)")
    chebyshev_warmup: int = Field(10, ge=1, le=10000, description="plain PD iterations of each solve before the Chebyshev acceleration starts (Wang 2015's S)")
    relaxation: float = Field(1.0, gt=0, le=1, allow_inf_nan=False, description="under-relaxation gamma of each global step (dimensionless; 1: the plain PD step)")
    time_budget: TimeBudget = None

    @field_validator("chebyshev_rho", mode="before")
    @classmethod
    def _rho_or_auto(cls, value: Any) -> Any:
        # one message for both forms (a union would report each member's error under its own tag)
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if value == CHEBYSHEV_RHO_AUTO or (number and 0.0 <= value < 1.0):
            return value
        raise ValueError(f"must be a number in [0, 1) or {CHEBYSHEV_RHO_AUTO!r} (got {value!r})")


class VBDParams(SolverParams):
    """Vertex block descent: Gauss-Seidel over vertex colours, a d x d Newton step per vertex; initial_guess: adaptive."""

    type: Literal["vbd"] = "vbd"
    initial_guess: Literal[INITIAL_GUESSES] = Field("adaptive", description="where each step's solve starts; vbd's default is the paper's adaptive initialisation (sec. 3.7): start | inertial | predictor | adaptive")  # type: ignore[valid-type]
    spd_projection: Literal[VBD_SPD_PROJECTIONS] = Field("clamp", description="each vertex block M_i + s K_i + (s/b) D_ii with the system's element blocks projected: clamp (negative eigenvalues set to 0) | abs (mirrored)")  # type: ignore[valid-type]
    chebyshev_rho: float = Field(0.0, ge=0, lt=1, allow_inf_nan=False, description="estimated spectral radius rho of the sweep (dimensionless): 0 no acceleration; else Chebyshev's y_{k+1} = omega (y^ - y_{k-1}) + y_{k-1}, restarted where it raises the energy (one energy evaluation per sweep)")
    determinant_floor: float = Field(1e-20, ge=0, lt=1, allow_inf_nan=False, description="skip a vertex in a sweep where |det H_i| <= determinant_floor |H_i|_F^d (dimensionless; the paper's small-determinant skip)")
    time_budget: TimeBudget = None


# config name -> solver class, and -> its parameter model: the one place where a new solver is made known
SOLVERS: dict[str, type[NonlinearSolver]] = {
    cls.name: cls for cls in (Newton, ProjectedNewton, LBFGS, GradientDescent, JacobiChebyshev, ProjectiveDynamics,
                              VertexBlockDescent)
}
SOLVER_PARAMS: dict[str, type[SolverParams]] = {
    model.solver_name(): model
    for model in (NewtonParams, ProjectedNewtonParams, LBFGSParams, GradientDescentParams, JacobiChebyshevParams,
                  ProjectiveDynamicsParams, VBDParams)
}


def solver_params(type: str = "newton", **options: Any) -> SolverParams:
    """The model of solver ``type`` with ``options``: ``solver_params(type="lbfgs", history=4).build()``.

    Raises SolverOptionError (a ValueError) with one line naming the option, e.g. for an option
    that the solver does not use."""
    return _from_mapping({"type": type, **options})


def _from_mapping(mapping: dict) -> SolverParams:
    model = _model_named(mapping.get("type", "newton"), ("type",))
    try:
        return model.model_validate(mapping)
    except ValidationError as error:
        raise _option_error(error) from None


def _from_config(value: Any) -> SolverParams:
    if isinstance(value, SolverParams):
        return value
    if not isinstance(value, dict):
        raise SolverOptionError((), "expected a mapping {type: " + " | ".join(SOLVER_PARAMS) + ", option: value}")
    return _from_mapping(value)


# The config's `solver:` field: a mapping (type defaults to newton) or a model, validated into the model of
# its type. SerializeAsAny: a dump of the experiment keeps the solver's own options, not only the shared ones.
SolverField = Annotated[SerializeAsAny[SolverParams], BeforeValidator(_from_config)]
