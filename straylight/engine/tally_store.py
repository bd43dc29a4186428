"""Where a batch's per-ray tallies go: x[row, ray] (rows: :class:`~straylight.engine.tally_rows.TallyRows`),
each cell a sum of the walk's writes in the order they are made.

- :class:`LoggedTallies` (the compiled walk): an append-only log of (row, ray, value) writes,
  made by the kernels through :func:`tally_add`. A ray touches a few rows of the few parts it hits,
  so the log is small where the dense matrix of an assembly with many parts is not: the 0.36M-
  triangle assembly's 310 rows x 38k rays were 96 MB per worker, of which 1.3 % non-zero, read back
  whole by every batch's sums, so two workers on one machine competed for memory bandwidth.
- :class:`DenseTallies` (the numpy reference walk): the (rows, rays) matrix M itself.

Both give the same per-chunk sums to the bit (:func:`straylight.engine.tallies.log_chunk_sums`
replays the dense sums on the log). Writes from numpy code (first- and second-vertex sampling) go
through ``add`` / ``subtract`` on either store; ``x -= c`` and ``x += (-c)`` are the same in IEEE
arithmetic.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from atomicio.inputs import physical_memory_bytes
from materials.jit_cache import njit

from straylight.engine.tallies import chunk_sums_numpy, log_chunk_sums


#: bytes the compiled walk's tally log of one batch may take (None: a quarter of this machine's memory).
#: Paths that never end (a closed perfect-mirror cavity with a large --max-events) grew the log by
#: ~20-30 MB/s until "Allocation failed"; past the budget the batch stops with a clear error.
LOG_BUDGET_BYTES: int | None = None
BYTES_PER_WRITE = 16  # row int32 + ray int32 + value float64


class TallyLogBudgetError(MemoryError):
    """The walk's tally log of one batch would outgrow :data:`LOG_BUDGET_BYTES`."""


def log_budget_bytes() -> float:
    if LOG_BUDGET_BYTES is not None:
        return float(LOG_BUDGET_BYTES)
    memory = physical_memory_bytes()
    return memory / 4 if memory else float("inf")


class TallyLog(NamedTuple):
    """The log as the kernels see it: ``count[0]`` writes so far; the first ``len(value)`` are kept."""

    row: np.ndarray  # int32
    ray: np.ndarray  # int32 (ray index in the batch)
    value: np.ndarray  # float64
    count: np.ndarray  # int64 (1,)


@njit(cache=True, nogil=True, inline="always")
def tally_add(log, row, ray, value):
    """x[row, ray] += value, as the next entry of the log. A write past the log's capacity is not
    stored but counted (``LoggedTallies.sums`` then raises): callers reserve room first."""
    k = log.count[0]
    if k < len(log.value):
        log.row[k] = row
        log.ray[k] = ray
        log.value[k] = value
    log.count[0] = k + 1


class LoggedTallies:
    """The compiled walk's tally store (module doc). ``reserve(k)`` before a kernel that may make up to
    k writes; then pass :attr:`log` (fetched after the reserve: the arrays may have grown)."""

    def __init__(self, n_rows: int, n_rays: int, capacity: int = 0):
        self.n_rows, self.n_rays = int(n_rows), int(n_rays)
        self.log = self._empty(max(int(capacity), 8 * self.n_rays, 1024))

    @staticmethod
    def _empty(cap: int) -> TallyLog:
        return TallyLog(np.empty(cap, np.int32), np.empty(cap, np.int32), np.empty(cap), np.zeros(1, np.int64))

    def reset(self, n_rows: int, n_rays: int) -> LoggedTallies:
        """Empty again, for a new batch (the arrays are kept)."""
        self.n_rows, self.n_rays = int(n_rows), int(n_rays)
        self.log.count[0] = 0
        return self

    @property
    def count(self) -> int:
        return int(self.log.count[0])

    @property
    def kernel_arg(self) -> TallyLog:
        return self.log

    def reserve(self, k: int) -> None:
        """Room for ``k`` more writes (the arrays double until they fit)."""
        n = self.count
        cap = len(self.log.value)
        if n + k <= cap:
            return
        if n > cap:
            raise RuntimeError(f"tally log overflow: {n} writes into {cap} slots (a kernel wrote more than it reserved)")
        size = max(2 * cap, n + int(k))
        budget = log_budget_bytes()
        if size * BYTES_PER_WRITE > budget:
            size = n + int(k)  # the least that fits, before giving up
            if size * BYTES_PER_WRITE > budget:
                raise TallyLogBudgetError(
                    f"the walk's tally records for {self.n_rays} rays reached {n * BYTES_PER_WRITE / 2**30:.3g} GB "
                    f"({n:,} writes), past the {budget / 2**30:.3g} GB budget (a quarter of this machine's memory): "
                    f"paths that do not end, as in a closed mirror cavity; lower --max-events or give the cavity an "
                    f"absorbing or escaping part")
        new = self._empty(size)
        for a, b in zip(new[:3], self.log[:3]):
            a[:n] = b[:n]
        new.count[0] = n
        self.log = new

    def add(self, row, ray, value) -> None:
        """x[row, ray] += value for each element, in order (``row`` may be a scalar)."""
        value = np.asarray(value, dtype=np.float64)
        m = value.size
        if m == 0:
            return
        self.reserve(m)
        n = self.count
        self.log.row[n:n + m] = row
        self.log.ray[n:n + m] = ray
        self.log.value[n:n + m] = value
        self.log.count[0] = n + m

    def subtract(self, row, ray, value) -> None:
        """x[row, ray] -= value for each element, in order."""
        self.add(row, ray, -np.asarray(value, dtype=np.float64))

    def sums(self, chunk: int, rows):
        """Per-chunk (S1, S2) of every tally row and the derived rows (``tallies.chunk_sums_numpy``'s)."""
        n, cap = self.count, len(self.log.value)
        if n > cap:
            raise RuntimeError(f"tally log overflow: {n} writes into {cap} slots (a kernel wrote more than it reserved)")
        return log_chunk_sums(self.log.row, self.log.ray, self.log.value, n, self.n_rays, chunk, rows)


class DenseTallies:
    """The numpy reference walk's tally store: the (rows, rays) matrix M, passed whole to the numpy kernels."""

    def __init__(self, n_rows: int, n_rays: int):
        self.n_rows, self.n_rays = int(n_rows), int(n_rays)
        self.M = np.zeros((self.n_rows, self.n_rays))

    @property
    def kernel_arg(self) -> np.ndarray:
        return self.M

    def reserve(self, k: int) -> None:
        """Nothing to do: every cell exists."""

    def add(self, row, ray, value) -> None:
        np.add.at(self.M, (row, ray), value)

    def subtract(self, row, ray, value) -> None:
        np.subtract.at(self.M, (row, ray), value)

    def sums(self, chunk: int, rows):
        return chunk_sums_numpy(self.M, chunk, rows)
