"""Imported surfaces closer than the default mesh chord tolerance are meshed finer (docs/optics.md).

The hit search runs on the meshes; two meshes within their chord error of each other would be met in the
wrong order. Golden: the gap between s7 and s8 of HoO-V2C18Ex27.zmx computed here from the file's own CURV
and DISZ numbers with the sphere sag formula, independent of the importer.
"""
import math
from pathlib import Path

import numpy as np
import pytest

LENSES = Path(__file__).resolve().parent / "data" / "lenses"


def _sphere_sag(c, rho):
    return c * rho * rho / (1.0 + np.sqrt(1.0 - c * c * rho * rho))


def test_a_thin_air_gap_gets_a_mesh_tolerance_below_a_quarter_of_the_gap():
    from geometry.analytic import surface_from_dict
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    p = read_prescription(LENSES / "ray-optics" / "HoO-V2C18Ex27.zmx")
    parts = {q["name"]: q for q in build_scene(p)["part"]}
    # the file: SURF 7 CURV -0.11659088259, DISZ 0.018 to SURF 8 CURV -0.11641443539, common DIAM 1.37503
    c7, c8, d78, r = -1.165908825929812265e-01, -1.164144353899883577e-01, 0.018, 1.3750279799325189
    rho = np.linspace(0.0, r, 2001)
    gap = float(np.min(d78 + _sphere_sag(c8, rho) - _sphere_sag(c7, rho)))
    assert 0.0 < gap < 0.2
    for name in ("s7", "s8"):
        assert parts[name]["tolerance_mm"] <= gap / 4.0 + 1e-9
    # surfaces far apart keep the scene's default (no key)
    assert "tolerance_mm" not in parts["s4"] and "tolerance_mm" not in parts["s1"]
    # meshed at that tolerance, every vertex and facet centre of s8's mesh stays behind s7's exact surface
    s7 = surface_from_dict(parts["s7"]["surface"])
    s8 = surface_from_dict(parts["s8"]["surface"])
    v8, f8 = s8.mesh(parts["s8"]["tolerance_mm"])
    pts = np.concatenate([v8, v8[f8].mean(axis=1)])
    z7 = float(s7.vertex_mm[2]) + (-1.0 if s7.axis[2] < 0 else 1.0) * s7.sag(np.hypot(pts[:, 0], pts[:, 1]).clip(0, r))
    assert np.all(pts[:, 2] > z7)
    v7, f7 = s7.mesh(parts["s7"]["tolerance_mm"])
    c7pts = np.concatenate([v7, v7[f7].mean(axis=1)])
    z8 = float(s8.vertex_mm[2]) + (-1.0 if s8.axis[2] < 0 else 1.0) * s8.sag(np.hypot(c7pts[:, 0], c7pts[:, 1]).clip(0, r))
    assert np.all(c7pts[:, 2] < z8)
    assert math.isclose(float(s8.vertex_mm[2] - s7.vertex_mm[2]), d78, abs_tol=1e-9)


def test_a_secondary_in_the_incoming_beam_gets_no_hole():
    """HoO-V2C18Ex27's flat secondary (s5, semi-diameter 5.44 mm) sits in the beam between the corrector and the
    primary: that beam is obscured by its back. The file gives it no hole, and none may be added (a hole of
    0.999 x its semi-diameter left a 6 um ring of mirror, and the sequential reference kept no ray)."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    p = read_prescription(LENSES / "ray-optics" / "HoO-V2C18Ex27.zmx")
    parts = {q["name"]: q for q in build_scene(p)["part"]}
    assert "inner_radius_mm" not in parts["s5"]["surface"]
    assert not [w for w in p.warnings if "hole" in w]


def test_a_decentred_clear_aperture_is_kept_in_the_scene():
    """zmax_37992.zmx: an off-axis paraboloid whose aperture the file decentres (OBDC 0 190.6 on SURF 3, CLAP 25.4);
    threemir.seq: CODE V REX/REY rectangles and ADY on the three mirrors (values as the file writes them);
    US08011793-1.zmx: Zemax SQAP 424 x 192 with OBDC 0 -397 on SURF 2."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    p = read_prescription(LENSES / "ray-optics" / "zmax_37992.zmx")
    s3 = next(s for s in p.surfaces if s.name == "s3")
    assert s3.aperture_offset_mm == pytest.approx((0.0, 190.6)) and s3.semi_diameter_mm == pytest.approx(25.4)
    part = next(q for q in build_scene(p)["part"] if q["name"] == "s3")["surface"]
    # the coordinate break puts the vertex at y = -190.6: the segment's centre is back on the z axis
    assert part["aperture_center_mm"] == pytest.approx([0.0, 0.0, 200.0])
    p = read_prescription(LENSES / "ray-optics" / "threemir.seq")
    shapes = {s.name: s.aperture_offset_mm + s.aperture_half_widths_mm for s in p.surfaces if not s.dummy}
    assert shapes["s2"] == pytest.approx((0.0, 99.602384, 75.734236, 78.538674))
    assert shapes["s4"] == pytest.approx((0.0, -6.213535, 24.789115, 24.791683))
    assert shapes["s5"] == pytest.approx((0.0, -112.35423, 66.581268, 65.453521))
    p = read_prescription(LENSES / "ray-optics" / "US08011793-1.zmx")
    s2 = next(s for s in p.surfaces if s.name == "s2")
    assert s2.aperture_offset_mm == pytest.approx((0.0, -397.0)) and s2.aperture_half_widths_mm == pytest.approx((424.0, 192.0))
    assert not any(s.aperture_offset_mm != (0.0, 0.0) or s.aperture_half_widths_mm
                   for s in read_prescription(LENSES / "ray-optics" / "rc_f16.seq").surfaces)
