"""Engine core: intersectors, self-intersection, the power ledger, NEE, roulette, reproducibility.

Monte Carlo comparisons use a fixed seed and a tolerance of 4 combined standard errors taken from
the runs themselves, with a sanity check that the compared quantity is non-zero.
"""
import math

import numpy as np
import pytest
import trimesh

from engine_helpers import (
    StandInLambertian, annulus_part, baffled_tube_scene, disk_part,
)
from geometry.mesh import Part, Scene
from straylight.intersect import EmbreeIntersector, ReferenceIntersector
from straylight.rng import SeedError
from straylight.sources import CollimatedDisk, LambertianDisk, PointSource
from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceError, TraceOptions, scene_epsilon, trace

BLACK = {"black": StandInLambertian(0.05)}


def _total(res):
    return (sum(t.power_w for t in res.detectors.values()) + sum(t.power_w for t in res.absorbed.values())
            + res.escaped.power_w)


def _small_mesh():
    a = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    b = trimesh.creation.box(extents=(8.0, 30.0, 2.0))
    b.apply_translation((12.0, 0.0, 3.0))
    return np.concatenate([a.vertices[a.faces], b.vertices[b.faces]])


def test_embree_agrees_with_numpy_reference_on_random_rays():
    tri = _small_mesh()
    rng = np.random.default_rng(3)
    n = 4000
    o = rng.uniform(-25, 25, size=(n, 3))
    d = rng.uniform(-14, 14, size=(n, 3)) - o  # aimed near the mesh, from all sides
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    fast, ref = EmbreeIntersector(tri), ReferenceIntersector(tri)
    tf, df = fast.intersect(o, d)
    tr, dr = ref.intersect(o, d)
    assert (tr >= 0).sum() > n // 4  # sanity: the rays do hit the mesh
    same = tf == tr
    # float32 (embree) vs float64 (reference) may pick a different triangle only at shared edges
    assert same.mean() > 0.999
    both = same & (tr >= 0)
    np.testing.assert_allclose(df[both], dr[both], rtol=1e-9, atol=1e-9)
    tmax = rng.uniform(0, 40, size=n)
    agree = fast.occluded(o, d, tmax) == ref.occluded(o, d, tmax)
    assert agree.mean() > 0.999


def test_ray_leaving_a_surface_does_not_hit_the_same_triangle():
    """Offset along the normal by scene_epsilon, far from the origin (large float32 coordinates)."""
    m = trimesh.creation.icosphere(subdivisions=4, radius=50.0)
    tri = m.vertices[m.faces] + np.array([900.0, -700.0, 400.0])
    eps = scene_epsilon(tri)
    fast = EmbreeIntersector(tri)
    rng = np.random.default_rng(5)
    n = 50000
    k = rng.integers(0, len(tri), n)
    b = rng.dirichlet([1, 1, 1], n)
    p = np.einsum("nj,njk->nk", b, tri[k])
    nrm = np.cross(tri[k, 1] - tri[k, 0], tri[k, 2] - tri[k, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    side = np.where(rng.random(n) < 0.5, 1.0, -1.0)[:, None]  # leave on either side (two-sided)
    nf = side * nrm
    # directions in the nf hemisphere including near-grazing ones
    d = rng.normal(size=(n, 3))
    d -= np.einsum("ij,ij->i", d, nf)[:, None] * nf
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cz = rng.uniform(1e-4, 1.0, n)[:, None]
    d = np.sqrt(1 - cz ** 2) * d + cz * nf
    hit, _ = fast.intersect(p + eps * nf, d)
    assert not np.any(hit == k)


def _plate_scene(extra=()):
    floor = disk_part("floor", 0.0, 40.0, 128, role="surface", material="grey")
    det = disk_part("det", 30.0, 8.0, 64, role="detector")
    det = Part("det", det.vertices_mm + np.array([-25.0, 0.0, 0.0]), det.faces, role="detector")
    return Scene((floor, det) + tuple(extra))


PLATE_MATS = {"grey": StandInLambertian(0.5)}
PLATE_SRC = CollimatedDisk([0, 0, 50], [0, 0, -1], [0.3, 0, -1], 15.0, power_w=2.0)


def test_nee_and_plain_random_walk_agree_within_errors():
    on = trace(_plate_scene(), PLATE_SRC, 40000, seed=11, materials=PLATE_MATS, options=TraceOptions(estimator=EstimatorOptions(nee=True)))
    off = trace(_plate_scene(), PLATE_SRC, 40000, seed=11, materials=PLATE_MATS, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    a, b = on.detectors["det"], off.detectors["det"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    assert a.stderr_w < 0.5 * b.stderr_w  # NEE is the point: much smaller error at equal rays
    split = trace(_plate_scene(), PLATE_SRC, 20000, seed=16, materials=PLATE_MATS,
                  options=TraceOptions(estimator=EstimatorOptions(nee=True, nee_samples=3))).detectors["det"]
    assert abs(split.power_w - b.power_w) < 4 * math.hypot(split.stderr_w, b.stderr_w)


def test_power_ledger_closes_with_mirror_absorber_roulette_and_truncation():
    mirror = annulus_part("mirror", 60.0, 0.0001, 30.0, 64, role="mirror", facing=-1)
    stop = annulus_part("stop", 45.0, 20.0, 35.0, 64, role="absorber")
    scene = _plate_scene((mirror, stop))
    for opts in (TraceOptions(), TraceOptions(estimator=EstimatorOptions(nee=False)), TraceOptions(physics=PhysicsOptions(max_events=2)), TraceOptions(estimator=EstimatorOptions(nee_samples=2)),
                 TraceOptions(estimator=EstimatorOptions(rr_threshold=0.4), physics=PhysicsOptions(mirror_reflectance=0.7))):
        res = trace(scene, [PLATE_SRC, PointSource([0, 0, 20], 1.0)], 5000, seed=4, materials=PLATE_MATS,
                    options=opts)
        assert res.emitted_w == 3.0
        assert abs(res.emitted_w - _total(res)) <= 1e-9 * res.emitted_w
        assert res.absorbed["stop"].power_w > 0 and res.absorbed["mirror"].power_w >= 0
    assert trace(scene, PLATE_SRC, 5000, seed=4, materials=PLATE_MATS,
                 options=TraceOptions(physics=PhysicsOptions(max_events=2))).ledger["truncated_w"].power_w > 0


def test_russian_roulette_is_unbiased_and_reported():
    plain = trace(_plate_scene(), PLATE_SRC, 40000, seed=8, materials=PLATE_MATS,
                  options=TraceOptions(estimator=EstimatorOptions(rr_threshold=0.0)))
    rr = trace(_plate_scene(), PLATE_SRC, 40000, seed=9, materials=PLATE_MATS,
               options=TraceOptions(estimator=EstimatorOptions(rr_threshold=0.6)))
    assert plain.ledger["roulette_w"].power_w == 0.0
    assert rr.ledger["roulette_w"].stderr_w > 0  # roulette did act
    a, b = plain.absorbed["floor"], rr.absorbed["floor"]
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    a, b = plain.detectors["det"], rr.detectors["det"]
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)


def test_mirror_sends_the_whole_beam_to_the_detector():
    """A 45 deg flat mirror folds a collimated beam onto a detector: power = R exactly."""
    v = np.array([[-20, -20, -20], [20, -20, 20], [20, 20, 20], [-20, 20, -20]], float)
    mirror = Part("mirror", v, np.array([[0, 1, 2], [0, 2, 3]]), role="mirror")
    det = Part("det", np.array([[-100, -30, -30], [-100, 30, -30], [-100, 30, 30], [-100, -30, 30]], float),
               np.array([[0, 1, 2], [0, 2, 3]]), role="detector")
    src = CollimatedDisk([0, 0, 50], [0, 0, -1], [0, 0, -1], 5.0, power_w=1.0)
    res = trace(Scene((mirror, det)), src, 2000, seed=1, options=TraceOptions(physics=PhysicsOptions(mirror_reflectance=0.9)))
    assert res.detectors["det"].power_w == pytest.approx(0.9, rel=1e-12)
    assert res.absorbed["mirror"].power_w == pytest.approx(0.1, rel=1e-12)


def test_point_source_inverse_square_solid_angle():
    """Isotropic point at height h over a disk of radius a: fraction (1 - h / sqrt(h^2 + a^2)) / 2."""
    h, a = 40.0, 15.0
    res = trace(Scene((disk_part("det", 0.0, a, 1024),)), PointSource([0, 0, h], 1.0), 50000, seed=2)
    expected = 0.5 * (1 - h / math.hypot(h, a)) * (1 - 0.5 * (math.pi / 1024) ** 2)  # N-gon area correction
    got = res.detectors["det"]
    assert got.power_w > 0
    assert abs(got.power_w - expected) < 4 * got.stderr_w


@pytest.mark.parametrize("batch", [1000, 10000, 100000])
def test_same_seed_same_numbers_for_any_batch_size(batch):
    scene = baffled_tube_scene()
    src = CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(0.35), 0, -math.cos(0.35)], 60.0)
    opts = TraceOptions(output=OutputOptions(record_paths=True), batch_rays=batch)
    # 12345 rays: the last chunk is partial
    res = trace(scene, src, 12345, seed=21, materials=BLACK, options=opts)
    ref = trace(scene, src, 12345, seed=21, materials=BLACK, options=TraceOptions(output=OutputOptions(record_paths=True), batch_rays=3000))
    assert res.detectors["detector"].power_w > 0
    assert res.to_json_dict() == ref.to_json_dict()
    np.testing.assert_array_equal(res.maps["detector"].power_w, ref.maps["detector"].power_w)
    np.testing.assert_array_equal(res.maps["detector"].stderr_w, ref.maps["detector"].stderr_w)
    np.testing.assert_array_equal(res.paths.key, ref.paths.key)
    np.testing.assert_array_equal(res.paths.power_w, ref.paths.power_w)


def test_different_seeds_differ():
    a = trace(_plate_scene(), PLATE_SRC, 3000, seed=1, materials=PLATE_MATS)
    b = trace(_plate_scene(), PLATE_SRC, 3000, seed=2, materials=PLATE_MATS)
    assert a.detectors["det"].power_w != b.detectors["det"].power_w


def test_path_records_group_to_the_detector_total():
    src = CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(0.35), 0, -math.cos(0.35)], 60.0)
    res = trace(baffled_tube_scene(), src, 5000, seed=3, materials=BLACK, options=TraceOptions(output=OutputOptions(record_paths=True)))
    groups = res.paths.group()
    assert len(groups) >= 5
    total = sum(g.power_w for g in groups)
    assert total > 0
    assert total == pytest.approx(res.detectors["detector"].power_w, rel=1e-12)
    assert all(g.detector == "detector" and g.stderr_w > 0 for g in groups[:3])
    assert all(part in ("wall", "vanes", "end_plate") and kind == "scatter"
               for g in groups for part, kind in g.events)
    assert groups[0].power_w >= groups[-1].power_w
    by_len = res.paths.group(by=lambda ev, det: len(ev))
    assert sum(g.power_w for g in by_len) == pytest.approx(total, rel=1e-12)
    # a single group holding everything has exactly the detector's standard error
    one = res.paths.group(by=lambda ev, det: "all")
    assert one[0].stderr_w == pytest.approx(res.detectors["detector"].stderr_w, rel=1e-9)


def test_irradiance_map_sums_to_detector_power():
    res = trace(_plate_scene(), PLATE_SRC, 10000, seed=3, materials=PLATE_MATS, options=TraceOptions(output=OutputOptions(map_bins=(8, 8))))
    m = res.maps["det"]
    assert m.power_w.shape == (8, 8)
    assert m.power_w.sum() == pytest.approx(res.detectors["det"].power_w, rel=1e-12)
    assert np.all(m.stderr_w >= 0) and m.stderr_w.max() > 0
    np.testing.assert_allclose(m.normal, [0, 0, 1], atol=1e-12)


def test_front_only_detector_ignores_light_from_behind():
    det = disk_part("det", 0.0, 10.0, 64, role="detector", facing=-1)  # faces -z, light comes from +z
    src = CollimatedDisk([0, 0, 10], [0, 0, -1], [0, 0, -1], 5.0)
    both = trace(Scene((det,)), src, 1000, seed=1)
    front = trace(Scene((det,)), src, 1000, seed=1, options=TraceOptions(output=OutputOptions(detector_sides="front")))
    assert both.detectors["det"].power_w == pytest.approx(1.0)
    assert front.detectors["det"].power_w == 0.0 and front.absorbed["det"].power_w == pytest.approx(1.0)


def test_bad_requests_are_one_line_value_errors():
    scene = _plate_scene()
    with pytest.raises(SeedError, match="seed"):
        trace(scene, PLATE_SRC, 100, seed=-1, materials=PLATE_MATS)
    with pytest.raises(TraceError, match="n_rays"):
        trace(scene, PLATE_SRC, 0, materials=PLATE_MATS)
    with pytest.raises(TraceError, match="max_events"):
        TraceOptions(physics=PhysicsOptions(max_events=0))
    bare = Scene((Part("floor", np.eye(3), np.array([[0, 1, 2]]), role="surface"),))
    with pytest.raises(TraceError, match="floor"):
        trace(bare, PLATE_SRC, 100)


def test_each_option_group_checks_its_own_fields():
    """The options come in groups (estimator / output / physics), each refusing its own bad values by
    name; a group in the wrong slot, or a flat keyword of the old single class, is refused."""
    for make, field in ((lambda: EstimatorOptions(rr_threshold=1.0), "rr_threshold"),
                        (lambda: EstimatorOptions(nee_samples=0), "nee_samples"),
                        (lambda: EstimatorOptions(target_fraction=1.0), "target_fraction"),
                        (lambda: OutputOptions(detector_sides="back"), "detector_sides"),
                        (lambda: OutputOptions(map_bins=(8,)), "map_bins"),
                        (lambda: PhysicsOptions(mirror_reflectance=1.5), "mirror_reflectance"),
                        (lambda: PhysicsOptions(diffraction="on"), "diffraction"),
                        (lambda: TraceOptions(batch_rays=0), "batch_rays"),
                        (lambda: TraceOptions(physics=OutputOptions()), "physics")):
        with pytest.raises(TraceError, match=field):
            make()
    with pytest.raises(TypeError):
        TraceOptions(nee=False)  # type: ignore[call-arg]
    assert EstimatorOptions(target_parts="det").target_parts == ("det",)


def test_target_importance_sampling_is_unbiased_and_helps():
    """One-sample MIS toward the detector (no NEE) against the plain walk, same scene, 4 sigma."""
    plain = trace(_plate_scene(), PLATE_SRC, 40000, seed=12, materials=PLATE_MATS, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    mis = trace(_plate_scene(), PLATE_SRC, 40000, seed=13, materials=PLATE_MATS,
                options=TraceOptions(estimator=EstimatorOptions(nee=False, target_parts=("det",), target_fraction=0.5)))
    a, b = plain.detectors["det"], mis.detectors["det"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    assert b.stderr_w < 0.5 * a.stderr_w
    assert abs(mis.emitted_w - _total(mis)) <= 1e-9 * mis.emitted_w
    with pytest.raises(TraceError, match="target part 'nope'"):
        trace(_plate_scene(), PLATE_SRC, 10, materials=PLATE_MATS, options=TraceOptions(estimator=EstimatorOptions(target_parts=("nope",))))


def test_source_on_a_detector_does_not_hit_it_backward_trace():
    """A Lambertian disk laid on the detector (backward trace for critical objects): no ray may be
    absorbed by the detector at t = 0; an absorbing disk above receives the view factor."""
    det = disk_part("det", 0.0, 10.0, 256)
    plate = disk_part("plate", 50.0, 20.0, 2048, role="absorber", facing=-1)
    res = trace(Scene((det, plate)), LambertianDisk([0, 0, 0], [0, 0, 1], 10.0), 20000, seed=3)
    assert res.detectors["det"].power_w == 0.0
    R1, R2 = 10 / 50, 20 / 50
    X = 1 + (1 + R2 ** 2) / R1 ** 2
    f12 = (X - math.sqrt(X * X - 4 * (R2 / R1) ** 2)) / 2  # PHYSICS.md §5 coaxial disks
    got = res.first_hit["plate"]
    assert got.power_w > 0 and abs(got.power_w - f12) < 4 * got.stderr_w


def test_nee_agrees_with_the_walk_on_a_glossy_material():
    """A narrow K-correlation lobe aimed at the detector: NEE alone would rarely sample the lobe
    (heavy tail, under-estimated error); with MIS between NEE and BRDF sampling both agree."""
    from materials import load_material

    mats = {"grey": load_material("z302_sample_a")}
    floor = disk_part("floor", 0.0, 40.0, 128, role="surface", material="grey")
    det = disk_part("det", 30.0, 6.0, 64, role="detector")
    det = Part("det", det.vertices_mm + np.array([30.0, 0.0, 0.0]), det.faces, role="detector")
    scene = Scene((floor, det))
    on = trace(scene, PLATE_SRC, 20000, seed=14, materials=mats, options=TraceOptions(estimator=EstimatorOptions(nee=True)))
    off = trace(scene, PLATE_SRC, 20000, seed=15, materials=mats, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    a, b = on.detectors["det"], off.detectors["det"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    assert abs(on.emitted_w - _total(on)) <= 1e-9 * on.emitted_w


def test_advance_gets_one_array_layout(monkeypatch):
    """The walk passes advance a contiguous roulette column whatever the batch: numba compiles (and a start
    loads from its cache) one advance per argument layout, and a column view is 'A' (or 'C' with one row)."""
    from straylight.engine import walk

    compiled_advance = walk.COMPILED.advance
    seen = []

    def advance(cont, out, rays, hit, roulette_u, *rest):
        seen.append(roulette_u.flags.c_contiguous)
        return compiled_advance(cont, out, rays, hit, roulette_u, *rest)

    monkeypatch.setattr(walk, "COMPILED", walk.COMPILED._replace(advance=advance))
    trace(_plate_scene(), PLATE_SRC, 3000, seed=5, materials=PLATE_MATS)
    assert seen and all(seen)
