"""Run trace batches on dask.distributed, combining results in chunk order.

A LocalCluster of one in-process worker whose tasks share a pool of ``workers`` threads by
default (:func:`local_cluster`), an existing ``Client``, or ``Client(scheduler_address)``. The
:class:`straylight.engine.spec.TraceSpec` (triangle array, materials, sources) is broadcast once; each worker process
builds its embree scene from the triangles on first use and keeps it (``straylight.engine.compiled_scene``), so no embree object is
ever pickled. Each task is a run of whole chunks (:func:`task_plan`) whose random streams are
keyed by chunk id, so the same seed gives the same numbers for any worker count.
"""
from __future__ import annotations

from straylight.engine.batch_pool import run_threads
from straylight.engine.walk import run_batch

TASK_BATCHES = 5  # at most this many batches per dask task

# a LocalCluster made for tracing: the event loop shares the GIL (threads) or the cores (processes)
# with the workers, so its periodic housekeeping is slowed down (idle CPU 40 -> 7 ms per second) and
# work stealing, useless for equal independent tasks, is off
LEAN_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.scheduler.work-stealing": False,
}


def _group_task(spec, ranges):
    return [run_batch(spec, a, b) for a, b in ranges]


def _pooled_task(spec, ranges, n_threads):
    """Queue whole batches on the worker's shared pool of ``n_threads`` threads
    (:func:`straylight.engine.batch_pool.shared_pool`) and return their results in batch order. The worker runs
    ``n_threads`` such tasks at once, so the next task's batches are already queued when this one's
    last batch runs: the pool's threads never wait at task ends."""
    return list(run_threads(spec, ranges, None, int(n_threads)))


def pooled_plan(ranges, n_threads: int) -> list:
    """Tasks for a pooled worker: runs of whole batches, a multiple of ``n_threads`` long (about
    half the run per task, at most 8 rounds of the pool), so a long run still reports progress
    task by task."""
    ranges = list(ranges)
    k = max(1, int(n_threads))
    per = k * max(1, min(8, -(-len(ranges) // (2 * k))))
    return [ranges[i:i + per] for i in range(0, len(ranges), per)]


def task_plan(ranges, n_slots: int) -> list:
    """Group batch ranges ``(first_chunk, stop_chunk)`` into dask tasks (lists of whole batches, in
    chunk order) of decreasing size (guided self-scheduling: about remaining / (2 slots) batches, at
    most TASK_BATCHES), so that few tasks carry the run (each costs the scheduler a few ms of CPU)
    and the last ones are single batches, so no worker thread idles long at the end. Batches are
    never cut: a small batch pays the per-event Python costs for few rays."""
    ranges = list(ranges)
    tasks = []
    k = 0
    while k < len(ranges):
        left = len(ranges) - k
        per = min(TASK_BATCHES, max(1, -(-left // (2 * max(1, int(n_slots))))))
        tasks.append(ranges[k:k + per])
        k += per
    return tasks


def local_cluster(n_workers: int, processes: bool = False):
    """LocalCluster for tracing with ``n_workers`` parallel workers: no dashboard port, dask's
    statistical profiler off (it samples every thread every 10 ms, ~5-10 % of a worker's CPU) and
    the housekeeping of :data:`LEAN_CONFIG`.

    Default: ONE in-process worker with ``n_workers`` dask threads whose tasks queue their batches
    on one shared pool of ``n_workers`` threads (:func:`_pooled_task`; the cluster carries
    ``straylight_threads = n_workers``). Embree and the compiled kernels release the GIL, and the
    threads share one copy of the scene. The tasks overlap, so the pool never idles at a task's
    end (tasks run one at a time on a private pool gave x1.61-1.90 from 1 to 2 workers on the
    reference tube; the shared pool x1.84-1.91, as a plain thread pool). 2 worker processes
    ran x1.77 by wall (each with its own scene and warm-up). ``processes=True`` gives ``n_workers``
    processes with one thread each."""
    import dask
    from dask.distributed import LocalCluster

    with dask.config.set(LEAN_CONFIG):
        if processes:
            return LocalCluster(n_workers=int(n_workers), threads_per_worker=1, processes=True,
                                dashboard_address=":0")
        cluster = LocalCluster(n_workers=1, threads_per_worker=int(n_workers), processes=False,
                               dashboard_address=":0")
        cluster.straylight_threads = int(n_workers)
        return cluster


def _warm_task(spec):
    import time

    run_batch(spec, 0, 1)
    return time.process_time()


def warm_up(client, spec) -> dict:
    """Build the scene (embree + compiled kernels) in every worker of ``client`` now, by tracing the
    first chunk of ``spec`` on each (so that start-up is not charged to the first real tasks).
    Returns {worker address: process CPU seconds so far}."""
    return client.run(_warm_task, spec)


def worker_cpu_seconds(client) -> dict:
    """{worker address: CPU seconds used by that worker process so far} (``time.process_time``)."""
    import time

    return client.run(time.process_time)


def run_distributed(spec, ranges, workers=None, client=None, scheduler=None, security=None):
    """Yield ``run_batch`` results for ``ranges`` (list of (first_chunk, stop_chunk)), in order."""
    from dask.distributed import Client, as_completed

    owned = []
    if client is None:
        if scheduler is not None:
            client = Client(scheduler, security=security)
            owned.append(client)
        else:
            n = 1 if workers is None else int(workers)
            if n < 1:
                raise ValueError(f"workers must be >= 1, got {workers}")
            cluster = local_cluster(n)
            client = Client(cluster)
            owned += [client, cluster]
    try:
        # a fresh key for every trace (hash=False): with the content's hash as key, a trace repeated
        # with the same spec re-scattered a key whose release by the previous trace was still on its
        # way, and the scheduler dropped the data under the new tasks (FutureCancelledError)
        spec_future = client.scatter(spec, broadcast=True, hash=False)
        # few tasks (each costs the scheduler a few ms of CPU, which competes with the workers on a
        # small machine), shrinking toward the end for balance: task_plan (the numbers are unchanged)
        pool = int(getattr(getattr(client, "cluster", None), "straylight_threads", 0) or 0)
        if pool > 1:  # our local cluster: a thread pool inside each task (local_cluster)
            groups = pooled_plan(ranges, pool)
            futures = client.map(_pooled_task, [spec_future] * len(groups), groups, [pool] * len(groups), pure=False)
        else:
            workers_info = client.scheduler_info().get("workers", {})
            n_slots = max(1, sum(int(w.get("nthreads", 1)) for w in workers_info.values()))
            groups = task_plan(ranges, n_slots)
            futures = client.map(_group_task, [spec_future] * len(groups), groups, pure=False)
        order = {fut.key: k for k, fut in enumerate(futures)}
        done = {}
        nxt = 0
        # results as they finish (one event-loop round trip for each), yielded in chunk order
        for fut, result in as_completed(futures, with_results=True):
            if fut.status != "finished":
                fut.result()  # raises the task's error (or the cancellation)
            done[order[fut.key]] = result
            fut.release()
            while nxt in done:
                yield from done.pop(nxt)
                nxt += 1
    finally:
        for obj in owned:
            obj.close()
