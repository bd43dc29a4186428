"""Second-vertex area sampling (straylight.engine.second_vertex) and the two-stage first-vertex
probe table: unbiased (analytic integrating sphere; agreement with the plain NEE walk on the
baffled tube), exact ledger, reproducible for any batch size or thread count, and the compiled and
numpy walks bit-identical with it on.

Tolerances: 3.5-4 combined standard errors taken from the runs."""
import math
from dataclasses import replace

import numpy as np
import pytest

from engine_helpers import StandInLambertian, baffled_tube_scene, icosphere_ports_scene
from straylight.engine import first_vertex
from straylight.engine.face_groups import face_groups
from straylight.engine.runtime import runtime
from straylight.engine.roles import ROLE_SURFACE
from straylight.engine.second_vertex import build_table
from straylight.sources import CollimatedDisk, PointSource
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, make_spec, run_batch, run_batch_reference, trace
from straylight.execution import Execution

BLACK = {"black": StandInLambertian(0.05)}
SV = TraceOptions(estimator=EstimatorOptions(second_vertex_sampling=True))


def _tube_source(angle_deg):
    a = math.radians(angle_deg)
    return CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(a), 0, -math.cos(a)], 60.0)


def _balanced(res):
    total = sum(t.power_w for t in res.detectors.values()) + sum(t.power_w for t in res.absorbed.values())
    assert abs(res.emitted_w - total - res.escaped.power_w) <= 1e-9 * res.emitted_w


def test_integrating_sphere_throughput_with_second_vertex():
    """Goebel (1967): throughput rho f_d / (1 - rho (1 - f)) with the mesh's port fractions; every
    vertex draws a second vertex on the wall the port sees (all of it), so most of the estimate
    goes through the new strategy."""
    R = 100.0
    scene, frac = icosphere_ports_scene(
        R, {"entrance": ([0, 0, 1], 0.01, None), "port": ([1, 0, 0], 0.005, "detector")}, subdivisions=4)
    rho = 0.98
    f_d, f = frac["port"], frac["entrance"] + frac["port"]
    expected = rho * f_d / (1 - rho * (1 - f))
    src = CollimatedDisk([0, 0, 0.97 * R], [0, 0, -1], [0, 0, -1], 2.0)
    res = trace(scene, src, 3000, seed=2, materials={"wall": StandInLambertian(rho)},
                options=TraceOptions(estimator=EstimatorOptions(second_vertex_sampling=True), batch_rays=3000))
    port = res.detectors["port"]
    assert abs(port.power_w - expected) < 3.5 * port.stderr_w, (port, expected)
    assert port.stderr_w < 0.02 * expected
    assert res.ledger["nee_exchange_w"].power_w != 0.0  # the area strategy did contribute
    _balanced(res)


@pytest.mark.parametrize("first", [False, True])
def test_agrees_with_plain_nee_on_the_baffled_tube(first):
    """30 deg: only scattered light arrives; double scatter vane -> vane -> detector is part of it."""
    scene, src = baffled_tube_scene(), _tube_source(30.0)
    on = trace(scene, src, 40000, seed=4, materials=BLACK,
               options=TraceOptions(estimator=EstimatorOptions(second_vertex_sampling=True, first_vertex_sampling=first)))
    off = trace(scene, src, 40000, seed=4, materials=BLACK, options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=first)))
    a, b = on.detectors["detector"], off.detectors["detector"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    assert on.shadow_rays > off.shadow_rays
    _balanced(on)


def test_double_scatter_share_agrees_with_the_walk():
    """The paths the new strategy makes (scatter, scatter, detector) alone: the path groups of depth
    2 with and without it agree, and carry a real share of the power."""
    scene, src = baffled_tube_scene(), _tube_source(30.0)

    def run(opts):
        return trace(scene, src, 40000, seed=8, materials=BLACK, options=replace(opts, output=replace(opts.output, record_paths=True)))

    def share(res):
        p = res.paths
        sel = p.depth == 2
        x = np.bincount(p.ray[sel], weights=p.power_w[sel], minlength=p.n_rays)
        return x.sum(), x.std() * math.sqrt(p.n_rays)

    on, off = run(SV), run(TraceOptions())
    (a, sa), (b, sb) = share(on), share(off)
    assert a > 0.02 * on.detectors["detector"].power_w
    assert abs(a - b) < 4 * math.hypot(sa, sb)


def test_same_numbers_for_any_batch_size_and_thread_count():
    scene, src = baffled_tube_scene(), _tube_source(30.0)
    opts = TraceOptions(estimator=EstimatorOptions(second_vertex_sampling=True, first_vertex_sampling=True), output=OutputOptions(record_paths=True), batch_rays=1000)
    ref = trace(scene, src, 12345, seed=9, materials=BLACK, options=opts)
    for batch, threads in ((10000, None), (2000, 2)):
        got = trace(scene, src, 12345, seed=9, materials=BLACK, options=replace(opts, batch_rays=batch), execution=Execution(threads=threads))
        assert got.detectors["detector"].power_w == ref.detectors["detector"].power_w
        assert got.detectors["detector"].stderr_w == ref.detectors["detector"].stderr_w
        assert np.array_equal(got.maps["detector"].power_w, ref.maps["detector"].power_w)
    again = trace(scene, src, 12345, seed=9, materials=BLACK, options=opts)
    assert again.detectors["detector"].power_w == ref.detectors["detector"].power_w
    groups = ref.paths.group()
    assert sum(g.power_w for g in groups) == pytest.approx(ref.detectors["detector"].power_w, rel=1e-9)


def test_compiled_and_numpy_walks_bit_identical():
    scene, src = baffled_tube_scene(), _tube_source(30.0)
    spec = make_spec(scene, src, 3000, seed=3, materials=BLACK, options=SV)
    spec = replace(spec, critical_table=build_table(spec, runtime().scene(spec)))
    a, b = run_batch(spec, 0, 3), run_batch_reference(spec, 0, 3)
    for key in a:
        va, vb = a[key], b[key]
        if isinstance(va, np.ndarray):
            assert np.array_equal(va, vb), key


def test_critical_table_is_a_density_on_scatter_surfaces():
    scene, src = baffled_tube_scene(), _tube_source(30.0)
    spec = make_spec(scene, src, 1000, seed=1, materials=BLACK, options=SV)
    table = build_table(spec, runtime().scene(spec))
    tri = spec.triangles_mm
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert (table.p_area * area).sum() == pytest.approx(1.0, rel=1e-12)
    det = spec.part_names.index("detector")
    assert not table.from_part[det] and (table.p_area[spec.triangle_part == det] == 0).all()
    # the detector (z = 0, facing +z) sees the end plate's hole edge and the vanes' undersides, not
    # the vanes' top faces (z = zc + 0.5 facing +z): nothing of the table lies on a face turned away
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    on_table = table.tri
    assert len(on_table) > 100
    assert not np.any((n[on_table, 2] > 0.99 * np.linalg.norm(n[on_table], axis=1)) & (tri[on_table, 0, 2] > 1.0))


@pytest.mark.parametrize("source", ["collimated", "point"])
def test_may_see_detector_rejects_only_dark_triangles(source):
    """The two-stage probe table's pre-filter is conservative: probes on the triangles it drops
    never carry single-scatter power."""
    scene = baffled_tube_scene()
    src = _tube_source(30.0) if source == "collimated" else PointSource([0, 20, 290], 1.0, axis=[0, 0, -1],
                                                                        half_angle_deg=80.0)
    spec = make_spec(scene, src, 1000, seed=1, materials=BLACK, options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)))
    comp = runtime().scene(spec)
    surf = np.flatnonzero(spec.part_roles[spec.triangle_part] == ROLE_SURFACE)
    ok = first_vertex._may_see_detector(spec, comp, src, surf)
    dropped = surf[~ok]
    assert 0 < len(dropped) < len(surf)
    kept_scores = first_vertex._probe_scores(spec, comp, src, surf[ok], 4, np.random.default_rng(1))
    dropped_scores = first_vertex._probe_scores(spec, comp, src, dropped, 4, np.random.default_rng(2))
    assert (kept_scores > 0).any()
    assert not (dropped_scores > 0).any()


def test_two_stage_probe_table_agrees_with_plain_nee(monkeypatch):
    """Forced on the small tube (budget below 8 probes per triangle): same answer as plain NEE, and
    still a smaller error."""
    scene, src = baffled_tube_scene(), _tube_source(20.0)
    spec = make_spec(scene, src, 1000, seed=5, materials=BLACK, options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)))
    n_surf = int((spec.part_roles[spec.triangle_part] == ROLE_SURFACE).sum())
    monkeypatch.setattr(first_vertex, "PROBE_BUDGET", 2 * n_surf)
    on = trace(scene, src, 60000, seed=5, materials=BLACK, options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)))
    off = trace(scene, src, 60000, seed=5, materials=BLACK, options=TraceOptions())
    a, b = on.detectors["detector"], off.detectors["detector"]
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    assert a.stderr_w < 0.6 * b.stderr_w
    _balanced(on)


def test_tables_are_built_once_per_seed_and_reused_without_changing_numbers(monkeypatch):
    """The rounds of --target-rel-error trace the same scene, sources and seed again: the kept
    tables give exactly the numbers a fresh build gives."""
    from straylight.engine.strategies.second_vertex import SECOND_VERTEX

    scene, src = baffled_tube_scene(), _tube_source(30.0)
    opts = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True))
    built = []
    real = SECOND_VERTEX.build_table
    monkeypatch.setattr(SECOND_VERTEX, "build_table", lambda spec, tools: built.append(1) or real(spec, tools))
    runtime().forget_tables()
    a = trace(scene, src, 3000, seed=6, materials=BLACK, options=opts)
    b = trace(scene, src, 3000, seed=6, materials=BLACK, options=opts, execution=Execution(first_chunk=3))
    assert len(built) == 1
    runtime().forget_tables()
    c = trace(scene, src, 3000, seed=6, materials=BLACK, options=opts, execution=Execution(first_chunk=3))
    assert len(built) == 2
    assert c.detectors["detector"].power_w == b.detectors["detector"].power_w
    assert c.detectors["detector"].stderr_w == b.detectors["detector"].stderr_w
    trace(scene, src, 3000, seed=7, materials=BLACK, options=opts)
    assert len(built) == 3
    assert a.detectors["detector"].power_w != b.detectors["detector"].power_w


def test_two_stage_probe_table_leaves_no_hole_in_a_face_it_saw(monkeypatch):
    """Large-scene table: every triangle of a face (part, quantised normal) where a probe saw single
    scatter keeps a share of the face's density (FACE_SHARE), so no sliver its probes missed is q = 0."""
    scene, src = baffled_tube_scene(), _tube_source(20.0)
    spec = make_spec(scene, src, 1000, seed=5, materials=BLACK, options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)))
    comp = runtime().scene(spec)
    n_surf = int((spec.part_roles[spec.triangle_part] == ROLE_SURFACE).sum())
    monkeypatch.setattr(first_vertex, "PROBE_BUDGET", 2 * n_surf)
    table = first_vertex.build_table(spec, comp)
    surf = np.flatnonzero(spec.part_roles[spec.triangle_part] == ROLE_SURFACE)
    surf = surf[first_vertex._may_see_detector(spec, comp, src, surf)]
    surf = surf[np.isin(spec.triangle_part[surf], np.unique(spec.triangle_part[table.tri]))]
    face = face_groups(spec, comp, surf)
    seen_faces = np.unique(face[table.p_area[surf] > 0])
    in_seen = np.isin(face, seen_faces)
    assert in_seen.sum() > len(table.tri) * 0.99 and (table.p_area[surf[in_seen]] > 0).all()
    tri = spec.triangles_mm
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert (table.p_area * area).sum() == pytest.approx(1.0, rel=1e-12)
