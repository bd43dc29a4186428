"""Requests beyond what the machine has, refused up front with the estimate.

A trace keeps, in the process that combines the results, two small tallies per chunk of
:data:`straylight.rng.CHUNK_RAYS` rays (the detector sums behind the reliability checks:
``straylight.engine.results.BatchTotals``) and a list of batch ranges, so its memory grows with the
number of rays whatever runs the rays: ``--rays 99999999999999999999`` used to grow to 6 GB before
the first ray. :func:`check_ray_budget` estimates that memory and the time (at a nominal rate per
core) and refuses, in one line with both numbers, a request whose memory is more than half this
machine's: it could never finish here.
"""
from __future__ import annotations

import os

from atomicio.inputs import physical_memory_bytes
from straylight.rng import CHUNK_RAYS

NUMPY_ARRAY_BYTES = 112  # sys.getsizeof of an empty 1-d numpy array (header), numpy 1.26-2.x
NOMINAL_RAYS_PER_S_PER_CORE = 1.0e6  # the order of the reference tube's rate (README speed rows)


def chunk_tally_bytes(n_detectors: int = 1) -> int:
    """Bytes the combining process keeps per chunk: two arrays of the detectors' sums, their list
    slots, and the (chunks, detectors) arrays they become."""
    n = max(1, int(n_detectors))
    return 2 * (NUMPY_ARRAY_BYTES + 8 * n) + 16 + 16 * n


def _human_seconds(s: float) -> str:
    for unit, size in (("years", 365.25 * 86400), ("days", 86400), ("hours", 3600), ("minutes", 60)):
        if s >= size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.3g} s"


def check_ray_budget(n_rays, n_detectors: int = 1, what: str = "--rays", memory_bytes: int | None = None) -> None:
    """Raise ValueError (one line, with the estimate) if ``n_rays`` rays need more than half of
    ``memory_bytes`` (default: this machine's physical memory) for their chunk tallies."""
    n = int(n_rays)
    memory = physical_memory_bytes() if memory_bytes is None else int(memory_bytes)
    if memory <= 0 or n < 1:
        return
    chunks = -(-n // CHUNK_RAYS)
    need = chunks * chunk_tally_bytes(n_detectors)
    if need <= memory // 2:
        return
    cores = os.cpu_count() or 1
    seconds = n / (NOMINAL_RAYS_PER_S_PER_CORE * cores)
    raise ValueError(f"{what} {n:.3g}: its {chunks:.3g} chunk tallies alone need about {need / 2**30:.3g} GB, more "
                     f"than half this machine's {memory / 2**30:.3g} GB (and about {_human_seconds(seconds)} at "
                     f"{NOMINAL_RAYS_PER_S_PER_CORE:.0e} rays/s on {cores} cores); trace at most "
                     f"{memory // 2 // chunk_tally_bytes(n_detectors) * CHUNK_RAYS:.3g} rays per run (several runs "
                     f"with other --seed values pool exactly)")


WORKER_PROCESS_BYTES = 300 * 2**20  # a worker process with the engine loaded (README: 307-369 MB peak RSS)
MAX_THREADS_PER_CORE = 32


def check_worker_budget(workers, processes: bool = False, what: str = "--workers") -> None:
    """Refuse a local pool this machine cannot hold: worker processes whose start-up memory alone
    (:data:`WORKER_PROCESS_BYTES` each) exceeds half the machine's, or more than
    :data:`MAX_THREADS_PER_CORE` threads per core (``--workers 99999 --processes`` would fork 99999
    interpreters)."""
    if workers is None or int(workers) < 1:
        return
    n = int(workers)
    cores = os.cpu_count() or 1
    memory = physical_memory_bytes()
    if processes and memory and n * WORKER_PROCESS_BYTES > memory // 2:
        raise ValueError(f"{what} {n} --processes: about {n * WORKER_PROCESS_BYTES / 2**30:.3g} GB for the worker "
                         f"processes alone (~{WORKER_PROCESS_BYTES // 2**20} MB each), more than half this machine's "
                         f"{memory / 2**30:.3g} GB; this machine has {cores} cores")
    if n > MAX_THREADS_PER_CORE * cores:
        raise ValueError(f"{what} {n}: more than {MAX_THREADS_PER_CORE} per core on this machine's {cores} cores; "
                         f"use a cluster (--scheduler) for more")


EMBREE_BYTES_PER_TRIANGLE = 600  # address space Embree's BVH build takes per triangle (measured: ~515 B, 1e6 triangles)


def address_space_left_bytes() -> float:
    """Bytes this process may still map under its address-space limit (``ulimit -v``, RLIMIT_AS); inf if none."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):
        return float("inf")
    if soft in (resource.RLIM_INFINITY, -1) or soft <= 0:
        return float("inf")
    try:
        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        used = 0
    return float(soft - used)


def check_embree_address_space(n_triangles: int, left_bytes: float | None = None) -> None:
    """Refuse (ValueError, one line) a scene whose Embree BVH would not fit in the address space left
    under this process's limit: Embree then aborts the process (SIGABRT / SIGSEGV, no message; an
    11.5 M-triangle scene under ``ulimit -v``)."""
    left = address_space_left_bytes() if left_bytes is None else float(left_bytes)
    need = int(n_triangles) * EMBREE_BYTES_PER_TRIANGLE
    if need <= left:
        return
    raise ValueError(f"the scene's {int(n_triangles):,} triangles need about {need / 2**30:.3g} GB of address space "
                     f"for the intersector (Embree, ~{EMBREE_BYTES_PER_TRIANGLE} B per triangle), more than the "
                     f"{max(left, 0) / 2**30:.3g} GB left under this process's limit (ulimit -v); raise the limit "
                     f"or mesh coarser (a larger tolerance_mm)")
