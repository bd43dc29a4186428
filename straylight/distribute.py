"""Run trace batches on dask.distributed, combining results in chunk order.

A LocalCluster of ``workers`` processes with one thread each by default, an existing ``Client``,
or ``Client(scheduler_address)``. The :class:`straylight.trace.TraceSpec` (triangle array,
materials, sources) is broadcast once; each worker process builds its embree scene from the
triangles on first use and keeps it (``straylight.trace._COMPILED``), so no embree object is
ever pickled. Each task is a batch of whole chunks whose random streams are keyed by chunk id,
so the same seed gives the same numbers for any worker count.
"""
from __future__ import annotations


def _batch_task(spec, first_chunk, stop_chunk):
    from straylight.trace import run_batch

    return run_batch(spec, first_chunk, stop_chunk)


def run_distributed(spec, ranges, workers=None, client=None, scheduler=None):
    """Yield ``run_batch`` results for ``ranges`` (list of (first_chunk, stop_chunk)), in order."""
    from dask.distributed import Client, LocalCluster

    owned = []
    if client is None:
        if scheduler is not None:
            client = Client(scheduler)
            owned.append(client)
        else:
            n = 1 if workers is None else int(workers)
            if n < 1:
                raise ValueError(f"workers must be >= 1, got {workers}")
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0")
            client = Client(cluster)
            owned += [client, cluster]
    try:
        spec_future = client.scatter(spec, broadcast=True)
        futures = [client.submit(_batch_task, spec_future, a, b, pure=False) for a, b in ranges]
        for fut in futures:
            yield fut.result()
            fut.release()
    finally:
        for obj in owned:
            obj.close()
