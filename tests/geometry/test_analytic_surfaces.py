"""Analytic surfaces (CONTRACTS §6.1): exact hits and normals from a coarse or fine mesh.

References: a paraboloid z = rho^2 / (2R) reflects every ray parallel to its axis through its focus
(0, 0, R/2) (the defining property of the parabola, e.g. Born & Wolf §4.10); a sphere's normal
points at its centre; the sag formula h(rho) for k = 0 is the circle R - sqrt(R^2 - rho^2).
"""
import numpy as np
import pytest

from geometry.analytic import Conic, analytic_part, surface_from_dict
from geometry.mesh import GeometryError
from materials.smooth import reflect
from straylight.intersect import EmbreeIntersector


def _beam(n, r_in, r_out, z0, seed=0):
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(r_in**2, r_out**2, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    o = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(n, z0)])
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    return o, d


@pytest.mark.parametrize("tolerance_mm", [0.5, 0.01])
def test_paraboloid_focuses_a_collimated_beam_whatever_the_mesh(tolerance_mm):
    """R = 2000 mm, k = -1, aperture 20..100 mm: every reflected ray passes within 1e-6 mm of the
    focus (0, 0, 1000), starting from a 0.5 mm or a 0.01 mm mesh."""
    surf = surface_from_dict({"type": "conic", "vertex_mm": [0, 0, 0], "axis": [0, 0, 1], "radius_mm": 2000.0,
                              "conic": -1.0, "outer_radius_mm": 100.0, "inner_radius_mm": 20.0})
    part = analytic_part("primary", surf, "al", tolerance_mm=tolerance_mm)
    isect = EmbreeIntersector(part.vertices_mm[part.faces])
    o, d = _beam(20_000, 20.5, 99.0, 1500.0)
    tri, t0 = isect.intersect(o, d)
    assert np.all(tri >= 0)
    t, ok = surf.refine(o, d, t0)
    assert np.all(ok)
    p = o + t[:, None] * d
    mesh_err = np.abs(t - t0).max()
    assert mesh_err > 1e-4 * tolerance_mm  # the mesh hit is really off the surface
    np.testing.assert_allclose(p[:, 2], np.hypot(p[:, 0], p[:, 1]) ** 2 / 4000.0, atol=1e-10)
    r = reflect(d, surf.normals(p))
    focus = np.array([0.0, 0.0, 1000.0])
    v = focus - p
    miss = np.linalg.norm(v - np.einsum("ij,ij->i", v, r)[:, None] * r, axis=1)
    assert miss.max() < 1e-6, miss.max()
    # the compiled kernel (used by the tracer) gives the same hits and normals as the numpy path
    t2, n2, ok2 = surf.refine_hits(o, d, t0)
    assert np.all(ok2)
    np.testing.assert_allclose(t2, t, atol=1e-9)
    np.testing.assert_allclose(n2, surf.normals(p), atol=1e-12)


def test_sphere_sag_and_normals_point_at_the_centre():
    s = Conic(np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0]), 50.0, 0.0, 30.0, 0.0)
    rho = np.linspace(0, 30, 7)
    np.testing.assert_allclose(s.sag(rho), 50 - np.sqrt(50**2 - rho**2), rtol=1e-12, atol=1e-14)
    v, f = s.mesh(0.05)
    o = v[f].mean(axis=1) + np.array([0.0, 10.0, 0.0])  # above each facet, shooting back down the axis
    d = np.tile([0.0, -1.0, 0.0], (len(o), 1))
    t, ok = s.refine(o, d, np.full(len(o), 10.0))
    assert np.all(ok)
    p = o + t[:, None] * d
    centre = np.array([1.0, 52.0, 3.0])
    np.testing.assert_allclose(np.linalg.norm(p - centre, axis=1), 50.0, rtol=1e-12)
    n = s.normals(p)
    np.testing.assert_allclose(n, (centre - p) / 50.0, atol=1e-12)  # front (+axis) side = concave side


def test_cylinder_hits_and_outward_normals():
    s = surface_from_dict({"type": "cylinder", "vertex_mm": [0, 0, 0], "axis": [0, 0, 1], "radius_mm": 10.0,
                           "length_mm": 20.0})
    o = np.array([[30.0, 1.0, 5.0], [0.0, -40.0, 19.0], [30.0, 0.0, 25.0]])
    d = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    t, ok = s.refine(o, d, np.array([20.0, 30.0, 20.0]))
    np.testing.assert_allclose(t[:2], [30 - np.sqrt(99.0), 30.0], rtol=1e-12)
    assert ok.tolist() == [True, True, False]  # the third is beyond length_mm
    n = s.normals(o[:2] + t[:2, None] * d[:2])
    np.testing.assert_allclose(n, [[np.sqrt(99) / 10, 0.1, 0], [0, -1, 0]], atol=1e-12)


@pytest.mark.parametrize("table, message", [
    ({"type": "conic", "radius_mm": 100.0, "outer_radius_mm": 10.0, "focus": 1}, "unknown surface key"),
    ({"type": "torus"}, "surface type"),
    ({"type": "conic", "radius_mm": 10.0, "outer_radius_mm": 20.0}, "no sag beyond"),
    ({"type": "conic", "radius_mm": 0.0, "outer_radius_mm": 20.0}, "non-zero"),
    ({"type": "plane", "outer_radius_mm": 5.0, "inner_radius_mm": 6.0}, "inner_radius_mm"),
    ({"type": "cylinder", "radius_mm": 5.0}, "length_mm"),
    ({"type": "plane", "outer_radius_mm": 5.0, "axis": [0, 0, 0]}, "axis"),
])
def test_bad_surface_tables_are_one_line_errors(table, message):
    with pytest.raises(GeometryError, match=message) as exc:
        surface_from_dict(table, where="scene.toml: [[part]] 2")
    assert str(exc.value).startswith("scene.toml: [[part]] 2") and "\n" not in str(exc.value)


@pytest.mark.parametrize("spec", [
    {"type": "conic", "radius_mm": 40.0, "conic": -0.5, "outer_radius_mm": 12.0, "inner_radius_mm": 3.0},
    {"type": "conic", "radius_mm": -25.0, "conic": 0.0, "outer_radius_mm": 0.5},
    {"type": "plane", "outer_radius_mm": 30.0, "inner_radius_mm": 10.0},
])
def test_compiled_aperture_test_is_valid_on_the_rho_z_points(spec):
    """refine_hits' compiled aperture and branch test of a conic about its axis gives ``done & valid(p)`` on the
    points (rho, 0, z): random rows, the aperture's edges with their tolerance and the next floats, the branch's
    edge, NaN and inf."""
    from geometry.analytic import _conic_valid_rho_z

    surf = surface_from_dict({"vertex_mm": [0, 0, 0], "axis": [0, 0, 1], **spec})
    rng = np.random.default_rng(5)
    n = 20_000
    loc = np.column_stack([rng.uniform(0.0, 1.5 * surf.outer_radius_mm, n), rng.uniform(-60.0, 60.0, n)])
    tol = 1e-9 * max(1.0, surf.outer_radius_mm)
    edges = [surf.outer_radius_mm + tol, surf.inner_radius_mm - tol, surf.outer_radius_mm, surf.inner_radius_mm]
    for i, e in enumerate(edges):
        loc[3 * i:3 * i + 3, 0] = [e, np.nextafter(e, -np.inf), np.nextafter(e, np.inf)]
    if surf.c:
        z_edge = 1.0 / ((1.0 + surf.conic) * surf.c) if surf.conic != -1.0 else 1.0
        loc[20:23, 1] = [z_edge, np.nextafter(z_edge, -np.inf), np.nextafter(z_edge, np.inf)]
    loc[30:32], loc[32, 0], loc[33, 1], loc[34, 0] = np.nan, np.inf, -np.inf, 0.0
    done = rng.uniform(size=n) < 0.9
    with np.errstate(invalid="ignore"):  # the plane's 0 * inf
        want = done & surf.valid(np.column_stack([loc[:, 0], np.zeros(n), loc[:, 1]]))
    got = _conic_valid_rho_z(surf, loc, done)
    np.testing.assert_array_equal(got, want)
    assert want.any() and not want.all()


def test_a_cylinder_mesh_stays_within_2e_4_of_its_radius_of_the_wall(tmp_path):
    """The inscribed prism's chords stand inside the exact wall by their sagitta; a ray leaving by an open end
    within a sagitta of the wall meets a chord first. At the scene's 0.05 mm a 10 mm tube took 0.72 % of a
    disk-to-disk exchange (8 sigma); now the sagitta is <= 2e-4 of the radius, and the traced exchange through the
    tube is the coaxial-disk view factor (PHYSICS 5) within 4 sigma."""
    import json as _json
    import math as _math

    from geometry.analytic import Cylinder
    from straylight.cli.main import main
    from tests.validation.thermal_scenes import view_factor_coaxial_disks

    cyl = Cylinder(vertex_mm=np.zeros(3), axis=np.array([0.0, 0.0, 1.0]), radius_mm=10.0, length_mm=20.0)
    v, f = cyl.mesh(0.05)
    a, b = v[f[:, 0]], v[f[:, 1]]
    mid = 0.5 * (a + b)
    sagitta = 10.0 - np.hypot(mid[:, 0], mid[:, 1])
    assert sagitta.max() <= 2e-4 * 10.0 + 1e-12
    scene = tmp_path / "tube.toml"
    scene.write_text('[[part]]\nname = "wall"\nsurface = {type = "cylinder", vertex_mm = [0.0, 0.0, 0.0], '
                     'axis = [0.0, 0.0, 1.0], radius_mm = 10.0, length_mm = 20.0}\nrole = "absorber"\n\n[[part]]\n'
                     'name = "top"\nsurface = {type = "plane", vertex_mm = [0.0, 0.0, 20.0], axis = [0.0, 0.0, -1.0], '
                     'outer_radius_mm = 10.0}\nrole = "detector"\n\n[[source]]\ntype = "lambertian_disk"\n'
                     'center_mm = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nradius_mm = 9.0\npower_w = 1.0\n')
    out = tmp_path / "t.json"
    assert main(["trace", str(scene), "--rays", "2000000", "--seed", "3", "--json", str(out)]) == 0
    det = _json.loads(out.read_text())["detectors"]["top"]
    f12 = view_factor_coaxial_disks(9.0, 10.0, 20.0)
    assert abs(det["power_w"] - f12) < 4 * det["stderr_w"], (det, f12)
    assert _math.isfinite(det["stderr_w"]) and det["stderr_w"] < 5e-4
