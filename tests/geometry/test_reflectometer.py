"""The reflectometer's parts land where the rig geometry says (module docstring of parts/reflectometer.py)."""
import numpy as np
import pytest

from geometry.mesh import GeometryError
from geometry.parts.reflectometer import ReflectometerParams, build_reflectometer
from geometry.scenes import reflectometer_scene


def normals_of(scene, name):
    return scene.triangle_normals[scene.triangle_part == scene.part_names.index(name)]


@pytest.fixture(scope="module")
def rig():
    return reflectometer_scene(30.0, 30.0, sample_material="z302", black_material="black")


def test_parts_names_roles_materials(rig):
    assert rig.part_names == ("sample", "holder", "holder_post", "slit_plate", "detector")
    tags = {p.name: (p.material, p.role) for p in rig.parts}
    assert tags["sample"] == ("z302", "surface") and tags["slit_plate"] == ("black", "surface")
    assert tags["detector"] == (None, "detector")


def test_sample_face_contains_the_axis_and_faces_the_beam(rig):
    """Normal n = (sin 30, 0, cos 30); the front face passes through the rotation axis (origin)."""
    n = np.array([np.sin(np.pi / 6), 0.0, np.cos(np.pi / 6)])
    sample = rig.part("sample").vertices_mm
    assert (sample @ n).max() == pytest.approx(0.0, abs=1e-9)  # front face through the origin
    assert (sample @ n).min() == pytest.approx(-0.5, abs=1e-9)  # 0.5 mm wafer behind it
    assert np.isclose(normals_of(rig, "sample") @ n, 1.0).sum() == 2  # the two front triangles


def test_slit_and_detector_on_the_specular_arm(rig):
    """theta_i = theta_r = 30 deg, phi_r = 0: the arm is at 60 deg from the beam, 200 mm long."""
    w = np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    plate = rig.part("slit_plate").vertices_mm
    assert (plate @ w).min() == pytest.approx(200.0, abs=1e-9)
    assert (plate @ w).max() == pytest.approx(201.0, abs=1e-9)
    assert plate.mean(axis=0) == pytest.approx(200.5 * w, abs=1e-9)
    # the slit: 0.2 mm across the arm in the plane of incidence, 5 mm along y
    x_arm = np.array([w[2], 0.0, -w[0]])
    front = plate[np.isclose(plate @ w, 200.0)]
    inner = front[np.abs(front @ x_arm) < 1.0]
    assert np.ptp(inner @ x_arm) == pytest.approx(0.2, abs=1e-9) and np.ptp(inner[:, 1]) == pytest.approx(5.0)
    area = rig.part("slit_plate").to_trimesh().area
    assert area == pytest.approx(2 * (25 * 25 - 0.2 * 5) + 1.0 * (4 * 25 + 2 * (0.2 + 5)), rel=1e-9)
    det = rig.part("detector").vertices_mm
    assert det @ w == pytest.approx(np.full(len(det), 203.0), abs=1e-9)
    assert np.allclose(normals_of(rig, "detector"), -w)  # sensitive side toward the sample


def test_backscatter_half_plane_and_bad_phi():
    parts = build_reflectometer(40.0, 10.0, 180.0, ReflectometerParams(arm_mm=150.0))
    bb = parts["detector"].shape.Center()
    a = np.deg2rad(30.0)  # theta_i - theta_r
    assert np.array([bb.x, bb.y, bb.z]) == pytest.approx(153.0 * np.array([np.sin(a), 0, np.cos(a)]), abs=1e-9)
    with pytest.raises(GeometryError, match="phi_r_deg"):
        build_reflectometer(40.0, 10.0, 90.0)
    with pytest.raises(GeometryError, match="arm_mm"):
        ReflectometerParams(arm_mm=-5.0)


def test_specular_ray_passes_the_slit_and_off_specular_rays_do_not(rig):
    """theta_i = theta_r = 30 deg: the laser (along -z) hits the sample first; the mirror ray leaves
    at 60 deg and reaches the detector through the slit; 0.1 deg off in the plane (0.35 mm at
    200 mm, more than the 0.1 mm half-width) it stops on the slit plate."""
    import embreex.mesh_construction as mc
    import embreex.rtcore_scene as rtcs

    emb = rtcs.EmbreeScene()
    mc.TriangleMesh(emb, rig.triangles_mm.astype(np.float32))

    def first(origins, dirs):
        prim = emb.run(np.asarray(origins, np.float32), np.asarray(dirs, np.float32))
        return [rig.part_names[rig.triangle_part[p]] if p >= 0 else None for p in prim]

    assert first([[0.0, 0.0, 100.0]], [[0.0, 0.0, -1.0]]) == ["sample"]
    n = np.array([np.sin(np.pi / 6), 0.0, np.cos(np.pi / 6)])
    start = 1e-3 * n
    angles = np.deg2rad([60.0, 60.1, 59.9])
    dirs = np.stack([np.sin(angles), np.zeros(3), np.cos(angles)], axis=1)
    assert first(np.tile(start, (3, 1)), dirs) == ["detector", "slit_plate", "slit_plate"]
