"""One writer per folder: an exclusive lock on a file in it, held for the life of a process.

``fcntl.flock`` locks belong to the open file: the operating system releases them when the process
ends, however it ends (a crash or a kill leaves no stale lock behind).  The file keeps the pid of
its holder, for the message of the process it refuses.  Used by `airpuff sweep` on its ``--out``
folder, so two runs into one folder cannot compute the same points twice or write ``sweep.nc``
and ``sweep.json`` of different sweeps.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import IO


class FolderLocked(RuntimeError):
    """Another process holds the lock; ``holder`` is its pid as it wrote it ("" if unknown)."""

    def __init__(self, path: Path, holder: str):
        self.path, self.holder = path, holder
        super().__init__(f"{path} is held by another process"
                         + (f" (pid {holder})" if holder else ""))


def hold_folder_lock(folder: str | os.PathLike, name: str) -> IO[str]:
    """Lock ``folder/name`` (the folder is created if needed) and return the open file: the lock
    lasts while the file stays open (keep a reference; ``close()`` releases it).  Raises
    FolderLocked at once if another process holds it."""
    path = Path(folder) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = open(path, "a+")
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip()[:20]
        fh.close()
        raise FolderLocked(path, holder) from None
    fh.seek(0)
    fh.truncate()
    fh.write(f"{os.getpid()}\n")
    fh.flush()
    return fh
