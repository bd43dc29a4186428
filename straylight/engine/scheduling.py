"""Stage: scheduling. The ray ids are cut into chunks of CHUNK_RAYS (each with its own random
stream), the chunks into batches (``batch_rays``, default :data:`straylight.engine.spec.AUTO_BATCH_RAYS`),
and the batches run in this process (one after another, or on a thread pool:
straylight.engine.backends.threads) or on dask (straylight.engine.backends.dask). Results come back in chunk
order, so every way gives the same numbers."""
from __future__ import annotations

from straylight.engine.backends.threads import run_local, run_threads
from straylight.engine.spec import AUTO_BATCH_RAYS
from straylight.rng import batches


def batch_ranges(spec) -> list:
    """(first_chunk, stop_chunk) of every batch of ``spec``."""
    return batches(spec.n_rays, spec.options.batch_rays or AUTO_BATCH_RAYS)


def run_batches(spec, ranges, workers=None, client=None, scheduler=None, intersector=None, threads=None, security=None,
                early=None):
    """Batch results for ``ranges``, in order: on dask if ``workers``, ``client`` or ``scheduler``
    is given (``early``: the spec already sent to ``client``'s workers, straylight.engine.backends.dask.ship_early),
    else on ``threads`` threads, else one after another."""
    if workers is not None or client is not None or scheduler is not None:
        # dask's backend only when a cluster is asked for: its module brings asyncio, sockets and the fork
        # server (~0.02 CPU s) that an in-process run (every `straylight pst` without --workers) never uses
        from straylight.engine.backends.dask import run_distributed

        return run_distributed(spec, ranges, workers=workers, client=client, scheduler=scheduler, security=security,
                               early=early)
    if threads is not None and int(threads) > 1:
        return run_threads(spec, ranges, intersector, int(threads))
    return run_local(spec, ranges, intersector)
