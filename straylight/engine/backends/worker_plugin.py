"""The dask worker plugin that sets up a worker process's :class:`straylight.engine.runtime.Runtime`: registered by :func:`straylight.engine.backends.dask.register_runtime` on every client
the engine runs on (``Client.register_plugin``, distributed's public API), so each worker starts
numba's target and tunes its allocator once, when it joins, not in its first task."""
from __future__ import annotations

from distributed import WorkerPlugin

from straylight.engine.runtime import runtime

PLUGIN_NAME = "straylight-runtime"


class RuntimePlugin(WorkerPlugin):
    """Starts the Runtime of the worker's process and records the worker in it (``Runtime.workers``).
    Teardown only forgets the worker: the Runtime is the process's (an in-process cluster shares it
    with the client's process)."""

    name = PLUGIN_NAME
    idempotent = True  # registering again (another client of the same cluster) does nothing

    def setup(self, worker):
        runtime().workers.add(worker.address)

    def teardown(self, worker):
        runtime().workers.discard(worker.address)
