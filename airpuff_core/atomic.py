"""Atomic file writes: a temporary file in the target's folder, then a rename.

A reader never sees a half-written file (``os.replace`` is atomic on POSIX), and a crash leaves at
most a stray temporary file, named ``.<name>.<random>.tmp``, which
:func:`remove_stale_temp_files` clears later (at the next start of the writer).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Callable

TEMP_SUFFIX = ".tmp"


def atomic_write(path: str | os.PathLike, write_function: Callable[[Path], object]) -> Path:
    """Create ``path`` atomically: ``write_function(temporary_path)`` writes the whole file to a
    temporary name in the same folder, which is then renamed to ``path``.  On any error the
    temporary file is removed and the error propagates; ``path`` is then untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    try:
        write_function(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def remove_stale_temp_files(folder: str | os.PathLike, older_than_s: float = 0.0) -> list[Path]:
    """Remove the temporary files of :func:`atomic_write` in ``folder`` (not recursive) last
    modified more than ``older_than_s`` seconds ago: left by a process killed while writing.
    Call it where no other process can be writing into ``folder`` (``older_than_s`` = 0), or with
    an age no write takes.  Returns the files removed."""
    removed = []
    limit = time.time() - older_than_s
    try:
        candidates = list(Path(folder).glob(f".*{TEMP_SUFFIX}"))
    except OSError:
        return removed
    for tmp in candidates:
        try:
            if tmp.is_file() and tmp.stat().st_mtime <= limit:
                tmp.unlink()
                removed.append(tmp)
        except FileNotFoundError:  # removed by someone else meanwhile
            pass
    return removed
