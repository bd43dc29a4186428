"""Random streams keyed by (seed, chunk of ray ids).

Ray ids ``0 .. n_rays-1`` are cut into chunks of the constant :data:`CHUNK_RAYS`.
Chunk ``k`` draws every random number it needs from ``np.random.default_rng([seed, k])``,
in a fixed order (STYLE §5), so results do not depend on how chunks are grouped into
batches or spread over workers.
"""
from __future__ import annotations

import numpy as np

CHUNK_RAYS = 1000


class SeedError(ValueError):
    """A seed or ray count that cannot key the random streams."""


def check_seed(seed) -> int:
    """Return ``int(seed)``; seeds are non-negative integers."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise SeedError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def chunk_rng(seed: int, chunk: int) -> np.random.Generator:
    """The generator of chunk ``chunk`` (PCG64 seeded by the entropy list [seed, chunk])."""
    return np.random.default_rng([check_seed(seed), int(chunk)])


def n_chunks(n_rays: int, chunk_rays: int = CHUNK_RAYS) -> int:
    return -(-int(n_rays) // chunk_rays)


def chunk_bounds(chunk: int, n_rays: int, chunk_rays: int = CHUNK_RAYS) -> tuple[int, int]:
    """First and one-past-last ray id of ``chunk``."""
    start = chunk * chunk_rays
    return start, min(start + chunk_rays, int(n_rays))


def batches(n_rays: int, batch_rays: int, chunk_rays: int = CHUNK_RAYS) -> list[tuple[int, int]]:
    """Consecutive chunk ranges ``(first_chunk, stop_chunk)`` of about ``batch_rays`` rays each."""
    per = max(1, int(batch_rays) // chunk_rays)
    total = n_chunks(n_rays, chunk_rays)
    return [(k, min(k + per, total)) for k in range(0, total, per)]
