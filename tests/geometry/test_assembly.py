"""The hooked-vane tube assembly (geometry.parts.assembly): names, volumes against analytic
formulas, clean checks, and the exported scene traced with an exact power balance."""
import numpy as np
import pytest

from geometry.mesh import GeometryError
from geometry.parts.assembly import SMALL, HookedTubeParams, hooked_tube_assembly


@pytest.fixture(scope="module")
def small_parts():
    return hooked_tube_assembly(SMALL)


def test_part_names_and_roles(small_parts):
    assert list(small_parts) == ["section_1", "section_2", "section_3", "vane_1", "vane_2", "vane_3", "vane_4",
                                 "spider", "entrance_stop", "end_plate", "detector"]
    assert small_parts["detector"].role == "detector" and small_parts["detector"].kind == "solid"
    assert all(p.role == "surface" for n, p in small_parts.items() if n != "detector")
    assert all(len(p.shape.Solids()) == 1 for p in small_parts.values())


def test_volumes_against_analytic_formulas(small_parts):
    """Section: wall annulus + two flange rings - bolt holes; vane: plate annulus + lip (a
    parallelogram of area t_h * L revolved about z, Pappus: 2 pi x_centroid * area)."""
    p = SMALL
    r, w, rf, t = p.inner_radius_mm, p.wall_thickness_mm, p.flange_radius_mm, p.flange_thickness_mm
    section = (np.pi * ((r + w) ** 2 - r**2) * p.section_length_mm + 2 * np.pi * (rf**2 - (r + w) ** 2) * t
               - 2 * p.bolt_count * np.pi * p.bolt_radius_mm**2 * t)
    assert small_parts["section_2"].shape.Volume() == pytest.approx(section, rel=1e-6)
    a = np.deg2rad(p.hook_angle_deg)
    r_out = r - p.vane_clearance_mm
    plate = np.pi * (r_out**2 - p.vane_inner_radius_mm**2) * p.vane_thickness_mm
    lip_area = p.hook_thickness_mm * p.hook_length_mm * np.cos(a)  # parallelogram: base t_h, height L cos a
    lip_centroid_r = p.vane_inner_radius_mm + p.hook_thickness_mm / 2 + p.hook_length_mm * np.sin(a) / 2
    vane = plate + 2 * np.pi * lip_centroid_r * lip_area
    assert small_parts["vane_1"].shape.Volume() == pytest.approx(vane, rel=1e-6)
    detector = np.pi * p.field_stop_radius_mm**2 * p.detector_thickness_mm
    assert small_parts["detector"].shape.Volume() == pytest.approx(detector, rel=1e-9)


def test_spider_has_an_elliptical_edge_and_a_torus(small_parts):
    """The hub's 45-deg cut is an ellipse with semi-axes r_hub * sqrt(2) and r_hub; its fillet a torus."""
    from OCP.BRepAdaptor import BRepAdaptor_Curve, BRepAdaptor_Surface
    from OCP.GeomAbs import GeomAbs_Ellipse, GeomAbs_Torus

    spider = small_parts["spider"].shape
    ellipses = [BRepAdaptor_Curve(e.wrapped) for e in spider.Edges()
                if BRepAdaptor_Curve(e.wrapped).GetType() == GeomAbs_Ellipse]
    assert ellipses  # split into arcs where the legs cross the cut face
    for curve in ellipses:
        assert curve.Ellipse().MajorRadius() == pytest.approx(SMALL.hub_radius_mm * np.sqrt(2), rel=1e-9)
        assert curve.Ellipse().MinorRadius() == pytest.approx(SMALL.hub_radius_mm, rel=1e-9)
    assert any(BRepAdaptor_Surface(f.wrapped).GetType() == GeomAbs_Torus for f in spider.Faces())


def test_small_scene_is_clean_and_within_tolerance(small_parts):
    from geometry.checks import check_scene
    from geometry.tessellate import scene_report, tessellate_parts

    scene = tessellate_parts(small_parts, tolerance_mm=0.2, material="black")
    assert check_scene(scene).ok
    reports = scene_report(scene)
    assert all(r.within_tolerance for r in reports)
    assert 3000 < scene.triangles_mm.shape[0] < 60000


def test_parameters_are_validated():
    with pytest.raises(GeometryError, match="vanes overlap"):
        HookedTubeParams(vane_count=120)
    with pytest.raises(GeometryError, match="hook_angle_deg"):
        HookedTubeParams(hook_angle_deg=85)
    with pytest.raises(GeometryError, match="section_count"):
        HookedTubeParams(section_count=0)
    with pytest.raises(GeometryError, match="unknown assembly parameter"):
        hooked_tube_assembly(SMALL, vanes=3)


def test_exported_scene_traces_with_exact_power_balance(tmp_path):
    from straylight.scene import load_scene

    from geometry.parts.assembly import export_hooked_tube

    toml = export_hooked_tube(tmp_path, SMALL, tolerance_mm=0.2, material="z302_sample_b")
    assert (tmp_path / "assembly.step").is_file()
    rs = load_scene(toml)
    assert "vane_4" in rs.scene.part_names and rs.scene.part("detector").role == "detector"
    result = rs.trace(3000, seed=1)
    assert abs(result.ledger["balance_residual_w"]) < 1e-9
    assert result.detectors["detector"].power_w > 0


def test_numpy_watertight_check_agrees_with_trimesh(small_parts):
    from geometry.mesh import Part
    from geometry.tessellate import tessellate

    part = tessellate(small_parts["vane_1"].shape, tolerance_mm=0.2)
    assert part.is_watertight and part.to_trimesh().is_watertight
    cut = Part("cut", part.vertices_mm, part.faces[:-1])
    assert not cut.is_watertight and not cut.to_trimesh().is_watertight
