"""The damping forces of the lectures, f = -D v, that a system of vertices may take: the config's terms
(``DampingTerm``) and the resolved ones (``Damping``) the systems are built with."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .fields import NonNegative


@dataclass(frozen=True)
class Damping:
    """One damping force of the lectures, f = -D v with D assembled in the Hessian's pattern.

    model: ``spring`` (-k_d ((v_i - v_j) . u) u per spring), ``relative`` (-k_d (v_i - v_j) per spring),
    ``drag`` (-k_d v_i per vertex), ``rayleigh`` (D = alpha M + beta K(rest shape), K projected SPD);
    coefficient: k_d (N s/m); alpha (1/s) and beta (s) for rayleigh."""

    model: str
    coefficient: float = 0.0
    alpha: float = 0.0
    beta: float = 0.0


DAMPING_MODELS = ("spring", "relative", "drag", "rayleigh")


class DampingTerm(BaseModel):
    """One damping force f = -D v of the lectures: spring, relative, drag, or rayleigh (alpha M + beta K_rest)."""

    model_config = ConfigDict(extra="forbid")
    model: Literal[DAMPING_MODELS] = Field(description=" | ".join(DAMPING_MODELS))  # type: ignore[valid-type]
    coefficient: NonNegative = Field(0.0, description="k_d (N s/m): spring, relative, drag")
    alpha: NonNegative = Field(0.0, description="rayleigh: mass factor (1/s)")
    beta: NonNegative = Field(0.0, description="rayleigh: stiffness factor (s)")
