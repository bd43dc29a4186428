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


def stream_chunk(chunk: int, stream: int, n_streams: int) -> int:
    """The chunk id (the key of :func:`chunk_rng`) of chunk ``chunk`` of stream ``stream``, when one run
    draws ``n_streams`` independent sequences of chunks from one seed (thermal: one per detector and
    traced sub-band, straylight.thermal.run): interleaved, ``chunk * n_streams + stream``, so every
    (stream, chunk) has its own generator, and a stream can grow by whole chunks round after round."""
    if not 0 <= int(stream) < int(n_streams):
        raise ValueError(f"stream {stream} is not one of {n_streams} streams")
    return int(chunk) * int(n_streams) + int(stream)


def chunk_stream_uniforms(gens: dict, seed: int, first_chunk: int, stream: int, ray: np.ndarray,
                          width: int) -> np.ndarray:
    """(len(ray), width) uniforms for the rays ``ray`` of a batch, each chunk's rows drawn in ray order
    from its own generator ``default_rng([seed, first_chunk + chunk, stream])`` (kept in ``gens`` by chunk,
    so a batch's later calls continue the same streams): what a chunk draws depends on its rays only,
    not on how chunks are grouped into batches (a strategy's own draws, e.g. NEE splitting's)."""
    out = np.empty((len(ray), width))
    chunk = ray // CHUNK_RAYS
    order = np.argsort(ray, kind="stable")
    for c in np.unique(chunk):
        at = order[chunk[order] == c]
        gen = gens.get(int(c))
        if gen is None:
            gen = gens[int(c)] = np.random.default_rng([seed, first_chunk + int(c), stream])
        out[at] = gen.random((len(at), width))
    return out


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


# ------------------------------------------------------------------ the same streams, compiled
#
# chunk_rng(seed, k) is PCG64 (XSL-RR 128/64; O'Neill 2014) seeded through SeedSequence([seed, k])
# (numpy/random/bit_generator.pyx, numpy/random/src/pcg64). straylight.pcg64 redoes both steps
# and the uniform draw (next64 >> 11) * 2^-53 in numba, so that the engine seeds its chunks' generators
# and fills its draws without Python calls or the GIL; they give numpy's numbers bit for bit
# (tests/straylight/test_rng.py), and run_batch_reference still draws with numpy's Generator, so the
# engine's bit-identity tests check them end to end as well.


def _entropy_words(value: int) -> list:
    """SeedSequence's uint32 words of a non-negative int (little-endian, [0] for 0)."""
    words = [value & 0xFFFFFFFF]
    value >>= 32
    while value:
        words.append(value & 0xFFFFFFFF)
        value >>= 32
    return words


class ChunkStreams:
    """The generators of chunks ``first_chunk .. stop_chunk-1`` (the streams of :func:`chunk_rng`),
    as a (chunks, 4) uint64 PCG64 state table filled by compiled code.

    ``fill(rows, width, out, per_chunk=1)`` writes, for each i, the next ``width`` uniforms of chunk
    ``c = rows[i] // per_chunk`` (relative to first_chunk; rows of a chunk contiguous, chunks
    ascending): what ``chunk_rng(seed, first_chunk + c).random((rows of c, width))`` gives, bit for bit."""

    def __init__(self, seed: int, first_chunk: int, stop_chunk: int, chunk_ids=None):
        """``chunk_ids``: the generators of these chunk ids instead (row c of the table is ``chunk_ids[c]``:
        chunks that are not consecutive, such as one stream's of :func:`stream_chunk`)."""
        seed = check_seed(seed)
        ids = range(int(first_chunk), int(stop_chunk)) if chunk_ids is None else [int(k) for k in chunk_ids]
        ents = [_entropy_words(seed) + _entropy_words(k) for k in ids]
        width = max((len(e) for e in ents), default=0)
        words = np.zeros((len(ents), max(width, 1)), np.uint64)
        for r, e in enumerate(ents):
            words[r, :len(e)] = e
        n_words = np.array([len(e) for e in ents], np.int64)
        from straylight.pcg64 import seed_states

        self.states = seed_states(words, n_words, np.empty((len(ents), 4), np.uint64))

    def fill(self, rows, width, out, per_chunk=1):
        from straylight.pcg64 import fill_uniforms

        return fill_uniforms(self.states, np.asarray(rows, dtype=np.int64), int(per_chunk), int(width), out)


class BatchDraws:
    """The uniforms of a batch of whole chunks traced together (rays ``0 .. sum(counts)-1``, chunk ``j``
    holding rays ``j * CHUNK_RAYS ..``, every chunk full but the last): each ray draws from its own
    chunk's stream (``chunk_rng(seed, chunk_ids[j])``), so a chunk gets the numbers it would get traced
    alone, whatever batch or thread it runs in. ``uniforms(rays, width)``: the next ``width`` uniforms
    of each ray in ``rays`` (ascending ray numbers)."""

    def __init__(self, seed: int, chunk_ids, counts):
        counts = [int(m) for m in counts]
        if any(m != CHUNK_RAYS for m in counts[:-1]) or not 0 < counts[-1] <= CHUNK_RAYS:
            raise ValueError(f"a batch is whole chunks of {CHUNK_RAYS} rays (the last may be short), got {counts}")
        self.chunk_ids = [int(k) for k in chunk_ids]
        self.counts = counts
        self.n_rays = sum(counts)
        self._streams = ChunkStreams(seed, 0, 0, chunk_ids=self.chunk_ids)

    def uniforms(self, rays, width: int) -> np.ndarray:
        rays = np.ascontiguousarray(rays, dtype=np.int64)
        return self._streams.fill(rays, int(width), np.empty((len(rays), int(width))), per_chunk=CHUNK_RAYS)

    def all(self, width: int) -> np.ndarray:
        """The next ``width`` uniforms of every ray of the batch."""
        return self.uniforms(np.arange(self.n_rays), width)

    def chunk_sums(self, values) -> tuple:
        """Per chunk, the sums and sums of squares of per-ray ``values`` (..., n_rays): two arrays (..., chunks)."""
        v = np.asarray(values, dtype=np.float64)
        edges = np.cumsum([0] + self.counts)
        s1 = np.stack([v[..., a:b].sum(axis=-1) for a, b in zip(edges[:-1], edges[1:])], axis=-1)
        s2 = np.stack([(v[..., a:b] ** 2).sum(axis=-1) for a, b in zip(edges[:-1], edges[1:])], axis=-1)
        return s1, s2
