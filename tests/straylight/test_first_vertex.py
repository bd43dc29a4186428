"""First-vertex area sampling (straylight.first_vertex): unbiased, exact ledger, reproducible, and
a real variance reduction where single scatter off small lit faces dominates.

References: a Gauss-Legendre quadrature of the single-scatter integral (point source over a
Lambertian floor, computed here independently of the engine), and the engine's plain NEE walk.
Tolerances: 4 combined standard errors taken from the runs.
"""
import math

import numpy as np
import pytest

from engine_helpers import StandInLambertian, baffled_tube_scene, disk_part
from geometry.mesh import Part, Scene
from straylight.sources import CollimatedDisk, LambertianDisk, PointSource
from straylight.trace import EstimatorOptions, OutputOptions, TraceError, TraceOptions, make_spec, run_batch_reference, trace
from straylight.execution import Execution

FV = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True))
BLACK = {"black": StandInLambertian(0.05)}
RHO = 0.5


def _floor_scene():
    floor = disk_part("floor", 0.0, 40.0, 1024, role="surface", material="grey")
    det = disk_part("det", 30.0, 8.0, 1024, role="detector")
    det = Part("det", det.vertices_mm + np.array([-25.0, 0.0, 0.0]), det.faces, role="detector")
    return Scene((floor, det))


SOURCE = PointSource([15.0, 0.0, 20.0], 1.0, axis=[0.0, 0.0, -1.0], half_angle_deg=60.0)


def _single_scatter_quadrature(n=96):
    """Power on the detector from one Lambertian bounce: integral over the lit floor (polar about the
    source's foot, clipped by the floor's edge in closed form) and the detector disk of
    E(x) (rho/pi) cos_o cos_z / d^2, E = I h / r^3, I = P / (2 pi (1 - cos 60 deg))."""
    gx, gw = np.polynomial.legendre.leggauss(n)
    h, intensity = 20.0, 1.0 / (2 * math.pi * (1 - 0.5))
    r_cone = h * math.tan(math.radians(60.0))
    phi = math.pi * (gx + 1)
    wphi = math.pi * gw
    # detector points (polar, radius 8 about (-25, 0, 30))
    rd = 4.0 * (gx + 1)
    wd = 4.0 * gw
    R, P = np.meshgrid(rd, phi, indexing="ij")
    WD = np.outer(wd * rd, wphi)
    zx, zy = -25.0 + R * np.cos(P), R * np.sin(P)
    total = 0.0
    for ph, wp in zip(phi, wphi):
        c = math.cos(ph)
        r_max = min(r_cone, -15.0 * c + math.sqrt(225.0 * c * c + 1375.0))
        r = 0.5 * r_max * (gx + 1)
        wr = 0.5 * r_max * gw
        x, y = 15.0 + r * c, r * math.sin(ph)
        e = intensity * h / (r * r + h * h) ** 1.5
        d2 = (zx[None] - x[:, None, None]) ** 2 + (zy[None] - y[:, None, None]) ** 2 + 900.0
        inner = np.sum(WD[None] * 900.0 / d2 ** 2, axis=(1, 2))  # cos_o cos_z / d^2 = 30^2 / d^4
        total += wp * np.sum(wr * r * e * inner)
    return total * RHO / math.pi


def test_point_source_single_scatter_matches_quadrature():
    expected = _single_scatter_quadrature()
    mats = {"grey": StandInLambertian(RHO)}
    on = trace(_floor_scene(), SOURCE, 40000, seed=3, materials=mats, options=FV).detectors["det"]
    off = trace(_floor_scene(), SOURCE, 40000, seed=3, materials=mats, options=TraceOptions()).detectors["det"]
    assert expected > 0 and on.power_w > 0
    assert abs(on.power_w - expected) < 4 * on.stderr_w
    assert abs(off.power_w - expected) < 4 * off.stderr_w


def _tube_source(angle_deg):
    a = math.radians(angle_deg)
    return CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(a), 0, -math.cos(a)], 60.0)


def test_agrees_with_plain_nee_and_cuts_the_error_on_the_baffled_tube():
    """20 deg off axis: light reaches the detector only by scatter; single scatter off the lit
    vane edges dominates the plain NEE estimate's variance (BENCHMARK.md)."""
    scene = baffled_tube_scene()
    src = _tube_source(20.0)
    on = trace(scene, src, 60000, seed=5, materials=BLACK, options=FV)
    off = trace(scene, src, 60000, seed=5, materials=BLACK, options=TraceOptions())
    a, b = on.detectors["detector"], off.detectors["detector"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w)
    assert a.stderr_w < 0.6 * b.stderr_w
    total = sum(t.power_w for t in on.detectors.values()) + sum(t.power_w for t in on.absorbed.values())
    assert abs(on.emitted_w - total - on.escaped.power_w) <= 1e-9 * on.emitted_w


def test_same_numbers_for_any_batch_size_and_thread_count():
    scene = baffled_tube_scene()
    src = _tube_source(30.0)
    ref = trace(scene, src, 12345, seed=9, materials=BLACK,
                options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True), output=OutputOptions(record_paths=True), batch_rays=1000))
    for opts, threads in ((TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True), output=OutputOptions(record_paths=True), batch_rays=10000), None),
                          (TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True), output=OutputOptions(record_paths=True), batch_rays=2000), 2)):
        got = trace(scene, src, 12345, seed=9, materials=BLACK, options=opts, execution=Execution(threads=threads))
        assert got.detectors["detector"].power_w == ref.detectors["detector"].power_w
        assert got.detectors["detector"].stderr_w == ref.detectors["detector"].stderr_w
        assert np.array_equal(got.maps["detector"].power_w, ref.maps["detector"].power_w)
    groups = ref.paths.group()
    assert sum(g.power_w for g in groups) == pytest.approx(ref.detectors["detector"].power_w, rel=1e-9)


def test_unsupported_sources_and_reference_engine_are_clear_errors():
    scene = baffled_tube_scene()
    lamb = LambertianDisk([0, 0, 310], [0, 0, -1], 60.0)
    with pytest.raises(TraceError, match="collimated and point sources"):
        trace(scene, lamb, 1000, materials=BLACK, options=FV)
    with pytest.raises(TraceError, match="exactly one source"):
        trace(scene, [_tube_source(0), _tube_source(5)], 1000, materials=BLACK, options=FV)
    spec = make_spec(scene, _tube_source(20.0), 1000, materials=BLACK, options=FV)
    from dataclasses import replace

    from straylight.engine.first_vertex import VertexTable
    spec = replace(spec, vertex_table=VertexTable(np.zeros(0, np.int64), np.zeros(0), np.zeros(1)))
    with pytest.raises(TraceError, match="reference engine"):
        run_batch_reference(spec, 0, 1)


def test_the_one_probe_screen_keeps_the_table():
    """Where the probes see single scatter the screen (one probe per triangle, own stream) lets the full
    probes run as without it: the same table, bit for bit."""
    from straylight.engine.first_vertex import build_table
    from straylight.engine.runtime import runtime

    spec = make_spec(baffled_tube_scene(), _tube_source(20.0), 1000, 5, BLACK, FV)
    comp = runtime().scene(spec)
    screened, full = build_table(spec, comp), build_table(spec, comp, screen=False)
    assert len(full.tri) > 0
    for field in ("tri", "cdf", "p_area"):
        assert np.array_equal(getattr(screened, field), getattr(full, field))
