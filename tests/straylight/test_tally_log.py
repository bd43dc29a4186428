"""The compiled walk keeps its tallies as a log of writes (straylight.engine.tally_store): check on
real batches that the sums from the log equal the numpy reference's on the dense matrix of the same
writes, and that numpy's pairwise summation is replayed to the bit."""
from pathlib import Path

import numpy as np
import pytest

from straylight.engine.kernel_sets import COMPILED
from straylight.engine.tallies import chunk_sums_numpy
from straylight.engine.tally_store import DenseTallies, LoggedTallies
from straylight.engine.walk import walk
from straylight.rng import CHUNK_RAYS
from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"


def _spec(scene, sources, n, seed, materials, options):
    """make_spec plus the sampling tables trace() adds (straylight.trace.trace)."""
    from dataclasses import replace

    from straylight.engine.runtime import runtime
    from straylight.engine.first_vertex import build_table
    from straylight.engine.second_vertex import build_table as build_critical_table
    from straylight.trace import make_spec

    spec = make_spec(scene, sources, n, seed, materials, options)
    if options.estimator.first_vertex_sampling:
        spec = replace(spec, vertex_table=build_table(spec, runtime().scene(spec)))
    if options.estimator.second_vertex_sampling:
        spec = replace(spec, critical_table=build_critical_table(spec, runtime().scene(spec)))
    return spec


class _CheckedLog(LoggedTallies):
    """The compiled walk's log, whose sums are checked against the dense matrix of the same writes."""

    seen = []

    def sums(self, chunk, rows):
        got = super().sums(chunk, rows)
        n = self.count
        dense = DenseTallies(rows.n_per_ray, self.n_rays)
        dense.add(self.log.row[:n].astype(np.int64), self.log.ray[:n].astype(np.int64), self.log.value[:n])
        want = chunk_sums_numpy(dense.M, chunk, rows)
        assert all(np.array_equal(g, w) for g, w in zip(got, want))
        self.seen.append((n, np.count_nonzero(dense.M), dense.M.size))
        return got


@pytest.mark.parametrize("opts", [
    TraceOptions(),
    TraceOptions(estimator=EstimatorOptions(nee_samples=2), output=OutputOptions(detector_sides="front"),
                 physics=PhysicsOptions(max_events=2)),
    TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)),
    # vertex parts the walk barely reaches
    TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True), physics=PhysicsOptions(max_events=1)),
    TraceOptions(estimator=EstimatorOptions(second_vertex_sampling=True), physics=PhysicsOptions(max_events=1)),
    TraceOptions(estimator=EstimatorOptions(nee=False, rr_threshold=0.3)),
    TraceOptions(estimator=EstimatorOptions(second_vertex_sampling=True)),
], ids=["default", "front_truncated", "first_vertex", "first_vertex_1", "second_vertex_1", "walk_roulette",
        "second_vertex"])
def test_logged_sums_on_real_batches_equal_the_dense_matrix(opts):
    """On real batches of the compiled walk (every writer: hits, NEE, advance, first- and second-vertex
    sampling), the sums from the tally log equal np.add.reduceat on the dense matrix of its writes."""
    from straylight.scene import load_scene

    rs = load_scene(GOLDEN / "tube_mixed.toml")
    est = opts.estimator
    sources = rs.sources[:1] if est.first_vertex_sampling or est.second_vertex_sampling else rs.sources
    spec = _spec(rs.scene, sources, 6 * CHUNK_RAYS, 3, rs.materials, opts)
    _CheckedLog.seen = []
    walk(spec, 0, 6, None, COMPILED._replace(tallies=_CheckedLog))
    writes, nonzero, size = _CheckedLog.seen[0]
    assert 0 < nonzero <= writes < size


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


def test_sparse_pairwise_sums_are_numpys():
    """numpy's pairwise sums of a mostly-zero vector, read from its non-zero positions only, equal
    numpy's own sum of the whole vector to the bit (every block size, split and tail)."""
    from straylight.engine.pairwise_sums import pairwise_sums_sparse, pairwise_work

    rng = np.random.default_rng(11)
    ist, fst = pairwise_work()
    for n in (0, 1, 5, 7, 8, 9, 15, 16, 127, 128, 129, 136, 255, 256, 999, 1000, 1001, 4097):
        for k in (0, 1, 2, 9, 40, 200):
            x = np.zeros(n + 3)
            if n:
                pos = np.unique(rng.integers(0, n + 3, k))
                x[pos] = rng.standard_normal(len(pos)) * np.exp(rng.uniform(-30, 30, len(pos)))
            nz = np.flatnonzero(x)
            for lo in (0, 1, 3):
                m = max(0, min(n, len(x) - lo))
                want = (np.add.reduce(x[lo:lo + m]), np.add.reduce(x[lo:lo + m] * x[lo:lo + m]))
                inside = nz[nz < lo + m]  # positions below lo are skipped by the sum itself
                got = pairwise_sums_sparse(x, lo, m, inside, len(inside), ist, fst, np.empty((2, 8)))
                assert got == want, (n, k, lo)
