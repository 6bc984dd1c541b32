"""The output folder: whether simrun may write there, one simrun at a time, and writes that leave nothing half-written.

One simrun at a time per output folder: an advisory lock on OUTPUT/.simrun.lock. The operating system
releases the lock when the holder dies, even by kill -9, so a stale lock file never blocks a later run.

Light (no numpy, no h5py): the command line checks its output paths with it before any heavy import.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from simrun.errors import ConfigError, OutputLocked

LOCK_NAME = ".simrun.lock"
# what is drawn from the results file beside it (simrun.format.layout.RESULTS_NAME): `simrun plot`'s and the run's
# figures, `simrun report`'s page; --force removes both with the old results
FIGURES_NAME = "figures"
REPORT_NAME = "report.html"
PARTIAL_PREFIX = ".simrun-partial-"  # temporary files and folders of a write that has not finished


class OutputLock:
    def __init__(self, folder: Path):
        self.path = Path(folder) / LOCK_NAME
        self.handle = None

    def __enter__(self) -> "OutputLock":
        handle = open(self.path, "a+")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise OutputLocked(f"output: another simrun (pid {holder}) is writing to {str(self.path.parent)!r}; "
                               "wait for it, or choose another --output") from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        self.handle = handle
        return self

    def __exit__(self, *exc) -> None:
        if self.handle is not None:
            fcntl.flock(self.handle, fcntl.LOCK_UN)
            self.handle.close()
            self.handle = None


# -- before any work: may we write there? -------------------------------------------------------------
def existing_ancestor(path: Path) -> Path:
    """``path`` itself if it exists, else its nearest parent that does."""
    path = Path(path)
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable(output: Path, field: str = "output", *, kind: str = "folder") -> None:
    """Refuse an output we cannot write before any work starts (and before creating anything).

    output: a folder to write into (``kind="folder"``) or a file to write (``kind="file"``); what does
    not exist yet must be creatable, i.e. its nearest existing parent is a folder we can write in.
    Raises ConfigError ``field: ...``."""
    output = Path(output)
    if kind == "file":
        if output.is_dir():
            raise ConfigError(f"{field}: {str(output)!r} is a folder; give a file name")
        output = output.parent
    elif output.exists() and not output.is_dir():
        raise ConfigError(f"{field}: {str(output)!r} is a file, not a folder")
    existing = existing_ancestor(output)
    if not existing.is_dir():
        raise ConfigError(f"{field}: {str(existing)!r} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError:
        raise ConfigError(f"{field}: cannot write in {str(existing)!r}; choose another {_option(field)}") from None


def _option(field: str) -> str:
    return field if field.startswith("-") else "--output"


def write_error(field: str, target: Path, error: OSError) -> ConfigError:
    """An OSError while writing (disk full, permission) as one line naming the path."""
    reason = error.strerror or str(error) or error.__class__.__name__
    return ConfigError(f"{field}: cannot write {str(target)!r}: {reason}")


# -- while writing: a reader never sees half a file ---------------------------------------------------
@contextlib.contextmanager
def replacing(target: Path, field: str = "--output") -> Iterator[Path]:
    """Yield a temporary path beside ``target`` (same suffix) to write; it replaces ``target`` at once
    when the block ends, and is removed when the block fails. An OSError becomes ``field: cannot write
    'target': reason``; the folders made for ``target`` are removed again with a failed write."""
    target = Path(target)
    made = _make_folders(target.parent, field, target)
    temporary = None
    done = False
    try:
        # not created here (mkstemp would make it private): the writer creates it with the usual permissions;
        # the suffix stays, as some writers pick the format by it
        temporary = target.parent / f"{PARTIAL_PREFIX}{target.stem}.{secrets.token_hex(4)}{target.suffix}"
        yield temporary
        os.replace(temporary, target)
        done = True
    except OSError as error:
        raise write_error(field, target, error) from None
    finally:
        if not done:
            if temporary is not None:
                with contextlib.suppress(OSError):
                    temporary.unlink(missing_ok=True)
            _remove_made(made)


@contextlib.contextmanager
def filling(folder: Path, field: str = "--output") -> Iterator[Path]:
    """Yield an empty temporary folder; when the block ends its files move into ``folder`` (made if
    needed), each replacing its namesake at once; when the block fails it is removed with everything
    in it. An OSError becomes ``field: cannot write 'folder': reason``."""
    folder = Path(folder)
    temporary = None
    made: list[Path] = []
    try:
        temporary = Path(tempfile.mkdtemp(dir=existing_ancestor(folder), prefix=PARTIAL_PREFIX))
        yield temporary
        made = _make_folders(folder, field, folder)
        for path in sorted(temporary.iterdir()):
            os.replace(path, folder / path.name)
        made = []
    except OSError as error:
        raise write_error(field, folder, error) from None
    finally:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)
        _remove_made(made)


def _make_folders(folder: Path, field: str, target: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; returns those created, innermost first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    try:
        for path in reversed(missing):
            path.mkdir()
    except OSError as error:
        _remove_made(missing)
        raise write_error(field, target, error) from None
    return missing


def _remove_made(folders: list[Path]) -> None:
    for path in folders:  # innermost first; a folder that is not empty (another writer's) stays
        with contextlib.suppress(OSError):
            path.rmdir()
