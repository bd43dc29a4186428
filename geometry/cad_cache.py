"""On-disk cache of CAD tessellations, so a second run on a big STEP assembly starts at once.

Key: SHA-256 of the file's bytes (:func:`atomicio.digest.file_sha256`, as the overwrite guard) + chord
and angular tolerance + how the file is split (``whole`` / ``solids``) + the code version (a hash of the
source of the modules that read and tessellate CAD, and OpenCascade's version). Editing the file, asking another tolerance or
updating the code makes a new entry; nothing is ever served stale.

Where: ``$STRAYLIGHT_CACHE_DIR`` if set, else the user cache directory
(``platformdirs.user_cache_dir("straylight")``, e.g. ``~/.cache/straylight`` on Linux), in
``tessellation/``; a private temporary folder when neither can be written (a read-only HOME:
:mod:`atomicio.cache_dirs`). ``STRAYLIGHT_CACHE=off`` (or ``0``, ``no``) disables the cache (the test
suite does, except the tests of the cache). Entries are ``.npz`` files written atomically
(:mod:`atomicio`): a crash or a concurrent run never leaves a half-written entry, and an
unreadable or inconsistent entry (zip CRC, shapes, face indices, names) is reported with a
:class:`CacheWarning` and rewritten. Each entry carries the SHA-256 of its arrays and metadata
(:func:`entry_checksum`), checked on every load: an entry changed after it was written (by hand,
by a disk fault, or by another program) is never served.

An entry also holds what was checked on the cold run, so a cached load recomputes nothing:
each solid's chord-error report (:class:`~geometry.tessellate.TessellationReport`) and whether its
mesh is watertight (``meta["watertight"]``, the test of :attr:`geometry.mesh.Part.is_watertight`,
which ``straylight.scene`` reads instead of testing the edges again).
"""
from __future__ import annotations

import hashlib
import io
import json
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from atomicio.cache_dirs import ENV_SWITCH, enabled  # noqa: F401 - ENV_SWITCH: the switch this cache obeys
from atomicio.digest import file_sha256
from geometry.mesh import Part
from geometry.tessellate import TessellationReport

ENV_DIR = "STRAYLIGHT_CACHE_DIR"
_CODE_FILES = ("cad.py", "cad_cache.py", "cad_child.py", "tessellate.py", "mesh.py")


class CacheWarning(UserWarning):
    """A cache entry that could not be used (damaged, or from an incompatible writer): it is rebuilt."""


def cache_dir() -> Path:
    """The tessellation cache folder (atomicio.cache_dirs: $STRAYLIGHT_CACHE_DIR, else the user's
    cache folder, else a private temporary one)."""
    from atomicio.cache_dirs import cache_dir as project_cache_dir

    return project_cache_dir("tessellation")


def entry_checksum(arrays: dict, meta_text: str) -> str:
    """SHA-256 of an entry's arrays (name, dtype, shape and bytes, in name order) and its metadata text."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.data.cast("B") if a.size else b"")
    h.update(meta_text.encode())
    return h.hexdigest()


@lru_cache(maxsize=1)
def code_version() -> str:
    """Hash of the code that turns a CAD file into triangles (and OpenCascade's version)."""
    from importlib import metadata

    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in _CODE_FILES:
        h.update((here / name).read_bytes())
    for dist in ("cadquery-ocp", "cadquery_ocp"):
        try:
            h.update(metadata.version(dist).encode())
            break
        except metadata.PackageNotFoundError:
            continue
    return h.hexdigest()[:16]


def entry_path(path, *, tolerance_mm: float, angular_tolerance_deg: float, mode: str) -> Path:
    key = json.dumps([file_sha256(path), repr(float(tolerance_mm)), repr(float(angular_tolerance_deg)), mode,
                      code_version()])
    return cache_dir() / f"{Path(path).stem[:40]}-{hashlib.sha256(key.encode()).hexdigest()[:32]}.npz"


def load(entry: Path, warn: bool = True):
    """[(name, kind, label, Part-without-tags)] from a cache entry, or None if missing or unusable
    (a damaged or inconsistent entry also gives a :class:`CacheWarning` unless ``warn`` is False; the
    caller rebuilds it)."""
    if not entry.is_file():
        return None
    try:
        with np.load(entry, allow_pickle=False) as data:
            meta_text = str(data["meta"])
            arrays = {k: data[k] for k in data.files if k not in ("meta", "sha256")}
            if "sha256" not in data.files or str(data["sha256"]) != entry_checksum(arrays, meta_text):
                raise ValueError("checksum mismatch (changed after it was written)")
            meta = json.loads(meta_text)
            out = []
            for i, item in enumerate(meta["solids"]):
                report = TessellationReport(**item["report"])
                faces, brep = arrays[f"f{i}"], arrays[f"b{i}"]
                if brep.shape != (len(faces),) or not isinstance(item["watertight"], bool):
                    raise ValueError(f"solid {i} ({item['name']!r}): inconsistent arrays")
                part = Part(item["name"], arrays[f"v{i}"], faces, None, "surface",
                            {"tessellation": report, "kind": item["kind"], "brep_face": brep,
                             "watertight": item["watertight"], "cache": str(entry),
                             "aliases": list(item.get("aliases", []))})
                out.append((item["name"], item["kind"], item["label"], part))
            return out
    except Exception as exc:  # noqa: BLE001 - a damaged entry is a cache miss, not an error
        if not warn:
            return None
        warnings.warn(f"{entry}: damaged or incompatible tessellation cache entry, tessellating again "
                      f"({type(exc).__name__}: {exc})", CacheWarning, stacklevel=2)
        return None


def store(entry: Path, solids, strict: bool = False) -> None:
    """Write [(name, kind, label, Part)] atomically; failures (read-only disk...) are ignored unless ``strict``."""
    import atomicio

    arrays: dict[str, Any] = {}
    items = []
    for i, (name, kind, label, part) in enumerate(solids):
        arrays[f"v{i}"] = np.asarray(part.vertices_mm, dtype=np.float64)
        arrays[f"f{i}"] = np.asarray(part.faces, dtype=np.int64 if len(part.vertices_mm) >= 2**31 else np.int32)
        arrays[f"b{i}"] = np.asarray(part.meta.get("brep_face", np.zeros(part.n_triangles)), dtype=np.int32)
        report = part.meta["tessellation"]
        fields = {k: getattr(report, k) for k in TessellationReport.__dataclass_fields__}
        items.append({"name": name, "kind": kind, "label": label, "report": fields,
                      "watertight": bool(part.meta.get("watertight", part.is_watertight)),
                      "aliases": [str(a) for a in part.meta.get("aliases", [])]})
    meta_text = json.dumps({"solids": items})
    checksum = entry_checksum(arrays, meta_text)
    arrays["meta"] = np.array(meta_text)
    arrays["sha256"] = np.array(checksum)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        atomicio.write_bytes(entry, buffer.getvalue(), fsync=False)
    except OSError:
        if strict:
            raise
