"""The meshes of the finite-element system: simplices (triangles in 2-D, tetrahedra in 3-D), from a file or a generator.

``SimplexMesh`` is what every source produces: the rest shape, the elements in the source's vertex order, and the
vertex sets a config may name. A mesh of triangles in 3-D is a shell (``is_shell``). Sources: any file meshio reads
with ``tetra`` or ``triangle`` cells (a 3-D file whose triangles are flat in z is a 2-D solid, unless the config
gives a thickness; any other a shell),
``{grid: {resolution, size, height}}`` (the cloth's grid of triangles, vertex for vertex), ``{box: {size, cells}}`` (each cell of a grid cut into six tetrahedra
along its main diagonal, the Kuhn triangulation, which conforms across cells) and ``{square: {segments, size}}``
(the triangles of the course code's 2-D FEM square, solid-sim-tutorial 6_inv_free/square_mesh.py) and
``{tetrahedralize: {surface, edge_length}}`` (a closed surface filled with tets by fTetWild).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ..vertex.errors import ModelError
from ..vertex.fields import Finite, Positive
from ..vertex.grids import GridCount, GridModel



@dataclass(frozen=True, eq=False)
class SimplexMesh:
    """vertices (n, d) rest positions (m); elements (t, d + 1) vertex indices, each positively oriented;
    named_vertices: name -> indices; source: what it came from (messages, provenance)."""

    vertices: np.ndarray
    elements: np.ndarray
    named_vertices: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""

    @property
    def dim(self) -> int:
        return int(self.vertices.shape[1])

    @property
    def element_dim(self) -> int:
        """2 for triangles, 3 for tetrahedra."""
        return int(self.elements.shape[1]) - 1

    @property
    def is_shell(self) -> bool:
        """Triangles in 3-D: a surface, whose elements are membranes."""
        return self.element_dim < self.dim

    @property
    def vertex_count(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def element_count(self) -> int:
        return int(self.elements.shape[0])

    # the attributes the vertex selectors and constraints read (systems/vertex/selectors.py, constraint_config.py)
    triangles = None

    def rest_volumes(self) -> np.ndarray:
        """Signed volumes (areas in 2-D) of the elements at rest: det(D_m) / d!; a shell's triangles' areas."""
        if self.is_shell:
            return triangle_areas(self.vertices, self.elements)
        return signed_volumes(self.vertices, self.elements)

    def boundary_faces(self) -> np.ndarray:
        """The faces that belong to one element only, oriented outwards: triangles (f, 3) of a tet mesh, edges
        (f, 2) of a triangle mesh (a solid's or a shell's), in the order of the elements they bound."""
        d = self.element_dim
        # the faces of a positively oriented simplex, each ordered so that its normal points out
        local = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)] if d == 3 else [(1, 2), (2, 0), (0, 1)]
        faces = np.concatenate([self.elements[:, list(face)] for face in local])
        keys = np.sort(faces, axis=1)
        _, first, counts = np.unique(keys, axis=0, return_index=True, return_counts=True)
        boundary = np.sort(first[counts == 1])
        return faces[boundary]

    def edges(self) -> np.ndarray:
        """Every edge of the elements once, (m, 2), its smaller vertex first."""
        pairs = np.concatenate([self.elements[:, [a, b]] for a, b in itertools.combinations(range(self.element_dim + 1), 2)])
        return np.unique(np.sort(pairs, axis=1), axis=0)

    def hinges(self) -> np.ndarray:
        """(h, 4): every interior edge (x0, x1) with the vertex x2 opposite it in one triangle and x3 in the other, in
        the order of the edges; ModelError naming the edge's vertices where more than two triangles meet."""
        local = [(0, 1, 2), (1, 2, 0), (2, 0, 1)]
        corners = np.concatenate([self.elements[:, list(order)] for order in local])  # edge (a, b), opposite c
        keys = np.sort(corners[:, :2], axis=1)
        order = np.lexsort((keys[:, 1], keys[:, 0]))
        keys, corners = keys[order], corners[order]
        _, first, counts = np.unique(keys, axis=0, return_index=True, return_counts=True)
        crowded = np.flatnonzero(counts > 2)
        if crowded.size:
            edge = keys[first[crowded[0]]]
            raise ModelError(f"the edge between vertices {int(edge[0])} and {int(edge[1])} is shared by "
                             f"{int(counts[crowded[0]])} triangles ({crowded.size} such edges): a hinge needs a "
                             "manifold surface, each edge in at most two triangles")
        pairs = first[counts == 2]
        return np.stack([corners[pairs, 0], corners[pairs, 1], corners[pairs, 2], corners[pairs + 1, 2]],
                        axis=1).astype(np.intp)

    def validate(self) -> "SimplexMesh":
        """Raise ModelError for a mesh that cannot be simulated (naming the element or vertex); return self with every
        element positively oriented (a mesh whose elements are all negatively oriented, a clockwise 2-D file, is
        turned over; one with both is refused, naming the first inverted element)."""
        vertices, elements = self.vertices, self.elements
        if vertices.ndim != 2 or vertices.shape[1] not in (2, 3) or vertices.shape[0] < 3:
            raise ModelError(f"vertices must be an n x 2 or n x 3 array with n >= 3, got shape {vertices.shape}")
        if not np.all(np.isfinite(vertices)):
            bad = int(np.flatnonzero(~np.isfinite(vertices).all(axis=1))[0])
            raise ModelError(f"vertex {bad} has a non-finite coordinate {vertices[bad].tolist()}")
        d = vertices.shape[1]
        if d == 3 and elements.ndim == 2 and elements.shape[1] == 3 and elements.shape[0] > 0:
            return self._validate_shell()
        if elements.ndim != 2 or elements.shape[1] != d + 1 or elements.shape[0] == 0:
            kind = "tetrahedra" if d == 3 else "triangles"
            raise ModelError(f"a {d}-D solid needs {kind} ({d + 1} vertices each); got an element array of shape "
                             f"{elements.shape}")
        _check_indices(elements, vertices.shape[0], "element")
        volumes = signed_volumes(vertices, elements)
        scale = float(np.max(np.ptp(vertices, axis=0))) ** d
        flat = np.abs(volumes) <= 1e-14 * scale
        if flat.any():
            row = int(np.flatnonzero(flat)[0])
            raise ModelError(f"element {row} (vertices {elements[row].tolist()}) has zero {'volume' if d == 3 else 'area'} "
                             "at rest (degenerate): every element needs a positive one")
        negative = volumes < 0
        if negative.all():
            elements = elements.copy()
            elements[:, [0, 1]] = elements[:, [1, 0]]
        elif negative.any():
            row = int(np.flatnonzero(negative)[0])
            raise ModelError(f"element {row} (vertices {elements[row].tolist()}) is inverted at rest: its vertices run the "
                             "other way round from the other elements' (swap two of them)")
        return SimplexMesh(vertices.astype(float), np.ascontiguousarray(elements, dtype=np.intp),
                           self.named_vertices, self.source)


    def _validate_shell(self) -> "SimplexMesh":
        """A shell's checks: indices in range and no triangle of zero area (a shell has no orientation to check)."""
        vertices, elements = self.vertices, self.elements
        _check_indices(elements, vertices.shape[0], "triangle")
        areas = triangle_areas(vertices, elements)
        flat = areas <= 1e-14 * float(np.max(np.ptp(vertices, axis=0))) ** 2
        if flat.any():
            row = int(np.flatnonzero(flat)[0])
            raise ModelError(f"triangle {row} (vertices {elements[row].tolist()}) has zero area at rest (degenerate): "
                             "every triangle of a shell needs a positive one")
        return SimplexMesh(vertices.astype(float), np.ascontiguousarray(elements, dtype=np.intp), self.named_vertices,
                           self.source)


def _check_indices(elements: np.ndarray, count: int, kind: str) -> None:
    """ModelError naming the first element with a vertex index outside 0..count - 1."""
    outside = (elements < 0) | (elements >= count)
    if outside.any():
        row = int(np.flatnonzero(outside.any(axis=1))[0])
        raise ModelError(f"{kind} {row} has vertices {elements[row].tolist()}: indices must be in 0..{count - 1}")


def triangle_areas(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Areas of triangles in 3-D, |(X_1 - X_0) x (X_2 - X_0)| / 2."""
    first, second = vertices[elements[:, 1]] - vertices[elements[:, 0]], vertices[elements[:, 2]] - vertices[elements[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(first, second), axis=1)


def signed_volumes(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    d = vertices.shape[1]
    edges = np.stack([vertices[elements[:, a]] - vertices[elements[:, 0]] for a in range(1, d + 1)], axis=2)
    return np.linalg.det(edges) / (2.0 if d == 2 else 6.0)


def _face_names(vertices: np.ndarray) -> dict[str, np.ndarray]:
    """x_min, x_max, y_min, ... : the vertices on each face of the bounding box; left/right (x), bottom/top (the
    last axis); in 2-D the corners too (top_left, ...)."""
    names = {}
    for axis, letter in enumerate("xyz"[:vertices.shape[1]]):
        column = vertices[:, axis]
        names[f"{letter}_min"] = np.flatnonzero(column == column.min())
        names[f"{letter}_max"] = np.flatnonzero(column == column.max())
    names["left"], names["right"] = names["x_min"], names["x_max"]
    last = "xyz"[vertices.shape[1] - 1]
    names["bottom"], names["top"] = names[f"{last}_min"], names[f"{last}_max"]
    if vertices.shape[1] == 2:  # the corners, as the mass-spring square names them
        for vertical in ("bottom", "top"):
            for side in ("left", "right"):
                names[f"{vertical}_{side}"] = np.intersect1d(names[vertical], names[side])
    return names


class BoxMesh(BaseModel):
    """The box [0, size] cut into cells[0] x cells[1] x cells[2] cubes of six tetrahedra each (Kuhn: the paths from the
    cell's lowest to its highest corner along the axes in every order). Vertex (i, j, k) is i + (cx + 1) (j + (cy + 1) k)."""

    model_config = ConfigDict(extra="forbid")
    size: tuple[float, float, float] = Field((1.0, 0.1, 0.1), description="side lengths (m)")
    cells: tuple[int, int, int] = Field((10, 1, 1), description="cells along x, y, z")

    def build(self) -> SimplexMesh:
        if min(self.size) <= 0 or min(self.cells) < 1:
            raise ModelError(f"box: size must be positive and cells >= 1, got size {list(self.size)}, cells {list(self.cells)}")
        counts = [c + 1 for c in self.cells]
        axes = [np.linspace(0.0, length, count) for length, count in zip(self.size, counts)]
        z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")  # x varies fastest
        vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
        index = np.arange(vertices.shape[0]).reshape(counts[2], counts[1], counts[0])
        cell = index[:-1, :-1, :-1].ravel()
        stride = np.array([1, counts[0], counts[0] * counts[1]])
        elements = []
        for order in itertools.permutations(range(3)):
            corner = np.zeros(3, dtype=int)
            path = [cell]
            for axis in order:
                corner[axis] = 1
                path.append(cell + int(corner @ stride))
            elements.append(np.stack(path, axis=1))
        elements = np.stack(elements, axis=1).reshape(-1, 4)  # cell by cell, six tets each
        negative = signed_volumes(vertices, elements) < 0
        elements[negative] = elements[negative][:, [1, 0, 2, 3]]
        return SimplexMesh(vertices, elements, _face_names(vertices),
                           f"box {self.cells[0]}x{self.cells[1]}x{self.cells[2]}").validate()


class SquareMesh(BaseModel):
    """The 2-D square of the course code (solid-sim-tutorial 6_inv_free/square_mesh.py): (segments + 1)^2 vertices on
    [-size/2, size/2]^2, vertex i (segments + 1) + j at (-size/2 + i step, -size/2 + j step), each cell cut into two
    triangles along the diagonal that alternates with the cell's parity, in the course code's order."""

    model_config = ConfigDict(extra="forbid")
    segments: int = Field(4, ge=1, le=1023, description="cells along each side")
    size: float = Field(1.0, gt=0, description="side length (m)")

    def build(self) -> SimplexMesh:
        count = self.segments + 1
        step = self.size / self.segments
        coordinate = -self.size / 2 + step * np.arange(count)
        along_x, along_y = np.meshgrid(coordinate, coordinate, indexing="ij")
        vertices = np.stack([along_x.ravel(), along_y.ravel()], axis=1)
        elements = []
        for i in range(self.segments):
            for j in range(self.segments):
                v00, v10, v01, v11 = i * count + j, (i + 1) * count + j, i * count + j + 1, (i + 1) * count + j + 1
                if (i % 2) ^ (j % 2):
                    elements += [[v00, v10, v01], [v10, v11, v01]]
                else:
                    elements += [[v00, v10, v11], [v00, v11, v01]]
        return SimplexMesh(vertices, np.array(elements, dtype=np.intp), _face_names(vertices),
                           f"square {self.segments}x{self.segments}").validate()


class GridMesh(BaseModel):
    """The cloth's grid as a shell: the triangles of ``{grid}`` (systems/vertex/grids.py, mass_spring's and the ``cloth``
    system's), vertex for vertex and with its vertex names (top_left, ..., left, right), flat at z = height."""

    model_config = ConfigDict(extra="forbid")
    resolution: tuple[GridCount, GridCount] = Field((32, 32), description="vertices along x and y")
    size: tuple[Positive, Positive] = Field((1.0, 1.0), description="side lengths along x and y (m)")
    height: Finite = Field(0.0, description="z of the flat grid (m)")

    def build(self) -> SimplexMesh:
        grid = GridModel(resolution=self.resolution, size=self.size, height=self.height).build()
        names = {**_face_names(grid.vertices), **grid.named_vertices}
        return SimplexMesh(grid.vertices, grid.triangles, names,
                           f"grid {self.resolution[0]}x{self.resolution[1]}").validate()


class MeshFile(BaseModel):
    """A volume mesh file (any format meshio reads: .msh, .vtk, .vtu, .mesh, ...) with tetra cells, or triangle cells
    of a 2-D solid (3-D files with a constant z are read as 2-D)."""

    model_config = ConfigDict(extra="forbid")
    file: Path = Field(description="path of the mesh file")

    def build(self) -> SimplexMesh:
        return read_mesh_file(self.file)


def read_mesh_file(path: Path, shell: bool = False) -> SimplexMesh:
    """The mesh of a file: its tetrahedra, or its triangles, as a 2-D solid where they lie flat in z (unless ``shell``:
    the config gives a thickness) and as a shell otherwise."""
    import meshio

    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: no such file")
    try:
        mesh = meshio.read(path)
    except Exception as error:  # meshio raises its own ReadError, KeyError, ValueError by format
        raise ModelError(f"{path}: meshio cannot read it ({type(error).__name__}: {error})") from None
    points = np.asarray(mesh.points, dtype=float)
    cells = {block.type: [] for block in mesh.cells}
    for block in mesh.cells:
        cells[block.type].append(np.asarray(block.data))
    if "tetra" in cells:
        elements = np.concatenate(cells["tetra"])
        vertices = points if points.shape[1] == 3 else np.column_stack([points, np.zeros(len(points))])
    elif "triangle" in cells:
        elements = np.concatenate(cells["triangle"])
        if shell:
            vertices = points if points.shape[1] == 3 else np.column_stack([points, np.zeros(len(points))])
        else:  # flat in z: a 2-D solid; any other surface in 3-D: a shell
            vertices = points[:, :2] if points.shape[1] == 2 or np.ptp(points[:, 2]) == 0 else points
    else:
        raise ModelError(f"{path}: no tetra or triangle cells (it has {', '.join(cells) or 'no cells'}): a solid "
                         "needs tetrahedra (3-D) or triangles (2-D), a shell triangles in 3-D")
    try:
        return SimplexMesh(vertices, elements.astype(np.intp), _face_names(vertices), str(path)).validate()
    except ModelError as error:
        raise ModelError(f"{path}: {error}") from None


class TetrahedralizedSurface(BaseModel):
    """A closed triangle surface (any model file that systems/vertex/model_files.py reads: OBJ, STL, PLY, ...) filled
    with tetrahedra of about ``edge_length`` by fTetWild, cached by the surface's sha256 (tetrahedralize.py)."""

    model_config = ConfigDict(extra="forbid")
    surface: Path = Field(description="a closed (watertight) triangle surface file")
    edge_length: float = Field(gt=0, allow_inf_nan=False, description="the tets' target edge length (m)")

    def build(self) -> SimplexMesh:
        from .tetrahedralize import tetrahedralize

        vertices, tets, cached = tetrahedralize(self.surface, self.edge_length)
        try:
            return SimplexMesh(vertices, tets, _face_names(vertices), f"{self.surface} tetrahedralized ({cached.name})"
                               ).validate()
        except ModelError as error:
            raise ModelError(f"{self.surface} tetrahedralized ({cached}): {error}") from None


# config key -> generator; a string is a file
MESH_SOURCES: dict[str, type[BaseModel]] = {"box": BoxMesh, "square": SquareMesh, "grid": GridMesh, "file": MeshFile,
                                            "tetrahedralize": TetrahedralizedSurface}


def mesh_source(value) -> BoxMesh | SquareMesh | GridMesh | MeshFile | TetrahedralizedSurface:
    """The source a config's ``model:`` names: a path, ``{file: path}``, ``{box: {...}}``, ``{square: {...}}``,
    ``{grid: {...}}`` or
    ``{tetrahedralize: {surface, edge_length}}``.
    Raises ValueError naming what is allowed."""
    if isinstance(value, tuple(MESH_SOURCES.values())):
        return value
    if isinstance(value, (str, Path)):
        return MeshFile(file=value)
    if isinstance(value, Mapping) and len(value) == 1:
        (key, fields), = value.items()
        if key == "file":
            return MeshFile(file=fields)
        if key in MESH_SOURCES:
            if fields is not None and not isinstance(fields, Mapping):
                raise ValueError(f"{key}: expected a mapping of its fields, got {fields!r}")
            return MESH_SOURCES[key].model_validate(dict(fields or {}))
    shown = "{" + ", ".join(f"{key!r}: ..." for key in value) + "}" if isinstance(value, Mapping) else repr(value)
    raise ValueError(f"expected a mesh file or one of {', '.join('{' + key + ': ...}' for key in MESH_SOURCES)}; got {shown}")
