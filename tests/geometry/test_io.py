"""Export / import of parts and scenes: names, counts and coordinates survive; errors name the file."""
import numpy as np
import pytest

from geometry.io import export_mesh, export_step, load_part, load_scene, read_scene_toml, save_scene
from geometry.mesh import GeometryError


def test_ply_scene_round_trip_is_lossless(reference, tmp_path):
    path = save_scene(reference, tmp_path)
    doc = read_scene_toml(path)
    assert [e["name"] for e in doc["part"]] == list(reference.part_names)
    assert doc["part"][-1]["role"] == "detector" and "material" not in doc["part"][-1]
    back = load_scene(path)
    assert back.part_names == reference.part_names
    for a, b in zip(reference.parts, back.parts):
        assert (a.material, a.role) == (b.material, b.role)
        assert np.array_equal(a.faces, b.faces) and np.array_equal(a.vertices_mm, b.vertices_mm), a.name


def test_stl_round_trip_keeps_names_and_triangle_counts(reference, tmp_path):
    back = load_scene(save_scene(reference, tmp_path, mesh_format="stl"))
    assert back.part_names == reference.part_names
    for a, b in zip(reference.parts, back.parts):
        assert a.n_triangles == b.n_triangles
        assert len(a.vertices_mm) == len(b.vertices_mm)  # STL corners merged back to shared vertices
        # same triangles in the same order, to float32 precision (STL stores float32)
        assert np.abs(a.vertices_mm[a.faces] - b.vertices_mm[b.faces]).max() < 1e-4
        assert b.to_trimesh().is_watertight == a.to_trimesh().is_watertight


def test_obj_round_trip(reference, tmp_path):
    vane = reference.part("vane_1")
    back = load_part(export_mesh(vane, tmp_path / "vane.obj"), name="vane_1", material="x")
    assert back.n_triangles == vane.n_triangles and back.material == "x"
    assert back.to_trimesh().volume == pytest.approx(vane.to_trimesh().volume, rel=1e-6)


def test_step_round_trip_keeps_triangle_count(tmp_path):
    from geometry.parts.tube import reference_tube
    from geometry.tessellate import tessellate

    vane = reference_tube()["vane_2"]
    original = tessellate(vane.shape, name="vane_2", tolerance_mm=0.05)
    path = export_step(vane, tmp_path / "vane_2.step")
    back = load_part(path, name="vane_2", material="black", role="surface", tolerance_mm=0.05)
    assert back.n_triangles == original.n_triangles
    assert back.meta["tessellation"].max_chord_error_mm <= 0.05
    assert back.to_trimesh().volume == pytest.approx(original.to_trimesh().volume, rel=1e-9)


def test_missing_mesh_file_is_a_one_line_error_naming_the_file(tmp_path):
    missing = tmp_path / "nope.stl"
    with pytest.raises(GeometryError) as err:
        load_part(missing, name="tube")
    assert str(missing) in str(err.value) and "\n" not in str(err.value)
    scene = tmp_path / "scene.toml"
    scene.write_text('[[part]]\nname = "tube"\nmesh = "gone.ply"\nrole = "surface"\n')
    with pytest.raises(GeometryError, match="gone.ply"):
        load_scene(scene)


def test_bad_files_are_errors_naming_the_file(tmp_path):
    bad = tmp_path / "garbage.ply"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(GeometryError, match="garbage.ply"):
        load_part(bad)
    weird = tmp_path / "part.xyz"
    weird.write_text("")
    with pytest.raises(GeometryError, match="part.xyz.*unsupported"):
        load_part(weird)
    toml = tmp_path / "broken.toml"
    toml.write_text("[[part]\nname = 1\n")
    with pytest.raises(GeometryError, match="broken.toml.*line 1"):
        load_scene(toml)
    typo = tmp_path / "typo.toml"
    typo.write_text('[[part]]\nname = "a"\nmesh = "a.stl"\nmaterail = "black"\n')
    with pytest.raises(GeometryError, match="typo.toml.*materail"):
        load_scene(typo)


def test_assembly_step_holds_every_solid(tmp_path):
    import cadquery as cq

    from geometry.io import export_assembly_step
    from geometry.parts.tube import reference_tube

    path = export_assembly_step(reference_tube(), tmp_path / "tube.step")
    back = cq.importers.importStep(str(path))
    assert len(back.solids().vals()) == 9  # wall, 7 vanes, end plate (the detector is a face)
    # 9 solids x 4 faces each + the detector disk
    assert len(back.faces().vals()) == 37


def test_triangle_ply_is_read_without_trimesh_to_the_same_numbers(reference, tmp_path, monkeypatch):
    """The plyfile reader of save_scene's PLY files gives trimesh's vertices and faces bit for bit."""
    import geometry.io as gio

    path = save_scene(reference, tmp_path)
    files = sorted(tmp_path.glob("*.ply"))
    assert files and all(gio._read_triangle_ply(f) is not None for f in files)  # the fast path is taken
    fast = [gio._read_mesh(f, ".ply") for f in files]
    monkeypatch.setattr(gio, "_read_triangle_ply", lambda p: None)  # trimesh reads them instead
    for f, (v, t) in zip(files, fast):
        v_ref, t_ref = gio._read_mesh(f, ".ply")
        assert v.dtype == v_ref.dtype and t.dtype == t_ref.dtype
        assert np.array_equal(v, v_ref) and np.array_equal(t, t_ref), f.name
    assert load_scene(path).part_names == reference.part_names


@pytest.mark.parametrize("lengths", [(4, 4), (3, 4)])
def test_polygon_ply_is_left_to_trimesh(tmp_path, lengths):
    """A PLY with quads (even after a triangle) is not a fixed triangle file: left to trimesh, which
    triangulates quads (and refuses mixed binary lists itself)."""
    import plyfile

    import geometry.io as gio

    v = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    f = np.empty(2, dtype=[("vertex_indices", object)])
    f["vertex_indices"] = [np.array([0, 1, 2, 3][:n], np.int32) for n in lengths]
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(f, "face")]).write(
        str(tmp_path / "quad.ply"))
    assert gio._read_triangle_ply(tmp_path / "quad.ply") is None
    if lengths == (4, 4):
        assert load_part(tmp_path / "quad.ply").n_triangles == 4
