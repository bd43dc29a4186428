"""Where and how a trace runs: :class:`Execution`, one object instead of six keywords.

``trace(..., execution=Execution(threads=2))``, ``pst_sweep(..., execution=...)``: every analysis takes
one ``Execution`` and no execution keywords. The numbers never depend on it (same seed, same results in
process, on threads or on dask). The command line builds it once from its flags
(:func:`straylight.cli.cluster_args.execution`).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, fields, replace

from straylight.engine.options import TraceError

FIELDS = ("workers", "client", "scheduler", "threads", "security", "progress", "intersector", "first_chunk")


@dataclass(frozen=True)
class Execution:
    """How to run: in this process (default), on ``threads`` threads, on a local dask cluster of
    ``workers`` processes, on a running ``scheduler`` (address; ``security``: TLS for it) or an
    existing dask ``client``; ``progress``: progress on stderr (a bar on a terminal, lines in a log).

    ``intersector``: an intersector object to find the hits with in this process (e.g.
    ``straylight.intersect.ReferenceIntersector``; default: the scene's Embree one). ``first_chunk``:
    this call traces the chunks ``first_chunk, first_chunk + 1, ...`` of a longer run (the ray ids from
    ``first_chunk * CHUNK_RAYS`` on, each chunk with its own random stream), so rounds of traces pool
    exactly into the trace of all their rays (:func:`straylight.analyses.precision.merge_results`):
    how a run is split, not what it computes."""

    workers: int | None = None
    client: object = None
    scheduler: str | None = None
    threads: int | None = None
    security: object = None
    progress: bool = False
    intersector: object = None
    first_chunk: int = 0

    def __post_init__(self):
        for name in ("workers", "threads"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
                raise TraceError(f"execution: {name} must be a positive integer, got {v!r}")
        if isinstance(self.first_chunk, bool) or not isinstance(self.first_chunk, int) or self.first_chunk < 0:
            raise TraceError(f"execution: first_chunk must be a non-negative integer, got {self.first_chunk!r}")
        if self.client is not None and self.scheduler is not None:
            raise TraceError("execution: give a dask client or a scheduler address, not both")

    def trace_keywords(self) -> dict:
        """The keywords the batch scheduler (:func:`straylight.engine.scheduling.run_batches`) takes."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("progress", "first_chunk")}

    def describe(self) -> dict:
        """Where it runs, for a report: threads, workers and the scheduler's address (a client's own)."""
        scheduler = self.scheduler
        if self.client is not None:
            scheduler = getattr(getattr(self.client, "scheduler", None), "address", None)
        return {"threads": self.threads, "workers": self.workers, "scheduler": scheduler}

    def quiet(self) -> Execution:
        """The same, without progress output (a step inside a larger run that shows its own)."""
        return replace(self, progress=False) if self.progress else self

    @contextmanager
    def opened(self, in_process_below: int = 2):
        """This execution with one dask client open for a whole run of many traces (one local cluster,
        not one per trace): ``workers`` or ``scheduler`` become a ``client``; ``workers`` below
        ``in_process_below`` run in this process (:func:`straylight.engine.backends.dask.dask_client`). A given
        client, or nothing to start, is yielded as it is."""
        if self.client is not None or (self.workers is None and self.scheduler is None):
            yield self
            return
        from straylight.engine.backends.dask import dask_client  # the engine and dask: only when a cluster is asked for

        with dask_client(self.workers, self.scheduler, security=self.security,
                         in_process_below=in_process_below) as client:
            yield replace(self, client=client, workers=None, scheduler=None)


def as_execution(execution: Execution | None) -> Execution:
    """``execution``, or the default (this process, no progress) for None."""
    if execution is None:
        return Execution()
    if not isinstance(execution, Execution):
        raise TraceError(f"execution must be a straylight.execution.Execution, got {type(execution).__name__}")
    return execution
