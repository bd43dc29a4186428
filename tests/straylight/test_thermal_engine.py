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

    n = 17_500 if method == "reverse" else 6_500
    one = thermal(enclosure, (8, 12), n_rays=n, seed=2, method=method).to_json_dict()
    assert one["detectors"]["det"]["power_w"] > 0
    assert thermal(enclosure, (8, 12), n_rays=n, seed=2, method=method,
                   execution=Execution(threads=2)).to_json_dict() == one
    assert thermal(enclosure, (8, 12), n_rays=n, seed=2, method=method,
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


# ---------------------------------------------------------------- emission as an engine source kind

def test_surface_emission_directions_follow_eps_cos():
    """A SurfaceEmission side emits with density eps(theta) cos(theta) / (pi eps_h): the histogram of
    theta against the integral of eps sin cos over each bin (a grazing-falling table), and points
    uniform over its triangles (area shares of a 1:3 pair)."""
    from straylight.sources import SurfaceEmission
    from straylight.thermal.model import THETA_GRID

    eps = 0.9 * np.cos(THETA_GRID) ** 0.5 + 0.05
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [0, -3, 0], [-1, 0, 0]]], float)
    src = SurfaceEmission(tri, np.array([[0, 0, 1.0], [0, 0, 1.0]]), eps, power_w=2.0)
    u = np.random.default_rng(1).random((200_000, 4))
    o, d = src.emit(u)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0) and (d[:, 2] >= 0).all()
    assert np.mean(o[:, 1] < 0) == pytest.approx(0.75, abs=0.005)  # the second triangle has 3/4 of the area
    theta = np.arccos(np.clip(d[:, 2], 0, 1))
    edges = np.linspace(0, np.pi / 2, 10)
    fine = np.linspace(0, np.pi / 2, 20001)
    dens = np.interp(fine, THETA_GRID, eps) * np.sin(fine) * np.cos(fine)
    cum = np.concatenate([[0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(fine))])
    expect = np.diff(np.interp(edges, fine, cum)) / cum[-1]
    got = np.histogram(theta, edges)[0] / len(theta)
    assert np.abs(got - expect).max() < 4 * np.sqrt(expect.max() / len(theta))
    phi = np.arctan2(d[:, 1], d[:, 0])  # azimuth uniform (from the triangle pick's remainder)
    assert np.abs(np.histogram(phi, 8, (-np.pi, np.pi))[0] / len(phi) - 1 / 8).max() < 0.004


def test_forward_is_the_engine_trace_of_the_emission_sources(enclosure, monkeypatch):
    """method="forward" traces straylight.sources.SurfaceEmission sources with the engine's trace():
    one per emitting side and sub-band, their powers pi B A eps_h."""
    import straylight.trace as trace_module
    from straylight.sources import SurfaceEmission

    seen = []
    real = trace_module.trace

    def spy(scene, sources, n_rays, **kw):
        seen.extend(sources)
        return real(scene, sources, n_rays, **kw)

    monkeypatch.setattr(trace_module, "trace", spy)
    thermal(enclosure, (8, 12), n_rays=800, seed=1, method="forward")
    assert seen and all(isinstance(s, SurfaceEmission) for s in seen)
    black = [s for s in seen if s.annulus is None and np.isclose(s.triangles_mm[:, :, 2], 0).all()]  # the floor
    assert black  # the black floor's front, in some sub-band


def test_forward_on_the_engine_agrees_with_the_reverse_estimator(tmp_path):
    """A diffuse cylindrical cavity (eps 0.5, L/R 2) at 500 K over a cold detector in its opening, and a
    warm glossy disk beside it: the engine's forward trace and the reverse walk within 4 sigma, both
    within 4 sigma of the cavity's net-radiation solution (tests/validation/cavity_radiosity.py) for the wall part."""
    from tests.validation.thermal_scenes import write_tube_inward

    wall = write_tube_inward(tmp_path, 10.0, 20.0)
    text = "[material.wallpaint]\ncomponents = [{type = \"lambertian\", rd = 0.5}]\n"
    text += part("wall", "wallpaint", 500.0, mesh=wall)
    text += part("bottom", "wallpaint", 500.0, surface=plane((0, 0, 0), (0, 0, 1), 10.0))
    text += part("opening", role="detector", temperature_k=77.0, surface=plane((0, 0, 20), (0, 0, -1), 10.0))
    ts = _ts(write_scene(tmp_path, text))
    f = thermal(ts, (3, 5), n_rays=30_000, seed=5, method="forward").detectors["opening"]
    r = thermal(ts, (3, 5), n_rays=6_000, seed=5).detectors["opening"]
    assert f.power_w > 0 and r.power_w > 0
    assert abs(f.power_w - r.power_w) <= 4 * np.hypot(f.stderr_w, r.stderr_w), (f.power_w, f.stderr_w, r.power_w, r.stderr_w)
    from tests.validation.cavity_radiosity import effective_emissivity

    ref = effective_emissivity(0.5, 10.0, 20.0) * np.pi * band_radiance_w_m2_sr(3, 5, 500.0) * np.pi * 100 * 1e-6
    for d in (f, r):  # 0.2 % model tolerance: the 256-facet wall (tests/validation/test_benchmark_cavity.py)
        assert abs(d.power_w - ref) <= 4 * d.stderr_w + 2e-3 * ref, (d.power_w, d.stderr_w, ref)
