"""Input files the user names: regular files of sane size, read without ever blocking.

A path in a scene, a material, a plan or a checkpoint may name anything: ``/dev/zero`` (a read that
never ends), a FIFO (a read that waits forever for a writer), a folder, a 50 GB file. Every reader of
the project goes through :func:`read_input_text` / :func:`check_input_file`, which refuse these in
one line naming the file and what it is. The file is opened with ``O_NONBLOCK`` and
checked with ``fstat`` on the open descriptor, so a FIFO swapped in after a check cannot block the
read either, and at most ``max_bytes + 1`` bytes are ever read.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

TEXT_LIMIT_BYTES = 64 * 2**20  # a scene, material, plan or checkpoint file: far above any real one


class InputFileError(ValueError):
    """An input path that is not a regular file, or is larger than the reader accepts."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _size_text(n: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n} bytes"


def _check_stat(path, st, what: str, max_bytes) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{path}: {what} is {_kind(st.st_mode)}, not a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputFileError(f"{path}: {what} is {_size_text(st.st_size)}, more than the {_size_text(max_bytes)} "
                             f"a {what} may be")


def check_input_file(path, what: str = "input file", max_bytes: int | None = None) -> Path:
    """``path`` if it is a regular file (symlinks followed) of at most ``max_bytes``; else an
    :class:`InputFileError` naming it (FileNotFoundError if there is nothing there). Does not open it."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: {what} not found") from None
    _check_stat(path, st, what, max_bytes)
    return path


def read_input_bytes(path, what: str = "input file", max_bytes: int = TEXT_LIMIT_BYTES) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (module doc); never blocks."""
    path = check_input_file(path, what, max_bytes)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        _check_stat(path, os.fstat(fd), what, max_bytes)  # what was opened, not what was there a moment ago
        chunks, left = [], max_bytes + 1
        while left > 0:
            block = os.read(fd, min(left, 1 << 20))
            if not block:
                break
            chunks.append(block)
            left -= len(block)
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > max_bytes:  # grew while being read
        raise InputFileError(f"{path}: {what} is more than the {_size_text(max_bytes)} a {what} may be")
    return data


def read_input_text(path, what: str = "input file", max_bytes: int = TEXT_LIMIT_BYTES,
                    encoding: str = "utf-8") -> str:
    """The text of a regular file of at most ``max_bytes``; a UnicodeDecodeError as for ``read_text``."""
    return read_input_bytes(path, what, max_bytes).decode(encoding)


def physical_memory_bytes() -> int:
    """This machine's physical memory (0 where the platform does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 0
