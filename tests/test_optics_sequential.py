"""Where a straight segment crosses an imported surface (straylight.optics.sequential.crossings), against the
line-sphere intersection in closed form, and the holes the import cuts where a later beam passes a surface."""
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from straylight.optics.sequential import crossings

LENSES = Path(__file__).resolve().parent / "data" / "lenses"
R_MM = 10.0  # a steep sphere: vertex at the origin, centre at z = R, semi-diameter 9.5 (sag 6.88 at the edge)
SD_MM = 9.5


def _sphere():
    return SimpleNamespace(local_z=np.array([0.0, 0.0, 1.0]), local_x=None, vertex_mm=np.zeros(3),
                           semi_diameter_mm=SD_MM, radius_mm=R_MM, conic=0.0, coefficients=(), power_terms=(),
                           aperture_offset_mm=(0.0, 0.0), aperture_half_widths_mm=None)


def _sag(rho):
    return R_MM - np.sqrt(R_MM * R_MM - rho * rho)


def _first_cap_crossing(a, b):
    """The smallest t in (0, 1) where a + t (b - a) meets the sphere's cap z < R (closed form), or NaN."""
    d = b - a
    c = np.array([0.0, 0.0, R_MM])
    qa, qb, qc = d @ d, 2.0 * d @ (a - c), (a - c) @ (a - c) - R_MM * R_MM
    disc = qb * qb - 4.0 * qa * qc
    if disc < 0:
        return np.nan
    roots = sorted([(-qb - np.sqrt(disc)) / (2 * qa), (-qb + np.sqrt(disc)) / (2 * qa)])
    for t in roots:
        p = a + t * d
        if 0.0 < t < 1.0 and p[2] < R_MM and np.hypot(p[0], p[1]) <= SD_MM:
            return t
    return np.nan


def test_a_segment_along_the_axis_crosses_where_the_closed_form_says():
    rng = np.random.default_rng(3)
    a = np.column_stack([rng.uniform(-6, 6, 50), rng.uniform(-6, 6, 50), np.full(50, -5.0)])
    b = a + np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-2, 2, 50), np.full(50, 12.0)])
    t, rho, x, y = crossings(_sphere(), a, b)
    want = np.array([_first_cap_crossing(p, q) for p, q in zip(a, b)])
    assert np.all(np.isfinite(want))
    np.testing.assert_allclose(t, want, rtol=0, atol=1e-9)
    p = a + t[:, None] * (b - a)
    np.testing.assert_allclose(rho, np.hypot(p[:, 0], p[:, 1]), atol=1e-9)
    np.testing.assert_allclose(np.column_stack([x, y]) @ np.eye(2), np.column_stack([x, y]), atol=0)
    np.testing.assert_allclose(p[:, 2], _sag(rho), atol=1e-8)


def test_a_steep_segment_just_in_front_of_a_steep_surface_does_not_cross_it():
    """The TH Swiss Irix 11 mm's failure: a segment 0.05-0.3 mm in front of the surface's steep zone, nearly along
    it, read as crossing it after the 3 fixed-point steps the search took before (no sequential ray then passed)."""
    rho = np.array([7.0, 9.0])
    a = np.array([rho[0], 0.0, _sag(rho[0]) - 0.3])
    b = np.array([rho[1], 0.0, _sag(rho[1]) - 0.3])
    mid = 0.5 * (a + b)
    assert 0 < _sag(8.0) - mid[2] < 0.3  # in front of the surface all the way (the chord of a convex sag)
    t, _, _, _ = crossings(_sphere(), a[None], b[None])
    assert np.isnan(t[0]) and np.isnan(_first_cap_crossing(a, b))


def test_a_segment_across_the_steep_edge_zone_finds_the_crossing_the_fixed_point_misses():
    """Nearly across the axis, 3 mm above the vertex: the fixed point on the sag's plane runs to the aperture's edge,
    where the sag is held flat beyond it, and meets that extension outside the segment; the surface itself is met
    at rho = 6.4 mm inside it (found by the sign-change search)."""
    a, b = np.array([-20.0, 0.0, 3.0]), np.array([-5.0, 0.0, 2.0])
    t, rho, _, _ = crossings(_sphere(), a[None], b[None])
    assert t[0] == pytest.approx(_first_cap_crossing(a, b), abs=1e-9)
    assert 5.0 < rho[0] < SD_MM


def test_segments_that_miss_or_end_on_the_surface():
    s = _sphere()
    a = np.array([[0.0, 0.0, -5.0], [0.0, 0.0, -5.0], [3.0, 0.0, float(_sag(3.0))]])
    b = np.array([[0.0, 0.0, -1.0], [5.0, 5.0, -5.0], [3.0, 0.0, -4.0]])
    t, _, _, _ = crossings(s, a, b)
    assert np.isnan(t[0]) and np.isnan(t[1]) and np.isnan(t[2])  # short of it, parallel to its plane, from it
    t, rho, x, y = crossings(s, a, b, start_on_surface=True)
    assert np.isnan(t[0]) and t[2] == 0.0 and rho[2] == pytest.approx(3.0) and x[2] == pytest.approx(3.0)


def test_a_beam_grazing_one_side_of_a_mirror_cuts_no_hole():
    """HoO-V2C18Ex66 (four mirrors, off-axis): the s7 -> s11 beam crosses s3's aperture at 14.6 of its 16.0 mm, on
    one side. A hole is where a later beam passes a surface's centre (a Cassegrain primary); a hole of 14.6 mm
    would take all of s3's own beam."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    scene = build_scene(read_prescription(LENSES / "ray-optics" / "HoO-V2C18Ex66.zmx"))
    s3 = next(part for part in scene["part"] if part["name"] == "s3")
    assert not s3["surface"].get("inner_radius_mm")


def test_a_rear_element_in_its_own_glass_crossing_a_mangin_primary_gets_a_hole():
    """US 5331467 (ray-optics models): the rear element, in its own glass, crosses the Mangin primary's front
    surface, whose glass is on neither side of it: that glass cannot be there, so the surface has a hole (before,
    876 of 924 sequential rays met it and the focus check had no reference)."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    p = read_prescription(LENSES / "ray-optics" / "US05331467-1.zmx")
    scene = build_scene(p)
    holes = {part["name"]: part["surface"].get("inner_radius_mm") for part in scene["part"] if "surface" in part}
    assert holes.get("s3") and holes["s3"] > 10.0, holes
