"""The rim of a curved lens surface: its mesh covers the whole clear aperture, and hits on it outside the
aperture pass through alike in the walk and in the intersector's queries (docs/optics.md, "Mesh of a lens
surface").

References (independent of the code under test):
- the clear aperture is the disk (annulus) ``inner <= rho <= outer`` about the aperture's centre; a ray aimed
  at a surface point inside it meets the surface there first (the geometry of the test rays, below);
- a beam inside a lens's clear aperture refracts at its front surface before anything else (Snell's law,
  Hecht, Optics, §4.4): no ray reaches the back surface or the glass from the air without crossing the front;
- incoherent multiple reflections in a plate (Born & Wolf §7.6.1): T = (1 - R) / (1 + R) at normal
  incidence, R = ((n - 1) / (n + 1))^2; a weak meniscus (|R| = 2000 mm over a 10 mm aperture, incidence
  below 0.3 deg) changes R by < 1e-6.
"""
import math

import numpy as np
import pytest

from geometry.analytic import Asphere, Conic, Plane, analytic_part
from geometry.mesh import Scene
from materials import load_material
from straylight.intersect.embree import EmbreeIntersector
from straylight.intersect.exact_boundary import ExactBoundaryIntersector, rim_parts
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace

UP = np.array([0.0, 0.0, 1.0])
N_GLASS = 1.5
GLASS = load_material({"name": "glass", "components": [{"type": "dielectric", "n": N_GLASS}]})
TOL_MM = 0.05  # optics import's chord tolerance (straylight.optics.scene_build.MESH_TOLERANCE_MM)

SURFACES = {  # the light comes from the +axis side (the front)
    "sphere": Conic(np.zeros(3), -UP, -61.47, 0.0, 12.0),
    "steep sphere": Conic(np.zeros(3), -UP, 15.0, 0.0, 12.0),
    "annulus": Conic(np.zeros(3), -UP, -61.47, 0.0, 12.0, 4.0),
    "off-axis paraboloid": Conic(np.zeros(3), -UP, -200.0, -1.0, 10.0, 0.0, (30.0, 5.0)),
    "asphere": Asphere(np.zeros(3), -UP, 30.0, -0.5, 12.0, 0.0, coefficients=(1e-5, -2e-8)),
}


def _rays_at(surface, rho_mm, tilt_deg, n=4000):
    """(origins, dirs) of rays aimed at the surface points at ``rho_mm`` from the aperture's centre (every
    azimuth), arriving on the front inclined by ``tilt_deg`` to the axis; and the points (local)."""
    phi = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    cu, cv = surface.aperture_center_uv
    local = np.column_stack([cu + rho_mm * np.cos(phi), cv + rho_mm * np.sin(phi), np.zeros(n)])
    local[:, 2] = surface.sag(np.hypot(local[:, 0], local[:, 1]))
    a = math.radians(tilt_deg)
    d = np.tile(surface.dirs_to_world(np.array([[math.sin(a), 0.0, -math.cos(a)]])), (n, 1))
    points = surface.to_world(local)
    return points - 100.0 * d, d, points


def _exact(surface):
    """The surface's mesh in the tracer's exact-boundary intersector (rim hits refined, refused outside)."""
    vertices, faces = surface.mesh(TOL_MM)
    tri = vertices[faces]
    part = np.zeros(len(faces), dtype=np.int64)
    return ExactBoundaryIntersector(EmbreeIntersector(tri), part, {}, 1e-6, rim_parts([surface], tri, part))


@pytest.mark.parametrize("name", SURFACES)
def test_the_mesh_covers_the_clear_aperture(name):
    """Every point of the aperture's circles (outer, and a hole's) is inside the mesh's projection: the
    rings were on the circles, so the chords left slivers of the aperture without mesh."""
    s = SURFACES[name]
    vertices, faces = s.mesh(TOL_MM)
    isect = EmbreeIntersector(vertices[faces])
    for rho in (s.outer_radius_mm, s.inner_radius_mm) if s.inner_radius_mm else (s.outer_radius_mm,):
        o, d, _ = _rays_at(s, rho, 0.0)
        assert (np.asarray(isect.first_triangle(o, d)) >= 0).all(), rho


@pytest.mark.parametrize("name", SURFACES)
@pytest.mark.parametrize("tilt_deg", [0.0, 20.0])
def test_hits_count_inside_the_clear_aperture_only(name, tilt_deg):
    """Rays aimed just inside the aperture's edge meet the surface where aimed; rays aimed 0.03 mm outside
    it (on the mesh's rim band) pass through, for the first hit and for a shadow ray alike."""
    s = SURFACES[name]
    ex = _exact(s)
    inside = [s.outer_radius_mm * (1 - 1e-7)] + ([s.inner_radius_mm * (1 + 1e-7)] if s.inner_radius_mm else [])
    for rho in inside:
        o, d, p = _rays_at(s, rho, tilt_deg)
        tri, t = ex.intersect(o, d)
        assert (tri >= 0).all(), rho
        t_exact, _, ok = s.refine_hits(o, d, t)  # the facet's distance refined onto the surface: the aimed point
        assert ok.all() and np.abs(o + t_exact[:, None] * d - p).max() < 1e-6
        assert ex.occluded(o, d, np.full(len(o), 200.0)).all()
    o, d, _ = _rays_at(s, s.outer_radius_mm + 0.03, tilt_deg)
    tri, _ = ex.intersect(o, d)
    assert (ex.inner.first_triangle(o, d) >= 0).any()  # the mesh is there
    assert (tri < 0).all() and not ex.occluded(o, d, np.full(len(o), 200.0)).any()


def test_rim_refusals_are_the_same_in_the_compiled_and_numpy_paths():
    """Rays aimed around the rim: both refusal queries (the compiled one the tracer uses and its numpy
    reference) refuse the same rim hits (some, not all) with the same distances."""
    s = SURFACES["sphere"]
    ex = _exact(s)
    rng = np.random.default_rng(5)
    n = 20000
    rho, phi = rng.uniform(11.5, 12.3, n), rng.uniform(0, 2 * math.pi, n)
    local = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), s.sag(rho)])
    target = s.to_world(local)
    o = target + np.column_stack([rng.normal(size=(n, 2)), np.full(n, -10.0)])
    d = target - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    tri = ex.inner.first_triangle(o, d)
    (r1, t1), (r2, t2) = ex._refused(tri, o, d), ex._refused_numpy(tri, o, d)
    assert r1.any() and (~r1 & (tri >= 0)).any()
    assert np.array_equal(r1, r2) and np.array_equal(t1, t2)


def _singlet(beam_radius_mm, radius_mm=-50.0, back_radius_mm=-50.0, thickness_mm=5.0, aperture_mm=10.0):
    """A lens (front at z = 0 facing -z, back at z = thickness facing +z: the local radii as the scene file
    writes them) with a collimated beam along +z of ``beam_radius_mm`` and a large detector behind it."""
    front = analytic_part("front", Conic(np.zeros(3), -UP, radius_mm, 0.0, aperture_mm), "glass",
                          tolerance_mm=TOL_MM)
    back = analytic_part("back", Conic(np.array([0, 0, thickness_mm]), UP, back_radius_mm, 0.0, aperture_mm),
                         "glass", tolerance_mm=TOL_MM)
    det = analytic_part("det", Plane(np.array([0, 0, 40.0]), -UP, math.inf, 0.0, 200.0, 0.0), None, "detector")
    src = CollimatedDisk(center_mm=np.array([0, 0, -5.0]), normal=UP, direction=UP, radius_mm=beam_radius_mm)
    return Scene((front, back, det)), src


def test_a_beam_filling_the_clear_aperture_refracts_at_the_front_surface_first():
    """Each logged ray of a beam exactly filling a biconvex lens's aperture first meets the front surface
    (none reaches the back surface from the air through the slivers without mesh: ~0.5 % of the beam
    did)."""
    scene, src = _singlet(10.0)
    n = 20000
    res = trace(scene, [src], n, seed=2, materials={"glass": GLASS},
                options=TraceOptions(estimator=EstimatorOptions(nee=False), output=OutputOptions(ray_log=n)))
    log = res.ray_log
    first = log.event == 0
    assert first.sum() == n
    part = np.asarray(scene.triangle_part)[np.maximum(log.tri[first], 0)]
    names = np.array([p.name for p in scene.parts])[part]
    names[log.tri[first] < 0] = "escaped"
    assert (names == "front").all(), dict(zip(*np.unique(names, return_counts=True)))


def test_weak_meniscus_filled_to_its_aperture_transmits_the_incoherent_series():
    """|R| = 2000 mm on both faces (same sign: 10 mm thick everywhere along the axis), the beam filling the
    10 mm aperture at normal incidence: T = (1 - R) / (1 + R)."""
    scene, src = _singlet(10.0, radius_mm=2000.0, back_radius_mm=-2000.0, thickness_mm=10.0)
    res = trace(scene, [src], 200_000, seed=3, materials={"glass": GLASS},
                options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    R = ((N_GLASS - 1) / (N_GLASS + 1)) ** 2
    det = res.detectors["det"]
    assert abs(det.power_w - (1 - R) / (1 + R)) < 4 * det.stderr_w


def test_a_lens_facet_just_behind_a_refused_sliver_is_not_stepped_over():
    """A stop's hole and a lens edge ring at the rim's height, as optics import builds them: their covering
    polygons' slivers inside the hole are refused and the ray is cast again ``eps_mm`` further on. The
    lens's facets cross the ring's plane there; a facet within ``eps_mm`` behind the refused sliver was
    stepped over, and the ray entered the glass past the front surface (944 of 4e5 rays aimed within 0.1 mm
    of the rim at the imported doublet's offset, 2.44e-4 mm); now only float32 ties (facet and sliver
    within ~1e-6 mm) can be."""
    lens = SURFACES["sphere"]
    z_rim = float(lens.to_world(np.array([[12.0, 0.0, lens.sag(12.0)]]))[0, 2])
    ring = Plane(np.array([0, 0, z_rim]), -UP, math.inf, 0.0, 13.0, 12.0)
    stop = Plane(np.array([0, 0, z_rim - 0.01]), -UP, math.inf, 0.0, 18.0, 12.0)
    meshes = [s.mesh(TOL_MM) for s in (lens, ring, stop)]
    tri = np.concatenate([v[f] for v, f in meshes])
    part = np.concatenate([np.full(len(f), k) for k, (_, f) in enumerate(meshes)])
    surfaces = [lens, ring, stop]
    from straylight.intersect.exact_boundary import plane_parts

    ex = ExactBoundaryIntersector(EmbreeIntersector(tri), part, plane_parts(surfaces), 2.44e-4,
                                  rim_parts(surfaces, tri, part))
    rng = np.random.default_rng(1)
    n = 400_000
    rho, phi = np.sqrt(rng.uniform(11.9 ** 2, 12.0 ** 2, n)), rng.uniform(0, 2 * math.pi, n)
    o = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), np.full(n, -5.0)])
    tri_hit, _ = ex.intersect(o, np.tile(UP, (n, 1)))
    assert ((tri_hit < 0) | (part[np.maximum(tri_hit, 0)] != 0)).sum() <= 5


def test_thermal_walks_see_the_same_clear_aperture():
    """Thermal's intersector (its reverse walk and exchange) refuses the rim band outside the aperture too."""
    from straylight.thermal.model import thermal_scene

    s = SURFACES["asphere"]
    ts = thermal_scene(Scene((analytic_part("lens", s, role="absorber", tolerance_mm=TOL_MM),)), {})
    for rho, found in ((s.outer_radius_mm * (1 - 1e-7), True), (s.outer_radius_mm + 0.03, False)):
        o, d, _ = _rays_at(s, rho, 20.0)
        tri, _ = ts.intersector.intersect(o, d)
        assert ((tri >= 0) == found).all(), rho


def test_thermal_emits_from_the_surface_area_over_the_clear_aperture():
    """A spherical cap's area is 2 pi R h (h its height over the aperture; a zone between two radii the
    difference of two caps): thermal's emitting area of a sphere's part is that, not its mesh's (+1.1 % at
    0.05 mm with the rim band, -0.6 % inscribed); a decentred paraboloid's, against a Monte Carlo of the
    same integral (a different method)."""
    from straylight.thermal.model import thermal_scene

    R = 61.47

    def cap(a):
        return 2 * math.pi * R * (R - math.sqrt(R * R - a * a))

    parts = [analytic_part(k, SURFACES[k], role="absorber", tolerance_mm=TOL_MM) for k in ("sphere", "annulus")]
    ts = thermal_scene(Scene(tuple(parts)), {})
    assert ts.part_area_mm2(0) == pytest.approx(cap(12.0), rel=1e-12)
    assert ts.part_area_mm2(1) == pytest.approx(cap(12.0) - cap(4.0), rel=1e-12)
    mesh = float(ts.areas_mm2[ts.triangle_part == 0].sum())
    assert abs(mesh / cap(12.0) - 1) > 5e-3  # the mesh's own area is not the surface's
    oap = SURFACES["off-axis paraboloid"]
    rng = np.random.default_rng(0)
    n = 1_000_000
    r, phi = 10.0 * np.sqrt(rng.uniform(size=n)), rng.uniform(0, 2 * math.pi, n)
    rho2 = (30.0 + r * np.cos(phi)) ** 2 + (5.0 + r * np.sin(phi)) ** 2
    dz_drho = np.sqrt(rho2) / 200.0  # z = rho^2 / (2 R): dz/drho = rho / R
    f = math.pi * 100.0 * np.sqrt(1.0 + dz_drho ** 2)
    assert abs(oap.clear_area_mm2() - f.mean()) < 4 * f.std() / math.sqrt(n)


def test_rim_refusals_of_two_curved_parts_and_a_disk_are_the_numpy_paths():
    """A disk in front of two curved parts (a sphere and an off-axis paraboloid, each with its rim band):
    the compiled refusal query, which finds the rim rows in its disk pass, refuses what the numpy reference
    refuses, with the same distances (misses, disk slivers and both rim bands among the rows)."""
    from straylight.intersect.exact_boundary import plane_parts

    surfaces = [SURFACES["sphere"], Plane(np.array([0.0, 0.0, 5.0]), -UP, math.inf, 0.0, 6.0, 2.0),
                Conic(np.array([0.0, 0.0, -20.0]), -UP, -200.0, -1.0, 10.0, 0.0, (30.0, 5.0))]
    tris, parts = [], []
    for p, s in enumerate(surfaces):
        vertices, faces = s.mesh(TOL_MM)
        tris.append(vertices[faces])
        parts.append(np.full(len(faces), p, dtype=np.int64))
    tri_mm, part = np.concatenate(tris), np.concatenate(parts)
    ex = ExactBoundaryIntersector(EmbreeIntersector(tri_mm), part, plane_parts(surfaces), 1e-6,
                                  rim_parts(surfaces, tri_mm, part))
    assert len(ex._rim_surfaces) == 2
    rng = np.random.default_rng(6)
    n = 30000
    rho, phi = rng.uniform(0.0, 13.0, n), rng.uniform(0, 2 * math.pi, n)
    centre = np.where(rng.uniform(size=n) < 0.5, 0.0, 30.0)[:, None] * [1.0, 0.0, 0.0]
    target = centre + np.column_stack([rho * np.cos(phi), rho * np.sin(phi), rng.uniform(-20.0, 5.0, n)])
    o = target + np.column_stack([rng.normal(size=(n, 2)), np.full(n, 30.0)])
    d = target - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    tri = ex.inner.first_triangle(o, d)
    (r1, t1), (r2, t2) = ex._refused(tri, o, d), ex._refused_numpy(tri, o, d)
    rim = ex._rim_or_miss[tri]
    assert (tri < 0).any() and (r1 & (ex._disk_or_miss[tri] >= 0)).any()
    assert (r1 & (rim == 0)).any() and (r1 & (rim == 1)).any() and (~r1 & (rim >= 0)).any()
    assert np.array_equal(r1, r2) and np.array_equal(t1, t2)
