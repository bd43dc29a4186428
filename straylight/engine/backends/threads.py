"""Batches in this process: one after another, or on this process's shared pool of threads
(:meth:`straylight.engine.runtime.Runtime.pool`; embree and the compiled kernels release the GIL;
materials, sources and the Python glue do not). Results are yielded in batch order, so the sums
are the same whichever way the batches ran."""
from __future__ import annotations

from straylight.engine.runtime import runtime
from straylight.engine.walk import run_batch


def run_local(spec, ranges, intersector=None):
    """``run_batch`` over ``ranges`` one after another, yielded in order."""
    for a, b in ranges:
        yield run_batch(spec, a, b, intersector)


def run_threads(spec, ranges, intersector, n_threads):
    """Batches on the shared pool of ``n_threads`` threads, results yielded in batch order (so the
    sums are the same). All batches are queued at once."""
    rt = runtime()
    if intersector is None:
        rt.scene(spec)  # build the embree scene once, before the threads share it
    pool = rt.pool(int(n_threads))
    futures = [pool.submit(run_batch, spec, a, b, intersector) for a, b in ranges]
    for fut in futures:
        yield fut.result()
