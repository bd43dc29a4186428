"""Which output files straylight itself wrote, so that a rerun may replace them without ``--force``
(docs/reference/commands.md, "Outputs").

An existing output file is replaced without ``--force`` only when it is empty, or when this user's
straylight wrote it and nobody changed it since: one small record per file under the private cache folder
(``written-outputs/<sha1 of the real path>``) holds its device, inode, size and modification time at the end
of the run that wrote it. A user's own file (a measured scan, a hand-written material, a scene) never has
such a record, and one edited after the run no longer matches it. Records are written atomically, one file
each, so concurrent runs never lose one another's.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path


def _record_path(path) -> Path:
    from atomicio.cache_dirs import cache_dir

    real = os.path.realpath(os.fspath(path))
    return cache_dir("written-outputs") / hashlib.sha1(real.encode("utf-8", "surrogateescape")).hexdigest()


def _signature(st) -> list:
    return [int(st.st_dev), int(st.st_ino), int(st.st_size), int(st.st_mtime_ns)]


def remember(path) -> None:
    """Record that this run wrote the regular file ``path`` (best effort: a record that cannot be written only
    means the next run asks for ``--force``)."""
    import atomicio

    try:
        st = os.stat(path)
        rec = _record_path(path)
        rec.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        atomicio.write_text(rec, json.dumps(_signature(st)))
    except OSError:
        pass


def replaceable(path) -> bool:
    """Whether the existing file ``path`` may be replaced without ``--force``: empty, or written by straylight
    and unchanged since."""
    try:
        st = os.stat(path)
    except OSError:
        return True
    if st.st_size == 0:
        return True
    try:
        return json.loads(_record_path(path).read_text()) == _signature(st)
    except (OSError, ValueError):
        return False
