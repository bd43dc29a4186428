"""Where and how a trace runs: :class:`Execution` (issue 23), one object instead of six keywords.

``trace(..., execution=Execution(workers=2))`` runs exactly as ``trace(..., workers=2)``: the
numbers never depend on it (same seed, same results in process, on threads or on dask). The
keywords stay accepted; giving the same field both ways with different values is an error.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

from straylight.engine.options import TraceError

FIELDS = ("workers", "client", "scheduler", "threads", "security", "progress")


@dataclass(frozen=True)
class Execution:
    """How to run: in this process (default), on ``threads`` threads, on a local dask cluster of
    ``workers`` processes, on a running ``scheduler`` (address; ``security``: TLS for it) or an
    existing dask ``client``; ``progress``: a progress bar on stderr."""

    workers: int | None = None
    client: object = None
    scheduler: str | None = None
    threads: int | None = None
    security: object = None
    progress: bool = False

    def __post_init__(self):
        for name in ("workers", "threads"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
                raise TraceError(f"execution: {name} must be a positive integer, got {v!r}")
        if self.client is not None and self.scheduler is not None:
            raise TraceError("execution: give a dask client or a scheduler address, not both")

    @classmethod
    def merged(cls, execution: "Execution | None" = None, **keywords) -> "Execution":
        """``execution`` with the execution keywords of an older call signature applied (None or
        False: not given). The same field given both ways with different values is an error."""
        base = execution if execution is not None else cls()
        given = {k: v for k, v in keywords.items() if v is not None and v is not False}
        unknown = sorted(set(given) - set(FIELDS))
        if unknown:
            raise TraceError(f"execution: unknown field(s) {', '.join(unknown)}")
        default = cls()
        for k, v in given.items():
            mine = getattr(base, k)
            if execution is not None and mine != getattr(default, k) and mine is not v and mine != v:
                raise TraceError(f"execution: {k} given twice ({mine!r} in the Execution, {v!r} as a keyword)")
        return replace(base, **given) if given else base

    def trace_keywords(self) -> dict:
        """The keywords :func:`straylight.trace.trace` passes on to the batch scheduler."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "progress"}
