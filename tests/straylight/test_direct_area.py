"""The unscattered light by 2-D clipping (straylight.engine.direct_area, strategy ``direct_area``).

Scene: a flat detector disk (radius RD, z = 0, facing +z) under an aperture plate (a black annulus, hole
radius RH, at z = H), lit by a collimated beam tilted by a about y. The light that reaches the detector
straight lands where the hole, carried down along the beam (a circle shifted by H tan a in the detector's
plane), overlaps the detector: the two circles' lens area (Weisstein, "Circle-Circle Intersection",
MathWorld), times the irradiance on the detector's plane, Phi / (pi r^2 cos a) x cos a for a source disk of
radius r normal to the axis.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from engine_helpers import annulus_part, baffled_tube_scene, disk_part
from geometry.mesh import Scene
from materials import load_material
from straylight.engine import direct_area
from straylight.engine.spec import make_spec
from straylight.engine.strategies.base import ANALOG
from straylight.sources import CollimatedDisk
from straylight.trace import OutputOptions, TraceOptions, trace

RD, RH, H = 10.0, 8.0, 50.0
SRC_R = 30.0
DIRECT = TraceOptions(estimator=replace(ANALOG, direct_area=True))


def _lens_area(r1: float, r2: float, s: float) -> float:
    """Area of the overlap of two circles of radii r1, r2 whose centres are s apart (MathWorld)."""
    if s >= r1 + r2:
        return 0.0
    if s <= abs(r1 - r2):
        return math.pi * min(r1, r2) ** 2
    a1 = r1 ** 2 * math.acos((s * s + r1 * r1 - r2 * r2) / (2 * s * r1))
    a2 = r2 ** 2 * math.acos((s * s + r2 * r2 - r1 * r1) / (2 * s * r2))
    a3 = 0.5 * math.sqrt((-s + r1 + r2) * (s + r1 - r2) * (s - r1 + r2) * (s + r1 + r2))
    return a1 + a2 - a3


def _plate_scene(n_seg=2048, facing=+1):
    black = load_material({"components": [{"type": "lambertian", "rd": 0.05}]}, "black")
    parts = (annulus_part("plate", H, RH, 40.0, n_seg, "surface", material="black"),
             disk_part("detector", 0.0, RD, n_seg, "detector", facing=facing))
    return Scene(parts), {"black": black}


def _exact_plate_scene():
    """The same as exact planes (CONTRACTS 6.4: a detector without a solid): the walk counts hits inside the
    exact disk and annulus only, and so does the strategy."""
    from geometry.analytic import Plane, analytic_part

    up = np.array([0.0, 0.0, 1.0])
    black = load_material({"components": [{"type": "lambertian", "rd": 0.05}]}, "black")
    plate = analytic_part("plate", Plane(np.array([0.0, 0.0, H]), up, math.inf, 0.0, 40.0, RH), "black")
    det = analytic_part("detector", Plane(np.zeros(3), up, math.inf, 0.0, RD, 0.0), None, "detector")
    return Scene((plate, det)), {"black": black}


def _source(a_deg: float) -> CollimatedDisk:
    a = math.radians(a_deg)
    return CollimatedDisk(center_mm=np.array([0.0, 0.0, H + 10.0]), normal=np.array([0.0, 0.0, -1.0]),
                          direction=np.array([math.sin(a), 0.0, -math.cos(a)]), radius_mm=SRC_R, power_w=1.0)


@pytest.mark.parametrize("a_deg", [0.0, 1.0, 2.5, 4.0])
def test_the_lit_area_is_the_overlap_of_the_hole_carried_along_the_beam_and_the_detector(a_deg):
    """Against the circles' lens area (module doc), to the 2048-gons' tessellation (< 1e-4 here)."""
    scene, mats = _plate_scene()
    src = _source(a_deg)
    table = direct_area.build(make_spec(scene, [src], 1000, 0, mats, DIRECT))
    a = math.radians(a_deg)
    expected = 1.0 / (math.pi * SRC_R ** 2 * math.cos(a)) * math.cos(a) * _lens_area(RH, RD, H * math.tan(a))
    assert isinstance(table, direct_area.DirectArea)
    assert table.power_w == pytest.approx(expected, rel=2e-4)
    # the records' points lie in the lit region: on the detector, inside the hole's shadow-free circle
    u = np.random.default_rng(1).random((2000, 3))
    z = direct_area.points_in(table, u)
    assert np.allclose(z[:, 2], 0.0, atol=1e-9)
    assert (np.hypot(z[:, 0], z[:, 1]) <= RD + 1e-9).all()
    assert (np.hypot(z[:, 0] - H * math.tan(a), z[:, 1]) <= RH + 1e-9).all()  # up the beam to the hole


@pytest.mark.parametrize("a_deg", [0.0, 2.5, 4.0])
def test_exact_planes_are_their_circles(a_deg):
    """An exact plate and an exact detector (analytic planes): the lens area of the circles themselves, to the
    equal-area 4096-gons (1e-5), not to the meshes that find their hits."""
    scene, mats = _exact_plate_scene()
    table = direct_area.build(make_spec(scene, [_source(a_deg)], 1000, 0, mats, DIRECT))
    a = math.radians(a_deg)
    expected = 1.0 / (math.pi * SRC_R ** 2) * _lens_area(RH, RD, H * math.tan(a))
    assert isinstance(table, direct_area.DirectArea)
    assert table.power_w == pytest.approx(expected, rel=1e-5)


def test_with_exact_planes_it_agrees_with_the_analog_walk():
    scene, mats = _exact_plate_scene()
    src = _source(3.0)
    analog = trace(scene, [src], 200_000, seed=7, materials=mats, options=TraceOptions(estimator=ANALOG))
    on = trace(scene, [src], 20_000, seed=8, materials=mats, options=DIRECT)
    a, b = on.detectors["detector"], analog.detectors["detector"]
    assert on.strategies.runs("direct_area")
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)


def test_direct_area_agrees_with_the_analog_walk_keeps_the_ledger_and_records_the_direct_family():
    """At 3 deg (a lit lens of the two circles and scatter off the plate's bore): the same power as the analog
    walk within 4 sigma, the ledger exact, and the "source -> detector" records summing to the computed power
    exactly (each ray's share P / N; the walk's own direct hits dropped)."""
    scene, mats = _plate_scene(n_seg=512)
    src = _source(3.0)
    analog = trace(scene, [src], 200_000, seed=5, materials=mats, options=TraceOptions(estimator=ANALOG))
    opts = replace(DIRECT, output=OutputOptions(record_paths=True))
    on = trace(scene, [src], 40_000, seed=6, materials=mats, options=opts)
    a, b = on.detectors["detector"], analog.detectors["detector"]
    assert abs(a.power_w - b.power_w) < 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)
    total = sum(t.power_w for t in on.detectors.values()) + sum(t.power_w for t in on.absorbed.values())
    assert abs(on.emitted_w - total - on.escaped.power_w) / on.emitted_w < 1e-9
    table = direct_area.build(make_spec(scene, [src], 1000, 0, mats, DIRECT))
    p = on.paths
    direct = p.depth == 0
    assert direct.any() and float(np.sum(p.power_w[direct])) == pytest.approx(table.power_w, rel=1e-12)
    # the direct part is exact, so the run's error is the scattered light's alone: far below the analog's
    # per ray (whose variance is the direct hits' Bernoulli)
    assert a.stderr_w * math.sqrt(40_000) < 0.2 * b.stderr_w * math.sqrt(200_000)


def test_the_tube_at_its_cut_off_counts_the_sliver_the_walk_misses():
    """The reference tube at 14.3 deg: the beam reaches the detector straight through a sliver (~1e-5 of the
    source's rays, tens of mm^2 at most). The strategy's power is what 1e6 first-hit casts see (a binomial
    estimate, 4 sigma), and a short run with it agrees with one without it only within the walk's own large
    error (the walk meets the sliver by chance)."""
    from straylight.intersect.embree import EmbreeIntersector

    scene = baffled_tube_scene("black")
    mats = {"black": load_material({"components": [{"type": "lambertian", "rd": 0.05}]}, "black")}
    a = math.radians(13.6)
    src = CollimatedDisk(center_mm=np.array([0.0, 0.0, 320.0]), normal=np.array([0.0, 0.0, -1.0]),
                         direction=np.array([math.sin(a), 0.0, -math.cos(a)]), radius_mm=60.0, power_w=1.0)
    spec = make_spec(scene, [src], 1000, 0, mats, DIRECT)
    table = direct_area.build(spec)
    assert isinstance(table, direct_area.DirectArea) and table.power_w > 0
    n = 1_000_000
    u = np.random.default_rng(3).random((n, 4))
    o, d = src.emit(u)
    tri = EmbreeIntersector(spec.triangles_mm).first_triangle(np.ascontiguousarray(o), np.ascontiguousarray(d))
    det = spec.part_names.index("detector")
    hits = int(np.count_nonzero((tri >= 0) & (spec.triangle_part[np.maximum(tri, 0)] == det)))
    assert hits > 20  # the test's own check: a sliver the casts do see
    p_mc = hits / n * src.power_w
    assert abs(table.power_w - p_mc) < 4 * math.sqrt(hits) / n * src.power_w, (table.power_w, p_mc, hits)


def test_it_declines_where_nothing_is_lit_or_counted_and_then_changes_no_number():
    """Beyond the hole's shadow (nothing lit), with the source behind the detector's plane (the rays leave the
    disk away from it), and with the beam on a detector counted on its front only (``detector_sides =
    "front"``, the disk facing down): declined with a reason, and the trace is the one without the strategy,
    number for number."""
    scene, mats = _plate_scene(n_seg=256)
    far = _source(30.0)  # H tan a = 28.9 > RH + RD
    spec = make_spec(scene, [far], 1000, 0, mats, DIRECT)
    declined = direct_area.build(spec)
    assert isinstance(declined, direct_area.Declined) and "sees the beam straight" in declined.reason
    base = TraceOptions(estimator=replace(ANALOG, nee=True))
    with_it = replace(base, estimator=replace(base.estimator, direct_area=True))
    r0 = trace(scene, [far], 20_000, seed=2, materials=mats, options=base)
    r1 = trace(scene, [far], 20_000, seed=2, materials=mats, options=with_it)
    assert r1.detectors["detector"].power_w == r0.detectors["detector"].power_w
    off = r1.strategies.to_dict()["off"]
    assert "sees the beam straight" in off["direct_area"]
    behind = CollimatedDisk(center_mm=np.array([0.0, 0.0, -5.0]), normal=np.array([0.0, 0.0, -1.0]),
                            direction=np.array([0.0, 0.0, -1.0]), radius_mm=SRC_R)  # under the detector, going down
    out = direct_area.build(make_spec(scene, [behind], 1000, 0, mats, DIRECT))
    assert isinstance(out, direct_area.Declined) and "outside the beam" in out.reason
    back, mats = _plate_scene(n_seg=256, facing=-1)
    front_only = replace(DIRECT, output=OutputOptions(detector_sides="front"))
    out = direct_area.build(make_spec(back, [_source(0.0)], 1000, 0, mats, front_only))
    assert isinstance(out, direct_area.Declined) and "back" in out.reason


def test_it_is_ruled_out_for_curved_analytic_surfaces_and_other_sources():
    from geometry.analytic import Conic, Plane, analytic_part
    from straylight.sources import PointSource

    scene, mats = _plate_scene(n_seg=256)
    assert direct_area.unsupported(make_spec(scene, [_source(1.0)], 10, 0, mats, DIRECT)) is None
    point = PointSource(position_mm=np.array([0.0, 0.0, 60.0]), power_w=1.0)
    assert "collimated_disk" in direct_area.unsupported(make_spec(scene, [point], 10, 0, mats, DIRECT))
    flat = analytic_part("window", Plane(np.array([0, 0, 30.0]), np.array([0, 0, 1.0]), math.inf, 0.0, 5.0, 0.0),
                         "black")
    assert direct_area.unsupported(make_spec(Scene((*scene.parts, flat)), [_source(1.0)], 10, 0, mats, DIRECT)) is None
    curved = analytic_part("lens", Conic(np.array([0, 0, 30.0]), np.array([0, 0, 1.0]), 50.0, 0.0, 5.0, 0.0), "black")
    spec = make_spec(Scene((*scene.parts, curved)), [_source(1.0)], 10, 0, mats, DIRECT)
    assert "curved analytic surfaces (lens)" in direct_area.unsupported(spec)  # a cylinder is followed (above)


def test_the_computed_straight_light_reaches_trace_json_pst_json_and_the_report():
    """``TraceResult.unscattered_w`` (trace --json), each PST point's ``unscattered_w`` (pst.json) and the
    report's "unscattered" column (its entrance ratio) carry the computed power, where the tube's formula (the
    two end circles, ignoring the tessellation that matters at the cut-off) stood before."""
    from straylight.analyses.builtin import tube_setup
    from straylight.analyses.pst import pst_sweep
    from straylight.analyses.report import unscattered_ratio

    setup = tube_setup()
    a = math.radians(13.0)
    pst = pst_sweep(setup, [a], n_rays=2_000, seed=1)
    src = setup.beam.source(a)
    spec = make_spec(setup.scene, [src], 1000, 0, setup.materials,
                     TraceOptions(estimator=replace(ANALOG, direct_area=True)))
    power = direct_area.build(spec).power_w
    assert pst.rows()[0]["unscattered_w"] == pytest.approx(power, rel=1e-12)
    p_ent = setup.entrance.power_w(setup.beam, a, 0.0)
    assert unscattered_ratio(pst, [math.nan])[0] == pytest.approx(power / p_ent, rel=1e-9)
    doc = trace(setup.scene, [src], 2_000, seed=1, materials=setup.materials, options=DIRECT).to_json_dict()
    assert doc["unscattered_w"] == {"detector": pytest.approx(power, rel=1e-12)}


@pytest.mark.parametrize("a_deg", [3.0, 6.0])
def test_an_exact_tube_wall_is_its_cylinder(a_deg):
    """An exact cylinder (a tube's wall, radius 10, 50 long) over an exact detector disk of the same radius: the
    beam reaches the detector straight where the top rim, carried down along the beam, overlaps the detector:
    the lens area of two radius-10 circles 50 tan a apart (a convex wall: a line inside both end circles stays
    inside); the prism of 4096 sides of the circle's area gives it to 1e-5. A trace agrees with the analog walk,
    which meets the exact cylinder."""
    from geometry.analytic import Cylinder, Plane, analytic_part

    up = np.array([0.0, 0.0, 1.0])
    black = load_material({"components": [{"type": "lambertian", "rd": 0.05}]}, "black")
    wall = analytic_part("wall", Cylinder(np.zeros(3), up, radius_mm=10.0, length_mm=50.0), "black")
    det = analytic_part("detector", Plane(np.zeros(3), up, math.inf, 0.0, 10.0, 0.0), None, "detector")
    scene, mats = Scene((wall, det)), {"black": black}
    a = math.radians(a_deg)
    src = CollimatedDisk(center_mm=np.array([0.0, 0.0, 55.0]), normal=np.array([0.0, 0.0, -1.0]),
                         direction=np.array([math.sin(a), 0.0, -math.cos(a)]), radius_mm=20.0, power_w=1.0)
    table = direct_area.build(make_spec(scene, [src], 1000, 0, mats, DIRECT))
    assert isinstance(table, direct_area.DirectArea)
    expected = _lens_area(10.0, 10.0, 50.0 * math.tan(a)) / (math.pi * 20.0 ** 2)
    assert table.power_w == pytest.approx(expected, rel=1e-5)
    analog = trace(scene, [src], 100_000, seed=3, materials=mats, options=TraceOptions(estimator=ANALOG))
    on = trace(scene, [src], 20_000, seed=4, materials=mats, options=DIRECT)
    x, y = on.detectors["detector"], analog.detectors["detector"]
    assert abs(x.power_w - y.power_w) < 4 * math.hypot(x.stderr_w, y.stderr_w), (x, y)
