"""One simrun at a time per output folder: an advisory lock on OUTPUT/.simrun.lock.

The operating system releases the lock when the holder dies, even by kill -9, so a stale lock file
never blocks a later run.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from simrun.errors import OutputLocked

LOCK_NAME = ".simrun.lock"


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
