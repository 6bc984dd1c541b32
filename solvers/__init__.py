"""Nonlinear and linear solvers, found by their config name (docs/solvers.md describes each).

SOLVERS maps a name to the solver class, SOLVER_PARAMS to its parameter model (solvers/params.py):
``solver_params(type="lbfgs", history=4).build()`` gives the solver (or its fallback chain).
"""

from __future__ import annotations

from .base import EXPLICIT_STEP, ConvergenceTest, NonlinearProblem, NonlinearSolver, SolveStats
from .descent import LBFGS, GradientDescent, JacobiChebyshev
from .fallback import FallbackChain
from .linear import LINEAR_SOLVERS, LinearSolver
from .newton import Newton, ProjectedNewton
from .params import (SOLVER_PARAMS, SOLVERS, GradientDescentParams, JacobiChebyshevParams, LBFGSParams, NewtonParams,
                     ProjectedNewtonParams, SolverField, SolverOptionError, SolverParams, solver_params)

__all__ = ["SOLVERS", "SOLVER_PARAMS", "LINEAR_SOLVERS", "SolverParams", "NewtonParams", "ProjectedNewtonParams",
           "LBFGSParams", "GradientDescentParams", "JacobiChebyshevParams", "solver_params", "SolverField",
           "SolverOptionError", "Newton", "ProjectedNewton", "LBFGS", "GradientDescent", "JacobiChebyshev",
           "FallbackChain", "NonlinearSolver", "LinearSolver", "NonlinearProblem", "SolveStats", "ConvergenceTest",
           "EXPLICIT_STEP"]
