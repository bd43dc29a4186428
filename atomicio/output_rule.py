"""One output rule for every command (docs/reference/commands.md, "Outputs").

Before any work, every output a command will write is checked:

- it is a regular file or a folder to be, never a symbolic link, a FIFO, a socket or a device
  (the atomic writer would silently replace such a path by a regular file);
- a file output is none of the command's own inputs (``material fit scan.csv -o scan.csv`` would
  destroy the measured scan);
- one run per output folder (``--out``, ``--report``) or per scan file at a time: a lock file
  ``.straylight-lock`` (created with O_EXCL, holding the pid, host and start time) says who holds it;
  a lock left by a process that no longer runs on this host is taken over with a warning.

The lock is released when the command ends, however it ends, and a folder the run created and left
empty is removed again.
"""
from __future__ import annotations

import json
import os
import socket
import stat
import time
import warnings
from contextlib import ExitStack, contextmanager
from pathlib import Path

LOCK_NAME = ".straylight-lock"


class OutputRuleError(ValueError):
    """An output path the rule refuses (one line, naming it)."""


def _kind(st) -> str | None:
    mode = st.st_mode
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return None


def check_plain_path(path, what: str) -> Path:
    """``path`` is not a symbolic link, FIFO, socket or device (it may not exist yet)."""
    p = Path(path)
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return p
    except OSError as exc:
        raise OutputRuleError(f"{p}: the {what} cannot be checked ({exc.strerror or exc})") from None
    if stat.S_ISLNK(st.st_mode):
        raise OutputRuleError(f"{p}: the {what} is a symbolic link; give the real path (outputs are written as "
                              "regular files and would replace the link)")
    kind = _kind(st)
    if kind:
        raise OutputRuleError(f"{p}: the {what} is {kind}, not a regular file or folder; give a file path")
    return p


def check_not_an_input(path, inputs, what: str) -> None:
    """A file output is none of the command's input files (same file by inode, or the same resolved path)."""
    p = Path(path)
    for src in inputs:
        s = Path(src)
        same = False
        try:
            same = p.exists() and s.exists() and os.path.samefile(p, s)
        except OSError:
            same = False
        if same or p.resolve() == s.resolve():
            raise OutputRuleError(f"{p}: the {what} is one of the command's own inputs ({src}); writing it would "
                                  "destroy the input: give another output path")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read_lock(lock: Path) -> dict:
    try:
        doc = json.loads(lock.read_text(encoding="utf-8"))
        return doc if isinstance(doc, dict) else {}
    except (OSError, ValueError):
        return {}


@contextmanager
def held(target, what: str, folder: bool):
    """Hold the lock of an output folder (``folder``) or of an output file (its lock sits beside it as
    ``.<name>.straylight-lock``) for the duration of the run."""
    target = Path(target)
    created = None
    if folder:
        if not target.exists():
            created = target
            target.mkdir(parents=True, exist_ok=True)
        lock = target / LOCK_NAME
    else:
        lock = target.parent / f".{target.name}{LOCK_NAME}"
    me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            other = _read_lock(lock)
            pid, host = other.get("pid"), other.get("host")
            if isinstance(pid, int) and host == me["host"] and not _alive(pid):
                warnings.warn(f"{target}: taking over the lock of a run that no longer runs (pid {pid}, started "
                              f"{other.get('started', '?')})", stacklevel=2)
                lock.unlink(missing_ok=True)
                continue
            if pid == me["pid"] and host == me["host"]:
                raise OutputRuleError(f"{target}: the {what} is already in use by this process") from None
            raise OutputRuleError(f"{target}: the {what} is in use by another straylight run (pid {pid} on {host}, "
                                  f"since {other.get('started', '?')}); wait for it or choose another path; a lock "
                                  f"left by a crash is in {lock}") from None
        except OSError:
            lock = None  # a folder we cannot lock (read-only: the write check says so); no lock
            break
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(me, fh)
        break
    try:
        yield target
    finally:
        if lock is not None:
            try:
                if _read_lock(lock).get("pid") == me["pid"]:
                    lock.unlink()
            except OSError:
                pass
        if created is not None:
            try:
                created.rmdir()  # only if the run left it empty
            except OSError:
                pass


@contextmanager
def outputs_held(folders=(), files=()):
    """Locks on several outputs at once: ``folders`` and ``files`` are ((path, what), ...)."""
    with ExitStack() as stack:
        for path, what in folders:
            stack.enter_context(held(path, what, folder=True))
        for path, what in files:
            stack.enter_context(held(path, what, folder=False))
        yield
