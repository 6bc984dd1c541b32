"""Trajectories written by a short script of plain numpy (no simrun), for `simrun measure`.

Velocity Verlet (kick-drift-kick) on two systems, each written as a trajectory file of t (n,), x (n, dof_count) and
v (n, dof_count) beside free-form metadata:
- spring.npz: the undamped spring x'' = -(k/m) x of spring.yaml (k = m = 1, x0 = 1), 20 periods at h = 0.1 s;
- cloth.npz: a 6 x 6 cloth of Hookean springs (structural and shear) hanging from its two top corners under gravity,
  0.5 s at h = 1 ms, with its model written as cloth_model.npz for cloth.yaml to read.

    python verlet.py [FOLDER]        # writes the three files into FOLDER (default: the current folder)
    simrun measure FOLDER/spring.npz --config spring.yaml --name numpy_verlet
"""

import sys
import time
from pathlib import Path

import numpy as np


def velocity_verlet(x0, v0, acceleration, h, steps, fixed=()):
    """States at t = 0, h, ..., steps h; the dofs in ``fixed`` never move."""
    x, v = np.empty((steps + 1, x0.size)), np.empty((steps + 1, x0.size))
    x[0], v[0] = x0, v0
    a = acceleration(x0)
    for n in range(steps):
        half = v[n] + 0.5 * h * a
        half[list(fixed)] = 0.0
        x[n + 1] = x[n] + h * half
        a = acceleration(x[n + 1])
        v[n + 1] = half + 0.5 * h * a
        v[n + 1][list(fixed)] = 0.0
    return x, v


def spring(folder, h=0.1, periods=20, name="spring.npz"):
    k = m = 1.0
    steps = round(periods * 2 * np.pi / h)
    start = time.perf_counter()
    x, v = velocity_verlet(np.array([1.0]), np.array([0.0]), lambda x: -k / m * x, h, steps)
    np.savez(folder / name, t=h * np.arange(steps + 1), x=x, v=v, method="velocity Verlet (numpy)",
             wall_time=time.perf_counter() - start)


def cloth(folder, h=1e-3, duration=0.5, count=6, size=1.0, stiffness=500.0, total_mass=0.5):
    """A square of count x count vertices in the x-z plane, top row at z = 0, pinned at its two top corners."""
    ticks = np.linspace(0.0, size, count)
    vertices = np.array([[ticks[j], 0.0, -ticks[i]] for i in range(count) for j in range(count)])
    index = np.arange(count * count).reshape(count, count)
    springs = np.concatenate([
        np.stack([index[:, :-1].ravel(), index[:, 1:].ravel()], axis=1),    # along rows
        np.stack([index[:-1, :].ravel(), index[1:, :].ravel()], axis=1),    # along columns
        np.stack([index[:-1, :-1].ravel(), index[1:, 1:].ravel()], axis=1),  # shear, one diagonal
        np.stack([index[:-1, 1:].ravel(), index[1:, :-1].ravel()], axis=1),  # shear, the other
    ])
    rest = np.linalg.norm(vertices[springs[:, 1]] - vertices[springs[:, 0]], axis=1)
    masses = np.full(count * count, total_mass / (count * count))
    corners = np.array([index[0, 0], index[0, -1]])
    np.savez(folder / "cloth_model.npz", vertices=vertices, springs=springs, rest_lengths=rest,
             stiffness=np.full(len(springs), stiffness), masses=masses, named_corners=corners)
    gravity = np.array([0.0, 0.0, -9.81])

    def acceleration(flat):
        points = flat.reshape(-1, 3)
        d = points[springs[:, 1]] - points[springs[:, 0]]
        length = np.linalg.norm(d, axis=1)
        pull = (stiffness * (length - rest) / length)[:, None] * d  # Hookean: k (L - l0) along the spring
        force = np.zeros_like(points)
        np.add.at(force, springs[:, 0], pull)
        np.add.at(force, springs[:, 1], -pull)
        return (force / masses[:, None] + gravity).ravel()

    steps = round(duration / h)
    fixed = [3 * vertex + axis for vertex in corners for axis in range(3)]
    start = time.perf_counter()
    x, v = velocity_verlet(vertices.ravel(), np.zeros(vertices.size), acceleration, h, steps, fixed)
    np.savez(folder / "cloth.npz", t=h * np.arange(steps + 1), x=x, v=v, method="velocity Verlet (numpy)",
             wall_time=time.perf_counter() - start)


if __name__ == "__main__":
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path.cwd()
    folder.mkdir(parents=True, exist_ok=True)
    spring(folder)
    cloth(folder)
