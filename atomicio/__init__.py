"""Atomic file writes: readers see the old file or the new one, never a mix.

The one writer every result file of the project goes through (scans, material files, CLI
JSON, reports, figures, meshes). It sits below every other package (materials, geometry,
straylight and rig may all import it; it imports none of them).

How a file is written (the POSIX recipe for a durable replace, cf. ``rename(2)`` and
LWN "Ensuring data reaches disk"):

1. a temp file ``.NAME.<random>.tmp`` is created in the target's folder with
   ``open(O_CREAT | O_EXCL, 0o666)``, so the kernel applies the user's umask exactly as for
   any other program (0644 under umask 022; ``tempfile.mkstemp`` would give 0600). When the
   target already exists its permission bits are kept;
2. the data are written, flushed and ``fsync``-ed (the file);
3. ``os.replace`` moves it over the target (atomic on POSIX and Windows);
4. the folder is ``fsync``-ed, so the rename itself survives a power cut.

Logs that grow as a run goes (a scan's CSV rows as they are measured, its bluesky document log)
are appended, not replaced: :func:`append_text` and :func:`append_json_line` write whole lines in
one ``write``, then flush and fsync, so every earlier line survives a crash.

JSON goes through :func:`dumps_json` / :func:`write_json` / :func:`append_json_line` only
(``tests/test_result_writers.py`` checks that no other module writes a result file by hand). Every
JSON file is strict JSON (RFC 8259, CONTRACTS 1): a number that is not finite is written as ``null``,
never ``NaN`` / ``Infinity``, so browsers, ``jq`` and other languages read it. Their options keep each
file's established bytes: ``indent``, ``sort_keys``, ``final_newline``. (``allow_nan`` is still
accepted for callers written before JSON was strict, and ignored: there is no non-strict output.)
Readers of the project's own older files keep accepting ``NaN`` (Python's ``json.loads`` does).

The reading side (:mod:`atomicio.inputs`): every file a user names is checked to be a regular
file of sane size before it is read, and read without blocking (``/dev/zero`` or a FIFO in a
scene is a one-line error, not a hang).

``fsync=False`` skips steps 2's and 4's fsync (fast, still atomic against crashes of the
process, not of the machine).
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import secrets
import stat
import typing
from pathlib import Path

__all__ = ["write_text", "write_bytes", "write_json", "dumps_json", "json_safe", "atomic_open", "write_figure",
           "append_text", "append_json_line"]


def _fsync_directory(directory: Path) -> None:
    """fsync a folder so a rename in it is durable (no-op where folders cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # Windows: folders cannot be opened; NTFS journals the rename
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems (e.g. certain network mounts) refuse fsync on a folder
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", *, fsync: bool = True, encoding: str = "utf-8", newline: str | None = ""):
    """Context manager yielding a file object; on a clean exit it replaces ``path`` atomically.

    ``mode`` is ``"w"`` (text) or ``"wb"`` (bytes). On an exception the temp file is removed
    and ``path`` is untouched.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', not {mode!r}")
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    directory.mkdir(parents=True, exist_ok=True)
    try:
        keep_mode = stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        keep_mode = None
    tmp = directory / f".{path.name}.{secrets.token_hex(4)}.tmp"
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    fd = os.open(tmp, flags, 0o666)  # the kernel applies the umask
    try:
        if keep_mode is not None:
            os.chmod(tmp, keep_mode)
        fh: typing.IO
        if mode == "wb":
            fh = os.fdopen(fd, "wb")
        else:
            fh = os.fdopen(fd, "w", encoding=encoding, newline=newline)
        with fh:
            yield fh
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if fsync:
        _fsync_directory(directory)


def write_text(path, text: str, *, fsync: bool = True, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (module doc); returns the path."""
    with atomic_open(path, "w", fsync=fsync, encoding=encoding) as fh:
        fh.write(text)
    return Path(path)


def write_bytes(path, data: bytes, *, fsync: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (module doc); returns the path."""
    with atomic_open(path, "wb", fsync=fsync) as fh:
        fh.write(data)
    return Path(path)


def json_safe(obj, *, nan_as_null: bool = True):
    """``obj`` made JSON-clean, recursively: numpy scalars/arrays to Python, tuples/sets to lists,
    Paths to strings, NaN and +-inf to ``None`` (strict JSON has no NaN; kept as floats with
    ``nan_as_null=False``), any other object to its ``str``. The project's one JSON sanitiser."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v, nan_as_null=nan_as_null) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [json_safe(v, nan_as_null=nan_as_null) for v in obj]
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return obj if math.isfinite(obj) or not nan_as_null else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    tolist = getattr(obj, "tolist", None)  # numpy scalars and arrays, without importing numpy
    if callable(tolist):
        return json_safe(tolist(), nan_as_null=nan_as_null)
    item = getattr(obj, "item", None)
    if callable(item):
        return json_safe(item(), nan_as_null=nan_as_null)
    return str(obj)  # anything else (an enum, a model object): its text, as json.dumps(default=str)


def dumps_json(obj, *, indent: int | None = 2, sort_keys: bool = False, allow_nan: bool = False) -> str:
    """``json_safe(obj)`` as strict JSON text (``json.dumps``' separators): non-finite numbers as
    ``null`` (CONTRACTS 1). ``allow_nan`` is ignored (module doc)."""
    del allow_nan  # strict JSON always
    return json.dumps(json_safe(obj, nan_as_null=True), indent=indent, sort_keys=sort_keys, allow_nan=False)


def write_json(path, obj, *, indent: int | None = 2, sort_keys: bool = False, allow_nan: bool = False,
               final_newline: bool = True, fsync: bool = True) -> Path:
    """Write :func:`dumps_json` of ``obj`` atomically, with a final newline unless ``final_newline`` is
    False (formats that have always ended without one keep their bytes)."""
    return write_text(path, dumps_json(obj, indent=indent, sort_keys=sort_keys, allow_nan=allow_nan)
                      + ("\n" if final_newline else ""), fsync=fsync)


def append_text(path, text: str, *, fsync: bool = True, encoding: str = "utf-8") -> Path:
    """Append ``text`` (whole lines) to ``path`` in one ``write``, then flush and (``fsync``) fsync it:
    a log that grows as a run goes. The file (and its folder) is created if missing, with the
    user's umask. Returns the path."""
    path = Path(path)
    if str(path.parent):
        path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding=encoding, newline="") as fh:
        fh.write(text)
        fh.flush()
        if fsync:
            os.fsync(fh.fileno())
    return path


def append_json_line(path, obj, *, encoder=None, fsync: bool = True) -> Path:
    """Append ``obj`` as one line of strict JSON (JSON lines; non-finite numbers as ``null``) with
    :func:`append_text`. ``encoder``: a ``json.JSONEncoder`` subclass that knows the objects' types
    (bluesky documents use event-model's ``NumpyEncoder``); its output is then made strict by
    :func:`json_safe`."""
    if encoder is not None:
        obj = json.loads(json.dumps(obj, cls=encoder))
    text = json.dumps(json_safe(obj, nan_as_null=True), allow_nan=False)
    return append_text(path, text + "\n", fsync=fsync)


def write_figure(fig, path, *, fsync: bool = False, **savefig_kwargs) -> Path:
    """Save a matplotlib figure atomically (format from the file suffix)."""
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format=path.suffix.lstrip(".") or "png", **savefig_kwargs)
    return write_bytes(path, buf.getvalue(), fsync=fsync)
