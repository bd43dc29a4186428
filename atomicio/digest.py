"""SHA-256 of a file's bytes: the project's one file hash.

Used wherever a file's content is recorded and checked later: the tessellation cache's keys
(:mod:`geometry.cad_cache`: a CAD file edited since is a new entry), the overwrite guard's manifest
(:mod:`atomicio.guard`: an output changed since straylight wrote it is refused) and numba's cache
keys (:mod:`materials.jit_cache`). Read in 1 MiB blocks, so a multi-GB STEP assembly is hashed in
constant memory.
"""
from __future__ import annotations

import hashlib

BLOCK_BYTES = 1 << 20


def file_sha256(path) -> str:
    """Hex SHA-256 of the bytes of the file at ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(BLOCK_BYTES), b""):
            h.update(block)
    return h.hexdigest()


def file_matches(path, sha256: str) -> bool:
    """Whether the file at ``path`` still holds the content whose :func:`file_sha256` was ``sha256``."""
    return file_sha256(path) == sha256
