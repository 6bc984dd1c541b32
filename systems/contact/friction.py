"""IPC's lagged smoothed Coulomb friction as a dissipative potential of a step (Li et al., "Incremental Potential
Contact", SIGGRAPH 2020, sec. 5): the mollifier, the lag (normal forces and tangent bases at the step's start) and
the potential of one step for the method's velocity map (model.py's docstring has the formulas)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse


def mollifier(speed: np.ndarray, epsilon: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IPC's friction mollifier at |w| = ``speed`` (m) with threshold epsilon (m), vectorised, as ipctk's
    smooth_friction_f0, f1_over_x and f2_x_minus_f1_over_x3:
    f0 = -y^3/(3 e^2) + y^2/e + e/3 (y < e) else y;  f1/y = 2/e - y/e^2 (y < e) else 1/y;
    (f2 y - f1)/y^3 = -1/(e^2 y) (y < e) else -1/y^3, finite times w w^T as y -> 0."""
    slow = speed < epsilon
    e2 = epsilon * epsilon
    value = np.where(slow, -speed ** 3 / (3.0 * e2) + np.square(speed) / epsilon + epsilon / 3.0, speed)
    safe = np.where(speed > 0.0, speed, 1.0)
    f1_over = np.where(slow, 2.0 / epsilon - speed / e2, 1.0 / safe)
    curvature = np.where(slow, -1.0 / (e2 * safe), -1.0 / safe ** 3)
    return value, f1_over, curvature


@dataclass
class FrictionLag:
    """The friction of one step, lagged at its start: per point contact (vertex, collider) the normal force lambda (N),
    the normal n (tangent projector I - n n^T) and the collider's velocity; and the mesh contacts' (ipctk's)."""

    vertices: np.ndarray  # (q,) vertex indices
    normal_force: np.ndarray  # (q,) N
    normals: np.ndarray  # (q, d)
    velocities: np.ndarray  # (q, d) m/s of the collider at each contact
    mesh: object | None  # mesh_contact's lag, or None


class FrictionTerm:
    """Psi(y) = sum mu lambda f0(|w|; epsv b), w = T (y - a - b v_c) per contact (see the module docstring), and the
    mesh contacts' friction potential through ipctk with the same w and epsilon; value (J), gradient (N), Hessian."""

    def __init__(self, friction: tuple[float, float], dim: int, mesh, lag: FrictionLag, velocity_origin: np.ndarray,
                 velocity_divisor: float):
        """``friction``: (mu, epsv (m/s)); ``dim``: 2 or 3; ``mesh``: the contact model's ipctk mesh contact (its
        friction potential), or None."""
        self.dim = dim
        self.mesh = mesh
        self.lag = lag
        self.origin = velocity_origin
        self.divisor = velocity_divisor
        self.mu, epsv = friction
        self.epsilon = epsv * velocity_divisor  # m: the sliding speed epsv as a displacement over b
        self.weight = self.mu * lag.normal_force  # (q,) N
        d = dim
        self.dofs = (d * lag.vertices[:, None] + np.arange(d)).ravel()

    def _tangential(self, y: np.ndarray) -> np.ndarray:
        """w = T (y_i - a_i - b v_c) per contact, (q, d) (m)."""
        d = self.dim
        offset = (y[self.dofs] - self.origin[self.dofs]).reshape(-1, d) - self.divisor * self.lag.velocities
        normals = self.lag.normals
        return offset - np.einsum("ij,ij->i", offset, normals)[:, None] * normals

    def value(self, y: np.ndarray) -> float:
        energy = 0.0
        if self.lag.vertices.size:
            w = self._tangential(y)
            speed = np.sqrt(np.einsum("ij,ij->i", w, w))
            energy = float(self.weight @ mollifier(speed, self.epsilon)[0])
        if self.lag.mesh is not None:
            energy += self.mesh.friction_energy(self.lag.mesh, y - self.origin, self.epsilon)
        return energy

    def gradient(self, y: np.ndarray) -> np.ndarray:
        gradient = np.zeros(y.size)
        if self.lag.vertices.size:
            w = self._tangential(y)
            speed = np.sqrt(np.einsum("ij,ij->i", w, w))
            np.add.at(gradient, self.dofs, ((self.weight * mollifier(speed, self.epsilon)[1])[:, None] * w).ravel())
        if self.lag.mesh is not None:
            gradient += self.mesh.friction_gradient(self.lag.mesh, y - self.origin, self.epsilon)
        return gradient

    def vertex_blocks(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The point contacts' Hessian blocks: (vertices (q,), blocks (q, d, d) N/m), each
        mu lambda [f1/|w| T + (f2 |w| - f1)/|w|^3 w w^T] (PSD: its eigenvalues are f1/|w| >= 0 across w and
        f2 >= 0 along it, so no projection is needed)."""
        if not self.lag.vertices.size:
            return self.lag.vertices, np.zeros((0, self.dim, self.dim))
        w = self._tangential(y)
        speed = np.sqrt(np.einsum("ij,ij->i", w, w))
        _, f1_over, curvature = mollifier(speed, self.epsilon)
        normals = self.lag.normals
        tangent = np.eye(self.dim) - normals[:, :, None] * normals[:, None, :]
        blocks = self.weight[:, None, None] * (f1_over[:, None, None] * tangent
                                               + curvature[:, None, None] * w[:, :, None] * w[:, None, :])
        return self.lag.vertices, blocks

    def mesh_hessian(self, y: np.ndarray, project_spd=False):
        """The mesh contacts' friction Hessian through ipctk (CSR, n d x n d), or None without them."""
        if self.lag.mesh is None:
            return None
        return self.mesh.friction_hessian(self.lag.mesh, y - self.origin, self.epsilon, project_spd)

    def point_matrix(self, y: np.ndarray):
        """``vertex_blocks`` as a CSR matrix (n d x n d)."""
        n, d = y.size, self.dim
        vertices, blocks = self.vertex_blocks(y)
        dofs = d * vertices[:, None] + np.arange(d)
        rows = np.repeat(dofs, d, axis=1).ravel()
        cols = np.tile(dofs, (1, d)).ravel()
        return scipy.sparse.csr_matrix((blocks.ravel(), (rows, cols)), shape=(n, n))

    def hessian(self, y: np.ndarray, project_spd=False):
        """The whole friction Hessian as a CSR matrix (n d x n d): the point contacts' and the meshes'."""
        mesh = self.mesh_hessian(y, project_spd)
        matrix = self.point_matrix(y)
        return matrix if mesh is None else (matrix + mesh).tocsr()
