"""scipy's own solvers as peers of simrun's methods: ``solve_ivp``'s Radau, BDF and LSODA (and its explicit RK45 and
DOP853) on the same system, the same tolerances and the same error norm.

A peer is not stepped by simrun: scipy chooses and takes its steps on the first-order form u = (x, v), u' = F(u) =
(v, M^-1 f(x, v)), with the system's sparse Jacobian J = [[0, I], [-M^-1 K, -M^-1 D]] (the Hessian K and the damping
matrix D at x) as ``jac``. runner/execution/peers.py runs it, stepping scipy's solver object itself so that each
step's size is recorded and the samples come from its dense output. Peers need a lumped mass (M^-1 per dof) and a
smooth right-hand side: consistent masses and contact are refused.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from .base import Integrator

# solve_ivp's methods that join the comparison, and the order each is known by (BDF and LSODA vary theirs, to 5)
PEER_METHODS = {"Radau": 5, "BDF": 5, "LSODA": 5, "RK45": 5, "DOP853": 8}
IMPLICIT_PEERS = ("Radau", "BDF", "LSODA")


class SolveIVP(Integrator):
    """``scipy.integrate.solve_ivp``'s ``method`` on the system's first-order form, with the tolerances of the config's
    ``step_control``; implicit methods get the system's sparse Jacobian (LSODA a dense one: it takes no other)."""

    name: ClassVar[str] = "solve_ivp"
    order: ClassVar[int] = 5
    explicit: ClassVar[bool] = False
    family: ClassVar[str] = "scipy"
    summary: ClassVar[str] = "scipy's solve_ivp (Radau, BDF, LSODA, RK45, DOP853) as a peer, at the same tolerances"
    # the whole run is scipy's: simulate hands it to runner/execution/peers.py
    whole_run: ClassVar[bool] = True
    method: Literal[tuple(PEER_METHODS)] = Field("Radau", description="Radau | BDF | LSODA | RK45 | DOP853")  # type: ignore[valid-type]
    jacobian: bool = Field(True, description="pass the system's Jacobian (false: scipy's finite differences)")

    @property
    def order_of_accuracy(self) -> int:
        return PEER_METHODS[self.method]

    @property
    def error_estimate(self) -> str | None:
        return f"scipy's {self.method}"

    def step(self, system, state, dt, solver):
        raise TypeError("solve_ivp is run by scipy as a whole (runner/execution/peers.py), not step by step")

    def refusal(self, system):
        if system.mass_correction is not None:
            return "takes u' = (v, M^-1 f) with a lumped mass (M^-1 per dof): use mass: lumped"
        if system.contact_form():
            return ("contact is no smooth force of an ODE (IPC's barrier is a potential of the step, a penalty's derivative "
                    "jumps at every touch): scipy's solvers are compared on systems without contact")
        if getattr(system, "lane_count", None) is not None:
            return "is not stepped as lanes"
        return None
