"""A model of vertices and springs as data: the rest shape, the springs and what a file or a generator says about them.

``SpringModel`` is what every source of models produces (a ``.npz`` file, a triangle or quad mesh read
through meshio, or one of the generators) and what ``MassSpring`` is built from; the finite elements read
their surfaces and start positions through it too (model_files.py). It holds no state and no parameters of
the config (stiffness, damping, ...) except what the source itself carries per spring or per vertex.
``spring_pairs`` and ``springs_by_kind`` list a generator's springs in kind order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import ModelError


@dataclass(frozen=True, eq=False)
class SpringModel:
    """The rest shape and springs of a mass-spring model.

    vertices: (n, d) float, d = 2 or 3, the rest positions (m).
    springs: (m, 2) intp, vertex pairs (i, j), i != j, no pair twice (in either order).
    kinds: (m,) intp, each spring's index into ``kind_names``.
    kind_names: the spring kinds, e.g. ("stretch_x", "stretch_y", "shear", "bend_x", "bend_y") for a grid,
        ("stretch", "bend") for a mesh, ("stretch",) for an npz file without ``kinds``.
    rest_lengths: (m,) float (m) from the file, or None (then the rest shape's spring lengths).
    stiffness: (m,) float (N/m) from the file, or None.
    masses: (n,) float (kg) from the file, or None.
    triangles: (t, 3) intp, the surface for shading and area masses (quads split in two), or None.
    named_vertices: name -> vertex indices, the sets a config may name in ``pinned`` and selectors
        (a grid's "top_left", "top", ...; a rope's "first", "last").
    grid_shape: (ny, nx) for models on a regular grid (vertex = row * nx + col), else None.
    source: what the model came from, for messages and provenance.
    """

    vertices: np.ndarray
    springs: np.ndarray
    kinds: np.ndarray
    kind_names: tuple[str, ...]
    rest_lengths: np.ndarray | None = None
    stiffness: np.ndarray | None = None
    masses: np.ndarray | None = None
    triangles: np.ndarray | None = None
    named_vertices: dict[str, np.ndarray] = field(default_factory=dict)
    grid_shape: tuple[int, int] | None = None
    source: str = ""
    degenerate_triangles: int = 0  # zero-area faces of a mesh file, left out of springs and triangles (model_files.py)

    @property
    def dim(self) -> int:
        return int(self.vertices.shape[1])

    @property
    def vertex_count(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def spring_count(self) -> int:
        return int(self.springs.shape[0])

    def validate(self) -> "SpringModel":
        """Raise ModelError for anything that cannot be simulated; return self."""
        vertices, springs = self.vertices, self.springs
        if vertices.ndim != 2 or vertices.shape[1] not in (2, 3):
            raise ModelError(f"vertices must be an n x 2 or n x 3 array, got shape {vertices.shape}")
        if vertices.shape[0] < 2:
            raise ModelError(f"a model needs at least 2 vertices, got {vertices.shape[0]}")
        if not np.all(np.isfinite(vertices)):
            bad = int(np.flatnonzero(~np.isfinite(vertices).all(axis=1))[0])
            raise ModelError(f"vertex {bad} has a non-finite coordinate {vertices[bad].tolist()}")
        if springs.ndim != 2 or springs.shape[1] != 2 or springs.shape[0] == 0:
            raise ModelError(f"springs must be an m x 2 array of vertex indices with m >= 1, got shape {springs.shape}")
        n = vertices.shape[0]
        outside = (springs < 0) | (springs >= n)
        if outside.any():
            row = int(np.flatnonzero(outside.any(axis=1))[0])
            raise ModelError(f"spring {row} joins {springs[row].tolist()}: vertex indices must be in 0..{n - 1}")
        loops = springs[:, 0] == springs[:, 1]
        if loops.any():
            row = int(np.flatnonzero(loops)[0])
            raise ModelError(f"spring {row} joins vertex {springs[row, 0]} to itself")
        ordered = np.sort(springs, axis=1)
        _, first, counts = np.unique(ordered, axis=0, return_index=True, return_counts=True)
        if (counts > 1).any():
            pair = ordered[first[np.flatnonzero(counts > 1)[0]]]
            raise ModelError(f"vertices {pair[0]} and {pair[1]} are joined by more than one spring")
        m = springs.shape[0]
        for name, array, length in (("kinds", self.kinds, m), ("rest_lengths", self.rest_lengths, m),
                                    ("stiffness", self.stiffness, m), ("masses", self.masses, n)):
            if array is not None and array.shape != (length,):
                raise ModelError(f"{name} must have one entry per {'vertex' if name == 'masses' else 'spring'} "
                                 f"({length}), got shape {array.shape}")
        lengths = self.rest_lengths if self.rest_lengths is not None else np.linalg.norm(
            vertices[springs[:, 0]] - vertices[springs[:, 1]], axis=1)
        if not (np.all(np.isfinite(lengths)) and np.all(lengths > 0)):
            row = int(np.flatnonzero(~(np.isfinite(lengths) & (lengths > 0)))[0])
            raise ModelError(f"spring {row} ({springs[row, 0]}-{springs[row, 1]}) has rest length {lengths[row]:g}: "
                             "it must be positive (two vertices at the same place?)")
        if self.stiffness is not None and not (np.all(np.isfinite(self.stiffness)) and np.all(self.stiffness >= 0)):
            raise ModelError("stiffness: every entry must be finite and >= 0")
        if self.masses is not None and not (np.all(np.isfinite(self.masses)) and np.all(self.masses > 0)):
            raise ModelError("masses: every entry must be finite and > 0")
        if self.kinds.size and (self.kinds.min() < 0 or self.kinds.max() >= len(self.kind_names)):
            raise ModelError(f"kinds must index kind_names ({len(self.kind_names)} names)")
        if self.triangles is not None:
            triangles = self.triangles
            if triangles.ndim != 2 or triangles.shape[1] != 3 or ((triangles < 0) | (triangles >= n)).any():
                raise ModelError(f"triangles must be a t x 3 array of vertex indices in 0..{n - 1}")
        return self


def spring_pairs(blocks: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(m, 2) vertex pairs from blocks of (first, second) index arrays, each raveled in C order."""
    return np.stack([np.concatenate([first.ravel() for first, _ in blocks]),
                     np.concatenate([second.ravel() for _, second in blocks])], axis=1).astype(np.intp)


def springs_by_kind(groups: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Springs (m, 2) and kinds (m,) from one pair array per kind, in kind order."""
    kinds = np.concatenate([np.full(len(pairs), kind, dtype=np.intp) for kind, pairs in enumerate(groups)])
    return np.concatenate(groups).astype(np.intp), kinds
