"""Mesh checks (trimesh + manifold3d): silent on a correct scene, naming the part otherwise."""
import warnings

import numpy as np
import pytest
import trimesh

from geometry.checks import GeometryWarning, check_part, check_scene, overlap_volumes, union_parts
from geometry.mesh import GeometryError, Part, Scene


def box(name, offset=(0.0, 0.0, 0.0), size=1.0, **kw):
    m = trimesh.creation.box(extents=(size, size, size))
    return Part(name, np.asarray(m.vertices) + offset, np.asarray(m.faces), **kw)


def test_reference_scene_passes_every_check_silently(reference):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a diagnostic must not fire on a correct scene
        result = check_scene(reference)
    assert result.ok, result.format()
    solids = [p for p in result.parts if p.kind == "solid"]
    assert len(solids) == 9
    assert all(p.watertight and p.winding_consistent and p.volume_mm3 > 0 for p in solids)
    assert all(p.manifold_status == "NoError" for p in solids)
    (detector,) = [p for p in result.parts if p.name == "detector"]
    assert detector.kind == "sheet" and detector.winding_consistent and detector.n_open_edges > 0
    # vanes touch the wall without interpenetrating: intersection volumes at round-off
    overlaps = overlap_volumes(reference)
    assert {(a, b) for a, b, _ in overlaps} >= {("wall", f"vane_{k}") for k in range(1, 8)}
    assert max(v for _, _, v in overlaps) < 1e-6


def test_non_watertight_part_is_reported_by_name(reference):
    wall = reference.part("wall")
    holed = Part("wall", wall.vertices_mm, wall.faces[1:], "black")
    scene = Scene((holed, reference.part("vane_1")))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = check_scene(scene)
    messages = [str(w.message) for w in caught if issubclass(w.category, GeometryWarning)]
    assert any("'wall' is not watertight" in m for m in messages)
    assert all("'wall'" in m for m in messages)  # vane_1 is fine and not mentioned
    assert not result.ok and result.parts[1].ok
    with pytest.raises(GeometryError, match="'wall' is not watertight"):
        check_scene(scene, strict=True)


def test_inward_normals_are_reported():
    flipped = box("flipped")
    flipped = Part("flipped", flipped.vertices_mm, flipped.faces[:, ::-1])
    check = check_part(flipped)
    assert check.volume_mm3 == pytest.approx(-1.0)
    assert any("'flipped'" in m and "inward" in m for m in check.problems)
    assert check_part(box("fine")).ok


def test_inconsistent_winding_is_reported():
    b = box("mixed")
    faces = b.faces.copy()
    faces[0] = faces[0, ::-1]
    check = check_part(Part("mixed", b.vertices_mm, faces))
    assert not check.winding_consistent
    assert any("'mixed'" in m and "winding" in m for m in check.problems)


def test_overlap_volume_and_union_are_analytic():
    """Unit cubes shifted by 0.5 along x: intersection 0.5 mm^3, union 1.5 mm^3."""
    a, b = box("a"), box("b", offset=(0.5, 0.0, 0.0))
    ((name_a, name_b, volume),) = overlap_volumes(Scene((a, b)))
    assert (name_a, name_b) == ("a", "b") and volume == pytest.approx(0.5, rel=1e-9)
    with pytest.warns(GeometryWarning, match="'a' and 'b' overlap"):
        check_scene(Scene((a, b)))
    fused = union_parts([a, b], name="ab")
    check = check_part(fused)
    assert check.ok and check.volume_mm3 == pytest.approx(1.5, rel=1e-9)


def test_touching_boxes_do_not_count_as_overlapping():
    a, b = box("a"), box("b", offset=(1.0, 0.0, 0.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_scene(Scene((a, b))).ok


def test_bevelled_tube_with_aperture_stop_passes_checks():
    from geometry.scenes import tube_scene

    scene = tube_scene(vane_count=4, vane_bevel_deg=35.0, vane_bevel_side="front", aperture_stop_radius_mm=45.0,
                       tolerance_mm=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = check_scene(scene)
    assert result.ok, result.format()
    assert "aperture_stop" in scene.part_names and len(result.parts) == 8
    # touching parts share their circle nodes at any tolerance: no interpenetration beyond round-off
    touching = overlap_volumes(scene)
    assert {(a, b) for a, b, _ in touching} >= {("wall", f"vane_{k}") for k in range(1, 5)}
    assert max(abs(v) for _, _, v in touching) < 1e-6
