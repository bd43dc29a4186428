"""Batches in this process: one after another, or on a process-wide pool of threads (embree and
the compiled kernels release the GIL; materials, sources and the Python glue do not). Results are
yielded in batch order, so the sums are the same whichever way the batches ran."""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

from straylight.engine.compiled_scene import compiled_scene
from straylight.engine.walk import run_batch


def run_local(spec, ranges, intersector=None):
    """``run_batch`` over ``ranges`` one after another, yielded in order."""
    for a, b in ranges:
        yield run_batch(spec, a, b, intersector)


_POOLS: dict = {}  # n_threads -> this process's shared batch pool
_POOLS_LOCK = threading.Lock()


def shared_pool(n_threads: int):
    """The process-wide pool of ``n_threads`` threads that batches run on (created once, kept: its
    threads keep their scratch buffers; dask tasks of one worker feed it together)."""
    with _POOLS_LOCK:
        pool = _POOLS.get(n_threads)
        if pool is None:
            pool = _POOLS[n_threads] = ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="straylight")
        return pool


def run_threads(spec, ranges, intersector, n_threads):
    """Batches on the shared pool of ``n_threads`` threads, results yielded in batch order (so the
    sums are the same). All batches are queued at once."""
    if intersector is None:
        compiled_scene(spec)  # build the embree scene once, before the threads share it
    futures = [shared_pool(int(n_threads)).submit(run_batch, spec, a, b, intersector) for a, b in ranges]
    for fut in futures:
        yield fut.result()
