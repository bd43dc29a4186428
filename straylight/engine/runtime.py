"""This process's engine state, in one object: :class:`Runtime`.

One per process (:func:`runtime`), made and started on first use, or on a dask worker by the
worker plugin (:mod:`straylight.engine.backends.worker_plugin`). It owns

- the compiled scene (embree BVH, planes, detector tables; one scene kept, keyed by the spec's token),
- the last first-/second-vertex sampling table of each kind (the rounds of ``--target-rel-error``
  trace the same scene and seed again and reuse it; the key holds everything a table depends on),
- the shared pools of batch threads (one per thread count, kept: their threads keep scratch buffers),
- the start: numba's CPU target started without scipy.linalg (:func:`materials.jit_start.start_numba`)
  and glibc's allocator tuned (:func:`tune_allocator`), once, explicitly, in :meth:`Runtime.start`.

Allocator tuning is process-wide (glibc's ``mallopt``); turn it off with the environment variable
``STRAYLIGHT_TUNE_ALLOCATOR=0`` or ``Runtime(tune_allocator=False)``. Nothing here changes a number:
the caches hold what would be rebuilt identically (docs/engine.md, "Backends and the runtime").

A forked child (the fork server's workers) gets a fresh Runtime on its first :func:`runtime` call:
threads and embree scenes do not survive a fork; the started numba target and the allocator
settings do (the new Runtime's start repeats them at no cost).
"""
from __future__ import annotations

import ctypes
import os
import threading
from concurrent.futures import ThreadPoolExecutor

from materials.jit_start import start_numba
from straylight.engine.compiled_scene import CompiledScene
from straylight.engine.spec import TraceSpec

ALLOCATOR_ENV = "STRAYLIGHT_TUNE_ALLOCATOR"
MMAP_THRESHOLD_B = 32 * 1024 * 1024  # glibc's maximum on 64-bit: blocks up to 32 MB come from the heap
TRIM_THRESHOLD_B = 256 * 1024 * 1024  # keep up to 256 MB of freed heap instead of returning it


def tune_allocator() -> bool:
    """glibc only: serve blocks up to 32 MB from the heap and keep up to 256 MB of freed heap
    (``mallopt(M_MMAP_THRESHOLD)``, ``mallopt(M_TRIM_THRESHOLD)``). The engine frees and reallocates
    MB-sized arrays every event; with glibc's defaults many came back as fresh pages (6k-50k page
    faults per 4e5-ray trace, up to 10 % of its CPU), now ~100. Returns whether it was applied
    (False elsewhere than glibc)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, MMAP_THRESHOLD_B)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, TRIM_THRESHOLD_B)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        return False
    return True


def _table_key(spec: TraceSpec) -> tuple:
    """What a sampling table depends on: geometry, seed, sources and materials (by identity, kept
    alive by the entry so their ids stay theirs), detector sides, polarization and the estimator
    options (the entrance pilot traces with them, the eye chains reach as far as they say: a table
    kept from another estimator set would make a trace's numbers depend on what the process ran before)."""
    opt = spec.options
    return (spec.token, spec.seed, tuple(id(s) for s in spec.sources), tuple(id(m) for m in spec.materials),
            opt.output.detector_sides, opt.physics.polarization, opt.estimator)


class Runtime:
    """This process's compiled scene, sampling tables, batch thread pools and start-up (module doc)."""

    def __init__(self, tune_allocator: bool | None = None):
        if tune_allocator is None:
            tune_allocator = os.environ.get(ALLOCATOR_ENV, "1").strip().lower() not in ("0", "no", "off", "false")
        self.tune_allocator = bool(tune_allocator)
        self.pid = os.getpid()
        self.started = False
        self.allocator_tuned = False
        self.workers: set = set()  # addresses of the dask workers of this process it serves (worker plugin)
        self._lock = threading.Lock()  # the start
        self._scene_lock, self._table_lock, self._pool_lock = threading.Lock(), threading.Lock(), threading.Lock()
        self._scenes: dict = {}  # spec token -> CompiledScene (one kept)
        self._tables: dict = {}  # kind -> (key, what keeps the key's ids alive, table)
        self._pools: dict = {}  # n_threads -> ThreadPoolExecutor

    def start(self) -> Runtime:
        """Start numba's CPU target (without scipy.linalg) and tune the allocator (unless turned
        off), once; before the first kernel runs. Returns self."""
        if self.started:
            return self
        with self._lock:
            if not self.started:
                start_numba()
                if self.tune_allocator:
                    self.allocator_tuned = tune_allocator()
                self.started = True
        return self

    def scene(self, spec: TraceSpec, intersector=None) -> CompiledScene:
        """The :class:`CompiledScene` of ``spec`` (built on first use; one scene kept); with an
        ``intersector`` a fresh one around it (not kept)."""
        self.start()
        if intersector is not None:
            return CompiledScene(spec, intersector)
        comp = self._scenes.get(spec.token)
        if comp is None:
            with self._scene_lock:  # threads of one worker may start their first batch together: build once
                comp = self._scenes.get(spec.token)
                if comp is None:
                    self._scenes.clear()  # keep one scene per process
                    comp = self._scenes[spec.token] = CompiledScene(spec)
        return comp

    def cached_scene(self, spec: TraceSpec) -> CompiledScene | None:
        """The scene of ``spec`` if it was built in this process, else None."""
        return self._scenes.get(spec.token)

    def scene_tokens(self) -> tuple:
        """The tokens of the scenes kept (at most one)."""
        return tuple(self._scenes)

    def table(self, kind: str, spec: TraceSpec, build, cache: bool = True):
        """The sampling table of ``kind`` ("first", "second") for ``spec``: the one kept from the
        previous call with the same key (:func:`_table_key`), else ``build()`` (kept, one per kind)."""
        if not cache:
            return build()
        key = _table_key(spec)
        with self._table_lock:
            hit = self._tables.get(kind)
            if hit is not None and hit[0] == key:
                return hit[2]
        table = build()
        with self._table_lock:
            self._tables[kind] = (key, (spec.sources, spec.materials), table)
        return table

    def forget_tables(self) -> None:
        """Drop the kept sampling tables (the next trace builds them)."""
        with self._table_lock:
            self._tables.clear()

    def pool(self, n_threads: int) -> ThreadPoolExecutor:
        """The shared pool of ``n_threads`` batch threads (made once, kept: its threads keep their
        scratch buffers; the dask tasks of one worker feed it together)."""
        n = int(n_threads)
        with self._pool_lock:
            pool = self._pools.get(n)
            if pool is None:
                pool = self._pools[n] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="straylight")
            return pool

    def close(self) -> None:
        """Shut the thread pools down and drop the scene and tables (their memory is freed)."""
        with self._pool_lock, self._scene_lock, self._table_lock:
            pools = list(self._pools.values())
            self._pools.clear()
            self._scenes.clear()
            self._tables.clear()
        for pool in pools:
            pool.shutdown(wait=True)


_RUNTIME: list = []  # [this process's Runtime]
_RUNTIME_LOCK = threading.Lock()


def runtime() -> Runtime:
    """This process's :class:`Runtime`, made and started on first use (a forked child makes its own)."""
    if _RUNTIME and _RUNTIME[0].pid == os.getpid():
        return _RUNTIME[0]
    with _RUNTIME_LOCK:
        if not _RUNTIME or _RUNTIME[0].pid != os.getpid():
            _RUNTIME[:] = [Runtime()]
    return _RUNTIME[0].start()
