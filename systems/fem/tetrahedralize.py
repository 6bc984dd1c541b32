"""A closed surface filled with tetrahedra by fTetWild (pytetwild, MPL-2.0), cached by the surface's sha256.

fTetWild does not give the same mesh twice for the same input (measured on an icosphere: 327 to 338 vertices over
three calls, one thread or many), so the first mesh made for a surface and an edge length is kept, and every later
run, worker and resume reads that one: the cache makes the mesh a function of its input. The cache is the folder
``$SIMRUN_CACHE/tetrahedralize`` (default ``~/.cache/simrun/tetrahedralize``); each entry is an ``.npz`` named by
the sha256 of the surface file's bytes, the edge length and pytetwild's version. Its own sha256 enters the
experiment's input digests, so a results file says which mesh it was made with.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

from ..vertex.errors import ModelError
from ..vertex.model_files import load_model_file

CACHE_VARIABLE = "SIMRUN_CACHE"


def cache_folder() -> Path:
    root = os.environ.get(CACHE_VARIABLE)
    return (Path(root).expanduser() if root else Path.home() / ".cache" / "simrun") / "tetrahedralize"


def _pytetwild():
    """pytetwild, imported. Its package imports pyvista for an optional accessor (``pytetwild._accessor``, which is a
    no-op on a pyvista without ``register_dataset_accessor``) though its metadata requires numpy alone; where pyvista
    is not installed, a bare module stands in for it during the import and is taken away again."""
    try:
        import pytetwild
        return pytetwild
    except ModuleNotFoundError as error:
        if error.name != "pyvista":
            raise ModelError("model: tetrahedralize needs pytetwild (pip install pytetwild)") from None
    sys.modules["pyvista"] = types.ModuleType("pyvista")
    try:
        import pytetwild
    finally:
        del sys.modules["pyvista"]
    return pytetwild


def closed_surface(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3), triangles (t, 3)) of a surface file; ModelError unless every edge has exactly two triangles."""
    model = load_model_file(path, 3)
    triangles = model.triangles
    if triangles is None or len(triangles) < 4:
        raise ModelError(f"{path}: no closed triangle surface (it has {0 if triangles is None else len(triangles)} triangles)")
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    open_edges = unique[counts != 2]
    if open_edges.size:
        first = open_edges[0].tolist()
        raise ModelError(f"{path}: the surface is not closed: {len(open_edges)} edges do not have exactly two triangles "
                         f"(the first: vertices {first}); tetrahedralize needs a watertight surface")
    return model.vertices.astype(float), triangles.astype(np.int32)


def cache_key(path: Path, edge_length: float) -> str:
    digest = hashlib.sha256(Path(path).read_bytes())
    digest.update(f"edge_length={edge_length!r};pytetwild={_version()}".encode())
    return digest.hexdigest()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pytetwild")
    except PackageNotFoundError:
        return "missing"


def cached_path(path: Path, edge_length: float) -> Path:
    return cache_folder() / f"{Path(path).stem}-{cache_key(path, edge_length)[:24]}.npz"


def tetrahedralize(path: Path, edge_length: float) -> tuple[np.ndarray, np.ndarray, Path]:
    """(vertices (n, 3), tets (t, 4), the cache file) of the closed surface in ``path`` filled with tets of about
    ``edge_length`` (m): from the cache where it holds them, else made by fTetWild and stored there."""
    cached = cached_path(path, edge_length)
    if cached.is_file():
        with np.load(cached, allow_pickle=False) as arrays:
            return arrays["vertices"], arrays["tets"], cached
    vertices, triangles = closed_surface(path)
    pytetwild = _pytetwild()
    with tempfile.TemporaryDirectory() as scratch, contextlib.chdir(scratch):  # fTetWild writes a file into the cwd
        points, tets = pytetwild.tetrahedralize(vertices, triangles, edge_length_abs=float(edge_length), quiet=True)
    points, tets = np.asarray(points, dtype=float), np.asarray(tets, dtype=np.intp)
    if not len(tets):
        raise ModelError(f"{path}: fTetWild made no tetrahedra at edge_length {edge_length:g} m (smaller than the "
                         "surface?)")
    cached.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=cached.parent, suffix=".npz", delete=False) as stream:  # whole or not at all
        np.savez(stream, vertices=points, tets=tets)
    try:
        os.link(stream.name, cached)  # only where no other process stored its mesh first: then that one is the mesh
    except FileExistsError:
        with np.load(cached, allow_pickle=False) as arrays:
            points, tets = arrays["vertices"], arrays["tets"]
    finally:
        os.unlink(stream.name)
    return points, tets, cached
