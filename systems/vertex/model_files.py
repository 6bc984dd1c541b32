"""Model files: ``.npz`` arrays, and triangle/quad meshes in any format meshio or trimesh reads, turned into a
SpringModel.

A ``.npz`` holds ``vertices`` (n x 2 or n x 3) and ``springs`` (m x 2 ints), optionally ``rest_lengths``,
``stiffness`` (m,), ``masses`` (n,), ``kinds`` (m ints, with an optional ``kind_names`` string array, or
m kind-name strings), ``triangles`` (t x 3 ints) and ``named_<name>`` index arrays (vertex sets a config may
pin by name). ``save_npz`` writes that format.

A mesh gives springs from its faces ("triangle" and "quad" cells; others are ignored), kinds
("stretch", "shear", "bend") whether or not each occurs:
- stretch: every face edge;
- shear: both diagonals of every quad;
- bend: across every interior edge shared by exactly two faces of the same type, the vertices across it:
  the two opposite vertices of two triangles; for two quads, each edge endpoint's neighbour off the edge in
  one quad with its neighbour in the other (on a grid: the springs that skip one vertex).
A pair met twice keeps its first kind in the order stretch, shear, bend; springs are in order of first
appearance, each as (smaller index, larger index).
"""

from __future__ import annotations

import contextlib
import io
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from .errors import ModelError
from .spring_model import SpringModel

MESH_KINDS = ("stretch", "shear", "bend")
NPZ_ARRAYS = ("vertices", "springs", "rest_lengths", "stiffness", "masses", "kinds", "kind_names", "triangles")
NAMED_PREFIX = "named_"
_REQUIRED = "a model file needs vertices (n x 2 or n x 3) and springs (m x 2)"


def load_model_file(path: Path, dimension: int | None = None) -> SpringModel:
    """The validated model in ``path`` (``.npz``, else a mesh through meshio).

    dimension: 2 drops a constant third coordinate (ModelError if it varies), 3 adds z = 0 to a 2-D model,
    None keeps the file's. Every problem is a ModelError whose message starts with the path.
    """
    path = Path(path)
    if dimension not in (None, 2, 3):
        raise ModelError(f"{path}: dimension must be 2, 3 or None, got {dimension!r}")
    if not path.is_file():
        raise ModelError(f"{path}: no such file")
    model = _read_npz(path) if path.suffix.lower() == ".npz" else _read_mesh(path)
    try:
        model.validate()
    except ModelError as error:
        raise ModelError(f"{path}: {error}") from None
    # a constant z dropped or z = 0 added leaves every spring length as it was: still valid
    return replace(model, vertices=_with_dimension(model.vertices, dimension, path))


def _with_dimension(vertices: np.ndarray, dimension: int | None, path: Path) -> np.ndarray:
    if dimension in (None, vertices.shape[1]):
        return vertices
    if dimension == 3:
        return np.column_stack([vertices, np.zeros(len(vertices))])
    z = vertices[:, 2]
    if np.ptp(z) != 0:
        raise ModelError(f"{path}: dimension 2 needs a planar model with constant z, but z ranges over "
                         f"[{z.min():g}, {z.max():g}]")
    return vertices[:, :2]


# -- .npz ------------------------------------------------------------------------------------------
def _read_npz(path: Path) -> SpringModel:
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except Exception as error:  # zipfile, pickle and format errors alike: the file is not a readable .npz
        raise ModelError(f"{path}: cannot read it as .npz ({type(error).__name__}: {error})") from None
    unknown = [name for name in arrays if name not in NPZ_ARRAYS and not name.startswith(NAMED_PREFIX)]
    if unknown:
        raise ModelError(f"{path} has an unknown array {unknown[0]!r}; allowed: {', '.join(NPZ_ARRAYS)}, "
                         f"{NAMED_PREFIX}<name>")
    for name in ("vertices", "springs"):
        if name not in arrays:
            raise ModelError(f"{path} has no array {name!r}; {_REQUIRED}")

    def numbers(name: str, integer: bool = False) -> np.ndarray | None:
        array = arrays.get(name)
        if array is None:
            return None
        allowed = "iu" if integer else "iuf"  # dtype kinds: signed, unsigned, float (no bool, complex, text)
        if array.dtype.kind not in allowed:
            raise ModelError(f"{path}: array {name!r} must hold {'integers' if integer else 'real numbers'}, "
                             f"got dtype {array.dtype}")
        return array.astype(np.intp if integer else float)

    vertices, springs = numbers("vertices"), numbers("springs", integer=True)
    kinds, kind_names = _npz_kinds(arrays, springs.shape[0] if springs.ndim else 0, path)
    named = {name[len(NAMED_PREFIX):]: numbers(name, integer=True).ravel()
             for name in arrays if name.startswith(NAMED_PREFIX)}
    for name, ids in named.items():
        if ids.size and (ids.min() < 0 or ids.max() >= len(vertices)):
            raise ModelError(f"{path}: array '{NAMED_PREFIX}{name}' must hold vertex indices in 0..{len(vertices) - 1}")
    return SpringModel(vertices, springs, kinds, kind_names, rest_lengths=numbers("rest_lengths"),
                       stiffness=numbers("stiffness"), masses=numbers("masses"),
                       triangles=numbers("triangles", integer=True), named_vertices=named, source=str(path))


def _npz_kinds(arrays: dict, spring_count: int, path: Path) -> tuple[np.ndarray, tuple[str, ...]]:
    """Kinds as indices into kind names, from int kinds (+ optional names) or per-spring name strings."""
    kinds, names = (arrays.get(name) for name in ("kinds", "kind_names"))
    kinds, names = (array.astype(str) if array is not None and array.dtype.kind == "S" else array
                    for array in (kinds, names))  # bytes strings read as text
    if names is not None and names.dtype.kind != "U":
        raise ModelError(f"{path}: array 'kind_names' must hold strings, got dtype {names.dtype}")
    names = None if names is None else tuple(str(name) for name in names.ravel())
    if kinds is None:
        return np.zeros(spring_count, dtype=np.intp), names or ("stretch",)
    if kinds.dtype.kind == "U":
        present, inverse = np.unique(kinds, return_inverse=True)
        if names is None:  # names in order of first appearance
            _, first = np.unique(kinds, return_index=True)
            names = tuple(str(present[i]) for i in np.argsort(first))
        missing = [str(name) for name in present if name not in names]
        if missing:
            raise ModelError(f"{path}: kind {missing[0]!r} is not in kind_names {list(names)}")
        position = np.array([names.index(str(name)) for name in present], dtype=np.intp)
        return position[inverse.ravel()].reshape(kinds.shape), names
    if not np.issubdtype(kinds.dtype, np.integer):
        raise ModelError(f"{path}: array 'kinds' must hold integers or kind names, got dtype {kinds.dtype}")
    kinds = kinds.astype(np.intp)
    if names is None:
        highest = int(kinds.max()) if kinds.size else 0
        if highest >= max(spring_count, 1):  # more kinds than springs: a mistake, and names kind_0.. would be many
            raise ModelError(f"{path}: kinds go up to {highest} for {spring_count} springs; give kind_names")
        names = tuple(f"kind_{k}" for k in range(highest + 1))
    return kinds, names


def save_npz(model: SpringModel, path: Path) -> None:
    """Write ``model`` in the ``.npz`` format ``load_model_file`` reads (kinds as ints plus kind_names).

    The same model gives the same bytes: unlike ``np.savez``, the archive's entries carry a fixed date.
    """
    arrays = {"vertices": model.vertices, "springs": model.springs, "kinds": model.kinds,
              "kind_names": np.array(model.kind_names)}
    optional = {"rest_lengths": model.rest_lengths, "stiffness": model.stiffness, "masses": model.masses,
                "triangles": model.triangles}
    arrays.update({name: array for name, array in optional.items() if array is not None})
    arrays.update({NAMED_PREFIX + name: ids for name, ids in model.named_vertices.items()})
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, array in arrays.items():
            buffer = io.BytesIO()
            np.save(buffer, np.asarray(array), allow_pickle=False)
            entry = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            archive.writestr(entry, buffer.getvalue(), compress_type=zipfile.ZIP_DEFLATED)


# -- meshes ----------------------------------------------------------------------------------------
# The mesh libraries, in the order they are asked: meshio keeps quads and polygons as the file has them; trimesh
# reads what meshio refuses in the files common tools write (an OBJ whose texture-coordinate or normal count differs
# from its vertex count, which is almost every textured export; a PLY with per-face colours; an ASCII STL), as
# triangles, in the file's vertex order (process=False, maintain_order=True).
def _read_mesh(path: Path) -> SpringModel:
    reasons = []
    for reader in (_meshio_faces, _trimesh_faces):
        try:
            points, triangles, quads = reader(path)
        except _NoFaces as error:  # read, but nothing to make springs of: no other reader will find faces
            raise ModelError(f"{path} has {error}") from None
        except ModelError as error:
            reasons.append(str(error))
            continue
        return _mesh_model(path, points, triangles, quads)
    raise ModelError(f"{path}: cannot read it as a mesh ({'; '.join(reasons)})")


class _NoFaces(ModelError):
    """A mesh file read whole, without a triangle or quad."""


def _meshio_faces(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, triangles, quads) through meshio; polygons of more than four corners are fanned into triangles."""
    import meshio  # only mesh files need it

    chatter = io.StringIO()
    try:
        # some of meshio's parsers print their complaint and call sys.exit (the PLY reader on a file that
        # is not PLY): caught, and their output kept for the message, so that a bad file is one line
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its STL reader's size test overflows on other files
            mesh = meshio.read(path)
    except (Exception, SystemExit) as error:  # meshio's parsers raise ReadError, KeyError, ValueError, IndexError, ...
        said = " ".join(chatter.getvalue().split()) or f"{type(error).__name__}: {error}"
        raise ModelError(f"meshio: {said}") from None
    points = np.asarray(mesh.points, dtype=float)
    blocks = {kind: [block.data for block in mesh.cells if block.type == kind] for kind in ("triangle", "quad", "polygon")}
    polygons = [_fan(np.asarray(block, dtype=np.intp)) for block in blocks["polygon"]]
    triangles = np.concatenate([*blocks["triangle"], *polygons]).astype(np.intp) if blocks["triangle"] or polygons \
        else np.zeros((0, 3), np.intp)
    quads = np.concatenate(blocks["quad"]).astype(np.intp) if blocks["quad"] else np.zeros((0, 4), np.intp)
    if len(triangles) + len(quads) == 0:
        found = sorted({block.type for block in mesh.cells if len(block.data)}) or ["none"]
        raise _NoFaces(f"no triangles or quads (cells: {', '.join(found)})")
    faces = np.concatenate([triangles.ravel(), quads.ravel()])
    if faces.min() < 0 or faces.max() >= len(points):  # meshio reads OBJ's relative (negative) indices as absolute
        raise ModelError(f"meshio: face indices outside 0..{len(points) - 1}")
    return points, triangles, quads


def _trimesh_faces(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, triangles, no quads) through trimesh, every vertex of the file kept in its order; an STL, which
    stores each triangle's corners apart, has its coincident corners merged."""
    import trimesh  # only the files meshio refuses need it

    merge = path.suffix.lower() == ".stl"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its numpy on texture coordinates (an all-NaN slice) is not ours to say
            mesh = trimesh.load(path, force="mesh", process=merge, maintain_order=not merge, skip_materials=True)
    except Exception as error:  # trimesh's loaders raise ValueError, IndexError, KeyError, ...
        raise ModelError(f"trimesh: {type(error).__name__}: {error}") from None
    if len(mesh.faces) == 0:
        raise ModelError("trimesh: no faces")
    points = np.asarray(mesh.vertices, dtype=float)
    if path.suffix.lower() == ".obj":
        points = _with_trailing_obj_vertices(path, points)
    return points, np.asarray(mesh.faces, dtype=np.intp), np.zeros((0, 4), np.intp)


def _with_trailing_obj_vertices(path: Path, points: np.ndarray) -> np.ndarray:
    """``points`` (trimesh's vertices of an OBJ, in the file's order) with the file's vertices after the last one a
    face uses, which trimesh leaves out of a textured OBJ: a scan's unused vertices keep their numbers. The file's
    ``v`` lines (x y z, then optional w or colour) are the only part read here; the faces are trimesh's."""
    with path.open("rb") as file:
        lines = [line for line in file if line.startswith(b"v ")]
    if len(lines) <= len(points):
        return points
    try:
        extra = np.array([line.split()[1:4] for line in lines[len(points):]], dtype=float)
    except ValueError:
        raise ModelError(f"trimesh: {path.name} has vertex lines that are not x y z") from None
    return np.concatenate([points, extra.reshape(-1, 3)])


def _fan(polygons: np.ndarray) -> np.ndarray:
    """(p * (k - 2), 3) triangles of p polygons of k corners each: a fan from each polygon's first corner."""
    k = polygons.shape[1]
    return np.stack([np.repeat(polygons[:, :1], k - 2, axis=1), polygons[:, 1:-1], polygons[:, 2:]], axis=-1).reshape(-1, 3)


def _mesh_model(path: Path, points: np.ndarray, triangles: np.ndarray, quads: np.ndarray) -> SpringModel:
    """The model of a mesh: springs from its faces (``mesh_springs``). A scanned mesh's degenerate triangles (zero
    area: a repeated, coincident or collinear corner) make no spring of zero length (coincident vertices are not
    joined) and are left out of the surface, so that they count no area; the assembler gives a vertex that touches
    only such faces its mass from its neighbours."""
    springs, kinds = mesh_springs(triangles, quads)
    length = np.linalg.norm(points[springs[:, 0]] - points[springs[:, 1]], axis=1)
    springs, kinds = springs[length > 0.0], kinds[length > 0.0]
    split = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]) if len(quads) else quads[:, :3]
    surface = np.concatenate([triangles, split])
    degenerate = ~(_triangle_areas(points, surface) > 0.0)
    return SpringModel(points, springs, kinds, MESH_KINDS, triangles=surface[~degenerate], source=str(path),
                       degenerate_triangles=int(np.count_nonzero(degenerate)))


def _triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(t,) area (m^2) of each triangle, in 2-D or 3-D."""
    first, second, third = (vertices[triangles[:, corner]] for corner in range(3))
    if vertices.shape[1] == 2:  # the cross product's z component (np.cross of 2-vectors is deprecated)
        u, w = second - first, third - first
        return 0.5 * np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
    return 0.5 * np.linalg.norm(np.cross(second - first, third - first), axis=1)


def mesh_springs(triangles: np.ndarray, quads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Springs (m, 2) and kinds (m,) into MESH_KINDS of a mesh of triangles (t, 3) and quads (q, 4)."""
    stretch = np.concatenate([_half_edges(triangles)[0], _half_edges(quads)[0]])
    shear = np.concatenate([quads[:, [0, 2]], quads[:, [1, 3]]])
    bend = np.concatenate([_bend_pairs(*_half_edges(triangles)), _bend_pairs(*_half_edges(quads))])
    candidates = np.sort(np.concatenate([stretch, shear, bend]), axis=1)
    kinds = np.repeat(np.arange(3), [len(stretch), len(shear), len(bend)])
    keep = candidates[:, 0] != candidates[:, 1]  # a degenerate face joins a vertex to itself
    candidates, kinds = candidates[keep], kinds[keep]
    _, first = np.unique(candidates, axis=0, return_index=True)
    first = np.sort(first)  # first occurrence wins: stretch before shear before bend
    return candidates[first].astype(np.intp), kinds[first].astype(np.intp)


def _half_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each face's edges (f * k, 2), (p, r) = (face[i], face[i + 1]), and beside each edge the neighbours off
    the edge (f * k, 2): of p, face[i - 1]; of r, face[i + 2] (for a triangle both are the opposite vertex)."""
    k = faces.shape[1]
    corner = np.arange(k)
    edges = np.stack([faces[:, corner], faces[:, (corner + 1) % k]], axis=-1).reshape(-1, 2)
    across = np.stack([faces[:, (corner - 1) % k], faces[:, (corner + 2) % k]], axis=-1).reshape(-1, 2)
    return edges, across


def _bend_pairs(edges: np.ndarray, across: np.ndarray) -> np.ndarray:
    """Bend springs across every edge shared by exactly two faces: each endpoint's neighbour in one face joined
    to the same endpoint's neighbour in the other (for triangles both give the opposite vertices)."""
    flipped = edges[:, 0] > edges[:, 1]  # orient every edge low -> high, its neighbours with it
    edges = np.where(flipped[:, None], edges[:, ::-1], edges)
    across = np.where(flipped[:, None], across[:, ::-1], across)
    _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    shared = counts[inverse] == 2  # an edge of more than two faces (non-manifold) gets no bend springs
    order = np.flatnonzero(shared)[np.argsort(inverse[shared], kind="stable")]
    one, other = across[order[0::2]], across[order[1::2]]
    return np.concatenate([np.stack([one[:, 0], other[:, 0]], axis=1), np.stack([one[:, 1], other[:, 1]], axis=1)])


def lumped_area_masses(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n,) area (m^2) lumped to the vertices: a third of each triangle's area to each of its corners.

    vertices: (n, 2) or (n, 3) (m); triangles: (t, 3) vertex indices. Multiply by an areal density (kg/m^2),
    or scale to a total mass, for the vertex masses.
    """
    vertices = np.asarray(vertices, dtype=float)
    triangles = np.asarray(triangles, dtype=np.intp)
    area = _triangle_areas(vertices, triangles)
    return np.bincount(triangles.ravel(), weights=np.repeat(area / 3, 3), minlength=len(vertices))
