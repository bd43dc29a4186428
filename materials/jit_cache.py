"""numba caches that cannot go stale: a cached kernel is keyed on its own source file AND on the
sources of every jitted helper it calls (in any file, transitively) and the values of the
module-level constants it reads.

numba's own cache (``cache=True``) checks only the file that defines the kernel: after an edit
to a helper in another file (``straylight/engine/vec3.py``'s ``dot3`` called from ``hits.py``), or to
a constant it imported (``EVENT_SCATTER``), a warm cache serves the old machine code. Here every
project kernel is compiled through :func:`njit` (a drop-in for ``numba.njit``) or
:func:`cached_jit`, and numba finds its cache through the locators below, numba's documented
extension point (``NUMBA_CACHE_LOCATOR_CLASSES``; ``numba/core/caching.py``). They are numba's own
``UserProvidedCacheLocator`` (``NUMBA_CACHE_DIR``), ``InTreeCacheLocator`` (``__pycache__``) and
``UserWideCacheLocator``, with one change: the source stamp that numba compares before using a
cached index is ``(numba's stamp of the kernel's file, dependency_key(kernel))``. A changed
helper or constant changes the stamp; numba then drops the stale index and compiles again.
The cache is keyed by content, not by where the checkout sits: numba's stamp is a SHA-256 of the
file, :func:`dependency_key` names files by their package path, and the cache folder of a kernel
is its package path (:func:`cache_subpath`) instead of a hash of its absolute folder, so a second
clone of the project finds the kernels the first one compiled.
Functions outside this project's packages keep numba's locators and behaviour.
"""
from __future__ import annotations

import hashlib
import os
import sys
import types
from functools import lru_cache
from pathlib import Path

from atomicio.digest import file_sha256

PROJECT_ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("materials", "geometry", "straylight", "rig")
_PACKAGE_DIRS = tuple(str(PROJECT_ROOT / p) + os.sep for p in PACKAGES)
_CONSTANT_TYPES = (int, float, complex, bool, str, bytes, type(None))
_LOCATORS = ("materials.jit_cache.ProjectUserProvidedLocator", "materials.jit_cache.ProjectInTreeLocator",
             "materials.jit_cache.ProjectUserWideLocator")
_NUMBA_DEFAULT_LOCATORS = ("numba.core.caching.UserProvidedCacheLocator", "numba.core.caching.InTreeCacheLocator",
                           "numba.core.caching.UserWideCacheLocator", "numba.core.caching.IPythonCacheLocator",
                           "numba.core.caching.ZipCacheLocator")


def in_project(path) -> bool:
    """Whether ``path`` is a source file of this project's packages."""
    return os.path.abspath(str(path)).startswith(_PACKAGE_DIRS)


def project_relative(path) -> str:
    """``path`` from its package folder on (``straylight/engine/hits.py``), whatever folder the checkout sits
    in: what the kernel cache is keyed by, so that a second clone (or a moved checkout) finds the kernels
    the first one compiled (numba's own key is the file's absolute folder). Other paths: absolute."""
    parts = Path(os.path.abspath(str(path))).parts
    for k in range(len(parts) - 1, -1, -1):
        if parts[k] in PACKAGES:
            return "/".join(parts[k:])
    return os.path.abspath(str(path))


def cache_subpath(py_file) -> str:
    """The folder (inside NUMBA_CACHE_DIR) of a project file's cached kernels: its package path
    (``straylight_engine``), not a hash of the checkout's absolute folder."""
    return project_relative(os.path.dirname(os.path.abspath(str(py_file)))).replace("/", "_")


@lru_cache(maxsize=None)
def _file_digest(path: str, mtime_ns: int, size: int) -> str:  # keyed on mtime and size: an edit re-hashes
    return file_sha256(path)


def file_digest(path) -> str:
    st = os.stat(path)
    return _file_digest(str(path), st.st_mtime_ns, st.st_size)


def _code_objects(code):
    yield code
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            yield from _code_objects(c)


def _python_function(obj):
    """The Python function behind a numba dispatcher (``py_func``) or a plain function, else None."""
    fn = getattr(obj, "py_func", obj)
    return fn if isinstance(fn, types.FunctionType) else None


def dependencies(py_func) -> tuple[list, dict]:
    """(source files, constants) a kernel's machine code depends on: the files of the kernel and of
    every project function it reaches through its globals (jitted helpers, also as ``module.helper``,
    and every jitted function imported into a reached module), transitively; and the values of the
    plain constants (numbers, strings, tuples of them) those functions read from their module
    globals, which numba freezes into the code."""
    files: set = set()
    constants: dict = {}
    seen: set = set()
    todo = [py_func]
    while todo:
        fn = todo.pop()
        if id(fn) in seen:
            continue
        seen.add(id(fn))
        src = getattr(fn.__code__, "co_filename", "")
        if not in_project(src):
            continue
        files.add(os.path.abspath(src))
        names = {n for c in _code_objects(fn.__code__) for n in c.co_names}
        glb = fn.__globals__
        modname = glb.get("__name__", "?")
        for name in sorted(names):
            if name not in glb:
                continue
            value = glb[name]
            if isinstance(value, types.ModuleType):  # module.helper / module.CONSTANT
                for attr in sorted(names):
                    sub = getattr(value, attr, None)
                    if sub is not None and not isinstance(sub, types.ModuleType):
                        _add(sub, f"{value.__name__}.{attr}", todo, constants)
                continue
            _add(value, f"{modname}.{name}", todo, constants)
        # a kernel may call a jitted helper defined further down its file (not yet among the globals
        # when numba computes the stamp, at decoration): every jitted function of its module counts
        for value in list(glb.values()):
            if hasattr(value, "py_func"):
                fn2 = _python_function(value)
                if fn2 is not None:
                    todo.append(fn2)
    return sorted(files), constants


def _add(value, label, todo, constants):
    fn = _python_function(value)
    if fn is not None:
        todo.append(fn)
    elif isinstance(value, _CONSTANT_TYPES) or (isinstance(value, tuple) and all(
            isinstance(v, _CONSTANT_TYPES) for v in value)):
        constants[label] = repr(value)


def dependency_key(py_func) -> str:
    """SHA-256 over the contents of :func:`dependencies`' files and its constants."""
    files, constants = dependencies(py_func)
    h = hashlib.sha256()
    for f in files:
        h.update(project_relative(f).encode())  # not the checkout's folder: clones share the cache
        h.update(file_digest(f).encode())
    for k in sorted(constants):
        h.update(f"{k}={constants[k]}".encode())
    return h.hexdigest()


def _locator(base):
    """A numba cache locator like ``base`` for project functions, whose source stamp also covers the
    kernel's dependencies (module doc); None (numba's next locator) for other functions."""

    class Locator(base):
        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._kernel = py_func

        def get_source_stamp(self):
            return (super().get_source_stamp(), dependency_key(self._kernel))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not in_project(py_file):
                return None
            return super().from_function(py_func, py_file)

        @classmethod
        def get_suitable_cache_subpath(cls, py_file):  # keyed by content and package path, not by checkout
            return cache_subpath(py_file)

    Locator.__name__ = Locator.__qualname__ = "Project" + base.__name__.replace("CacheLocator", "Locator")
    return Locator


def _install() -> None:
    """Put this module's locators first in numba's list (the user's list, if set, after them)."""
    from numba import config

    current = [c.strip() for c in (getattr(config, "CACHE_LOCATOR_CLASSES", "") or "").split(",") if c.strip()]
    if current[:len(_LOCATORS)] == list(_LOCATORS):
        return
    rest = [c for c in current if c not in _LOCATORS] or list(_NUMBA_DEFAULT_LOCATORS)
    setattr(config, "CACHE_LOCATOR_CLASSES", ",".join(list(_LOCATORS) + rest))


def _locator_classes():
    from numba.core import caching

    return (_locator(caching.UserProvidedCacheLocator), _locator(caching.InTreeCacheLocator),
            _locator(caching.UserWideCacheLocator))


def __getattr__(name):  # the locator classes, built when numba imports them by name
    if name in ("ProjectUserProvidedLocator", "ProjectInTreeLocator", "ProjectUserWideLocator"):
        user, tree, wide = _locator_classes()
        g = globals()
        g["ProjectUserProvidedLocator"], g["ProjectInTreeLocator"], g["ProjectUserWideLocator"] = user, tree, wide
        return g[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def njit(*args, **kwargs):
    """``numba.njit`` with the project's cache locators installed first (use it for every cached
    kernel of the project: ``@njit(cache=True, nogil=True)``)."""
    import numba

    if kwargs.get("cache"):
        _install()
    return numba.njit(*args, **kwargs)


def installed() -> bool:
    """Whether numba looks up caches through this module's locators (numba imported and set up)."""
    numba = sys.modules.get("numba")
    return numba is not None and (getattr(numba.config, "CACHE_LOCATOR_CLASSES", "") or "").startswith(_LOCATORS[0])
