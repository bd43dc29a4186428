"""Atomic file writes for materials (the project's one helper lives in :mod:`atomicio`)."""
from __future__ import annotations

from atomicio import atomic_open, json_safe, write_bytes, write_json, write_text

__all__ = ["atomic_write_text", "atomic_open", "json_safe", "write_bytes", "write_json", "write_text"]


def atomic_write_text(path, text: str, fsync: bool = True):
    """Write ``text`` to ``path`` atomically, with the user's umask, fsyncing file then folder
    (:func:`atomicio.write_text`)."""
    return write_text(path, text, fsync=fsync)
