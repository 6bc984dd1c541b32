"""numba's on-disk cache kept in step with every source it was compiled from.

numba keys a cached function by its own file's time stamp and size only, so a kernel that calls compiled functions of
another module keeps its cached machine code when only that other module changes: after an edit of
contact/point_kernels.py alone, the cached VBD sweeps (mass_spring/vbd_kernels.py) ran the old collider code and
landed elsewhere than the numpy sweep. A `git pull` into an editable install would do the same to a user.

Every module with cached kernels calls ``keep_fresh(globals())`` after its last kernel. The digest of the sources of
all of simrun's modules with cached kernels is recorded next to the module's cache files; where it differs (or is
missing), those cache files are removed first, and numba compiles the module's kernels again at their first call.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

# the folders whose modules hold compiled kernels; a module counts where its source asks numba for a cache
COMPILED_FOLDERS = ("systems", "solvers", "integrators")
CACHE_MARK = "cache=True"


@functools.cache
def sources_digest(root: Path = Path(__file__).resolve().parent.parent) -> str:
    """SHA-256 over the paths and texts of the modules under ``root``'s COMPILED_FOLDERS that ask numba for a cache."""
    digest = hashlib.sha256()
    for folder in COMPILED_FOLDERS:
        for path in sorted((root / folder).rglob("*.py")):
            text = path.read_bytes()
            if CACHE_MARK.encode() in text:
                digest.update(str(path.relative_to(root)).encode() + b"\0" + text + b"\0")
    return digest.hexdigest()


def keep_fresh(namespace: dict) -> None:
    """Remove the cache files of the module whose globals are ``namespace`` where they were compiled from other sources
    than the present ones (see the module docstring). Quiet where the cache folder cannot be written: numba then
    caches nothing there either."""
    module = namespace["__name__"]
    cached = [value for value in namespace.values()
              if getattr(getattr(value, "py_func", None), "__module__", None) == module
              and hasattr(getattr(value, "_cache", None), "_cache_path")]
    if not cached:
        return
    folder = Path(cached[0]._cache._cache_path)
    stem = Path(namespace["__file__"]).stem
    stamp = folder / f"{stem}.simrun-sources"
    digest = sources_digest()
    try:
        if stamp.read_text() == digest:
            return
    except OSError:
        pass  # none yet: compiled before this check existed, or never
    try:
        for path in folder.glob(f"{stem}.*.nb[ic]"):
            path.unlink(missing_ok=True)
        folder.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass  # the folder cannot be written: numba cannot cache there either
