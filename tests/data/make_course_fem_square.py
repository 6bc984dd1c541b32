"""Record the course code's own numbers for its 2-D neo-Hookean square (tests/data/course_fem_square.npz).

The course code is phys-sim-book/solid-sim-tutorial, folder 6_inv_free (commit f463ddc4cb517001721c1d6e471437106afce67a,
2026-03-28). Its functions are called as they are; nothing of it is copied here. Made with

    python tests/data/make_course_fem_square.py PATH/TO/solid-sim-tutorial/6_inv_free

The scene is the course code's square: side 1 m, 4 segments, E = 1e5 Pa, nu = 0.4, rho = 1000 kg/m^2, and the equal
node masses rho L^2 / (n + 1)^2. The simulator's floor and ceiling are moved 100 m away (no contact), and there is no
Dirichlet node, so that the step is inertia + neo-Hookean + gravity alone. Recorded:
- the neo-Hookean energy and gradient (NeoHookeanEnergy.val, .grad) at a fixed deformed state;
- 20 backward Euler steps of h = 0.01 s (time_integrator.step_forward, Newton on the projected Hessian, with the
  filtered line search) from the square stretched 1.4x along x, at rest, with tolerance 1e-10 m/s on the step's
  largest Newton direction over h.
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

import numpy as np

SIDE, SEGMENTS, YOUNG, POISSON, DENSITY, DT, STEPS, TOLERANCE = 1.0, 4, 1.0e5, 0.4, 1000.0, 0.01, 20, 1e-10
STRETCH = 1.4
OUTPUT = Path(__file__).with_name("course_fem_square.npz")


def main(folder: str) -> None:
    sys.path.insert(0, folder)
    import NeoHookeanEnergy
    import square_mesh
    import time_integrator

    x, e = square_mesh.generate(SIDE, SEGMENTS)
    count = len(x)
    vol, IB = [0.0] * len(e), [None] * len(e)
    for i in range(len(e)):
        TB = [x[e[i][1]] - x[e[i][0]], x[e[i][2]] - x[e[i][0]]]
        vol[i] = np.linalg.det(np.transpose(TB)) / 2
        IB[i] = np.linalg.inv(np.transpose(TB))
    mu = [0.5 * YOUNG / (1 + POISSON)] * len(e)
    lam = [YOUNG * POISSON / ((1 + POISSON) * (1 - 2 * POISSON))] * len(e)
    rng = np.random.default_rng(27)
    deformed = x + 0.03 * rng.standard_normal(x.shape)
    energy = NeoHookeanEnergy.val(deformed, e, vol, IB, mu, lam)
    gradient = NeoHookeanEnergy.grad(deformed, e, vol, IB, mu, lam)

    # the simulator's arrays, with its ceiling node (the last) and floor 100 m away
    start = x.copy()
    start[:, 0] *= STRETCH
    positions = np.append(start, [[0.0, 100.0]], axis=0)
    velocities = np.zeros_like(positions)
    masses = [DENSITY * SIDE * SIDE / count] * len(positions)
    normal, origin = np.array([0.0, 1.0]), np.array([0.0, -100.0])
    contact_area = [SIDE / SEGMENTS] * len(positions)
    trajectory = [positions[:count].copy()]
    for _ in range(STEPS):
        with contextlib.redirect_stdout(io.StringIO()):  # the course code prints every Newton iteration
            positions, velocities = time_integrator.step_forward(
                positions, e, velocities, masses, vol, IB, mu, lam, normal, origin, contact_area, 0.0,
                [False] * len(positions), [], [], [], [1000.0], DT, TOLERANCE)
        trajectory.append(positions[:count].copy())
    np.savez(OUTPUT, rest=x, elements=np.array(e), deformed=deformed, energy=energy, gradient=gradient,
             trajectory=np.array(trajectory), dt=DT, stretch=STRETCH, masses=np.array(masses[:count]))
    print(f"wrote {OUTPUT}: energy {energy:.10g} J, {STEPS} steps")


if __name__ == "__main__":
    main(sys.argv[1])
