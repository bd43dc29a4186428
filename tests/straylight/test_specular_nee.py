"""Specular next-event estimation (straylight.engine.specular_nee) and its solver
(straylight.engine.specular_manifold).

Solver: analytic cases, independent of the solver's equations: the reflection point in a plane mirror
is where the line to the mirror image crosses the plane and the geometry term is cos_z / d'^2 (d' the
unfolded length); a point and its mirror image about the axis of a concave sphere reflect at the
vertex (symmetry); a refraction through a plane obeys Snell's law n1 sin = n2 sin; the geometry term of
two refractions agrees with a brute-force finite difference of re-solved paths.

Estimator: a Lambertian plate lit by a beam is seen by a small detector only through a concave
spherical mirror (one reflection) or through a glass singlet (two refractions); the estimate with it
on agrees with the analog walk (another seed) within 4 sigma, the ledger closes, it engages (casts
and path records of its family), and the error per ray is smaller than with the split trees alone.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from engine_helpers import disk_part, quad_part
from geometry.analytic import Conic, Cylinder, Plane
from geometry.mesh import Part, Scene
from materials import load_material
from straylight.analyses.estimators import estimator_options
from straylight.engine import specular_manifold as sm
from straylight.engine.capabilities import Capability
from straylight.engine.interactions.registry import parts_with
from straylight.engine.options import TraceError
from straylight.engine.specular_nee import candidate_sequences, unsupported
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, make_spec, trace


# ---------------------------------------------------------------------- the solver

def _plane(z0, axis_z, r=50.0):
    return Plane(vertex_mm=np.array([0.0, 0.0, z0]), axis=np.array([0.0, 0.0, axis_z]), outer_radius_mm=r)


def test_plane_mirror_reflection_point_and_geometry_term():
    mirror = _plane(0.0, 1.0)
    p = np.array([[10.0, 3.0, 20.0], [-4.0, 1.0, 7.0]])
    z = np.array([[-15.0, -2.0, 30.0], [6.0, -5.0, 12.0]])
    seq = (sm.Vertex(mirror, True),)
    sol = sm.solve(seq, p, z)
    assert sol.ok.all() and sm.side_checks(seq, sol, p, z).all()
    image = z * np.array([1.0, 1.0, -1.0])
    t = -p[:, 2] / (image - p)[:, 2]
    np.testing.assert_allclose(sol.X[:, 0], p + t[:, None] * (image - p), atol=1e-9)
    nz = np.array([[0.3, 0.0, -1.0], [0.0, 0.2, -1.0]])
    nz /= np.linalg.norm(nz, axis=1)[:, None]
    d_unfolded = np.linalg.norm(image - p, axis=1)
    arrive = z - sol.X[:, 0]
    arrive /= np.linalg.norm(arrive, axis=1)[:, None]
    expected = np.abs(np.einsum("ij,ij->i", arrive, nz)) / d_unfolded ** 2
    for term in (sm.geometry_term, sm.implicit_geometry_term):  # the plane's closed form and the general route
        J, _omega = term(seq, sol, p, z, nz)
        np.testing.assert_allclose(J, expected, rtol=1e-6)


def test_concave_sphere_reflects_symmetric_points_at_its_vertex():
    sphere = Conic(vertex_mm=np.array([0.0, 0.0, 0.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=100.0,
                   outer_radius_mm=40.0)
    p = np.array([[12.0, 0.0, 60.0], [0.0, -7.0, 35.0]])
    z = np.array([[-12.0, 0.0, 60.0], [0.0, 7.0, 35.0]])
    seq = (sm.Vertex(sphere, True),)
    sol = sm.solve(seq, p, z)
    assert sol.ok.all() and sm.side_checks(seq, sol, p, z).all()
    np.testing.assert_allclose(sol.X[:, 0], 0.0, atol=1e-9)


def test_refraction_through_a_plane_obeys_snell():
    n_glass = 1.5
    window = _plane(0.0, 1.0)
    seq = (sm.Vertex(window, False, 1.0 / n_glass, n_glass),)
    p = np.array([[5.0, 0.0, 10.0]])
    z = np.array([[-5.0, 1.0, -20.0]])
    sol = sm.solve(seq, p, z)
    assert sol.ok.all()
    X = sol.X[0, 0]
    a = (p[0] - X) / np.linalg.norm(p[0] - X)
    b = (z[0] - X) / np.linalg.norm(z[0] - X)
    assert math.isclose(math.hypot(a[0], a[1]), n_glass * math.hypot(b[0], b[1]), rel_tol=1e-9)
    assert abs(np.dot(np.cross(a, b), [0.0, 0.0, 1.0])) < 1e-9  # in the plane of incidence


def test_geometry_term_of_two_refractions_matches_resolved_paths():
    """|d omega / dA_z| through a lens (sphere then plane) against the solid angle of re-solved paths to
    a small square around z (each solved from scratch, no implicit-function step)."""
    n_glass = 1.5
    front = Conic(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=-40.0,
                  outer_radius_mm=12.0)
    back = _plane(6.0, -1.0, 12.0)
    glass = 7
    seq = (sm.Vertex(front, False, 1.0 / n_glass, n_glass, -1, glass),
           sm.Vertex(back, False, 1.0 / n_glass, n_glass, -1, glass))
    p = np.array([[3.0, 2.0, 40.0]])
    z = np.array([[-1.0, 0.5, -30.0]])
    nz = np.array([[0.0, 0.0, 1.0]])
    sol = sm.solve(seq, p, z)
    assert sol.ok.all() and sm.side_checks(seq, sol, p, z).all()
    J, omega = sm.geometry_term(seq, sol, p, z, nz)
    h = 1e-3
    corners = []
    for dx, dy in ((h, 0.0), (0.0, h)):
        zz = np.array([z[0] + [dx, dy, 0.0], z[0] - [dx, dy, 0.0]])
        s2 = sm.solve(seq, np.repeat(p, 2, axis=0), zz)
        w = s2.X[:, 0] - p
        w /= np.linalg.norm(w, axis=1)[:, None]
        corners.append((w[0] - w[1]) / (2 * h))
    brute = np.linalg.norm(np.cross(*corners))
    assert math.isclose(J[0], brute, rel_tol=1e-4), (J[0], brute)


def _thick_singlet(radius_mm, n_glass=2.0):
    """The thick mirror "back (T) -> front (R, inside) -> back (T)" of a singlet: flat back face at z = 6
    facing down, a sphere of radius ``radius_mm`` at z = 10 (r = 12 mm)."""
    front = Conic(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=radius_mm,
                  outer_radius_mm=12.0)
    back = _plane(6.0, -1.0, 12.0)
    glass = 7
    into = sm.Vertex(back, False, 1.0 / n_glass, n_glass, -1, glass)
    return (into, sm.Vertex(front, True, 1.0 / n_glass, n_glass, -1, glass), into)


@pytest.mark.parametrize("radius_mm", [40.0, -40.0])
def test_geometry_term_of_a_thick_mirror_matches_resolved_paths(radius_mm):
    """|d omega / dA_z| through "enter, reflect inside, leave" (three vertices; the sphere a convex or a
    concave mirror seen from the glass) against the solid angle of re-solved paths to a small square
    around z, and each vertex obeys its law: equal angles at the reflection, Snell's law at both
    refractions."""
    n_glass = 2.0
    seq = _thick_singlet(radius_mm, n_glass)
    p = np.array([[4.0, 1.5, -3.0], [-4.0, -5.0, 0.0]])
    z = np.array([[0.5, -0.5, -5.0], [1.0, 1.5, -5.0]])
    _check_laws_and_geometry_term(seq, p, z, np.tile([0.0, 0.0, 1.0], (2, 1)), n_glass)


def _check_laws_and_geometry_term(seq, p, z, nz, n_glass, give_up_residual=sm.GIVE_UP_RESIDUAL):
    """Solve ``seq`` (a singlet's: it enters from the air first and leaves into it last) between p and z; each vertex
    obeys its law (equal angles at a reflection, Snell's law at a refraction, in the plane of incidence) and the
    geometry term matches the solid angle of re-solved paths to a small square around z. Returns the solution, J
    and omega."""
    sol = sm.solve(seq, p, z, give_up_residual=give_up_residual)
    assert sol.ok.all() and sm.side_checks(seq, sol, p, z).all()
    J, omega = sm.geometry_term(seq, sol, p, z, nz)
    for r in range(len(p)):
        pts = [p[r], *sol.X[r], z[r]]
        for i, vtx in enumerate(seq):
            a = (pts[i] - pts[i + 1]) / np.linalg.norm(pts[i] - pts[i + 1])
            b = (pts[i + 2] - pts[i + 1]) / np.linalg.norm(pts[i + 2] - pts[i + 1])
            n = sol.N[r, i]
            sin_a, sin_b = np.linalg.norm(np.cross(a, n)), np.linalg.norm(np.cross(b, n))
            if vtx.reflect:
                assert math.isclose(np.dot(a, n), np.dot(b, n), rel_tol=1e-9)
            else:  # from the air (i = 0) into the glass, and back out (the last)
                n_a, n_b = (1.0, n_glass) if i == 0 else (n_glass, 1.0)
                assert math.isclose(n_a * sin_a, n_b * sin_b, rel_tol=1e-8)
            assert abs(np.dot(np.cross(a, b), n)) < 1e-9  # in the plane of incidence
        h = 1e-3
        corners = []
        for dx, dy in ((h, 0.0), (0.0, h)):
            zz = np.array([z[r] + [dx, dy, 0.0], z[r] - [dx, dy, 0.0]])
            s2 = sm.solve(seq, np.repeat(p[r:r + 1], 2, axis=0), zz, give_up_residual=give_up_residual)
            assert s2.ok.all()
            w = s2.X[:, 0] - p[r]
            w /= np.linalg.norm(w, axis=1)[:, None]
            corners.append((w[0] - w[1]) / (2 * h))
        brute = np.linalg.norm(np.cross(*corners))
        assert math.isclose(J[r], brute, rel_tol=1e-4), (J[r], brute)
    return sol, J, omega


# ---------------------------------------------------------------------- the estimator

MATTE = {"components": [{"type": "lambertian", "rd": 0.6}]}


def _quad(name, p0, e1, e2, material=None, role="surface", n=4):
    return quad_part(name, p0, e1, e2, material, role, n)


def _surface_part(name, surface, material, role="surface"):
    v, f = surface.mesh(0.01)
    return Part(name, v, f, material=material, role=role, surface=surface)


def _mirror_scene():
    """A concave spherical mirror (z = 40, facing down, R = 60 mm, 85 % specular) over a matte plate
    (z = 0, facing up) lit by a slanted beam; a disk detector (r = 3 mm at z = 0, x = 25) beside the
    plate, shielded from it by an absorbing wall: it sees the plate only in the mirror."""
    mirror = Conic(vertex_mm=np.array([0.0, 0.0, 40.0]), axis=np.array([0.0, 0.0, -1.0]), radius_mm=60.0,
                   outer_radius_mm=30.0)
    plate = _quad("plate", (-20, -15, 0), (30, 0, 0), (0, 30, 0), "matte")
    wall = _quad("wall", (15, -20, 0), (0, 40, 0), (0, 0, 8), role="absorber", n=2)
    det = disk_part("det", 0.0, 3.0, 64, role="detector")
    det = Part("det", det.vertices_mm + [25.0, 0.0, 0.0], det.faces, role="detector")
    d = np.array([math.sin(math.radians(20.0)), 0.0, -math.cos(math.radians(20.0))])
    src = CollimatedDisk(center_mm=[-18.0, 0.0, 30.0], normal=d, direction=d, radius_mm=5.0)
    mats = {"mirror": load_material({"components": [{"type": "specular", "r": 0.85}]}, "mirror"),
            "matte": load_material(MATTE, "matte")}
    return Scene((_surface_part("mirror", mirror, "mirror"), plate, wall, det)), src, mats


def _lens_scene():
    """A glass singlet (n = 1.5: sphere R = -40 mm at z = 10, flat back at z = 6, r = 12 mm, black rim)
    over a disk detector (r = 3 mm at z = -40, facing up); above it a matte plate (z = 25, facing
    down) lit by a beam from the side that misses the lens: the detector sees the plate only through
    the glass (two refractions, and the lens's own ghosts)."""
    front = Conic(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=-40.0,
                  outer_radius_mm=12.0)
    back = _plane(6.0, -1.0, 12.0)
    rim = Cylinder(vertex_mm=np.array([0.0, 0.0, 6.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=12.0,
                   length_mm=float(10.0 + front.sag(12.0) - 6.0))
    plate = _quad("plate", (-25, -25, 25), (0, 50, 0), (50, 0, 0), "matte")  # normal -z
    det = disk_part("det", -40.0, 3.0, 64, role="detector")
    d = np.array([math.sin(math.radians(35.0)), 0.0, math.cos(math.radians(35.0))])
    src = CollimatedDisk(center_mm=[-25.0, 0.0, 0.0], normal=d, direction=d, radius_mm=4.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": 1.5}]}, "glass"),
            "matte": load_material(MATTE, "matte")}
    parts = (_surface_part("lens_front", front, "glass"), _surface_part("lens_back", back, "glass"),
             _surface_part("rim", rim, None, role="absorber"), plate, det)
    return Scene(parts), src, mats


TREES = EstimatorOptions(delta_chain=4)
MANIFOLD = EstimatorOptions(delta_chain=4, specular_nee=2)
ANALOG = EstimatorOptions(nee=False)


def _run(scene, n, seed, est, record_paths=False):
    sc, src, mats = scene
    return trace(sc, src, n, seed=seed, materials=mats,
                 options=TraceOptions(estimator=est, output=OutputOptions(record_paths=record_paths)))


@pytest.mark.parametrize("build,n_analog,k", [(_mirror_scene, 300_000, 2), (_mirror_scene, 300_000, 1),
                                               (_lens_scene, 300_000, 2)])
def test_agrees_with_the_analog_walk_and_beats_the_trees(build, n_analog, k):
    """Through up to k interfaces (the mirror scene's family is one reflection: k = 1, the default set's,
    already has it all; the singlet's is two refractions)."""
    scene = build()
    n = 20_000
    on = _run(scene, n, 3, replace(MANIFOLD, specular_nee=k), record_paths=True)
    trees = _run(scene, n, 3, TREES)
    analog = _run(scene, n_analog, 4, ANALOG)
    a, t, b = on.detectors["det"], trees.detectors["det"], analog.detectors["det"]
    assert "specular_nee" in on.strategies.on
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) <= 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)
    assert abs(t.power_w - b.power_w) <= 4 * math.hypot(t.stderr_w, b.stderr_w), (t, b)
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w
    assert on.shadow_rays > trees.shadow_rays
    # it made paths of its family: scatter on the plate, then 1-2 interfaces, straight into the detector
    assert len(on.paths) > 0.05 * n
    assert a.stderr_w / a.power_w < 0.5 * t.stderr_w / t.power_w, (a, t)


def _polarized_scene():
    """The mirror scene with a flat glass mirror (uncoated n = 1.5: R_s and R_p differ) over a plate of
    a polarizing rough coating (microfacet on n = 1.5 and a Lambertian part), the beam polarized by a glass slab (n = 1.8) on its way
    to the plate: the plate scatters polarized light (f = M[0] . S) into reflections that weigh s and p
    differently."""
    sc, src, mats = _mirror_scene()
    top = Plane(vertex_mm=np.array([-16.2, 0.0, 25.0]), axis=np.array([0.0, 0.0, 1.0]), outer_radius_mm=7.0)
    bottom = Plane(vertex_mm=np.array([-16.2, 0.0, 24.0]), axis=np.array([0.0, 0.0, -1.0]), outer_radius_mm=7.0)
    parts = (_surface_part("mirror", _plane(40.0, -1.0, 30.0), "window"),) + sc.parts[1:] + (
        _surface_part("slab_top", top, "dense"), _surface_part("slab_bottom", bottom, "dense"))
    mats = {"window": load_material({"components": [{"type": "dielectric", "n": 1.5}]}, "window"),
            "dense": load_material({"components": [{"type": "dielectric", "n": 1.8}]}, "dense"),
            "matte": load_material({"components": [{"type": "microfacet", "alpha": 0.6, "n": 1.5, "weight": 0.5},
                                                   {"type": "lambertian", "rd": 0.2}]}, "rough")}
    return Scene(parts), src, mats


def test_polarized_scatter_agrees_with_the_split_trees():
    """Polarized light on a polarizing coating: the estimate (its f = M[0] . S and the Stokes vector it
    carries through the reflection) agrees with the split trees alone (carrying M S unnormalised, a
    first version, fails here)."""
    scene = _polarized_scene()
    on = _run(scene, 10_000, 3, MANIFOLD)
    trees = _run(scene, 200_000, 4, TREES)
    a, t = on.detectors["det"], trees.detectors["det"]
    assert "specular_nee" in on.strategies.on and on.shadow_rays > 10_000
    assert abs(a.power_w - t.power_w) <= 4 * math.hypot(a.stderr_w, t.stderr_w), (a, t)
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w


def test_one_interface_leaves_the_two_refraction_paths_to_the_trees():
    """specular_nee = 1 on the singlet: only the single reflections are candidates (no single
    refraction starts and ends in the air), so the plate seen through the glass stays the trees' alone
    (their branches keep the whole path: p_nee = 0), and the sum still agrees with the analog walk."""
    sc, src, mats = _lens_scene()
    spec = make_spec(sc, src, 100, 0, mats, TraceOptions(estimator=replace(MANIFOLD, specular_nee=1)))
    splits = parts_with(spec, Capability.DELTA_CHAIN)
    one, two = candidate_sequences(spec, splits, 1), candidate_sequences(spec, splits, 2)
    assert {s.k for s in one} == {1} and all(all(s.reflect) for s in one) and len(one) == 2
    assert max(s.k for s in two) == 2 and len(two) > len(one)
    scene = (sc, src, mats)
    single = _run(scene, 20_000, 3, replace(MANIFOLD, specular_nee=1))
    both = _run(scene, 20_000, 3, MANIFOLD)
    analog = _run(scene, 300_000, 4, ANALOG)
    a, b = single.detectors["det"], analog.detectors["det"]
    assert "specular_nee" in single.strategies.on and single.shadow_rays < both.shadow_rays
    assert abs(a.power_w - b.power_w) <= 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)
    assert abs(single.ledger["balance_residual_w"]) < 1e-9 * single.emitted_w


def test_the_option_counts_interfaces_and_the_default_set_uses_the_mirrors_with_glass():
    assert EstimatorOptions(specular_nee=True).specular_nee == 1  # the former switch
    for bad in (5, -1, 1.5, "2"):
        with pytest.raises(TraceError, match="specular_nee"):
            EstimatorOptions(specular_nee=bad)
    with pytest.raises(TraceError, match="specular_nee_sequences"):
        EstimatorOptions(specular_nee=3, specular_nee_sequences="thick")
    # a thick mirror has one reflection: "mirrors" needs one of the trees, "all" at three interfaces three
    assert EstimatorOptions(delta_chain=4, delta_chain_reflections=1, specular_nee=3,
                            specular_nee_sequences="mirrors").specular_nee == 3
    with pytest.raises(TraceError, match="delta_chain_reflections"):
        EstimatorOptions(delta_chain=4, delta_chain_reflections=2, specular_nee=3)
    _, _, lens_mats = _lens_scene()
    est = estimator_options("default", materials=lens_mats).estimator
    assert (est.specular_nee, est.specular_nee_sequences) == (3, "mirrors")
    _, _, mirror_mats = _mirror_scene()  # no refracting material: the default set leaves it off
    assert estimator_options("default", materials=mirror_mats).estimator.specular_nee == 0


def test_what_rules_it_out():
    sc, src, mats = _mirror_scene()

    def why(est):
        return unsupported(make_spec(sc, src, 100, 0, mats, TraceOptions(estimator=est)))

    assert why(MANIFOLD) is None
    assert "delta_chain" in why(EstimatorOptions(delta_chain=1, specular_nee=2))
    assert "target" in why(EstimatorOptions(delta_chain=4, specular_nee=2, target_parts=("plate",)))
    flat = Scene(tuple(p for p in sc.parts if p.name != "mirror") + (
        _quad("mirror", (-30, -30, 40), (0, 60, 0), (60, 0, 0), "mirror"),))
    assert "analytic" in unsupported(make_spec(flat, src, 100, 0, mats, TraceOptions(estimator=MANIFOLD)))


def _thick_mirror_scene(n_glass=2.0):
    """A glass singlet (n = 2: flat front face at z = 6 facing down, a sphere R = 40 mm at z = 10 whose
    centre is above it, r = 12 mm, black rim) above a disk detector (r = 3 mm at z = -5, facing up) and a
    matte plate beside it (x = 21-31 mm, z = 0, facing up) lit by a slanted beam that misses the lens: the
    plate's light goes up, so the detector sees it only by "plate -> lens_back (T) -> lens_front (R,
    inside) -> lens_back (T)" (the sphere is a convex mirror seen from the glass: its field reaches past
    the flat face's own reflection, which sees the plate only within 20 mm of the axis) and higher ghosts."""
    front = Conic(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=40.0,
                  outer_radius_mm=12.0)
    back = _plane(6.0, -1.0, 12.0)
    rim = Cylinder(vertex_mm=np.array([0.0, 0.0, 6.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=12.0,
                   length_mm=float(10.0 + front.sag(12.0) - 6.0))
    plate = _quad("plate", (21, -8, 0), (10, 0, 0), (0, 16, 0), "matte")  # normal +z
    det = disk_part("det", -5.0, 3.0, 64, role="detector")
    d = np.array([-math.sin(math.radians(30.0)), 0.0, -math.cos(math.radians(30.0))])
    src = CollimatedDisk(center_mm=[26.0 + 25.0 * math.tan(math.radians(30.0)), 0.0, 25.0], normal=d, direction=d,
                         radius_mm=3.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": n_glass}]}, "glass"),
            "matte": load_material(MATTE, "matte")}
    parts = (_surface_part("lens_front", front, "glass"), _surface_part("lens_back", back, "glass"),
             _surface_part("rim", rim, None, role="absorber"), plate, det)
    return Scene(parts), src, mats


THICK = EstimatorOptions(delta_chain=4, specular_nee=3, specular_nee_sequences="mirrors")


def test_thick_mirror_agrees_with_the_analog_walk():
    """The plate seen only through "lens_back (T) -> lens_front (R) -> lens_back (T)": with the thick
    mirrors among the sequences (tried with probability q, try_rate) the estimate agrees with the analog walk
    within 4 sigma, the ledger closes, its connections are the records of that family, and its error is
    a small fraction of the split trees' alone (which find the family only when the plate's scatter
    direction goes into it)."""
    scene = _thick_mirror_scene()
    n = 20_000
    on = _run(scene, n, 3, THICK, record_paths=True)
    trees = _run(scene, n, 3, TREES)
    analog = _run(scene, 5_000_000, 4, ANALOG)
    a, t, b = on.detectors["det"], trees.detectors["det"], analog.detectors["det"]
    assert "specular_nee" in on.strategies.on and on.shadow_rays > trees.shadow_rays
    assert b.stderr_w < 0.15 * b.power_w  # ~100 analog hits
    assert abs(a.power_w - b.power_w) <= 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)
    assert abs(t.power_w - b.power_w) <= 4 * math.hypot(t.stderr_w, b.stderr_w), (t, b)
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w
    families = {tuple(name for name, _ in on.paths.describe(i)) for i in range(min(len(on.paths), 2000))}
    assert ("plate", "lens_back", "lens_front", "lens_back") in families
    assert len(on.paths) > 0.05 * n
    assert a.stderr_w / a.power_w < 0.2 * t.stderr_w / t.power_w, (a, t)


def test_the_thick_mirror_sequences():
    """``specular_nee_sequences = "mirrors"``: a singlet's two single reflections and its two thick
    mirrors (from the back and from the front); "all" at three interfaces has many more."""
    sc, src, mats = _thick_mirror_scene()
    spec = make_spec(sc, src, 100, 0, mats, TraceOptions(estimator=THICK))
    splits = parts_with(spec, Capability.DELTA_CHAIN)
    names = [p.name for p in sc.parts]
    seqs = candidate_sequences(spec, splits, 3, "mirrors")
    got = sorted((tuple(names[p] for p in s.parts), s.reflect) for s in seqs)
    assert got == [(("lens_back",), (True,)),
                   (("lens_back", "lens_front", "lens_back"), (False, True, False)),
                   (("lens_front",), (True,)),
                   (("lens_front", "lens_back", "lens_front"), (False, True, False))]
    assert [s.sampled for s in seqs] == [s.k == 3 for s in seqs]
    assert len(candidate_sequences(spec, splits, 3, "all")) > len(candidate_sequences(spec, splits, 2, "all")) > 4
    assert candidate_sequences(spec, splits, 1, "mirrors") == candidate_sequences(spec, splits, 1, "all")


@pytest.mark.parametrize("build,est", [(_lens_scene, MANIFOLD), (_thick_mirror_scene, THICK)])
def test_same_numbers_for_any_batch_size(build, est):
    """Its detector points come from the event's own uniforms, the thick mirrors' tries from an own stream
    per chunk, and each vertex's solve is its own: the batch size does not change a bit."""
    sc, src, mats = build()
    runs = [trace(sc, src, 3000, seed=9, materials=mats, options=TraceOptions(estimator=est, batch_rays=b))
            for b in (1000, 3000)]
    assert runs[0].detectors["det"].power_w == runs[1].detectors["det"].power_w
    assert runs[0].detectors["det"].stderr_w == runs[1].detectors["det"].stderr_w


def test_first_vertex_sampling_declines_behind_a_lens(monkeypatch):
    """The plate the beam lights is seen by the detector only through the lens: first-vertex sampling's
    probes see no single scatter straight to it, its table is empty and the plan turns it off with that
    reason; run with the empty table instead, it changes no number (its weights are all the walk's)."""
    from straylight.engine.strategies import first_vertex as fv

    scene = _thick_mirror_scene()
    est = replace(THICK, first_vertex_sampling=True)
    off = _run(scene, 5_000, 3, est)
    assert "its probes saw no surface" in dict(off.strategies.off)["first_vertex"]
    monkeypatch.setattr(fv.FirstVertex, "declines", lambda self, spec: None)
    forced = _run(scene, 5_000, 3, est)
    assert "first_vertex" in forced.strategies.on
    assert forced.detectors["det"].power_w == off.detectors["det"].power_w > 0
    assert forced.detectors["det"].stderr_w == off.detectors["det"].stderr_w
    assert forced.escaped.power_w == off.escaped.power_w


# ---------------------------------------------------------------------- the ghosts (specular_nee = 4)

GHOSTS = EstimatorOptions(delta_chain=4, specular_nee=4, specular_nee_sequences="mirrors")


def _ghost_of(seq_thick):
    """The singlet's two-reflection ghost "back (T) -> front (R, inside) -> back (R, inside) -> front (T)" from the
    vertices of its thick mirror (``_thick_singlet``)."""
    into, mirror, _ = seq_thick
    inside_back = sm.Vertex(into.surface, True, into.eta_front, into.eta_back, into.medium_front, into.medium_back)
    out = sm.Vertex(mirror.surface, False, mirror.eta_front, mirror.eta_back, mirror.medium_front, mirror.medium_back)
    return (into, mirror, inside_back, out)


@pytest.mark.parametrize("radius_mm", [40.0, -40.0])
def test_geometry_term_of_a_ghost_matches_resolved_paths(radius_mm):
    """|d omega / dA_z| through a singlet's ghost (four vertices: enter the flat face, reflect inside off the
    sphere and off the flat face, leave through the sphere) against the solid angle of re-solved paths to a
    small square around z, and each vertex obeys its law (equal angles at the reflections, Snell's law at
    the refractions, in the plane of incidence)."""
    n_glass = 2.0
    seq = _ghost_of(_thick_singlet(radius_mm, n_glass))
    p = np.array([[1.0, 0.5, -3.0], [-3.0, -2.0, 0.0]])
    z = np.array([[3.0, 2.0, 40.0], [0.2, 0.1, 15.0]])  # (with R = -40 the ghost reaches only part of the plane)
    nz = np.tile([0.0, 0.0, -1.0], (2, 1))
    sol, J, omega = _check_laws_and_geometry_term(seq, p, z, nz, n_glass, give_up_residual=1e-2)
    # the estimator's own solve for the ghosts, by shooting on the first vertex: the same paths and geometry term
    shot = sm.shoot(seq, p, z, nz)
    assert shot.solution.ok.all()
    assert np.abs(shot.solution.X - sol.X).max() < 1e-8
    assert np.allclose(shot.J, J, rtol=1e-5) and np.allclose(shot.omega, omega, atol=1e-9)


def _ghost_scene():
    """The thick-mirror scene with the detector above the lens (r = 3 mm at z = 25, facing down): the plate's
    light reaches it straight, through the lens, and through the lens's ghost "plate -> lens_back (T) ->
    lens_front (R) -> lens_back (R) -> lens_front (T)"."""
    sc, src, mats = _thick_mirror_scene()
    parts = tuple(p for p in sc.parts if p.name != "det")
    return Scene(parts + (disk_part("det", 25.0, 3.0, 64, role="detector", facing=-1),)), src, mats


def _family_power(res, n, family):
    """The power of one path family on the detector and its standard error, from the path records per ray."""
    p = res.paths
    keep = np.array([tuple(name for name, _ in p.describe(i)) == family for i in range(len(p))], dtype=bool)
    x = np.bincount(np.asarray(p.ray)[keep], weights=np.asarray(p.power_w)[keep], minlength=n)
    return x.sum(), math.sqrt(n * x.var())


def test_the_ghost_sequences():
    """With four interfaces "mirrors" adds the singlet's two ghosts (entering either face) to its reflections
    and thick mirrors; they are not sampled (tried at every first vertex)."""
    sc, src, mats = _thick_mirror_scene()
    spec = make_spec(sc, src, 100, 0, mats, TraceOptions(estimator=GHOSTS))
    splits = parts_with(spec, Capability.DELTA_CHAIN)
    names = [p.name for p in sc.parts]
    seqs = candidate_sequences(spec, splits, 4, "mirrors")
    ghosts = sorted((tuple(names[p] for p in s.parts), s.reflect) for s in seqs if s.ghost)
    assert ghosts == [(("lens_back", "lens_front", "lens_back", "lens_front"), (False, True, True, False)),
                      (("lens_front", "lens_back", "lens_front", "lens_back"), (False, True, True, False))]
    assert len(seqs) == 6 and not any(s.sampled for s in seqs if s.ghost)
    assert [s for s in seqs if not s.ghost] == candidate_sequences(spec, splits, 3, "mirrors")


def test_ghost_agrees_with_the_split_trees():
    """The ghost family "plate -> back (T) -> front (R) -> back (R) -> front (T) -> detector" counted by the
    ghost connections (with the walk's trees' balance share) agrees within 4 sigma with the split trees alone
    (another seed, 100x the rays; the trees are checked against the analog walk above), at a small fraction
    of their error; the ledger closes."""
    scene = _ghost_scene()
    family = ("plate", "lens_back", "lens_front", "lens_back", "lens_front")
    n = 20_000
    on = _run(scene, n, 3, GHOSTS, record_paths=True)
    trees = _run(scene, 100 * n, 4, TREES, record_paths=True)
    a, sa = _family_power(on, n, family)
    b, sb = _family_power(trees, 100 * n, family)
    assert "specular_nee" in on.strategies.on
    assert sb < 0.1 * b  # the trees find the family: ~0.5 % of their rays' records
    assert abs(a - b) <= 4 * math.hypot(sa, sb), (a, sa, b, sb)
    assert sa / a < 0.1 * sb / b, (sa / a, sb / b)
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w


def _slab(plate_material="glossy"):
    """The glossy slab of tests/straylight/test_tree_split.py with analytic faces (n = 1.5 glass, 10 mm, planes
    of r = 60 mm): a plate lit by a beam (glossy: z302_sample_b, its lobe's peak sent through the slab; or
    "matte") seen by a r = 4 mm detector through the slab, by two refractions and by the slab's ghost "top (T)
    -> bottom (R) -> top (R) -> bottom (T)"; the plate's points are the eye chains' end points (and, glossy,
    the lobe draws' vertices)."""
    top = _surface_part("top", _plane(0.0, 1.0, 60.0), "glass")
    bottom = _surface_part("bottom", _plane(-10.0, -1.0, 60.0), "glass")
    plate = _quad("plate", (-40, -40, 30), (0, 80, 0), (80, 0, 0), plate_material, n=6)  # normal -z
    det = disk_part("det", -20.0, 4.0, 64, role="detector")
    d = np.array([math.sin(math.radians(35.0)), 0.0, math.cos(math.radians(35.0))])
    src = CollimatedDisk(center_mm=[-49.5, 0.0, 5.0], normal=d, direction=d, radius_mm=6.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": 1.5}]}, "glass"),
            "glossy": load_material("z302_sample_b"), "matte": load_material(MATTE, "matte")}
    return Scene((top, bottom, plate, det)), src, mats


THREE_WAY = EstimatorOptions(delta_chain=4, reverse_chain=4, tree_split=8, specular_nee=4,
                             specular_nee_sequences="mirrors")


@pytest.mark.parametrize("plate", ["glossy", "matte"])
def test_ghosts_join_the_eye_chains_and_the_lobe_draws(plate):
    """At the plate's points the eye chains own, the ghost connections, the eye chains' source connections
    and the walk's K = 8 lobe draws share the ghost family by the three-way balance heuristic: the family's
    power agrees within 4 sigma with the split trees alone (another seed, 10x the rays), the whole with the
    analog walk, the ledger closes, and with the matte plate the family's error is a fraction of what the
    chains give without the ghosts."""
    scene = _slab(plate)
    family = ("plate", "top", "bottom", "top", "bottom")
    n = 20_000
    on = _run(scene, n, 3, THREE_WAY, record_paths=True)
    without = _run(scene, n, 3, replace(THREE_WAY, specular_nee=3), record_paths=True)
    trees = _run(scene, 10 * n, 4, EstimatorOptions(delta_chain=4, tree_split=8), record_paths=True)
    analog = _run(scene, 400_000, 5, ANALOG)
    assert {"specular_nee", "reverse_chain", "delta_chain"} <= set(on.strategies.on)
    a, sa = _family_power(on, n, family)
    c, sc = _family_power(without, n, family)
    b, sb = _family_power(trees, 10 * n, family)
    assert abs(a - b) <= 4 * math.hypot(sa, sb), (a, sa, b, sb)
    if plate == "matte":  # (the glossy plate's K lobe draws find the ghost at its peak themselves)
        assert sa / a < 0.5 * sc / c, (sa / a, sc / c)
    t, r = on.detectors["det"], analog.detectors["det"]
    assert abs(t.power_w - r.power_w) <= 4 * math.hypot(t.stderr_w, r.stderr_w), (t, r)
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w


def test_the_ghosts_are_those_of_one_element():
    """Two singlets on one axis: the ghosts are each singlet's own two (faces with no other interface between them);
    "a T, b R, a R, b T" through faces of different singlets would cross the faces between and is not tried."""
    sc, src, mats = _thick_mirror_scene()
    lens_parts = [p for p in sc.parts if p.name in ("lens_front", "lens_back")]
    front2 = Conic(vertex_mm=np.array([0.0, 0.0, 30.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=40.0,
                   outer_radius_mm=12.0)
    second = (_surface_part("lens2_front", front2, "glass"), _surface_part("lens2_back", _plane(26.0, -1.0, 12.0),
                                                                           "glass"))
    scene = Scene(tuple(lens_parts) + second + tuple(p for p in sc.parts if p.name not in ("lens_front", "lens_back")))
    spec = make_spec(scene, src, 100, 0, mats, TraceOptions(estimator=GHOSTS))
    names = [p.name for p in scene.parts]
    seqs = candidate_sequences(spec, parts_with(spec, Capability.DELTA_CHAIN), 4, "mirrors")
    pairs = sorted(tuple(names[p] for p in s.parts[:2]) for s in seqs if s.ghost)
    assert pairs == [("lens2_back", "lens2_front"), ("lens2_front", "lens2_back"), ("lens_back", "lens_front"),
                     ("lens_front", "lens_back")]
