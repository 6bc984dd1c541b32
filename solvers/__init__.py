"""Nonlinear and linear solvers, found by their config name."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .base import EXPLICIT_STEP, NonlinearProblem, SolveStats
from .linear import LINEAR_SOLVERS
from .newton import Newton, ProjectedNewton

# config name -> class; each takes the fields of SolverParams that it uses
SOLVERS = {
    "newton": Newton,
    "projected_newton": ProjectedNewton,
}


class SolverParams(BaseModel):
    """Config of the solver used by implicit integrators."""

    model_config = ConfigDict(extra="forbid")
    type: Literal[tuple(SOLVERS)] = Field("newton", description="nonlinear solver")  # type: ignore[valid-type]
    tolerance: float = Field(1e-10, gt=0, lt=1, allow_inf_nan=False, description="stop when |residual|_inf <= tolerance * |initial residual|_inf")
    max_iterations: int = Field(50, ge=1, description="nonlinear iterations per step before the step counts as not converged")
    linear_solver: Literal[tuple(LINEAR_SOLVERS)] = Field("direct", description="linear solver for Newton directions")  # type: ignore[valid-type]
    line_search: Literal["none", "backtracking", "armijo"] = Field("backtracking", description="projected_newton: halve the step until the energy decreases (backtracking) or decreases enough (armijo)")
    on_not_converged: Literal["continue", "stop"] = Field("continue", description="go on after a step that did not converge (status not_converged at the end), or stop the run there")

    def build(self):
        common = dict(tolerance=self.tolerance, max_iterations=self.max_iterations, linear_solver=self.linear_solver)
        if self.type == "projected_newton":
            return ProjectedNewton(**common, line_search=self.line_search)
        return Newton(**common)


__all__ = ["SOLVERS", "LINEAR_SOLVERS", "SolverParams", "Newton", "ProjectedNewton", "NonlinearProblem", "SolveStats", "EXPLICIT_STEP"]
