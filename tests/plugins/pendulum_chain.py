"""A simrun plug-in: point masses on hardening springs, hanging from a pinned pivot (docs/systems.md)."""

import numpy as np
from pydantic import Field

from simrun.systems import System, SystemParams


class ChainParams(SystemParams):
    """A chain of `count` masses below a pivot at the origin, released at rest at `angle` from the vertical."""

    type: str = "pendulum_chain:ChainParams"
    count: int = Field(3, ge=1, description="free masses")
    length: float = Field(1.0, gt=0, description="m, from the pivot to the last mass (springs at rest)")
    mass: float = Field(0.1, gt=0, description="kg per mass")
    stiffness: float = Field(1e4, gt=0, description="k (N/m): spring force k e (1 + c e^2) at stretch e (m)")
    hardening: float = Field(100.0, ge=0, description="c (1/m^2)")
    gravity: float = Field(9.81, ge=0, description="g (m/s^2), along -y")
    angle: float = Field(0.3, description="rad")

    @property
    def dof_count(self) -> int:
        return 2 * (self.count + 1)  # x, y of the pivot (fixed) and of each mass


class Chain(System):
    """P(x) = sum_springs k (e^2/2 + c e^4/4) + sum_masses m g y, e = |x_j - x_i| - rest length."""

    dim = 2
    fixed_dofs = np.array([0, 1])  # the pivot

    def __init__(self, p: ChainParams):
        self.p, self.rest, self.dof_count = p, p.length / p.count, p.dof_count
        self.mass = np.full(self.dof_count, p.mass)
        s = np.arange(p.count + 1) * self.rest  # arc length from the pivot
        self.x0 = np.column_stack([s * np.sin(p.angle), -s * np.cos(p.angle)]).ravel()
        self.v0 = np.zeros(self.dof_count)

    def springs(self, x):
        """Unit vectors u (n, 2), lengths L (m) and stretches e = L - rest (m) of the n springs."""
        d = np.diff(x.reshape(-1, 2), axis=0)
        length = np.linalg.norm(d, axis=1)
        return d / length[:, None], length, length - self.rest

    def potential_energy(self, x):
        _, _, e = self.springs(x)
        k, c, g = self.p.stiffness, self.p.hardening, self.p.gravity
        return float(np.sum(k * (e**2 / 2 + c * e**4 / 4)) + g * self.mass[1::2] @ x[1::2])

    def gradient(self, x):
        u, _, e = self.springs(x)
        tension = (self.p.stiffness * e * (1 + self.p.hardening * e**2))[:, None] * u
        g = np.zeros((self.dof_count // 2, 2))
        g[:-1] -= tension
        g[1:] += tension
        g[:, 1] += self.p.gravity * self.mass[1::2]
        return g.ravel()

    def hessian(self, x, project_spd=False):
        """Per spring K = k (1 + 3 c e^2) u u^T + (f / L)(I - u u^T); projected: f / L >= 0 (the only negative part)."""
        u, length, e = self.springs(x)
        k, c = self.p.stiffness, self.p.hardening
        transverse = k * e * (1 + c * e**2) / length
        if project_spd:
            transverse = np.maximum(transverse, 0.0)
        uu = u[:, :, None] * u[:, None, :]
        blocks = (k * (1 + 3 * c * e**2))[:, None, None] * uu + transverse[:, None, None] * (np.eye(2) - uu)
        h = np.zeros((self.dof_count, self.dof_count))
        for i, block in enumerate(blocks):
            a, b = slice(2 * i, 2 * i + 2), slice(2 * i + 2, 2 * i + 4)
            h[a, a] += block
            h[b, b] += block
            h[a, b] -= block
            h[b, a] -= block
        return h


ChainParams.system_class = Chain
