"""Nonlinear and linear solvers, found by their config name (docs/solvers.md describes each)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .base import EXPLICIT_STEP, ConvergenceTest, NonlinearProblem, NonlinearSolver, SolveStats
from .descent import LBFGS, GradientDescent, JacobiChebyshev
from .fallback import FallbackChain
from .line_search import LINE_SEARCHES
from .linear import LINEAR_SOLVERS, LinearSolver
from .newton import SPD_PROJECTIONS, Newton, ProjectedNewton

# config name -> class; each takes the fields of SolverParams that it uses (SolverParams.build)
SOLVERS: dict[str, type[NonlinearSolver]] = {
    cls.name: cls for cls in (Newton, ProjectedNewton, LBFGS, GradientDescent, JacobiChebyshev)
}
SolverName = Literal[tuple(SOLVERS)]  # type: ignore[valid-type]


class SolverParams(BaseModel):
    """Config of the solver used by implicit integrators."""

    model_config = ConfigDict(extra="forbid")
    type: SolverName = Field("newton", description="nonlinear solver: " + " | ".join(SOLVERS))
    tolerance: float = Field(1e-10, gt=0, lt=1, allow_inf_nan=False, description="residual mode: stop when |residual|_inf <= tolerance * |initial residual|_inf; step mode: when |p|_inf <= tolerance * |first p|_inf")
    tolerance_mode: Literal["residual", "step"] = Field("residual", description="residual (every solver) or step (newton, projected_newton: the Newton step relative to the first one)")
    max_iterations: int = Field(50, ge=1, description="nonlinear iterations per step (per solver of the fallback chain) before the step counts as not converged")
    line_search: Literal[LINE_SEARCHES] = Field("backtracking", description="projected_newton, lbfgs, gradient_descent, jacobi_chebyshev: none | backtracking (halve the step until the energy decreases) | armijo (until it decreases enough)")  # type: ignore[valid-type]
    spd_projection: Literal[SPD_PROJECTIONS] = Field("clamp", description="projected_newton (and the Jacobi diagonal of jacobi_chebyshev): none | clamp (the system's own projection) | eigen (whole-matrix eigenvalue clamp for dense problems; clamp for sparse ones)")  # type: ignore[valid-type]
    history: int = Field(8, ge=1, le=1000, description="lbfgs: number of (s, dg) pairs kept")
    chebyshev_rho: float = Field(0.99, ge=0, lt=1, allow_inf_nan=False, description="jacobi_chebyshev: estimated spectral radius rho of the Jacobi iteration")
    relaxation: float = Field(0.9, gt=0, le=1, allow_inf_nan=False, description="jacobi_chebyshev: under-relaxation gamma of each Jacobi step (halved when a plain step raises the energy)")
    linear_solver: Literal[tuple(LINEAR_SOLVERS)] = Field("direct", description="linear solver for Newton directions: " + " | ".join(LINEAR_SOLVERS))  # type: ignore[valid-type]
    linear_tolerance: float = Field(1e-10, gt=0, lt=1, allow_inf_nan=False, description="iterative linear solvers: stop when |b - A p|_2 <= linear_tolerance * |b|_2")
    linear_max_iterations: int = Field(1000, ge=1, description="iterative linear solvers: iterations per linear solve")
    fallback: list[SolverName] = Field([], description="solvers tried in turn when the previous one does not converge on a step (from its best iterate)")  # type: ignore[valid-type]
    on_not_converged: Literal["continue", "stop"] = Field("continue", description="go on after a step that did not converge (status not_converged at the end), or stop the run there")

    @field_validator("linear_solver")
    @classmethod
    def _installed(cls, name: str) -> str:
        missing = LINEAR_SOLVERS[name].missing()
        if missing is not None:
            raise ValueError(missing)
        return name

    @model_validator(mode="after")
    def _consistent(self) -> "SolverParams":
        chain = [self.type, *self.fallback]
        if len(set(chain)) != len(chain):
            raise ValueError(f"fallback: each solver may appear once in the chain {chain}; a repeat would redo the same attempt")
        if self.tolerance_mode == "step":
            unsupported = [name for name in chain if not SOLVERS[name].supports_step_test]
            if unsupported:
                raise ValueError(f"tolerance_mode: step needs Newton-type solvers (newton, projected_newton), "
                                 f"not {', '.join(unsupported)}: their steps do not estimate the error")
        return self

    def build_one(self, name: str) -> NonlinearSolver:
        """The solver ``name`` with this config's parameters."""
        linear = LINEAR_SOLVERS[self.linear_solver](self.linear_tolerance, self.linear_max_iterations)
        common = dict(tolerance=self.tolerance, max_iterations=self.max_iterations, linear_solver=linear,
                      tolerance_mode=self.tolerance_mode)
        if name == "newton":
            return Newton(**common)
        if name == "projected_newton":
            return ProjectedNewton(**common, line_search=self.line_search, spd_projection=self.spd_projection)
        if name == "lbfgs":
            return LBFGS(**common, line_search=self.line_search, history=self.history)
        if name == "gradient_descent":
            return GradientDescent(**common, line_search=self.line_search)
        if name == "jacobi_chebyshev":
            return JacobiChebyshev(**common, line_search=self.line_search, chebyshev_rho=self.chebyshev_rho,
                                   relaxation=self.relaxation, spd_projection=self.spd_projection)
        raise ValueError(f"unknown solver {name!r}; valid: " + ", ".join(SOLVERS))

    def build(self):
        """The configured solver, or a FallbackChain when ``fallback`` names more."""
        if not self.fallback:
            return self.build_one(self.type)
        return FallbackChain([self.build_one(name) for name in (self.type, *self.fallback)])


__all__ = ["SOLVERS", "LINEAR_SOLVERS", "SolverParams", "Newton", "ProjectedNewton", "LBFGS", "GradientDescent",
           "JacobiChebyshev", "FallbackChain", "NonlinearSolver", "LinearSolver", "NonlinearProblem", "SolveStats",
           "ConvergenceTest", "EXPLICIT_STEP"]
