"""Start numba's CPU target once per process without importing scipy.linalg; here,
in the lowest package that compiles code, so that whichever package compiles first (a material's loop,
the engine's kernels) starts it this way.

The first time numba compiles or loads a cached kernel in a process, its CPU target imports its
implementation registries, among them ``numba.np.arraymath``, whose module body asks whether a
BLAS is there by importing ``scipy.linalg.cython_blas`` (``numba.np.arraymath._HAVE_BLAS``). That
import runs all of ``scipy.linalg`` and scipy's array-API layer (which loads ``numpy.f2py``):
0.2-0.3 s of CPU per process, a fifth of a cached start-up's budget, for nothing the tracer uses.

:func:`start_numba` initialises the target with ``import scipy.linalg`` made to fail (``sys.modules``
holds None for it meanwhile), so numba records "no BLAS" for ``_HAVE_BLAS``. What that changes, in numba 0.5x-0.6x: ``np.correlate`` and
``np.convolve`` in jitted code use numba's own loop instead of BLAS ``dot`` (no kernel of this
project calls them). ``np.dot``, ``@`` and ``np.linalg`` in jitted code are unaffected: they
check for BLAS again when they are compiled, and then import scipy for real. Nothing is done when
scipy.linalg is already imported, when the target is already initialised, or after the first
call; if numba ever fails with the import blocked, the target is initialised again normally.

The typing registries also import ``numba.core.typing.cffi_utils``, which imports cffi and builds a
``cffi.FFI()`` (pycparser's lexer and parser: ~0.02 CPU s) so that jitted code may call cffi functions;
no kernel here does. After :func:`for_command_line` (the ``straylight`` command calls it) cffi is blocked
the same way, unless it is imported already: numba then records ``cffi_utils.SUPPORTED = False`` for the
whole process, and jitted code there cannot call cffi functions (a typing error; ctypes functions are
unaffected). Not by default: in a notebook or a library user's process their own jitted cffi calls
would fail.

numba also registers callbacks on llvmlite's LLVM lock (``numba.core.base._initialize_llvm_lock_event``):
every call into LLVM's C API broadcasts a ``numba:llvm_lock`` start and end event, which the dispatcher
times into a compile's metadata (``dispatcher.get_metadata()["timers"]["llvm_lock"]``). Loading a cached
kernel makes thousands of such calls (its module's symbols, one call each): the events were ~0.03 of the
~0.18 CPU s a ``straylight pst`` command spends loading its 43 kernels. After :func:`for_command_line`,
:func:`start_numba` unregisters them (llvmlite's ``ffi.unregister_lock_callback``); what is lost is that
timer, a diagnostic no code here reads. Not by default either: a notebook may time its own compiles.

Cached kernels do not depend on it: numba's cache index is keyed on the signature, the target
and the source file, and kernels loaded from it are the same machine code either way.
"""
from __future__ import annotations

import sys
import threading

_BLOCKED = ("scipy.linalg",)  # the package: importing scipy.linalg.cython_blas runs its __init__ first
_SKIPPED: list = []  # "cffi" after for_command_line()
_QUIET: list = []  # True after for_command_line(): numba's LLVM-lock events off
_DONE: list = []
_LOCK = threading.Lock()


def for_command_line() -> None:
    """This process runs only this project's kernels (the ``straylight`` command): :func:`start_numba`
    starts numba without cffi and without its LLVM-lock events (module doc; ~0.02 + ~0.03 CPU s). No effect
    once numba's target has started."""
    if "cffi" not in _SKIPPED:
        _SKIPPED.append("cffi")
    if not _QUIET:
        _QUIET.append(True)


def _lock_events_off() -> None:
    """Unregister numba's callbacks on llvmlite's LLVM lock (module doc); nothing if llvmlite keeps them
    elsewhere than it does today (``ffi.lib._lock``)."""
    from llvmlite.binding import ffi

    lock = getattr(getattr(ffi, "lib", None), "_lock", None)
    for acquire, release in list(getattr(lock, "_cblist", ())):
        if getattr(acquire, "__module__", None) == "numba.core.base":
            ffi.unregister_lock_callback(acquire, release)


def start_numba() -> None:
    """Initialise numba's CPU target now (it would be on the first kernel anyway), without scipy.linalg
    (and, after :func:`for_command_line`, without cffi and numba's LLVM-lock events).

    ``sys.modules[name]`` is None for each of them while the target starts: Python's import system then
    raises ModuleNotFoundError for it (the documented way to block an import; no import hook). That
    holds for the whole process for these ~0.1 s, so the engine starts numba before it starts threads:
    :meth:`straylight.engine.runtime.Runtime.start`, the first thing a command or a dask worker does."""
    if _DONE:
        return
    with _LOCK:
        if _DONE:
            return
        from numba.core.registry import cpu_target

        if _QUIET:
            _lock_events_off()  # numba.core.base, which registers them, is imported by now
        if "numba.np.arraymath" in sys.modules:
            cpu_target.target_context.refresh()  # nothing to save: the target is up
        else:
            blocked = [name for name in (*_BLOCKED, *_SKIPPED) if name not in sys.modules]  # loaded: nothing to save
            for name in blocked:
                sys.modules[name] = None  # type: ignore[assignment]
            try:
                cpu_target.target_context.refresh()
            except Exception:  # noqa: BLE001 - an unforeseen numba: start it the normal way
                _unblock(blocked)
                cpu_target.target_context.refresh()
            finally:
                _unblock(blocked)
        _DONE.append(True)


def _unblock(names) -> None:
    """Let ``names`` be imported again (drop the None entries :func:`start_numba` put in sys.modules)."""
    for name in names:
        if name in sys.modules and sys.modules[name] is None:
            del sys.modules[name]
