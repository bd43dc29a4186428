"""Atomic file writes: readers see the old file or the new one, never a mix.

Used by every writer of results in the project (material files, scans, the rig's CSV,
CLI JSON outputs), so an interrupted run never leaves half a file behind.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path


def atomic_write_text(path, text: str, fsync: bool = True) -> Path:
    """Write ``text`` to ``path`` via a temp file in the same folder and ``os.replace``.

    ``fsync`` also forces the bytes to disk before the rename (survives a power cut).
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    directory.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
