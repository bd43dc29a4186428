"""The chunk sums skip the rows of parts a chunk's rays did not hit (straylight.engine.tallies,
``parts_hit``): check on real batches that every block they skip is all zeros, and that the
sums equal the numpy reference's, which sums every block."""
from pathlib import Path

import numpy as np
import pytest

from straylight.engine.kernel_sets import COMPILED
from straylight.engine.tallies import chunk_sums, chunk_sums_numpy
from straylight.engine.walk import walk
from straylight.rng import CHUNK_RAYS

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"


def _spec(scene, sources, n, seed, materials, options):
    """make_spec plus the sampling tables trace() adds (straylight.trace.trace)."""
    from dataclasses import replace

    from straylight.engine.compiled_scene import compiled_scene
    from straylight.engine.first_vertex import build_table
    from straylight.engine.second_vertex import build_table as build_critical_table
    from straylight.trace import make_spec

    spec = make_spec(scene, sources, n, seed, materials, options)
    if options.first_vertex_sampling:
        spec = replace(spec, vertex_table=build_table(spec, compiled_scene(spec)))
    if options.second_vertex_sampling:
        spec = replace(spec, critical_table=build_critical_table(spec, compiled_scene(spec)))
    return spec


def _checked_kernels(seen):
    def checking_sums(M, chunk, rows, clear=False, parts_hit=None):
        assert parts_hit is not None
        P = rows.n_parts
        for c in range(parts_hit.shape[0]):
            block = M[:rows.truncated + P, c * chunk:(c + 1) * chunk]
            for k in np.flatnonzero(~parts_hit[c]):
                assert not block[k::P].any(), f"part {k} not hit in chunk {c} but its rows are non-zero"
        seen.append((int(parts_hit.sum()), parts_hit.size))
        want = chunk_sums_numpy(M.copy(), chunk, rows)
        got = chunk_sums(M, chunk, rows, clear, parts_hit)
        assert all(np.array_equal(g, w) for g, w in zip(got, want))
        return got
    return COMPILED._replace(chunk_sums=checking_sums)


@pytest.mark.parametrize("opts", [
    dict(),
    dict(max_events=2, nee_samples=2, detector_sides="front"),
    dict(first_vertex_sampling=True),
    dict(first_vertex_sampling=True, max_events=1),  # vertex parts the walk barely reaches
    dict(second_vertex_sampling=True, max_events=1),
    dict(nee=False, rr_threshold=0.3),
    dict(second_vertex_sampling=True),
])
def test_skipped_blocks_are_zero(opts):
    from straylight.scene import load_scene
    from straylight.trace import TraceOptions

    rs = load_scene(GOLDEN / "tube_mixed.toml")
    sources = rs.sources[:1] if opts.get("first_vertex_sampling") or opts.get("second_vertex_sampling") else rs.sources
    spec = _spec(rs.scene, sources, 6 * CHUNK_RAYS, 3, rs.materials, TraceOptions(**opts))
    seen = []
    walk(spec, 0, 6, None, _checked_kernels(seen))
    hit, size = seen[0]
    assert 0 < hit <= size


def test_pairwise_sums_are_numpys():
    """The compiled pairwise sums (with their reused scratch) equal numpy's own sum to the bit."""
    from straylight.engine.pairwise_sums import pairwise_sums, pairwise_sums_with, pairwise_work

    rng = np.random.default_rng(5)
    x = rng.standard_normal(80_000) * np.exp(rng.uniform(-30, 30, 80_000))
    ist, fst = pairwise_work()
    for n in (0, 1, 7, 8, 9, 127, 128, 129, 136, 255, 256, 999, 1000, 1001, 4097, 70_001):
        for lo in (0, 3):
            want = (np.add.reduce(x[lo:lo + n]), np.add.reduce(x[lo:lo + n] * x[lo:lo + n]))
            assert pairwise_sums_with(x, lo, n, ist, fst) == want, n
            assert pairwise_sums(x, lo, n) == want, n


def test_any_nonzero_finds_every_position():
    from numba import njit

    from straylight.engine.pairwise_sums import any_nonzero

    call = njit(lambda x, a, b: any_nonzero(x, a, b))
    x = np.zeros(700)
    assert not call(x, 0, 700)
    for i in (0, 5, 255, 256, 257, 511, 699):
        for value in (1e-300, -2.0, np.nan):
            x[i] = value
            assert call(x, 0, 700) and call(x, i, i + 1) and not call(x, i + 1, 700)
            assert call(x, 0, i + 1) and not call(x, 0, i)
            x[i] = 0.0


def test_sampled_vertices_on_parts_the_walk_never_hits():
    """A beam from inside the tube lights only the wall and the walk stops after that first event,
    while second-vertex sampling puts vertices on the parts of its table: their rows may be written
    with no walk hit there, so the walk marks those parts itself (with the table built from probes of
    direct irradiance, the table here holds only lit parts: the check then covers the marking only)."""
    opts = dict(second_vertex_sampling=True)
    from straylight.engine.walk import walk as walk_fn
    from straylight.scene import load_scene
    from straylight.sources import CollimatedDisk
    from straylight.trace import TraceOptions

    rs = load_scene(GOLDEN / "tube_mixed.toml")
    beam = CollimatedDisk([0, 0, 100], [1, 0, 0], [1, 0, 0], 5.0)
    spec = _spec(rs.scene, [beam], 3 * CHUNK_RAYS, 5, rs.materials, TraceOptions(max_events=1, **opts))
    seen = []
    checked = _checked_kernels(seen)
    hit_parts = set()

    def hits_recording(tri, rays, scene, rows, settings, M, parts_hit):
        out = COMPILED.hits(tri, rays, scene, rows, settings, M, parts_hit)
        hit_parts.update(np.unique(out[3][out[3] >= 0]).tolist())
        return out

    walk_fn(spec, 0, 3, None, checked._replace(hits=hits_recording))
    assert hit_parts == {rs.scene.part_names.index("wall")}
    table_parts = set(np.unique(spec.triangle_part[spec.critical_table.tri]).tolist())
    # every chunk marks the wall and the table's parts (the zero check above ran on the rest)
    assert seen and seen[0][0] == 3 * len(table_parts | hit_parts)
