"""The peers of simrun's compiled VBD sweeps in `make bench` (realtime_kernels.py): the same algorithm written in C,
single-threaded, compiled with the system's compiler (``cc -O2``) and called on simrun's own arrays.

- ``sweep``: a Hookean mass-spring cloth (clamped transverse factors, no damping; systems/mass_spring/vbd_kernels.py).
- ``fem_sweep``: a stable neo-Hookean tetrahedral solid (systems/fem/tet_terms.py's ``invariant_elements_3d`` and
  ``invariant_change_3d`` in vbd_kernels.py's sweep): each incident element's F = sum_a x_a g_a^T, P n and
  K = (mu - mu / (I_C + 1)) |n|^2 I + 2 mu / (I_C + 1)^2 w w^T + lambda c c^T (w = F n, c = cof(F) n), the kept-volume
  cut J + t c . u >= kept J, and the backtracking on the exact change of E from the changes of I_C and J.

Both share the vertex's Newton step (the determinant floor and Gaussian elimination with partial pivoting, as
systems/vertex_kernels.py's) and the backtracking, and take the vertices colour by colour in the order of simrun's
plans. Written in the order of simrun's arithmetic: without FMA contraction (x86-64's baseline has no FMA) both give the
same positions to the last bit, which the benchmark checks before it compares the times.
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import tempfile
from pathlib import Path

_NEWTON_STEP = r"""
#include <math.h>
/* u = -H^-1 g (H of the whole potential at the vertex), or 0 where |det H| <= floor |H|_F^3 or det H is not finite */
static void newton_step(double H[3][3], const double g[3], double floor_, double u[3]) {
    double det = H[0][0] * (H[1][1] * H[2][2] - H[1][2] * H[2][1]) - H[0][1] * (H[1][0] * H[2][2] - H[1][2] * H[2][0])
                 + H[0][2] * (H[1][0] * H[2][1] - H[1][1] * H[2][0]);
    double size = 0.0;
    for (int a = 0; a < 3; a++) for (int b = 0; b < 3; b++) size += H[a][b] * H[a][b];
    size = sqrt(size);
    if (!(fabs(det) > floor_ * size * size * size) || !isfinite(det)) {
        u[0] = u[1] = u[2] = 0.0;
        return;
    }
    double w[3][4];  /* Gaussian elimination with partial pivoting */
    for (int r = 0; r < 3; r++) { for (int s = 0; s < 3; s++) w[r][s] = H[r][s]; w[r][3] = -g[r]; }
    for (int col = 0; col < 3; col++) {
        int pivot = col;
        for (int r = col + 1; r < 3; r++) if (fabs(w[r][col]) > fabs(w[pivot][col])) pivot = r;
        if (pivot != col) for (int s = 0; s < 4; s++) { double t = w[col][s]; w[col][s] = w[pivot][s]; w[pivot][s] = t; }
        for (int r = col + 1; r < 3; r++) {
            double f = w[r][col] / w[col][col];
            for (int s = col; s < 4; s++) w[r][s] -= f * w[col][s];
        }
    }
    for (int r = 2; r >= 0; r--) {
        double t = w[r][3];
        for (int s = r + 1; s < 3; s++) t -= w[r][s] * u[s];
        u[r] = t / w[r][r];
    }
}

/* g = M (y_i - y~_i) + s (dP/dy_i - m_i g_grav), H = s H_P + M: the incremental potential's blocks at vertex i */
static void finish_blocks(long i, const double *y, const double *y_tilde, const double *mass, double scale,
                          const double *gravity, double g[3], double H[3][3]) {
    for (int a = 0; a < 3; a++) {
        g[a] = mass[3 * i + a] * (y[3 * i + a] - y_tilde[3 * i + a]) + scale * (g[a] - gravity[3 * i + a]);
        for (int b = 0; b < 3; b++) H[a][b] *= scale;
        H[a][a] += mass[3 * i + a];
    }
}

static double inertia_change(long i, const double *u, const double *y, const double *y_tilde, const double *mass) {
    double inertia = 0.0;
    for (int a = 0; a < 3; a++) inertia += mass[3 * i + a] * u[a] * (y[3 * i + a] - y_tilde[3 * i + a] + 0.5 * u[a]);
    return inertia;
}
"""

CLOTH_SOURCE = _NEWTON_STEP + r"""
/* the change of E when vertex i alone moves by u; deltas and lengths: its springs' y_i - y_j and |y_i - y_j| */
static double change_of(long i, const double *u, const double *y, const double *y_tilde, const double *mass,
                        double scale, const long *indptr, const long *springs, const double *stiffness,
                        const double *rest_length, const double *gravity, const double *deltas, const double *lengths) {
    double potential = 0.0;
    for (long p = indptr[i]; p < indptr[i + 1]; p++) {
        long e = springs[p], slot = p - indptr[i];
        double moved = 0.0, squared_change = 0.0;
        for (int a = 0; a < 3; a++) {
            double shifted = deltas[3 * slot + a] + u[a];
            moved += shifted * shifted;
            squared_change += u[a] * (deltas[3 * slot + a] + deltas[3 * slot + a] + u[a]);
        }
        double length = lengths[slot], moved_length = sqrt(moved);
        potential += 0.5 * stiffness[e] * squared_change / (moved_length + length)
                     * (moved_length + length - 2.0 * rest_length[e]);
    }
    for (int a = 0; a < 3; a++) potential -= gravity[3 * i + a] * u[a];
    return inertia_change(i, u, y, y_tilde, mass) + scale * potential;
}

void sweep(double *y, const long *colour_starts, long colours, const long *vertices, const double *y_tilde,
           const double *mass, double scale, const long *indptr, const long *other, const long *springs,
           const double *stiffness, const double *rest_length, const double *gravity, double floor_,
           int max_halvings, double *deltas, double *lengths) {
    for (long c = 0; c < colours; c++) {
        for (long k = colour_starts[c]; k < colour_starts[c + 1]; k++) {
            long i = vertices[k];
            double g[3] = {0, 0, 0}, H[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}}, u[3];
            for (long p = indptr[i]; p < indptr[i + 1]; p++) {
                long j = other[p], e = springs[p], slot = p - indptr[i];
                double squared = 0.0;
                for (int a = 0; a < 3; a++) {
                    deltas[3 * slot + a] = y[3 * i + a] - y[3 * j + a];
                    squared += deltas[3 * slot + a] * deltas[3 * slot + a];
                }
                double length = sqrt(squared);
                lengths[slot] = length;
                double factor = stiffness[e] * (length - rest_length[e]) / length;
                double along = stiffness[e], ratio = 1.0 - rest_length[e] / length;
                double transverse = stiffness[e] * (ratio > 0.0 ? ratio : 0.0);
                double outer_scale = (along - transverse) / squared;
                for (int a = 0; a < 3; a++) {
                    g[a] += factor * deltas[3 * slot + a];
                    H[a][a] += transverse;
                    for (int b = 0; b < 3; b++) H[a][b] += outer_scale * deltas[3 * slot + a] * deltas[3 * slot + b];
                }
            }
            finish_blocks(i, y, y_tilde, mass, scale, gravity, g, H);
            newton_step(H, g, floor_, u);
            int rounds = 0;
            double change = change_of(i, u, y, y_tilde, mass, scale, indptr, springs, stiffness, rest_length, gravity,
                                      deltas, lengths);
            while (!(change <= 0.0) && rounds < max_halvings) {
                for (int a = 0; a < 3; a++) u[a] *= 0.5;
                change = change_of(i, u, y, y_tilde, mass, scale, indptr, springs, stiffness, rest_length, gravity,
                                   deltas, lengths);
                rounds++;
            }
            if (!(change <= 0.0)) u[0] = u[1] = u[2] = 0.0;
            for (int a = 0; a < 3; a++) y[3 * i + a] += u[a];
        }
    }
}
"""

FEM_SOURCE = _NEWTON_STEP + r"""
/* the change of E when vertex i alone moves by u, from its elements' w = F n, c = cof(F) n, J and 1 / (I_C + 1) */
static double fem_change_of(long i, const double *u, const double *y, const double *y_tilde, const double *mass,
                            double scale, const unsigned long *indptr, const double *shape_gradients,
                            const double *volumes, const double *mu, const double *lam, const double *alpha,
                            const double *gravity, const double *ws, const double *cs, const double *Js,
                            const double *kept) {
    double u0 = u[0], u1 = u[1], u2 = u[2], squared_u = u0 * u0 + u1 * u1 + u2 * u2, potential = 0.0;
    for (unsigned long p = indptr[i]; p < indptr[i + 1]; p++) {
        unsigned long slot = p - indptr[i];
        const double *n = shape_gradients + 12 * p, *w = ws + 3 * slot, *c = cs + 3 * slot;
        double invariant_change = 2.0 * (u0 * w[0] + u1 * w[1] + u2 * w[2])
                                  + squared_u * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        double volume_change = u0 * c[0] + u1 * c[1] + u2 * c[2];
        potential += volumes[p] * (0.5 * mu[p] * invariant_change
                                   + 0.5 * lam[p] * volume_change * (2.0 * (Js[slot] - alpha[p]) + volume_change)
                                   - 0.5 * mu[p] * log1p(invariant_change * kept[slot]));
    }
    for (int a = 0; a < 3; a++) potential -= gravity[3 * i + a] * u[a];
    return inertia_change(i, u, y, y_tilde, mass) + scale * potential;
}

void fem_sweep(double *y, const long *colour_starts, long colours, const long *vertices, const double *y_tilde,
               const double *mass, double scale, const unsigned long *indptr, const unsigned long *elements,
               const double *shape_gradients, const double *volumes, const double *mu, const double *lam,
               const double *alpha, const double *gravity, double kept_volume, double floor_, int max_halvings,
               double *ws, double *cs, double *Js, double *kept) {
    for (long colour = 0; colour < colours; colour++) {
        for (long k = colour_starts[colour]; k < colour_starts[colour + 1]; k++) {
            long i = vertices[k];
            double g[3] = {0, 0, 0}, H[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}}, u[3];
            for (unsigned long p = indptr[i]; p < indptr[i + 1]; p++) {
                unsigned long slot = p - indptr[i];
                const unsigned long *v = elements + 4 * p;  /* the element's corners, vertex i's first */
                const double *s = shape_gradients + 12 * p;
                double f[3][3];
                for (int r = 0; r < 3; r++)
                    for (int col = 0; col < 3; col++)
                        f[r][col] = y[3 * v[0] + r] * s[col] + y[3 * v[1] + r] * s[3 + col]
                                    + y[3 * v[2] + r] * s[6 + col] + y[3 * v[3] + r] * s[9 + col];
                double n0 = s[0], n1 = s[1], n2 = s[2];
                /* cof(F)'s columns: f1 x f2, f2 x f0, f0 x f1 (f_j = F[:, j]) */
                double c00 = f[1][1] * f[2][2] - f[2][1] * f[1][2], c10 = f[2][1] * f[0][2] - f[0][1] * f[2][2],
                       c20 = f[0][1] * f[1][2] - f[1][1] * f[0][2];
                double c01 = f[1][2] * f[2][0] - f[2][2] * f[1][0], c11 = f[2][2] * f[0][0] - f[0][2] * f[2][0],
                       c21 = f[0][2] * f[1][0] - f[1][2] * f[0][0];
                double c02 = f[1][0] * f[2][1] - f[2][0] * f[1][1], c12 = f[2][0] * f[0][1] - f[0][0] * f[2][1],
                       c22 = f[0][0] * f[1][1] - f[1][0] * f[0][1];
                double J = f[0][0] * c00 + f[1][0] * c10 + f[2][0] * c20;
                double invariant = f[0][0] * f[0][0] + f[0][1] * f[0][1] + f[0][2] * f[0][2] + f[1][0] * f[1][0]
                                   + f[1][1] * f[1][1] + f[1][2] * f[1][2] + f[2][0] * f[2][0] + f[2][1] * f[2][1]
                                   + f[2][2] * f[2][2];
                double w0 = f[0][0] * n0 + f[0][1] * n1 + f[0][2] * n2, w1 = f[1][0] * n0 + f[1][1] * n1 + f[1][2] * n2,
                       w2 = f[2][0] * n0 + f[2][1] * n1 + f[2][2] * n2;
                double a0 = c00 * n0 + c01 * n1 + c02 * n2, a1 = c10 * n0 + c11 * n1 + c12 * n2,
                       a2 = c20 * n0 + c21 * n1 + c22 * n2;
                double squared = n0 * n0 + n1 * n1 + n2 * n2, inverse = 1.0 / (invariant + 1.0);
                double shear = mu[p] - mu[p] * inverse, stretch = 2.0 * mu[p] * inverse * inverse, spread = lam[p];
                double volume_stress = lam[p] * (J - alpha[p]), diagonal = shear * squared, volume = volumes[p];
                ws[3 * slot] = w0; ws[3 * slot + 1] = w1; ws[3 * slot + 2] = w2;
                cs[3 * slot] = a0; cs[3 * slot + 1] = a1; cs[3 * slot + 2] = a2;
                Js[slot] = J; kept[slot] = inverse;
                g[0] += volume * (shear * w0 + volume_stress * a0);
                g[1] += volume * (shear * w1 + volume_stress * a1);
                g[2] += volume * (shear * w2 + volume_stress * a2);
                H[0][0] += volume * (diagonal + stretch * w0 * w0 + spread * a0 * a0);
                H[1][1] += volume * (diagonal + stretch * w1 * w1 + spread * a1 * a1);
                H[2][2] += volume * (diagonal + stretch * w2 * w2 + spread * a2 * a2);
                H[0][1] += volume * (stretch * w0 * w1 + spread * a0 * a1);
                H[0][2] += volume * (stretch * w0 * w2 + spread * a0 * a2);
                H[1][2] += volume * (stretch * w1 * w2 + spread * a1 * a2);
            }
            H[1][0] = H[0][1]; H[2][0] = H[0][2]; H[2][1] = H[1][2];
            finish_blocks(i, y, y_tilde, mass, scale, gravity, g, H);
            newton_step(H, g, floor_, u);
            double fraction = 1.0;  /* every element keeps kept_volume of its volume: J + t c . u >= kept_volume J */
            for (unsigned long slot = 0; slot < indptr[i + 1] - indptr[i]; slot++) {
                double rate = cs[3 * slot] * u[0] + cs[3 * slot + 1] * u[1] + cs[3 * slot + 2] * u[2];
                if (Js[slot] > 0.0 && rate < 0.0) fraction = fmin(fraction, (1.0 - kept_volume) * Js[slot] / -rate);
            }
            if (fraction < 1.0) for (int a = 0; a < 3; a++) u[a] *= fraction;
            int rounds = 0;
            double change = fem_change_of(i, u, y, y_tilde, mass, scale, indptr, shape_gradients, volumes, mu, lam,
                                          alpha, gravity, ws, cs, Js, kept);
            while (!(change <= 0.0) && rounds < max_halvings) {
                for (int a = 0; a < 3; a++) u[a] *= 0.5;
                change = fem_change_of(i, u, y, y_tilde, mass, scale, indptr, shape_gradients, volumes, mu, lam,
                                       alpha, gravity, ws, cs, Js, kept);
                rounds++;
            }
            if (!(change <= 0.0)) u[0] = u[1] = u[2] = 0.0;
            for (int a = 0; a < 3; a++) y[3 * i + a] += u[a];
        }
    }
}
"""


def compiled(source: str) -> ctypes.CDLL | None:
    """The C source built into a shared library with the system's compiler (``cc -O2``); None where there is none."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    folder = Path(tempfile.mkdtemp(prefix="simrun_vbd_c_"))
    source_file, library = folder / "vbd.c", folder / "vbd.so"
    source_file.write_text(source)
    subprocess.run([compiler, "-O2", "-shared", "-fPIC", str(source_file), "-o", str(library), "-lm"], check=True)
    return ctypes.CDLL(str(library))
