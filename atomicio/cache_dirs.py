"""Where the project's caches live: compiled kernels (numba) and CAD tessellations.

Both sit under the user's cache directory (``platformdirs.user_cache_dir("straylight")``, e.g.
``~/.cache/straylight`` on Linux), never inside the installed package, so a read-only install
works:

- compiled kernels: ``$NUMBA_CACHE_DIR`` if the user set it, else ``<user cache>/numba``;
  :func:`configure_numba_cache` sets ``NUMBA_CACHE_DIR`` for numba before any kernel is compiled
  (``materials``, ``geometry`` and ``straylight`` call it on import; worker processes inherit it);
- tessellations: ``$STRAYLIGHT_CACHE_DIR/tessellation`` if set, else ``<user cache>/tessellation``
  (``geometry.cad_cache``).

When that folder cannot be created or written (a read-only HOME, no HOME), a private folder in the
system's temporary directory is used instead: ``straylight-cache-<uid>``, created with mode 0700,
used only if it is a real folder owned by this user that nobody else can write (another local user
could otherwise plant compiled code or meshes there for this one to load); else a fresh
``mkdtemp`` folder for this process.

Every cache folder (and dask's scratch folder, :func:`private_dir`) is created with mode 0700 and
used only while :func:`check_private` holds (a real folder, ours, that no other user can write): a
folder planted by someone else, or opened to others, is passed over for the fallback.
"""
from __future__ import annotations

import os
import stat
import sys
import tempfile
import typing
from pathlib import Path

ENV_DIR = "STRAYLIGHT_CACHE_DIR"
ENV_SWITCH = "STRAYLIGHT_CACHE"  # off / 0 / no / false: no tessellation or energy-check cache
NUMBA_ENV = "NUMBA_CACHE_DIR"
_CHOSEN: dict = {}


def enabled() -> bool:
    """The project's own caches (tessellations, energy checks) are used unless ``$STRAYLIGHT_CACHE`` is off."""
    return os.environ.get(ENV_SWITCH, "on").strip().lower() not in ("off", "0", "no", "false")


class NotPrivateError(OSError):
    """A cache or scratch folder another user could write into (and so plant code or data for us)."""


def check_private(path: Path) -> Path:
    """``path`` itself (not a symlink) is a folder owned by this user that no one else can write, or
    :class:`NotPrivateError` naming it and why ( a world-writable ``dask-scratch-space`` put
    on ``sys.path`` let another local user run code as this one)."""
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise NotPrivateError(f"{path}: is not a folder (a symlink or a file): not used as a private folder")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise NotPrivateError(f"{path}: belongs to user id {st.st_uid}, not to you: not used as a private folder")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise NotPrivateError(f"{path}: other users can write into it (mode {stat.S_IMODE(st.st_mode):o}): "
                              f"not used as a private folder; chmod go-w it")
    return path


def _make_private(path: Path) -> Path:
    """Create ``path`` (parents as needed; the folder itself with mode 0700) and :func:`check_private` it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        path.mkdir(mode=0o700)
    except FileExistsError:
        st = os.lstat(path)
        if (stat.S_ISDIR(st.st_mode) and (not hasattr(os, "getuid") or st.st_uid == os.getuid())
                and st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)):
            os.chmod(path, stat.S_IMODE(st.st_mode) & ~0o022)  # ours, made by an older version under umask 002
    return check_private(path)


def _usable(path: Path) -> bool:
    """Can this process create ``path`` (with its parents, the folder itself private: 0700, ours, no one
    else may write) and a file in it?"""
    try:
        _make_private(path)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".probe-")
        os.close(fd)
        os.unlink(probe)
        return True
    except OSError:
        return False


def _private_temp() -> Path:
    """``<tmp>/straylight-cache-<uid>`` if it is (or can be made) a folder of this user's that no one
    else can write; else a fresh mkdtemp folder (module doc)."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    path = Path(tempfile.gettempdir()) / f"straylight-cache-{uid}"
    try:
        path.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError:
        return Path(tempfile.mkdtemp(prefix="straylight-cache-"))
    try:
        st = os.lstat(path)
    except OSError:
        return Path(tempfile.mkdtemp(prefix="straylight-cache-"))
    if (not stat.S_ISDIR(st.st_mode) or (hasattr(os, "getuid") and st.st_uid != uid)
            or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)):
        return Path(tempfile.mkdtemp(prefix="straylight-cache-"))
    return path


def user_cache_root() -> Path:
    """``platformdirs.user_cache_dir("straylight")`` if usable, else the private temp folder."""
    if "root" not in _CHOSEN:
        import platformdirs

        base = Path(platformdirs.user_cache_dir("straylight"))
        _CHOSEN["root"] = base if _usable(base) else _private_temp()
    return _CHOSEN["root"]


def cache_dir(kind: str) -> Path:
    """The folder of one cache (``"tessellation"``, ``"numba"``): under ``$STRAYLIGHT_CACHE_DIR`` for
    the tessellations if set (and usable), else under :func:`user_cache_root`. Not created here
    beyond what checking it needs."""
    given = os.environ.get(ENV_DIR) if kind != "numba" else None
    memo = ("dir", kind, given)
    if memo in _CHOSEN and os.path.isdir(_CHOSEN[memo]):
        return _CHOSEN[memo]
    _CHOSEN[memo] = path = _find_cache_dir(kind, given)
    return path


def _find_cache_dir(kind: str, given) -> Path:
    if given:
        path = Path(given) / kind
        if _usable(path):
            return path
    path = user_cache_root() / kind
    if not _usable(path):  # planted or opened to others: this user's private temp folder instead
        path = _private_temp() / kind
        if not _usable(path):
            path = Path(tempfile.mkdtemp(prefix=f"straylight-{kind}-"))
    return path


def private_dir(kind: str) -> Path:
    """A private folder (0700, ours, checked: :func:`check_private`) under the user cache root for
    scratch files (``"dask-scratch"``: dask's ``temporary-directory``), never a shared ``<tmp>`` folder."""
    return cache_dir(kind)


def configure_numba_cache() -> str:
    """Point numba's on-disk cache at :func:`cache_dir` ("numba") unless the user set
    ``NUMBA_CACHE_DIR`` (kept when usable); done once, before the first compiled kernel. Returns the folder."""
    if "numba" in _CHOSEN:
        return _CHOSEN["numba"]
    given = os.environ.get(NUMBA_ENV)
    folder = given if given and _usable(Path(given)) else str(cache_dir("numba"))
    os.environ[NUMBA_ENV] = folder
    config: typing.Any = sys.modules.get("numba.core.config")  # a module whose settings are set at import
    if config is not None:  # numba read its settings already: tell it too
        config.CACHE_DIR = folder
    _CHOSEN["numba"] = folder
    return folder
