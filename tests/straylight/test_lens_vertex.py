"""Scatter points lit through a lens (straylight.engine.lens_vertex, strategy ``lens_vertex``).

Solver: through a flat window (two parallel planes) the ray reaching x left the disk displaced sideways by
t sin(theta - theta_t) / cos(theta_t) (Snell; the window's lateral shift), the beam keeps its cross-section
(|J_a x J_b| = 1) and the power through both faces is the mean over s and p of T_1 T_2 (Fresnel, Born & Wolf
1.5.2: the two planes share their plane of incidence). Through a singlet the solved ray, traced again,
passes x, and the walk's side recovers the same entrance point from the ray's end.

Estimator: a matte plate below a singlet, lit only through the glass, seen straight by a tilted detector
beside the beam: the estimate with the strategy agrees with the analog walk (another seed) and with the walk
alone within 4 sigma, the ledger closes and it engages (its family's records). Where it pays (a glint the
walk meets rarely: the guide scope's lens cell at 15 deg) is measured in benchmarks/variance_paths.py.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from engine_helpers import quad_part
from geometry.analytic import Conic, Cylinder, Plane
from geometry.mesh import Part, Scene
from materials import load_material
from straylight.engine import lens_vertex as lv
from straylight.engine.runtime import runtime
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, make_spec, trace

N_GLASS = 1.5
MATTE = {"components": [{"type": "lambertian", "rd": 0.6}]}


def _surface_part(name, surface, material, role="surface"):
    v, f = surface.mesh(0.01)
    return Part(name, v, f, material=material, role=role, surface=surface)


def _plane(z0, axis_z, r):
    return Plane(vertex_mm=np.array([0.0, 0.0, z0]), axis=np.array([0.0, 0.0, axis_z]), outer_radius_mm=r)


def _detector(centre, facing):
    facing = np.asarray(facing, float) / np.linalg.norm(facing)
    return _surface_part("det", Plane(vertex_mm=np.asarray(centre, float), axis=facing, outer_radius_mm=3.0), None,
                         role="detector")


def _materials(plate="matte"):
    """The glass and the plate's material: matte (Lambertian) or glossy (z302_sample_b: its lobe drawn)."""
    return {"glass": load_material({"components": [{"type": "dielectric", "n": N_GLASS}]}, "glass"),
            "matte": load_material(MATTE, "matte") if plate == "matte" else load_material("z302_sample_b")}


def _beam(tilt_deg, radius_mm=10.0, z=30.0):
    d = np.array([math.sin(math.radians(tilt_deg)), 0.0, -math.cos(math.radians(tilt_deg))])
    return CollimatedDisk(center_mm=[0.0, 0.0, z], normal=d, direction=d, radius_mm=radius_mm)


def _lens_scene(tilt_deg=10.0, plate_material="matte"):
    """A singlet (sphere R = 40 mm convex to the sky at z = 10, flat back at z = 6, r = 12 mm, black rim), a
    beam of radius 10 mm tilted tilt_deg; a matte plate (z = -20, facing up) in the converging beam; a
    detector (r = 3 mm) at x = -20, z = -5, facing the plate: it sees the plate straight, lit only through
    the glass."""
    front = Conic(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=-40.0,
                  outer_radius_mm=12.0)
    back = _plane(6.0, -1.0, 12.0)
    rim = Cylinder(vertex_mm=np.array([0.0, 0.0, 6.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=12.0,
                   length_mm=float(10.0 + front.sag(12.0) - 6.0))
    plate = quad_part("plate", (-10, -20, -20), (40, 0, 0), (0, 40, 0), "matte", "surface", 8)  # normal +z
    det = _detector((-20.0, 0.0, -5.0), (35.0, 0.0, -15.0))
    parts = (_surface_part("lens_front", front, "glass"), _surface_part("lens_back", back, "glass"),
             _surface_part("rim", rim, None, role="absorber"), plate, det)
    return Scene(parts), _beam(tilt_deg), _materials(plate_material)


def _window_scene(tilt_deg):
    """A flat window (z = 10 and z = 6, r = 20 mm) over the matte plate: the run is two refractions."""
    top, bottom = _plane(10.0, 1.0, 20.0), _plane(6.0, -1.0, 20.0)
    plate = quad_part("plate", (-10, -20, -20), (40, 0, 0), (0, 40, 0), "matte", "surface", 8)
    det = _detector((-20.0, 0.0, -5.0), (35.0, 0.0, -15.0))
    parts = (_surface_part("top", top, "glass"), _surface_part("bottom", bottom, "glass"), plate, det)
    return Scene(parts), _beam(tilt_deg), _materials()


def _spec(scene, est=EstimatorOptions(lens_vertex=True)):
    sc, src, mats = scene
    return make_spec(sc, src, 1000, 1, mats, TraceOptions(estimator=est))


def _fresnel_t(cos_i, n1, n2):
    sin_t = n1 / n2 * math.sqrt(1.0 - cos_i * cos_i)
    cos_t = math.sqrt(1.0 - sin_t * sin_t)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return 1.0 - rs * rs, 1.0 - rp * rp, cos_t


def test_window_shift_cross_section_and_throughput():
    tilt = 25.0
    scene = _window_scene(tilt)
    spec = _spec(scene)
    runs = lv.find_runs(spec, runtime().scene(spec))
    assert [len(r.parts) for r in runs] == [2]
    run = runs[0]
    x = np.array([[22.0, 1.0, -20.0], [18.0, -2.5, -20.0], [26.0, 0.0, -20.0]])  # in the beam (tilted to +x)
    ab, J, X, d, ok = lv.solve(spec, run, x)
    assert ok.all()
    src = spec.sources[0]
    np.testing.assert_allclose(lv._area_ratio(J), 1.0, rtol=1e-6)
    np.testing.assert_allclose(d, np.broadcast_to(src.direction, d.shape), atol=1e-12)
    # the straight line back from x along the beam misses the entry point by the window's lateral shift
    th = math.radians(tilt)
    Ts1, Tp1, cos_t = _fresnel_t(math.cos(th), 1.0, N_GLASS)
    shift = 4.0 * math.sin(th - math.acos(cos_t)) / cos_t
    straight = lv._on_disk(src, ab) + (np.einsum("ij,j->i", x - lv._on_disk(src, ab), src.direction)[:, None]
                                       * src.direction)
    np.testing.assert_allclose(np.linalg.norm(straight - x, axis=1), shift, rtol=1e-7)
    S, _, _, _ = lv.stokes_through(spec, run, ab)
    Ts2, Tp2, _ = _fresnel_t(cos_t, N_GLASS, 1.0)
    np.testing.assert_allclose(S[:, 0], 0.5 * (Ts1 * Ts2 + Tp1 * Tp2), rtol=1e-10)


def test_singlet_solution_passes_x_and_the_walk_recovers_it():
    scene = _lens_scene()
    spec = _spec(scene)
    (run,) = lv.find_runs(spec, runtime().scene(spec))
    rng = np.random.default_rng(2)
    r, phi = 7.0 * np.sqrt(rng.random(50)), 2 * np.pi * rng.random(50)
    ab0 = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
    X0, d0, ok0 = lv.trace_run(spec, run, ab0)  # points of the plate (z = -20) the run lights
    assert ok0.all()
    x = X0[-1] + ((-20.0 - X0[-1][:, 2]) / d0[:, 2])[:, None] * d0
    ab, J, X, d, ok = lv.solve(spec, run, x)
    assert ok.all()
    np.testing.assert_allclose(ab, ab0, atol=1e-5)  # one ray reaches each point before the focus (solve: 1e-6 mm)
    X2, d2, ok2 = lv.trace_run(spec, run, ab[ok])
    assert ok2.all()
    np.testing.assert_allclose(np.linalg.norm(lv._offset(x[ok], X2[-1], d2), axis=1), 0.0, atol=lv.SOLVE_TOL_MM)
    back, same = lv.recover(spec, run, x[ok], d2)
    assert same.all()
    np.testing.assert_allclose(back, ab[ok], atol=1e-5)


def _run(scene, n, seed, est, record_paths=False):
    sc, src, mats = scene
    return trace(sc, src, n, seed=seed, materials=mats,
                 options=TraceOptions(estimator=est, output=OutputOptions(record_paths=record_paths)))


@pytest.mark.parametrize("plate", ["matte", "glossy"])
def test_agrees_with_the_analog_walk_and_the_walk_alone(plate):
    """The glossy plate also takes the lobe's own draw at each vertex (power heuristic with the uniform
    detector point)."""
    scene = _lens_scene(plate_material=plate)
    n = 20_000
    walk = EstimatorOptions(delta_chain=4)
    on = _run(scene, n, 3, replace(walk, lens_vertex=True), record_paths=True)
    alone = _run(scene, n, 3, walk)
    analog = _run(scene, 300_000, 4, EstimatorOptions(nee=False))
    a, w, b = on.detectors["det"], alone.detectors["det"], analog.detectors["det"]
    assert "lens_vertex" in on.strategies.on
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) <= 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)
    assert abs(w.power_w - b.power_w) <= 4 * math.hypot(w.stderr_w, b.stderr_w), (w, b)
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w
    assert abs(a.power_w - w.power_w) <= 4 * math.hypot(a.stderr_w, w.stderr_w), (a, w)
    assert on.shadow_rays > alone.shadow_rays
    # it made paths of its family: the two refractions, the plate, the detector (the walk's NEE keeps a share)
    fam = [i for i in range(len(on.paths)) if len(on.paths.describe(i)) == 3]
    assert len(fam) > 0.5 * n


def test_declines_without_a_lens_in_the_beam():
    """The beam misses the lens (the plate lit straight): no run, the strategy turns itself off."""
    sc, src, mats = _lens_scene()
    far = CollimatedDisk(center_mm=[40.0, 0.0, 30.0], normal=src.normal, direction=src.direction, radius_mm=3.0)
    res = trace(sc, far, 2000, seed=1, materials=mats, options=TraceOptions(estimator=EstimatorOptions(lens_vertex=True)))
    assert "lens_vertex" not in res.strategies.on


def test_two_singlets_a_run_of_four():
    """Two singlets one above the other (the lower one 2 mm smaller in radius of curvature): the run is
    four refractions; the solve returns the entry points of rays traced forward to the plate, and the walk's
    back-trace recovers them."""
    sc, src, mats = _lens_scene()
    front2 = Conic(vertex_mm=np.array([0.0, 0.0, 2.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=-60.0,
                   outer_radius_mm=12.0)
    back2 = _plane(-1.0, -1.0, 12.0)
    parts = sc.parts[:3] + (_surface_part("lens2_front", front2, "glass"), _surface_part("lens2_back", back2, "glass")) \
        + sc.parts[3:]
    spec = _spec((Scene(parts), src, mats))
    runs = lv.find_runs(spec, runtime().scene(spec))
    assert len(runs[0].parts) == 4
    run = runs[0]
    rng = np.random.default_rng(3)
    r, phi = 6.0 * np.sqrt(rng.random(40)), 2 * np.pi * rng.random(40)
    ab0 = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
    X0, d0, ok0 = lv.trace_run(spec, run, ab0)
    assert ok0.all()
    x = X0[-1] + ((-20.0 - X0[-1][:, 2]) / d0[:, 2])[:, None] * d0
    ab, J, X, d, ok = lv.solve(spec, run, x)
    assert ok.all()
    np.testing.assert_allclose(ab, ab0, atol=1e-5)
    back, same = lv.recover(spec, run, x, d)
    assert same.all()
    np.testing.assert_allclose(back, ab, atol=1e-5)


def test_the_table_keeps_to_first_vertex_sampling_probe_budget(monkeypatch):
    """Eight probes per triangle of the lit parts while that stays within first_vertex.PROBE_BUDGET, fewer
    beyond (at least one): a large housing behind a lens costs one probe per triangle, not eight. With a budget
    that allows 2 per triangle of the plate the table still holds the plate's lit triangles, q summing to 1."""
    assert lv.probes_per_triangle(1000) == lv.PROBES_PER_TRIANGLE
    assert lv.probes_per_triangle(lv.PROBE_BUDGET // 2) == 2
    assert lv.probes_per_triangle(10 * lv.PROBE_BUDGET) == 1
    spec = _spec(_lens_scene())
    comp = runtime().scene(spec)
    asked = []
    real = lv._probe

    def counting(spec_, comp_, run, tris, m, rng):
        asked.append((len(tris), m))
        return real(spec_, comp_, run, tris, m, rng)

    monkeypatch.setattr(lv, "_probe", counting)
    full = lv.build_table(spec, comp)
    n_plate = asked[-1][0]
    assert asked[-1][1] == lv.PROBES_PER_TRIANGLE and not full.empty
    asked.clear()
    monkeypatch.setattr(lv, "PROBE_BUDGET", 2 * n_plate)
    small = lv.build_table(spec, comp)
    assert asked[-1] == (n_plate, 2)
    assert not small.empty and abs(small.cdf[-1] - 1.0) < 1e-12
    assert set(small.tri) <= set(full.tri) and len(small.tri) > 0.5 * len(full.tri)
