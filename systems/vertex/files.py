"""Where the files a config names are found (beside the config, then in the current folder) and their digests, for
every system that reads files: model files, start positions, colliders' meshes and distance grids."""

from __future__ import annotations

import contextvars
import hashlib
from pathlib import Path

from .errors import ModelError

# Folders where relative model paths are looked for after the current one: the config file's folder, set by
# the config loader while it validates a config read from a file (runner/experiment/config.py: load_experiment).
SEARCH_FOLDERS: contextvars.ContextVar[tuple[Path, ...]] = contextvars.ContextVar("model_search_folders", default=())


def find_file(name: str, field: str) -> Path:
    """The absolute path of a model file: as given if absolute, else relative to the config's folder, else to
    the current folder; ModelError naming the field and where it looked."""
    path = Path(name).expanduser()
    folders = [] if path.is_absolute() else [*SEARCH_FOLDERS.get(), Path.cwd()]
    candidates = [path] if path.is_absolute() else list(dict.fromkeys((folder / path).resolve() for folder in folders))
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    looked = ", ".join(dict.fromkeys(str(candidate.parent) for candidate in candidates))
    raise ModelError(f"{field}: file {name!r} not found (looked in {looked})")


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes: a changed model file is a changed experiment (config hash, resume)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()
