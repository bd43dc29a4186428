"""The compiled engine (the numba kernels of straylight.engine, used by run_batch) against their
numpy twins (run_batch_reference: the same walk): the same random streams and arithmetic order, so every tally, map bin and
path record must be bit-identical, not merely close (STYLE §9: a fast path with a slow reference
beside it, tested against each other)."""
import math

import numpy as np
import pytest
from numba import njit

from engine_helpers import StandInLambertian, annulus_part, baffled_tube_scene, disk_part
from geometry.mesh import Part, Scene
from straylight.engine.tally_store import DenseTallies, LoggedTallies, tally_add
from straylight.engine.tally_rows import TallyRows
from straylight.sources import CollimatedDisk, PointSource
from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions, make_spec, run_batch, run_batch_reference


def _same(a, b, where=""):
    """Exact equality of nested batch results (dicts, lists, arrays, numbers)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


def _plate_scene():
    floor = disk_part("floor", 0.0, 40.0, 128, role="surface", material="grey")
    det = disk_part("det", 30.0, 8.0, 64, role="detector")
    det = Part("det", det.vertices_mm + np.array([-25.0, 0.0, 0.0]), det.faces, role="detector")
    mirror = annulus_part("mirror", 60.0, 0.0001, 30.0, 64, role="mirror", facing=-1)
    stop = annulus_part("stop", 45.0, 20.0, 35.0, 64, role="absorber")
    det2 = disk_part("det2", 12.0, 5.0, 32, role="detector")
    det2 = Part("det2", det2.vertices_mm + np.array([25.0, 0.0, 0.0]), det2.faces, role="detector")
    return Scene((floor, det, mirror, stop, det2))


PLATE_SOURCES = [CollimatedDisk([0, 0, 50], [0, 0, -1], [0.3, 0, -1], 15.0, power_w=2.0), PointSource([0, 0, 20], 1.0)]
CASES = {
    "nee_paths_two_detectors": TraceOptions(output=OutputOptions(record_paths=True)),
    "no_nee": TraceOptions(estimator=EstimatorOptions(nee=False), output=OutputOptions(record_paths=True)),
    "nee_samples_roulette_mirror": TraceOptions(estimator=EstimatorOptions(nee_samples=2, rr_threshold=0.4), physics=PhysicsOptions(mirror_reflectance=0.7)),
    "front_truncated": TraceOptions(output=OutputOptions(detector_sides="front", record_paths=True), physics=PhysicsOptions(max_events=2)),
    "target": TraceOptions(estimator=EstimatorOptions(target_parts=("det",)), output=OutputOptions(record_paths=True)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_batch_is_bit_identical_to_numpy_reference(case):
    spec = make_spec(_plate_scene(), PLATE_SOURCES, 3500, seed=9, materials={"grey": StandInLambertian(0.5)},
                     options=CASES[case])
    fast = run_batch(spec, 1, 4)  # chunks 1..3, the last one partial
    ref = run_batch_reference(spec, 1, 4)
    assert fast["s1"].shape[0] == 3 and np.abs(fast["s1"]).sum() > 0  # sanity: something was tallied
    _same(fast, ref)


def test_compiled_batch_matches_reference_with_two_real_materials():
    """Glossy K-correlation and Lambertian materials on different parts (per-material grouping)."""
    from materials import Lambertian, load_material

    scene = baffled_tube_scene()
    names = sorted({p.material for p in scene.parts if p.role == "surface"})
    parts = [Part(p.name, p.vertices_mm, p.faces, role=p.role,
                  material=("glossy" if p.name == "wall" else p.material) if p.role == "surface" else None)
             for p in scene.parts]
    mats = {names[0]: Lambertian(0.05), "glossy": load_material("z302_sample_a")}
    src = CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(0.35), 0, -math.cos(0.35)], 60.0)
    spec = make_spec(Scene(tuple(parts)), src, 2000, seed=3, materials=mats,
                     options=TraceOptions(output=OutputOptions(record_paths=True), physics=PhysicsOptions(polarization="s")))
    fast, ref = run_batch(spec, 0, 2), run_batch_reference(spec, 0, 2)
    assert fast["paths"] is not None and len(fast["paths"]["ray"]) > 0
    _same(fast, ref)


_ROWS = TallyRows(n_parts=2, n_detectors=1, incident=-1, first_hit=-1, absorbed=0, roulette=2, nee_exchange=4,
                  truncated=6, detector_nee=8, detector_direct=10, detector_walk=-1, escaped=-1, n_per_ray=13,
                  ledger_absorbed=13, detector_total=15, n_summed=16)


@njit(cache=False)
def _log_writes(log, row, ray, value):
    for e in range(len(value)):
        tally_add(log, row[e], ray[e], value[e])


@pytest.mark.parametrize("n", [1, 7, 8, 9, 129, 1000, 2345])
@pytest.mark.parametrize("fill", [0.002, 0.05, 0.9])
def test_logged_chunk_sums_equal_numpy_reduceat(n, fill):
    """Per-chunk S1, S2 (and the derived ledger rows) from the log of writes (compiled, as the walk's
    kernels make them, and from numpy's add / subtract) equal np.add.reduceat on the dense matrix of the
    same writes, to the bit: cells written several times (in write order), subtractions, cancellations
    to exactly 0, sparse and dense blocks, chunk edges."""
    rng = np.random.default_rng(n)
    m = max(4, int(fill * 13 * n * 2))
    row = rng.integers(0, 13, m)
    ray = rng.integers(0, n, m)
    ray[:4] = [0, n - 1, min(999, n - 1), min(1000, n - 1)]  # block edges
    value = rng.normal(size=m) * np.exp(4 * rng.normal(size=m))
    value[rng.random(m) < 0.1] = 0.0
    dense = DenseTallies(13, n)
    logged = LoggedTallies(13, n, capacity=16)  # grows on reserve
    half = m // 2
    # first half as the kernels write (compiled tally_add), the rest through numpy's add / subtract
    logged.reserve(half)
    _log_writes(logged.kernel_arg, row[:half], ray[:half], value[:half])
    np.add.at(dense.M, (row[:half], ray[:half]), value[:half])
    for lo in range(half, m, 37):
        sl = slice(lo, min(lo + 37, m))
        if lo % 2:
            dense.subtract(row[sl], ray[sl], value[sl])
            logged.subtract(row[sl], ray[sl], value[sl])
        else:
            dense.add(row[sl], ray[sl], value[sl])
            logged.add(row[sl], ray[sl], value[sl])
    if m > 8:  # a cell that cancels to exactly zero
        for store in (dense, logged):
            store.add(5, ray[:1], [3.25])
            store.subtract(5, ray[:1], [3.25])
    M = dense.M
    ext = np.concatenate([M, M[0:2] + M[2:4] + M[4:6] + M[6:8], M[8:9] + M[10:11]])
    starts = np.arange(0, n, 1000)
    s1, s2 = logged.sums(1000, _ROWS)
    assert np.abs(s1).sum() > 0
    np.testing.assert_array_equal(s1, np.add.reduceat(ext, starts, axis=1).T)
    np.testing.assert_array_equal(s2, np.add.reduceat(ext * ext, starts, axis=1).T)
    d1, d2 = dense.sums(1000, _ROWS)
    np.testing.assert_array_equal(s1, d1)
    np.testing.assert_array_equal(s2, d2)
    # reused for a new batch: empty again, same arrays
    logged.reset(13, n)
    assert logged.count == 0 and not logged.sums(1000, _ROWS)[0].any()


def test_tally_log_overflow_is_an_error_not_a_silent_loss():
    """A kernel that writes more than was reserved does not write past the arrays; the sums refuse."""
    logged = LoggedTallies(13, 10, capacity=4)
    cap = len(logged.kernel_arg.value)
    k = cap + 3
    _log_writes(logged.kernel_arg, np.zeros(k, np.int64), np.zeros(k, np.int64), np.ones(k))
    assert logged.count == k
    with pytest.raises(RuntimeError, match="tally log overflow"):
        logged.sums(1000, _ROWS)


def _chunk_maps_numpy(map_rows, nch, C, D, bins):
    """The numpy formulation the compiled map sums replaced (reduceat per key, bincount per cell)."""
    nb = bins[0] * bins[1]
    out = [[None] * D for _ in range(nch)]
    ray, det, b, pw = (np.concatenate(x) for x in zip(*map_rows))
    key = (ray.astype(np.int64) * D + det) * nb + b
    order = np.argsort(key, kind="stable")
    key, pw = key[order], pw[order]
    ukey, start = np.unique(key, return_index=True)
    xr = np.add.reduceat(pw, start)
    cell = ((ukey // (nb * D)) // C * D + (ukey // nb) % D) * nb + ukey % nb
    ucell, cinv = np.unique(cell, return_inverse=True)
    cinv = cinv.ravel()
    s1 = np.bincount(cinv, weights=xr)
    s2 = np.bincount(cinv, weights=xr * xr)
    cd = ucell // nb
    for grp in np.split(np.arange(len(ucell)), np.flatnonzero(np.diff(cd)) + 1):
        c, j = divmod(int(cd[grp[0]]), D)
        out[c][j] = (ucell[grp] % nb, s1[grp], s2[grp])
    return out


def test_compiled_map_sums_equal_the_numpy_formulation():
    """Records with repeated (ray, detector, bin) keys (up to 40 contributions: pairwise sums),
    several detectors, empty chunks, in several record calls."""
    from straylight.engine.tallies import chunk_maps as _chunk_maps

    rng = np.random.default_rng(4)
    C, D, bins, nch = 100, 3, (4, 5), 6
    rows = []
    for _ in range(7):
        m = int(rng.integers(1, 400))
        ray = rng.integers(0, 4 * C, size=m)  # chunks 4 and 5 stay empty
        ray[: m // 4] = 17  # one ray with many contributions in one bin
        det = rng.integers(0, D, size=m)
        det[: m // 4] = 1
        b = rng.integers(0, 20, size=m)
        b[: m // 4] = 3
        rows.append((ray, det, b, rng.lognormal(size=m)))
    got = _chunk_maps(rows, nch, C, D, bins)
    want = _chunk_maps_numpy(rows, nch, C, D, bins)
    assert sum(e is not None for row in want for e in row) > 5
    _same(got, want)
