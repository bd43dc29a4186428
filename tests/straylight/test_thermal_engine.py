"""Thermal on the engine's chunks, random streams and roulette: the numbers against independent
references (closed forms) within 4 standard errors, and the pieces it shares with the engine."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import straylight.thermal.walk as thermal_walk
from straylight import rng
from straylight.engine.roulette import survivor_weight, survivor_weights
from straylight.scene import load_scene
from straylight.thermal.model import thermal_scene
from straylight.thermal.planck import band_radiance_w_m2_sr
from straylight.thermal.run import thermal
from tests.validation.thermal_scenes import part, plane, view_factor_coaxial_disks, write_box, write_scene


def _ts(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(path, sources=False)
    return thermal_scene(rs.scene, rs.materials)


@pytest.fixture(scope="module")
def enclosure(tmp_path_factory):
    """A closed box at 300 K (black, grey, glossy: 5 sub-bands, mirror walls) with a 300 K detector disk."""
    d = tmp_path_factory.mktemp("box")
    meshes = write_box(d)
    mats = {"floor": "black", "ceiling": "mirror", "wx0": "glossy", "wx1": "glossy", "wy0": "mirror", "wy1": "grey"}
    text = "".join(part(n, mats[n], 300.0, mesh=m) for n, m in meshes.items())
    text += part("det", role="detector", temperature_k=300.0, surface=plane((50, 50, 0.5), (0, 0, 1), 30.0))
    return _ts(write_scene(d, text))


@pytest.mark.parametrize("method", ["reverse", "forward"])
def test_isothermal_enclosure_reads_pi_b_within_4_sigma(enclosure, method):
    """Kirchhoff: in a closed isothermal box E = pi B_band(T) whatever the walls' BRDFs (model
    tolerance 0.1 %: the 0.5-deg emissivity tables)."""
    d = thermal(enclosure, (8, 12), n_rays=8000, seed=4, method=method).detectors["det"]
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300.0)
    err = d.stderr_w / (d.area_mm2 * 1e-6)
    assert 0 < err < 0.05 * expect
    assert abs(d.irradiance_w_m2 - expect) <= 4 * err + 1e-3 * expect, (method, d.irradiance_w_m2, err, expect)


@pytest.mark.parametrize("method", ["reverse", "forward"])
def test_cold_detector_under_a_warm_disk_is_the_view_factor_within_4_sigma(tmp_path, method):
    """P = pi B(300 K) A_disk F(disk -> detector), F the coaxial-disk view factor (PHYSICS §5)."""
    text = part("det", role="detector", temperature_k=77.0, surface=plane((0, 0, 0), (0, 0, 1), 5.0))
    text += part("hot", role="absorber", temperature_k=300.0, surface=plane((0, 0, 30), (0, 0, -1), 20.0))
    d = thermal(_ts(write_scene(tmp_path, text)), (8, 12), n_rays=6000, seed=7, method=method).detectors["det"]
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300.0) * np.pi * 20 ** 2 * 1e-6 * view_factor_coaxial_disks(20, 5, 30)
    assert d.power_w > 0
    assert abs(d.power_w - expect) <= 4 * d.stderr_w, (method, d.power_w, d.stderr_w, expect)


def test_rays_run_in_the_engine_chunks(enclosure):
    """No chunk size, stream or roulette of its own: --rays N is N rays cut into the engine's chunks."""
    assert getattr(thermal_walk, "CHUNK_RAYS", rng.CHUNK_RAYS) == rng.CHUNK_RAYS
    assert not hasattr(thermal_walk, "chunk_rng") and not hasattr(thermal_walk, "roulette")
    res = thermal(enclosure, (8, 12), n_rays=3 * rng.CHUNK_RAYS + 7, seed=1)
    assert res.rays == 3 * rng.CHUNK_RAYS + 7


def test_stream_chunks_are_distinct_and_interleaved():
    ids = {rng.stream_chunk(c, s, 6) for c in range(50) for s in range(6)}
    assert ids == set(range(300))
    with pytest.raises(ValueError, match="not one of 6 streams"):
        rng.stream_chunk(0, 6, 6)


def test_roulette_rule_is_unbiased_and_the_engine_reference_agrees():
    """E[weight after] = weight (survive with probability w / thr at thr), as the engine's numpy
    reference twin (advance_numpy) plays it."""
    u = np.random.default_rng(0).random(200_000)
    for w in (0.0, 2e-4, 7e-4, 1e-3, 0.4):
        out = survivor_weights(np.full(len(u), w), 1e-3, u)
        assert out.mean() == pytest.approx(w, rel=0.02, abs=1e-12)
        twin = np.where((w < 1e-3) & (w > 0), np.where(u * 1e-3 < w, 1e-3, 0.0), w)  # advance_numpy's rule
        assert np.array_equal(out, twin)
    assert survivor_weight(5e-4, 1e-3, 0.49) == 1e-3 and survivor_weight(5e-4, 1e-3, 0.51) == 0.0


@pytest.mark.parametrize("method", ["reverse", "forward"])
def test_two_threads_give_the_numbers_of_one(enclosure, method):
    """The engine's chunk streams: the same seed, the same numbers on 1 or 2 threads (and with a
    precision target, whose rounds are the same)."""
    from straylight.execution import Execution

    one = thermal(enclosure, (8, 12), n_rays=17_500, seed=2, method=method).to_json_dict()
    assert one["detectors"]["det"]["power_w"] > 0
    assert thermal(enclosure, (8, 12), n_rays=17_500, seed=2, method=method,
                   execution=Execution(threads=2)).to_json_dict() == one
    assert thermal(enclosure, (8, 12), n_rays=17_500, seed=2, method=method,
                   execution=Execution(workers=2)).to_json_dict() == one


def test_a_dask_client_is_refused(enclosure):
    from straylight.execution import Execution
    from straylight.trace import TraceError

    with pytest.raises(TraceError, match="thermal runs in this process"):
        thermal(enclosure, (8, 12), n_rays=100, execution=Execution(scheduler="tcp://127.0.0.1:8786"))


def test_batches_draw_each_chunk_from_its_own_engine_stream():
    """BatchDraws: a batch of chunks draws, per ray, what its chunk's chunk_rng draws alone."""
    b = rng.BatchDraws(5, [7, 19, 3], [rng.CHUNK_RAYS, rng.CHUNK_RAYS, 17])
    alone = [rng.chunk_rng(5, k) for k in (7, 19, 3)]
    ref = np.concatenate([alone[0].random((rng.CHUNK_RAYS, 5)), alone[1].random((rng.CHUNK_RAYS, 5)),
                          alone[2].random((17, 5))])
    assert np.array_equal(b.all(5), ref)
    later = b.uniforms(np.array([3, 999, rng.CHUNK_RAYS + 4, 2 * rng.CHUNK_RAYS + 16]), 8)  # some rays only
    assert np.array_equal(later[:2], alone[0].random((2, 8)))
    assert np.array_equal(later[2], alone[1].random(8)) and np.array_equal(later[3], alone[2].random(8))
    with pytest.raises(ValueError, match="whole chunks"):
        rng.BatchDraws(5, [1, 2], [10, rng.CHUNK_RAYS])
