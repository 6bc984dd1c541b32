"""A sampled signed distance field: samples on a regular grid (from a file), interpolated multilinearly."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from .sdf import Collider, _ball_derivatives, _vector


@dataclass(frozen=True, eq=False)
class GridSDF(Collider):
    """A sampled SDF: multilinear interpolation (bilinear in 2-D, trilinear in 3-D) of samples on a regular grid.

    values: (n_0, ..., n_{d-1}), sample j along axis i at origin[i] + j spacing[i] (m), n_i >= 2, finite;
    origin: (d,) m; spacing: (d,) or a scalar, m (> 0). Inside the grid box, phi = sum over the cell's 2^d corners of
    value * prod_i (w_i or 1 - w_i) (w the position in the cell); grad and hess are the interpolant's within the
    cell (pure second derivatives 0, mixed ones not). Outside: phi(p) = phi(clamp(p)) + |p - clamp(p)|, a lower
    bound of a true SDF there. Kinks: on a grid line the cell above is used (the last cell at the far face); on
    the box's surface, the inside formula. ``lipschitz`` = sqrt(L^2 + 1) bounds |grad phi| everywhere (L: the
    interpolant's largest |grad|; outside, |grad phi|^2 = |grad along the box|^2 + 1), for conservative advancement.
    """

    shape: ClassVar[str] = "grid_sdf"
    exact: ClassVar[bool] = False
    positions: ClassVar[tuple[str, ...]] = ("origin",)
    values: np.ndarray
    origin: np.ndarray
    spacing: np.ndarray | float

    def _check(self) -> int:
        values = np.asarray(self.values, dtype=float)
        d = values.ndim
        if d not in (2, 3):
            raise ValueError(f"values must be a 2-D or 3-D array, got {d} dimensions")
        for name, value in (("origin", self.origin), ("spacing", self.spacing)):
            if np.shape(value) != (d,) and not (name == "spacing" and np.ndim(value) == 0):
                raise ValueError(f"{name} has {np.size(value)} components but values has {d} dimensions")
        spacing = np.full(d, float(self.spacing)) if np.ndim(self.spacing) == 0 else np.asarray(self.spacing, dtype=float)
        if not np.all((spacing > 0) & np.isfinite(spacing)):
            raise ValueError(f"spacing must be > 0 and finite, got {spacing.tolist()}")
        if min(values.shape) < 2:
            raise ValueError(f"values must have at least 2 samples along every axis, got shape {values.shape}")
        if (bad := np.count_nonzero(~np.isfinite(values))) > 0:
            raise ValueError(f"values must be finite: {bad} of {values.size} samples are NaN or infinite")
        self._set(values=values, origin=_vector(self.origin, "origin", d), spacing=spacing,
                  lipschitz=_grid_lipschitz(values, spacing))
        return d

    def _upper(self) -> np.ndarray:
        return self.origin + (np.array(self.values.shape) - 1) * self.spacing

    def _locate(self, q):
        """The nearest point of the grid box (k, d), its cell (k, d) and its position w (k, d) in [0, 1]^d within it."""
        clamped = np.clip(q, self.origin, self._upper())
        u = (clamped - self.origin) / self.spacing  # grid coordinates
        cell = np.minimum(np.floor(u).astype(np.intp), np.array(self.values.shape) - 2)
        return clamped, cell, u - cell

    def _distance(self, q):
        clamped, cell, w = self._locate(q)
        phi = sum(self.values[tuple((cell + corner).T)] * np.where(np.array(corner) == 1, w, 1 - w).prod(axis=1)
                  for corner in itertools.product((0, 1), repeat=self.dim))
        return phi + np.linalg.norm(q - clamped, axis=1)

    def _derivatives(self, q):
        d = self.dim
        clamped, cell, w = self._locate(q)
        eye = np.eye(d, dtype=bool)
        both = eye[:, None, :] | eye[None, :, :]  # [j, l, i]: axis i is one of the two differentiated
        phi, grad, hess = 0.0, 0.0, 0.0
        for corner in itertools.product((0, 1), repeat=d):  # the 2^d corners of every point's cell at once
            corner = np.array(corner)
            sample = self.values[tuple((cell + corner).T)]
            factor = np.where(corner == 1, w, 1 - w)  # (k, d): each axis' linear weight
            slope = 2.0 * corner - 1  # d factor_i / d u_i
            phi = phi + sample * factor.prod(axis=1)
            grad = grad + (sample[:, None] * slope) * np.where(eye, 1.0, factor[:, None, :]).prod(axis=2)
            hess = hess + (sample[:, None, None] * np.outer(slope, slope)) * np.where(both, 1.0, factor[:, None, None, :]).prod(axis=3)
        hess[:, eye] = 0.0  # each factor is linear in its own u_i
        grad, hess = grad / self.spacing, hess / np.outer(self.spacing, self.spacing)
        # outside: the clamped axes no longer move the interpolant; the distance to the box adds its own terms
        r = q - clamped
        beyond = r != 0
        grad, hess = np.where(beyond, 0.0, grad), hess * (~beyond[:, :, None] & ~beyond[:, None, :])
        gap = np.linalg.norm(r, axis=1)
        outside = gap > 0
        if np.any(outside):
            _, n, curvature = _ball_derivatives(r[outside], 0.0, np.zeros(d), beyond[outside][:, :, None] * np.eye(d))
            grad[outside] += n
            hess[outside] += curvature
        return phi + gap, grad, hess

    def _bounds(self):
        # phi >= min(values) + distance to the grid box, so phi <= 0 lies within -min(values) of it
        margin = max(0.0, -float(self.values.min()))
        return self.origin - margin, self._upper() + margin


def _grid_lipschitz(values: np.ndarray, spacing: np.ndarray) -> float:
    """sqrt(L^2 + 1) with L = max |grad| of the multilinear interpolant. Component i of its gradient is the difference
    along a cell edge of axis i over spacing_i, interpolated over the other axes, so |grad| is convex along every
    coordinate line and largest at a cell corner, where component i is the difference along the edge through it."""
    d = values.ndim
    slopes = [np.diff(values, axis=i) / spacing[i] for i in range(d)]
    largest = 0.0
    for corner in itertools.product((0, 1), repeat=d):
        squared = sum(slopes[i][tuple(slice(None) if j == i else slice(corner[j], corner[j] + values.shape[j] - 1)
                                      for j in range(d))] ** 2 for i in range(d))
        largest = max(largest, float(squared.max()))
    return float(np.sqrt(largest + 1.0))


def load_grid_sdf(path, origin=None, spacing=None, *, velocity=None) -> GridSDF:
    """A GridSDF from a ``.npy`` file (the values only: origin and spacing must be given) or a ``.npz`` file (arrays
    ``values`` and, optionally, ``origin`` and ``spacing``, which given arguments override). origin: (d,) m;
    spacing: (d,) or scalar m; velocity: (d,) m/s. A bad file or grid is a one-line ValueError naming the problem."""
    path = Path(path)
    if path.suffix == ".npy":
        values = np.load(path, allow_pickle=False)
    elif path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            if "values" not in archive.files:
                raise ValueError(f"{path.name} has no array 'values' (it holds: {', '.join(archive.files) or 'nothing'})")
            values = archive["values"]
            origin = archive["origin"] if origin is None and "origin" in archive.files else origin
            spacing = archive["spacing"] if spacing is None and "spacing" in archive.files else spacing
    else:
        raise ValueError(f"path must end in .npy or .npz, got {path.name!r}")
    for name, value in (("origin", origin), ("spacing", spacing)):
        if value is None:
            raise ValueError(f"{name} must be given: {path.name} does not hold it")
    return GridSDF(values, origin, spacing, velocity=velocity)
