"""The engine's ray log (OutputOptions.ray_log) and the rays the pictures draw from it
(straylight.viz.trace_ray_paths): the drawn rays are the engine's own walk.

Independent references for the drawn geometry: Snell's law n1 sin(theta_1) = n2 sin(theta_2) with
the refracted ray in the plane of incidence, and the law of reflection r = d - 2 (d . n) n
(Hecht, Optics, §4.4 and §4.3). Neither is computed by the code under test here.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from geometry.analytic import Plane, analytic_part
from geometry.mesh import Part, Scene
from straylight.analyses.types import Beam, Setup
from straylight.engine.ray_log import SEGMENT_ESCAPE
from straylight.trace import EstimatorOptions, OutputOptions, TraceError, TraceOptions, scene_epsilon, trace

from engine_helpers import window_scene

N_GLASS = 1.5  # window_scene's glass
UP = np.array([0.0, 0.0, 1.0])


def _unit(v):
    return v / np.linalg.norm(v)


def _window_setup():
    scene, _, materials = window_scene()  # glass faces at z = 10 (top) and z = 0 (bottom), detector at z = -20
    return Setup(scene, materials, Beam(center_mm=(0, 0, 60), axis=(0, 0, -1), radius_mm=5.0), None, "det")


def _analog(**output):
    return TraceOptions(estimator=EstimatorOptions(nee=False), output=OutputOptions(**output), batch_rays=700)


def test_ray_log_is_off_by_default_and_does_not_change_the_numbers():
    scene, src, materials = window_scene()
    off = trace(scene, [src], 2000, seed=3, materials=materials, options=_analog())
    on = trace(scene, [src], 2000, seed=3, materials=materials, options=_analog(ray_log=1500))
    assert off.ray_log is None
    assert on.detectors["det"] == off.detectors["det"]  # bit for bit
    assert on.escaped == off.escaped and on.segments == off.segments
    assert on.absorbed == off.absorbed


def test_ray_log_ids_are_the_traces_own_and_do_not_depend_on_the_batches():
    scene, src, materials = window_scene()
    a = trace(scene, [src], 2500, seed=4, materials=materials, options=_analog(ray_log=1800))
    b = trace(scene, [src], 2500, seed=4, materials=materials,
              options=TraceOptions(estimator=EstimatorOptions(nee=False), output=OutputOptions(ray_log=1800),
                                   batch_rays=2500))
    ids = np.unique(a.ray_log.ray)
    assert ids.tolist() == list(range(1800))  # rays of the second and third chunk too: global ids
    for field in ("ray", "event", "origin_mm", "direction", "end_mm", "tri", "kind", "weight_w", "detector"):
        assert np.array_equal(getattr(a.ray_log, field), getattr(b.ray_log, field)), field
    log = a.ray_log
    for _, rows in log.rays()[:50]:
        assert np.array_equal(log.event[rows], np.arange(rows.stop - rows.start))  # every event, in order
        # each segment starts where the last one ended (up to the self-intersection offset)
        gap = np.linalg.norm(log.origin_mm[rows][1:] - log.end_mm[rows][:-1], axis=1)
        assert (gap <= 4 * scene_epsilon(scene.triangles_mm)).all()  # the walk offsets a few epsilons
    # the window passes most light: detector hits are flagged, on the detector plane
    det = log.detector
    assert det.sum() > 1500 and np.allclose(log.end_mm[det, 2], -20.0)
    assert (log.tri[~det] != SEGMENT_ESCAPE).any()
    # the engine's own event kinds: rays leave the source (0), then smooth interfaces only (2: specular)
    assert (log.kind[log.event == 0] == 0).all() and (log.kind[log.event > 0] == 2).all()


@pytest.mark.parametrize("bad", [-1, 2.5, True])
def test_ray_log_must_be_a_count(bad):
    with pytest.raises(TraceError, match="ray_log"):
        OutputOptions(ray_log=bad)


def test_drawn_rays_refract_through_a_window_by_snells_law():
    from straylight import viz

    setup = _window_setup()
    theta_i = math.radians(30.0)
    paths = viz.trace_ray_paths(setup, theta_i, n_rays=300, seed=2, with_triangles=True)
    assert len(paths) == 300
    part_of = setup.scene.triangle_part
    names = setup.scene.part_names
    inside = reflected = through = 0
    for pts, w, reached, tris in paths:
        hit = [names[part_of[t]] if t >= 0 else None for t in tris]
        d_in = _unit(pts[1] - pts[0])
        assert abs(math.acos(-d_in[2]) - theta_i) < 1e-9  # the beam's own tilt
        if hit[0] != "top":
            continue
        d_out = _unit(pts[2] - pts[1])
        plane_normal = np.cross(d_in, UP)  # the plane of incidence
        assert abs(np.dot(d_out, plane_normal)) < 1e-6
        if d_out[2] < 0:  # transmitted into the glass
            inside += 1
            sin_t = np.linalg.norm(np.cross(d_out, UP))
            assert abs(1.0 * math.sin(theta_i) - N_GLASS * sin_t) < 1e-6  # n1 sin = n2 sin
            assert hit[1] == "bottom"
            if len(pts) > 3 and d_out[2] < 0 and hit[2] == "det":
                d_exit = _unit(pts[3] - pts[2])
                assert np.allclose(d_exit, d_in, atol=1e-6)  # a plate: leaves parallel to how it came
                assert reached and np.isclose(pts[3][2], -20.0)
                through += 1
        else:  # the Fresnel reflection
            reflected += 1
            assert np.allclose(d_out, d_in - 2 * np.dot(d_in, UP) * UP, atol=1e-9)
    # R(30 deg, n = 1.5) ~ 4.2 %: most rays go through, a few reflect
    assert inside > 250 and through > 200 and reflected >= 1


def _mirror_setup():
    mirror = analytic_part("mirror", Plane(np.zeros(3), UP, math.inf, 0.0, 100.0, 0.0), None, "mirror")
    v = np.array([[60, -50, 0], [60, 50, 0], [60, 50, 100], [60, -50, 100]], float)
    det = Part("det", v, np.array([[0, 2, 1], [0, 3, 2]]), None, "detector")  # the plane x = 60
    return Setup(Scene((mirror, det)), {}, Beam(center_mm=(0, 0, 60), axis=(0, 0, -1), radius_mm=5.0), None, "det")


def test_drawn_rays_reflect_at_a_mirror():
    from straylight import viz

    setup = _mirror_setup()
    paths = viz.trace_ray_paths(setup, math.radians(30.0), n_rays=40, seed=1, with_triangles=True)
    assert len(paths) == 40
    names, part_of = setup.scene.part_names, setup.scene.triangle_part
    for pts, w, reached, tris in paths:
        assert [names[part_of[t]] for t in tris] == ["mirror", "det"]
        assert np.isclose(pts[1][2], 0.0) and np.isclose(pts[2][0], 60.0)
        d, r = _unit(pts[1] - pts[0]), _unit(pts[2] - pts[1])
        assert np.allclose(r, d - 2 * np.dot(d, UP) * UP, atol=1e-9)  # angle in = angle out
        assert reached and np.allclose(w, 1.0)  # mirror_reflectance 1: the power carried on


@pytest.mark.parametrize("scene", ["window", "mirror"])
def test_the_3d_views_sample_rays_follow_refraction_and_mirrors(scene):
    """The view's rays of a path group run through the glass (Snell) or off the mirror (reflection)
    under the path report's own label, with the engine's event kinds (specular at each interface)."""
    from straylight import view3d
    from straylight.analyses.paths_report import paths_analysis

    setup = _window_setup() if scene == "window" else _mirror_setup()
    theta_i = math.radians(30.0)
    report, _ = paths_analysis(setup, theta_i, n_rays=2000, seed=1)
    samples = view3d.path_samples(setup, report, theta_i, top=1, n_walks=200, seed=1)
    expected = {"window": "source -> top (specular) -> bottom (specular) -> det",
                "mirror": "source -> mirror (specular) -> det"}[scene]
    assert samples[0].label == expected and len(samples[0].polylines) == 6
    for line in samples[0].polylines:
        pts = np.asarray(line)
        d_in, d_out = _unit(pts[1] - pts[0]), _unit(pts[2] - pts[1])
        if scene == "window":
            assert len(pts) == 4 and np.allclose(pts[1:, 2], [10.0, 0.0, -20.0], atol=2e-3)
            # the points are rounded to 1 um: Snell's law to ~1e-4 over the 10 mm plate
            assert abs(math.sin(theta_i) - N_GLASS * np.linalg.norm(np.cross(d_out, UP))) < 1e-3
        else:
            assert len(pts) == 3 and abs(pts[1][2]) < 2e-3
            assert np.allclose(d_out, d_in - 2 * np.dot(d_in, UP) * UP, atol=1e-3)


def test_drawn_rays_through_an_imported_lens_meet_at_its_focus(tmp_path, capsys):
    """A lens from ``straylight optics import`` (Thorlabs ACL3026U, an aspheric condenser, EFL 25.9 mm):
    the drawn rays of the on-axis beam refract at both faces and meet on the axis at the back focal
    distance rayoptics' paraxial trace gives (``optics info``: bfl 18.0957 mm after the last vertex,
    which is 5 + 11.9 mm from the first)."""
    from straylight import viz
    from straylight.analyses.scene_setup import scene_setup
    from straylight.cli.main import main

    lens = Path(__file__).resolve().parents[1] / "data" / "lenses" / "ray-optics" / "ACL3026U.zmx"
    assert main(["optics", "import", str(lens), "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    setup = scene_setup(tmp_path / "scene.toml")
    paths = viz.trace_ray_paths(setup, 0.0, n_rays=600, seed=1, max_events=20, with_triangles=True)
    names, part_of = setup.scene.part_names, setup.scene.triangle_part
    focus_z = 5.0 + 11.9 + 18.0957
    crossings, reached_image, direct = [], 0, 0
    for pts, _, reached, tris in paths:
        if not reached:
            continue
        reached_image += 1
        # the front face is named after its comment in the file (COMM ACL3026U), the back face s3
        if [names[part_of[t]] for t in tris] != ["ACL3026U", "s3", "image"]:  # a ghost (Fresnel reflections)
            continue
        direct += 1  # through the glass: the old display walk stopped every ray at the first face
        a, b = pts[-2], pts[-1]  # the last segment, from the back face to the image
        height = math.hypot(*a[:2])
        if 0.5 < height < 3.0:  # near the axis (paraxial): where it crosses the axis (in its own plane)
            d = b - a
            t = -np.dot(a[:2], d[:2]) / np.dot(d[:2], d[:2])
            crossings.append(a[2] + t * d[2])
    assert direct > 0.9 * reached_image and len(crossings) > 10
    assert np.allclose(crossings, focus_z, atol=0.05)


def test_a_drawing_cut_at_max_events_warns_nothing(recwarn):
    """The picture stops its rays after max_events on purpose; the trace's truncation warning is for runs."""
    from straylight import viz

    setup = _window_setup()
    paths = viz.trace_ray_paths(setup, math.radians(30.0), n_rays=100, seed=1, max_events=1)
    assert all(len(p[0]) == 2 for p in paths)  # one event each: most power still in flight
    assert not [w for w in recwarn if "max_events" in str(w.message)]


def test_logged_hits_on_an_exact_surface_end_on_it_not_on_its_facets():
    """A concave spherical mirror (R = 200 mm) meshed coarsely (0.5 mm sagitta): the segments that end on it
    end on the sphere |P - C| = R (C the centre of curvature), to round-off, as the walk reflects there; the
    facets alone lie up to the sagitta inside it."""
    from geometry.analytic import Conic

    radius = 200.0
    mirror = analytic_part("mirror", Conic(np.zeros(3), UP, radius, 0.0, 40.0, 0.0), None, "mirror",
                           tolerance_mm=0.5)
    scene = Scene((mirror,))
    beam = Beam(center_mm=(0, 0, 60), axis=(0, 0, -1), radius_mm=35.0)
    res = trace(scene, [beam.source(0.0)], 400, seed=3, materials={}, options=_analog(ray_log=400))
    log = res.ray_log
    on = np.flatnonzero(log.tri >= 0)
    assert len(on) > 300
    centre = np.array([0.0, 0.0, radius])
    off = np.abs(np.linalg.norm(log.end_mm[on] - centre, axis=1) - radius)
    assert off.max() < 1e-9
    # the facets' own points (the hit before the walk refines it) are not on the sphere: the check can fail
    v = mirror.vertices_mm
    assert np.abs(np.linalg.norm(v[mirror.faces].mean(axis=1) - centre, axis=1) - radius).max() > 1e-3
