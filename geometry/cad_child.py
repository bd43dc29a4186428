"""Reading and tessellating a STEP/IGES file in a child process, so OpenCascade cannot take the run down.

OpenCascade's readers are native code: a damaged file (a dangling entity reference, a truncated
record) can end in SIGSEGV inside the STEP transfer, which no Python ``try`` catches. Here the file is
read and meshed in a child process (``fork`` where the platform has it and this process has not
started OpenCascade's meshing thread pool: the parent's imports are shared and a child starts in
milliseconds, meshing serially; otherwise a fresh interpreter, ``python -m geometry.cad_reader_main``) that writes its result as a
tessellation-cache entry (:mod:`geometry.cad_cache`, the cache entry itself when the cache is on, else
a temporary file), and the parent reads that. The parent turns every way the child can end into a
one-line :class:`~geometry.mesh.GeometryError` naming the file:

- killed by a signal (SIGSEGV, SIGABRT, SIGBUS...): "OpenCascade crashed reading the file";
- out of memory: the child runs under an address-space limit (``$STRAYLIGHT_CAD_MEMORY_MB``, default
  :data:`DEFAULT_MEMORY_MB`, or half the machine's memory if that is less);
- too long: ``$STRAYLIGHT_CAD_TIMEOUT_S`` (default :data:`DEFAULT_TIMEOUT_S`) seconds, then killed;
- Ctrl-C in the parent kills the child at once (a native meshing loop ignores SIGINT) and re-raises.

``STRAYLIGHT_CAD_ISOLATE=off`` reads in the calling process instead (debugging; the test suite's
general tests, to save a child per load; the isolation's own tests turn it on).
A warm cache never gets here: :func:`geometry.io.tessellate_cad` serves it without importing OCP.
"""
from __future__ import annotations

import os
import signal
import sys
import tempfile
import traceback
from multiprocessing.process import BaseProcess
from pathlib import Path

import atomicio
from geometry.mesh import GeometryError

ENV_ISOLATE = "STRAYLIGHT_CAD_ISOLATE"
ENV_MEMORY = "STRAYLIGHT_CAD_MEMORY_MB"
ENV_TIMEOUT = "STRAYLIGHT_CAD_TIMEOUT_S"
DEFAULT_MEMORY_MB = 8000
DEFAULT_TIMEOUT_S = 900.0


def progress_interval_s() -> float:
    """Seconds between the progress lines of a long read (``STRAYLIGHT_PROGRESS_INTERVAL_S``, default 5, as the
    tracer's progress lines)."""
    try:
        value = float(os.environ.get("STRAYLIGHT_PROGRESS_INTERVAL_S", "5"))
    except ValueError:
        return 5.0
    return value if value > 0 else 5.0


def isolated() -> bool:
    return os.environ.get(ENV_ISOLATE, "on").strip().lower() not in ("off", "0", "no", "false")


def _env_number(name: str, default: float) -> float:
    raw = os.environ.get(name, "").strip()
    if not raw:
        return default
    try:
        value = float(raw)
    except ValueError:
        raise GeometryError(f"{name}={raw!r}: expected a number") from None
    if not value > 0:
        raise GeometryError(f"{name}={raw!r}: expected a number > 0")
    return value


def memory_limit_mb() -> int:
    """The child's address-space limit: the setting, at most half the machine's memory."""
    limit = _env_number(ENV_MEMORY, DEFAULT_MEMORY_MB)
    try:
        total_mb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20
        if not os.environ.get(ENV_MEMORY):
            limit = min(limit, total_mb / 2)
    except (ValueError, OSError, AttributeError):
        pass
    return int(limit)


def _child(run, path: str, target: str, error: str, tolerance_mm: float, angular_tolerance_deg: float, split: bool,
           memory_mb: int, forked: bool = False) -> None:
    """Child process body: read, tessellate, store to ``target``; a failure's one line goes to ``error``."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # Ctrl-C ends the child even inside native code
    if not os.environ.get("STRAYLIGHT_DEBUG"):  # a crash is the parent's one line, not a dump of the child's stack
        import faulthandler

        faulthandler.disable()
    try:
        import resource

        soft = memory_mb * 2**20
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        if hard != resource.RLIM_INFINITY:
            soft = min(soft, hard)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    except (ImportError, ValueError, OSError):
        pass
    import warnings

    from geometry import cad_cache, tessellate
    from geometry.tessellate import TessellationWarning

    if forked:  # the parent's OpenCascade thread pool did not come along (a parallel mesh would hang)
        tessellate.MESH_IN_PARALLEL = False

    warnings.simplefilter("ignore", TessellationWarning)  # the parent warns from the reports
    try:
        out = run(Path(path), tolerance_mm=tolerance_mm, angular_tolerance_deg=angular_tolerance_deg,
                                  split=split)
        cad_cache.store(Path(target), out, strict=True)
    except GeometryError as exc:
        atomicio.write_text(error, str(exc), fsync=False)
        os._exit(3)
    except MemoryError:
        atomicio.write_text(error, f"{path}: out of memory reading and tessellating the file "
                                   f"(limit {memory_mb} MB, {ENV_MEMORY})", fsync=False)
        os._exit(4)
    except BaseException as exc:  # noqa: BLE001 - report any failure as one line
        atomicio.write_text(error, f"{path}: cannot read and tessellate the file: "
                                   f"{type(exc).__name__}: {exc}".splitlines()[0], fsync=False)
        traceback.print_exc(file=sys.stderr) if os.environ.get("STRAYLIGHT_DEBUG") else None
        os._exit(5)
    os._exit(0)


class _Popen:
    """A subprocess.Popen with the few methods of multiprocessing.Process used here."""

    def __init__(self, popen):
        self.popen = popen

    def start(self) -> None:
        """Nothing to do: a Popen runs from its creation."""

    def is_alive(self) -> bool:
        return self.popen.poll() is None

    def join(self, timeout=None) -> None:
        import subprocess

        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            pass

    def kill(self) -> None:
        self.popen.kill()

    @property
    def exitcode(self):
        return self.popen.returncode


def _preload() -> None:
    """Import the reader's modules here once, so every forked child starts with them loaded (milliseconds,
    not the seconds OCP's import takes); the same imports an in-process read would make."""
    import OCP.BRepMesh  # noqa: F401
    import OCP.IGESCAFControl  # noqa: F401
    import OCP.ShapeAnalysis  # noqa: F401
    import OCP.STEPCAFControl  # noqa: F401
    import OCP.XCAFApp  # noqa: F401
    import OCP.XCAFDoc  # noqa: F401
    import scipy.sparse.csgraph  # noqa: F401
    import scipy.spatial  # noqa: F401

    import geometry.cad  # noqa: F401
    import geometry.tessellate  # noqa: F401


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


def tessellate_isolated(run, path, entry: Path | None, *, tolerance_mm: float, angular_tolerance_deg: float,
                        split: bool):
    """[(solid name, kind, label, Part)] of ``path`` read and tessellated by ``run`` (a module-level function
    ``run(path, tolerance_mm=, angular_tolerance_deg=, split=)``, :func:`geometry.io.tessellate_cad_here`) in a
    child process (see module docstring); ``entry`` is the cache entry to fill (None: cache off, a temporary
    file is used)."""
    import multiprocessing
    import time

    from geometry import cad_cache

    path = Path(path)
    timeout_s = _env_number(ENV_TIMEOUT, DEFAULT_TIMEOUT_S)
    memory_mb = memory_limit_mb()
    from geometry import tessellate

    # fork when this process has no OpenCascade thread pool yet (a forked child gets none of its threads; the
    # child meshes serially anyway); a fresh interpreter otherwise (a few seconds of imports).
    fork = "fork" in multiprocessing.get_all_start_methods() and not tessellate.POOL_STARTED
    if fork:
        _preload()
    with tempfile.TemporaryDirectory(prefix="straylight-cad-") as tmp:
        target = Path(tmp) / "result.npz" if entry is None else Path(entry)
        error_file = Path(tmp) / "error.txt"
        args = (str(path), str(target), str(error_file), float(tolerance_mm), float(angular_tolerance_deg),
                bool(split), memory_mb)
        process: BaseProcess | _Popen
        if fork:
            process = multiprocessing.get_context("fork").Process(target=_child, args=(run, *args, True), daemon=True)
        else:  # a fresh interpreter (not multiprocessing's spawn, which re-runs the caller's __main__)
            import subprocess

            env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
            process = _Popen(subprocess.Popen(
                [sys.executable, "-m", "geometry.cad_reader_main", *map(str, args[:5]), "1" if split else "0",
                 str(memory_mb)], env=env, stdin=subprocess.DEVNULL))
        start = time.monotonic()
        process.start()
        every_s = progress_interval_s()
        next_line = start + every_s
        try:
            while process.is_alive():
                process.join(0.2)
                now = time.monotonic()
                if now >= next_line:  # a line, not a redrawn bar: it reaches a log file as well as a terminal
                    next_line = now + every_s
                    print(f"reading and meshing {path.name}: {now - start:.0f} s (OpenCascade; once per file and "
                          f"tolerance, then cached)", file=sys.stderr, flush=True)
                if time.monotonic() - start > timeout_s:
                    process.kill()
                    process.join()
                    raise GeometryError(f"{path}: reading and tessellating took more than {timeout_s:g} s and was "
                                        f"stopped ({ENV_TIMEOUT}; or a coarser --tolerance-mm)")
        except BaseException:  # Ctrl-C (KeyboardInterrupt) or the timeout: never leave the child running
            if process.is_alive():
                process.kill()
                process.join()
            raise
        code = process.exitcode
        message = error_file.read_text().strip() if error_file.is_file() else ""
        if code is not None and code < 0:
            raise GeometryError(f"{path}: OpenCascade crashed reading the file ({_signal_name(code)}); the file is "
                                f"damaged or uses entities its reader cannot translate")
        if code != 0:
            raise GeometryError(message or f"{path}: the CAD reader process failed (exit code {code}; out of "
                                           f"memory? limit {memory_mb} MB, {ENV_MEMORY})")
        items = cad_cache.load(target, warn=False)
        if items is None:
            raise GeometryError(f"{path}: the CAD reader process wrote no usable result ({target})")
        for item in items:  # made now, not served from the cache
            item[3].meta.pop("cache", None)
        return items
