"""simrun.solvers (folder solvers/): the nonlinear and linear solvers, found by their config name.

SOLVERS maps a name (the config's ``solver.type``) to the solver class, SOLVER_PARAMS to its parameter
model (solvers/params.py): ``solver_params(type="lbfgs", history=4).build()`` gives the solver (or its
fallback chain); docs/solvers.md describes each. A new nonlinear solver joins with a ``NonlinearSolver``
subclass (solvers/base.py has the contract), a ``SolverParams`` model in solvers/params.py with
``type: Literal["<name>"] = "<name>"`` and its constructor's own keyword arguments as fields, and an
entry in both SOLVERS and SOLVER_PARAMS at the bottom of that module; the tests in tests/test_solvers.py
run over SOLVER_PARAMS. A linear solver (``solver.linear_solver``) is a ``LinearSolver`` subclass with an
entry in LINEAR_SOLVERS (solvers/linear.py).
"""

from __future__ import annotations

from .base import EXPLICIT_STEP, ConvergenceTest, NonlinearProblem, NonlinearSolver, SolveStats
from .descent import LBFGS, GradientDescent, JacobiChebyshev
from .fallback import FallbackChain
from .linear import LINEAR_SOLVERS, LinearSolver
from .newton import Newton, ProjectedNewton
from .params import (SOLVER_PARAMS, SOLVERS, GradientDescentParams, JacobiChebyshevParams, LBFGSParams, NewtonParams,
                     ProjectedNewtonParams, ProjectiveDynamicsParams, SolverField, SolverOptionError, SolverParams,
                     VBDParams, solver_params)
from .projective import ProjectiveDynamics, refusal, solver_refusal
from .vbd import VertexBlockDescent

__all__ = ["SOLVERS", "SOLVER_PARAMS", "LINEAR_SOLVERS", "SolverParams", "NewtonParams", "ProjectedNewtonParams",
           "LBFGSParams", "GradientDescentParams", "JacobiChebyshevParams", "solver_params", "SolverField",
           "SolverOptionError", "Newton", "ProjectedNewton", "LBFGS", "GradientDescent", "JacobiChebyshev",
           "FallbackChain", "NonlinearSolver", "LinearSolver", "NonlinearProblem", "SolveStats", "ConvergenceTest",
           "EXPLICIT_STEP", "ProjectiveDynamics", "ProjectiveDynamicsParams", "refusal", "solver_refusal",
           "VertexBlockDescent", "VBDParams"]
