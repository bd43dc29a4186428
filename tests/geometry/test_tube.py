"""The parametric tube against BENCHMARK.md and analytic volumes/areas."""
import numpy as np
import pytest

from geometry.mesh import GeometryError
from geometry.parts.tube import REFERENCE_TUBE, TubeParams, build_tube, reference_tube

VANE_Z = [40.0, 80.0, 120.0, 160.0, 200.0, 240.0, 280.0]  # BENCHMARK.md: centred at z = 40, 80, ..., 280


def radius(v):
    return np.hypot(v[:, 0], v[:, 1])


def test_reference_tube_has_the_benchmark_part_names():
    parts = reference_tube()
    assert list(parts) == ["wall"] + [f"vane_{k}" for k in range(1, 8)] + ["end_plate", "detector"]
    assert parts["detector"].role == "detector" and parts["detector"].kind == "sheet"
    assert all(p.kind == "solid" and p.role == "surface" for n, p in parts.items() if n != "detector")


def test_reference_scene_extents_match_benchmark(reference):
    wall = reference.part("wall").vertices_mm
    assert radius(wall).min() == pytest.approx(50, abs=1e-9) and radius(wall).max() == pytest.approx(51, abs=1e-9)
    assert wall[:, 2].min() == pytest.approx(0, abs=1e-12) and wall[:, 2].max() == pytest.approx(300, abs=1e-12)
    for k, zc in enumerate(VANE_Z, start=1):
        v = reference.part(f"vane_{k}").vertices_mm
        # mesh vertices lie on the true circles: the vane hole radius is exactly 35
        assert radius(v).min() == pytest.approx(35, abs=1e-9), k
        assert radius(v).max() == pytest.approx(50, abs=1e-9), k
        assert v[:, 2].min() == pytest.approx(zc - 0.5, abs=1e-12)
        assert v[:, 2].max() == pytest.approx(zc + 0.5, abs=1e-12)
    plate = reference.part("end_plate").vertices_mm
    assert radius(plate).min() == pytest.approx(35, abs=1e-9) and radius(plate).max() == pytest.approx(51, abs=1e-9)
    assert plate[:, 2].min() == pytest.approx(-1, abs=1e-12) and plate[:, 2].max() == pytest.approx(0, abs=1e-12)


def test_detector_is_a_single_sided_disk_at_z0_facing_plus_z(reference):
    det = reference.part("detector")
    assert det.role == "detector" and det.material is None
    assert np.all(det.vertices_mm[:, 2] == 0.0)
    assert radius(det.vertices_mm).max() == pytest.approx(35, abs=1e-9)
    normals = reference.triangle_normals[reference.triangle_part == reference.part_names.index("detector")]
    assert np.allclose(normals, [0, 0, 1])
    # its rim is the end plate's hole: the same vertices, so no gap for rays to slip through
    plate = reference.part("end_plate").vertices_mm
    rim = plate[(plate[:, 2] == 0) & (radius(plate) < 35 + 1e-6)]
    assert len(rim) == len(det.vertices_mm)
    assert np.allclose(np.sort(np.arctan2(rim[:, 1], rim[:, 0])),
                       np.sort(np.arctan2(det.vertices_mm[:, 1], det.vertices_mm[:, 0])), atol=1e-9)


def test_brep_volumes_are_analytic():
    """CadQuery solids before tessellation: annulus volumes pi (ro^2 - ri^2) h, to round-off."""
    parts = reference_tube()
    assert parts["wall"].shape.Volume() == pytest.approx(np.pi * (51**2 - 50**2) * 300, rel=1e-9)
    assert parts["vane_3"].shape.Volume() == pytest.approx(np.pi * (50**2 - 35**2) * 1, rel=1e-9)
    assert parts["end_plate"].shape.Volume() == pytest.approx(np.pi * (51**2 - 35**2) * 1, rel=1e-9)
    assert parts["detector"].shape.Area() == pytest.approx(np.pi * 35**2, rel=1e-9)


def test_mesh_volume_and_area_within_tolerance_of_analytic(reference):
    """Each tessellated surface lies within the chord tolerance t of the true one, so the volume
    differs from the analytic annulus pi (51^2 - 50^2) 300 by at most t times the lateral area
    of the two cylinders (the flat rims are exact)."""
    t = 0.05
    wall = reference.part("wall").to_trimesh()
    exact = np.pi * (51**2 - 50**2) * 300
    lateral = 2 * np.pi * (51 + 50) * 300
    assert wall.volume > 0
    assert abs(wall.volume - exact) <= t * lateral
    # area: the mesh is the prism over inscribed regular polygons (N counted on the mesh), whose area is
    # N 2 R sin(pi / N) L per side and N / 2 R^2 sin(2 pi / N) per polygon; and it is within the
    # chord bound of the true area: an inscribed side loses 2 pi R L (1 - sinc) ~ 2 pi L s / 3 <= 2 pi L t
    v = reference.part("wall").vertices_mm
    n_in, n_out = (int(np.sum((np.abs(radius(v) - r) < 1e-9) & (v[:, 2] == 0))) for r in (50.0, 51.0))
    prism = sum(n * 2 * r * np.sin(np.pi / n) * 300 + 2 * sign * n / 2 * r**2 * np.sin(2 * np.pi / n)
                for n, r, sign in ((n_in, 50.0, -1), (n_out, 51.0, 1)))
    assert wall.area == pytest.approx(prism, rel=1e-9)
    area_exact = lateral + 2 * np.pi * (51**2 - 50**2)
    assert 0 < area_exact - wall.area <= 2 * 2 * np.pi * 300 * t
    det = reference.part("detector").to_trimesh()
    # a regular N-gon inscribed in r = 35: area N/2 r^2 sin(2 pi / N), N counted from the mesh
    n = len(det.vertices)
    assert det.area == pytest.approx(n / 2 * 35**2 * np.sin(2 * np.pi / n), rel=1e-9)
    assert np.pi * 35**2 - det.area <= t * 2 * np.pi * 35


def test_bevelled_vane_volume_by_pappus():
    """V = 2 pi r_centroid A for the revolved trapezoid profile (Pappus' centroid theorem)."""
    params = TubeParams(vane_count=1, vane_bevel_deg=30.0)
    vane = build_tube(params)["vane_1"]
    run = np.tan(np.deg2rad(30.0))  # 1 mm thick
    # profile (r, z): rectangle 35..50 x 1 minus the bevel triangle
    a_rect, c_rect = 15.0, 42.5
    a_tri, c_tri = run / 2, 35 + run / 3  # triangle (35, top), (35, bottom), (35 + run, bottom)
    area = a_rect - a_tri
    centroid = (a_rect * c_rect - a_tri * c_tri) / area
    assert vane.shape.Volume() == pytest.approx(2 * np.pi * centroid * area, rel=1e-9)
    # the knife edge is on the entrance (+z) side: the hole is 35 there, 35 + run at the back
    from geometry.tessellate import tessellate

    mesh = tessellate(vane.shape, name="vane", tolerance_mm=0.05).vertices_mm
    top, bottom = mesh[mesh[:, 2] > 280.4], mesh[mesh[:, 2] < 279.6]
    assert radius(top).min() == pytest.approx(35, abs=1e-9)
    assert radius(bottom).min() == pytest.approx(35 + run, abs=1e-9)
    front = build_tube(TubeParams(vane_count=1, vane_bevel_deg=30.0, vane_bevel_side="front"))["vane_1"]
    assert front.shape.Volume() == pytest.approx(vane.shape.Volume(), rel=1e-9)
    mesh = tessellate(front.shape, name="vane", tolerance_mm=0.05).vertices_mm
    top, bottom = mesh[mesh[:, 2] > 280.4], mesh[mesh[:, 2] < 279.6]
    assert radius(top).min() == pytest.approx(35 + run, abs=1e-9)  # bevel faces the entrance
    assert radius(bottom).min() == pytest.approx(35, abs=1e-9)


@pytest.mark.parametrize("tolerance_mm", [0.2, 0.05, 0.01])
def test_chord_error_below_tolerance_and_matches_sagitta(tolerance_mm):
    """The measured max chord error of the wall equals the sagitta r (1 - cos(pi / N)) of its
    coarsest circle (N segments counted on the mesh) and does not exceed the tolerance."""
    from geometry.tessellate import tessellate_parts

    scene = tessellate_parts({"wall": reference_tube()["wall"]}, tolerance_mm=tolerance_mm)
    part = scene.part("wall")
    report = part.meta["tessellation"]
    assert report.max_chord_error_mm <= tolerance_mm
    assert report.method == "sampled" and report.n_triangles == part.n_triangles
    v = part.vertices_mm
    sagitta = []
    for r in (50.0, 51.0):
        on = v[(np.abs(radius(v) - r) < 1e-9) & (v[:, 2] == 0)]
        sagitta.append(r * (1 - np.cos(np.pi / len(on))))
    assert report.max_chord_error_mm == pytest.approx(max(sagitta), rel=1e-9)


def test_finer_tolerance_gives_more_triangles():
    from geometry.tessellate import tessellate

    shape = reference_tube()["vane_1"].shape
    counts = [tessellate(shape, tolerance_mm=t).n_triangles for t in (0.2, 0.05, 0.01)]
    assert counts[0] < counts[1] < counts[2]


def test_bevel_chord_error_against_dense_sampling():
    """The cone face is measured by sampling; check it against 66 points per triangle and the
    analytic distance to the cone r = r0 + (z_top - z) tan(b) (a second, denser estimate)."""
    from geometry.tessellate import tessellate

    b = np.deg2rad(40.0)
    vane = build_tube(TubeParams(vane_count=1, vane_bevel_deg=40.0, vane_thickness_mm=2.0))["vane_1"]
    part = tessellate(vane.shape, tolerance_mm=0.05)
    tri = part.vertices_mm[part.faces]
    zc = 280.0
    r_in = radius(tri.reshape(-1, 3))
    z = tri[..., 2]
    on_cone = np.all(np.abs(radius(tri.reshape(-1, 3)).reshape(-1, 3) - (35 + (zc + 1 - z) * np.tan(b))) < 1e-9, axis=1)
    assert on_cone.sum() > 10 and r_in.min() == pytest.approx(35, abs=1e-9)
    w = np.array([(i, j, 10 - i - j) for i in range(11) for j in range(11 - i)]) / 10
    pts = np.einsum("kj,mjc->mkc", w, tri[on_cone]).reshape(-1, 3)
    dist = np.abs(radius(pts) - (35 + (zc + 1 - pts[:, 2]) * np.tan(b))) * np.cos(b)
    assert dist.max() > 0
    assert dist.max() <= part.meta["tessellation"].max_chord_error_mm * (1 + 1e-6) + 1e-9
    assert part.meta["tessellation"].max_chord_error_mm <= 0.05


def test_parameters_are_validated_naming_the_parameter():
    with pytest.raises(GeometryError, match="vane_bevel_deg"):
        TubeParams(vane_bevel_deg=89.0)  # 1 mm * tan(89) = 57 mm: deeper than the 15 mm vane
    with pytest.raises(GeometryError, match="overlap"):
        TubeParams(vane_z_mm=(100.0, 100.5))
    with pytest.raises(GeometryError, match="vane_inner_radius_mm"):
        TubeParams(vane_inner_radius_mm=55.0)
    with pytest.raises(GeometryError, match="length_mm"):
        TubeParams(length_mm=-1.0)
    with pytest.raises(GeometryError, match="detector_radius_mm"):
        TubeParams(detector_radius_mm=40.0)


def test_vane_layout_options():
    assert TubeParams(vane_count=1).vane_centres_mm == (280.0,)
    assert TubeParams(vane_count=4).vane_centres_mm == (40.0, 120.0, 200.0, 280.0)
    assert TubeParams(vane_z_mm=[150, 50]).vane_centres_mm == (50.0, 150.0)
    assert REFERENCE_TUBE.vane_centres_mm == tuple(VANE_Z)
    parts = build_tube(TubeParams(vane_count=0, aperture_stop_radius_mm=45.0))
    assert list(parts) == ["wall", "end_plate", "aperture_stop", "detector"]
    stop = parts["aperture_stop"].shape
    assert stop.Volume() == pytest.approx(np.pi * (51**2 - 45**2) * 1.0, rel=1e-9)
    bb = stop.BoundingBox()
    assert (bb.zmin, bb.zmax) == pytest.approx((300.0, 301.0))


def test_fused_tube_is_one_solid_with_the_union_volume():
    from geometry.parts.tube import fuse_solids

    fused = fuse_solids(reference_tube())
    exact = np.pi * ((51**2 - 50**2) * 300 + 7 * (50**2 - 35**2) * 1 + (51**2 - 35**2) * 1)
    assert len(fused.shape.Solids()) == 1
    assert fused.shape.Volume() == pytest.approx(exact, rel=1e-9)


def test_sphere_and_torus_chord_error_against_analytic_distance():
    """The generic (parametric) measurement on a sphere and a torus against the analytic distances
    | |p| - r | and | sqrt((rho - R)^2 + z^2) - r | at 66 points per triangle. OpenCascade's
    first sphere mesh at 0.05 mm deflection is 0.088 mm off: tessellate must refine it."""
    import cadquery as cq

    from geometry.tessellate import tessellate

    n = 10
    w = np.array([(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)]) / n
    sphere = cq.Solid.makeSphere(20.0, angleDegrees1=-90, angleDegrees2=90)
    cases = [(sphere, "sphere", lambda p: np.abs(np.linalg.norm(p, axis=1) - 20.0)),
             (cq.Solid.makeTorus(30.0, 5.0), "torus",
              lambda p: np.abs(np.hypot(radius(p) - 30.0, p[:, 2]) - 5.0))]
    for shape, method, distance in cases:
        part = tessellate(shape, tolerance_mm=0.05)
        report = part.meta["tessellation"]
        assert report.method in ("sampled", "sampled+projected")  # suspect samples re-measured by projection
        dense = distance(np.einsum("kj,mjc->mkc", w, part.vertices_mm[part.faces]).reshape(-1, 3)).max()
        assert dense > 0.005  # sanity: a coarse enough mesh to measure
        assert report.max_chord_error_mm <= 0.05
        # the report samples fewer points than this dense grid, but not much coarser; it measures the
        # other way round (surface points -> triangle plane), which agrees to second order
        assert 0.9 * dense <= report.max_chord_error_mm <= dense * (1 + 1e-3) + 1e-9
        assert dense <= 0.05 / 0.9
        assert part.to_trimesh().is_watertight and part.to_trimesh().volume > 0
        if method == "sphere":
            assert report.deflection_mm < 0.05  # refined
