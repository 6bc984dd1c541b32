"""Counting what a run evaluates: the system's force (gradient) and Jacobian (Hessian) evaluations, the currencies of
work-precision besides wall time.

The counts wrap the bound methods on the system instance (shadowing its class's), so that integrators and solvers,
which call ``system.gradient`` and ``system.hessian`` / ``hessian_data``, are counted wherever they call them. A call
made inside another counted call of the same kind (a Hessian built from its pattern's data) counts once. An evaluation
at several states at once (``forces``: Radau IIA's stages) counts one per state. A released system
(``System.released``: a shallow copy) is instrumented again, so that its methods run on the copy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# what each count counts: the instance attributes wrapped
FUNCTION_METHODS = ("gradient", "force", "acceleration", "kick")
# the evaluations at several states at once (the rows of their first argument): each row counts one
ROW_METHODS = ("gradients", "forces")
JACOBIAN_METHODS = ("hessian", "hessian_data")


@dataclass
class EvaluationCounts:
    functions: int = 0  # force evaluations: gradients, forces, accelerations (one, however they nest)
    jacobians: int = 0  # Hessian evaluations (dense, sparse or in the fixed pattern)
    # per kind: inside a counted call (one of the same kind made inside it is not counted again)
    _inside: dict = field(default_factory=lambda: {"functions": False, "jacobians": False}, repr=False)

    def instrument(self, system) -> None:
        """Wrap ``system``'s evaluations so that this object counts them (again after a release)."""
        for name in FUNCTION_METHODS:
            self._wrap(system, name, "functions")
        for name in ROW_METHODS:
            self._wrap(system, name, "functions", per_row=True)
        for name in JACOBIAN_METHODS:
            self._wrap(system, name, "jacobians")

    def _wrap(self, system, name: str, count: str, per_row: bool = False) -> None:
        method = getattr(type(system), name, None)
        if method is None:
            return
        counts, inside = self, self._inside

        def counted(*args, **kwargs):
            if inside[count]:
                return method(system, *args, **kwargs)
            setattr(counts, count, getattr(counts, count) + (len(args[0]) if per_row else 1))
            inside[count] = True
            try:
                return method(system, *args, **kwargs)
            finally:
                inside[count] = False

        setattr(system, name, counted)

    def as_attrs(self) -> dict[str, int]:
        return {"function_evaluations": self.functions, "jacobian_evaluations": self.jacobians}
