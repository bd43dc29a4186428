"""straylight.rng.ChunkStreams (compiled PCG64 + SeedSequence) against numpy's own generators:
the engine's draws must be chunk_rng(seed, k).random(...) bit for bit (numpy is the independent
reference here: np.random.default_rng([seed, k]))."""
import numpy as np
import pytest

from straylight.rng import ChunkStreams, chunk_rng


@pytest.mark.parametrize("seed", [0, 1, 7, 2**32 - 1, 2**32, 2**40 + 3, 2**64 - 1, 2**64 + 5, 3**50])
def test_seeding_gives_numpy_pcg64_state(seed):
    chunks = [0, 1, 2, 999, 2**32 + 1]
    for k in chunks:
        st = ChunkStreams(seed, k, k + 1).states[0]
        ref = np.random.default_rng([seed, k]).bit_generator.state["state"]
        assert (int(st[0]) << 64 | int(st[1])) == ref["state"]
        assert (int(st[2]) << 64 | int(st[3])) == ref["inc"]


def test_fill_continues_each_chunk_stream_like_numpy():
    """Several 'events' of uneven live rows per chunk, as run_batch draws them."""
    seed, first, stop = 12345, 40, 44
    streams = ChunkStreams(seed, first, stop)
    gens = [chunk_rng(seed, k) for k in range(first, stop)]
    rng = np.random.default_rng(0)
    for width in (5, 7, 7, 11, 1, 7):
        counts = rng.integers(0, 30, size=stop - first)
        counts[rng.integers(0, stop - first)] = 0  # a chunk with no live ray this event
        # live ray ids (ascending, 30 rays per chunk), as run_batch passes them
        ids = np.concatenate([30 * c + np.sort(rng.choice(30, size=k, replace=False)) for c, k in enumerate(counts)])
        got = streams.fill(ids, width, np.empty((len(ids), width)), per_chunk=30)
        want = np.concatenate([g.random((c, width)) for g, c in zip(gens, counts)])
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
