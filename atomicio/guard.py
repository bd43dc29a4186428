"""Outputs checked before the work, and a user's files never overwritten.

:func:`check_output_file` / :func:`check_output_dir`: before a command starts its work, the place
it will write must be writable, and a file output must not be a folder, so a read-only folder or a
typo fails at once (not after an hour's trace). The check creates and removes a probe file where
the result will go, which is what the atomic writer will do (``os.access`` answers for the real
uid and ignores read-only mounts).

:func:`check_overwrite` / :func:`record_outputs`: commands that write a folder of files the user may
edit afterwards (``geometry build -o``, ``design vanes --out``, ``geometry scene -o``) record the
SHA-256 of every file they wrote in ``.straylight-outputs.json`` in that folder. A later run may
replace a file whose content is still what it recorded; a file it did not write, or one changed
since (a hand-edited ``scene.toml``), is refused in one line naming it, unless ``--force``. Files are
hashed by :func:`atomicio.digest.file_sha256`, as the tessellation cache hashes CAD files.
"""
from __future__ import annotations

import fnmatch
import json
import os
import secrets
from pathlib import Path

import atomicio
from atomicio.digest import file_matches, file_sha256

MANIFEST = ".straylight-outputs.json"


class OutputError(ValueError):
    """An output that cannot be written where it was asked."""


class OverwriteError(ValueError):
    """An output would replace a file the user wrote or changed."""


def _nearest_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe(directory: Path, what: str, target: Path) -> None:
    """Create and remove a file in ``directory`` (what the atomic writer will do), or OutputError."""
    if not directory.is_dir():
        raise OutputError(f"{target}: cannot write the {what}: {directory} is not a folder")
    probe = directory / f".straylight-probe.{secrets.token_hex(4)}.tmp"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise OutputError(f"{target}: cannot write the {what} in {directory} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(path, what: str = "output") -> Path:
    """``path`` can be written as a file: it is not a folder, and its folder (or the nearest existing
    ancestor, where the writer will create the rest) accepts a new file. Else one-line OutputError."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: the {what} is a folder; give a file name")
    _probe(_nearest_existing(path.parent if str(path.parent) else Path(".")), what, path)
    return path


def check_output_dir(path, what: str = "output folder") -> Path:
    """``path`` can be (created and) written as a folder; else one-line OutputError."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: the {what} is a file, not a folder")
    _probe(_nearest_existing(path), what, path)
    return path


def _manifest(directory: Path) -> dict:
    try:
        doc = json.loads((directory / MANIFEST).read_text(encoding="utf-8"))
        files = doc.get("files", {}) if isinstance(doc, dict) else {}
        return files if isinstance(files, dict) else {}
    except (OSError, ValueError):
        return {}


def _candidates(directory: Path, names, patterns) -> list[Path]:
    found = [directory / n for n in (names or ()) if (directory / n).is_file()]
    if patterns and directory.is_dir():
        for entry in sorted(directory.iterdir()):
            if entry.is_file() and entry.name != MANIFEST and any(fnmatch.fnmatch(entry.name, p) for p in patterns):
                if entry not in found:
                    found.append(entry)
    return found


def check_overwrite(directory, names=(), patterns=(), force: bool = False, flag: str = "--force") -> None:
    """Refuse (OverwriteError naming the first file) if an output would replace a file of
    ``directory`` (given by name, or matching a glob pattern) that this program did not write, or
    that changed since it wrote it (module doc); nothing with ``force``."""
    directory = Path(directory)
    if force or not directory.is_dir():
        return
    recorded = _manifest(directory)
    bad = []
    for path in _candidates(directory, names, patterns):
        sha = recorded.get(path.name)
        if sha is None:
            bad.append((path, "was not written by straylight"))
        elif not file_matches(path, sha):
            bad.append((path, "was changed since straylight wrote it"))
    if bad:
        path, why = bad[0]
        more = f" (and {len(bad) - 1} other file{'s' if len(bad) > 2 else ''})" if len(bad) > 1 else ""
        raise OverwriteError(f"{path}: {why}{more}; it would be overwritten: choose another output or pass {flag}")


def record_outputs(directory, names=(), patterns=(), since: float | None = None) -> None:
    """Record the SHA-256 of the outputs just written (by name or glob pattern) in the folder's
    manifest, so the next run may replace them while they are unchanged. ``since`` (a ``time.time()``):
    only files modified since then (what an interrupted run wrote before it stopped)."""
    directory = Path(directory)
    if not directory.is_dir():
        return
    files = _manifest(directory)
    for path in _candidates(directory, names, patterns):
        if since is not None and path.stat().st_mtime < since:
            continue
        files[path.name] = file_sha256(path)
    atomicio.write_json(directory / MANIFEST, {"files": files}, indent=1, sort_keys=True, fsync=False)
