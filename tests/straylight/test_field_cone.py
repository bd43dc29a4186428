"""The detectors' field through a lens (straylight.engine.field_cone) and the trees' end draws aimed into it
(straylight.engine.tree_ends, "Draws into the field").

Field: a plano-convex singlet (R = 40 mm, n = 1.5: f = R / (n - 1) = 80 mm) with a 3 mm detector at its back
focus sees the object-side directions within ~atan(3 / 80) = 2.15 deg of its axis (thin lens), whatever the
point they leave from. Draws: any cone leaves the end draws unbiased (a one-sample mixture with the lobe): on
tests/straylight/test_tree_ends.py's slab and glossy plate, with a cone forced about the plate's glint through
the slab, the estimate agrees with the analog walk and the aimed draws are there.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from engine_helpers import assert_agrees_with_analog
from geometry.analytic import Conic, Plane
from geometry.mesh import Part, Scene
from materials import load_material
from straylight.engine import field_cone, tree_ends
from straylight.engine.field_cone import FieldCone, FieldTable, cone_of
from straylight.engine.runtime import runtime
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceOptions, make_spec

from test_tree_ends import ANALOG, TREES, _run, _scene


def _directions_in_cone(axis, half_deg, n, seed=0):
    return FieldCone(tuple(axis), half_deg).sample(np.random.default_rng(seed).random((n, 2)))


def test_a_sample_of_a_cone_gives_its_axis_and_its_half_angle_widened_by_the_margin():
    axis = np.array([0.3, -0.2, -0.9])
    axis /= np.linalg.norm(axis)
    cone = cone_of(_directions_in_cone(axis, 2.0, 5000))
    assert math.degrees(math.acos(np.dot(cone.axis, axis))) < 0.05
    assert cone.half_angle_deg == pytest.approx(2.0 * field_cone.FIELD_MARGIN, rel=0.01)


def test_no_cone_from_too_few_directions_or_a_wide_field():
    assert cone_of(_directions_in_cone((0, 0, 1), 2.0, field_cone.FIELD_MIN_RAYS - 1)) is None
    assert cone_of(_directions_in_cone((0, 0, 1), field_cone.FIELD_MAX_DEG, 5000)) is None  # x margin: too wide


def test_the_cone_draw_is_uniform_in_solid_angle_within_it():
    """Uniform in solid angle within half-angle a: cos theta uniform on [cos a, 1], mean (1 + cos a) / 2."""
    cone = FieldCone((0.0, 0.0, 1.0), 5.0)
    n = 200_000
    d = cone.sample(np.random.default_rng(1).random((n, 2)))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert cone.contains(d).all()
    sigma = (1.0 - cone.cos_half) / math.sqrt(12.0 * n)  # the mean's standard error
    assert np.mean(d[:, 2]) == pytest.approx((1.0 + cone.cos_half) / 2.0, abs=4.0 * sigma)
    assert np.mean(d[:, 0]) == pytest.approx(0.0, abs=4.0 * math.sin(math.radians(5.0)) / math.sqrt(2.0 * n))
    assert cone.density_per_sr * 2.0 * math.pi * (1.0 - cone.cos_half) == pytest.approx(1.0)


def _surface_part(name, surface, material, role="surface"):
    v, f = surface.mesh(0.01)
    return Part(name, v, f, material=material, role=role, surface=surface)


def _focused_singlet():
    """The singlet (front sphere R = 40 at z = 10, flat back at z = 6, r = 12) and a 3 mm detector facing it at the
    back focus, z = 6 - (f - t / n) = 6 - (80 - 4 / 1.5)."""
    front = Conic(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=-40.0,
                  outer_radius_mm=12.0)
    back = Plane(vertex_mm=np.array([0.0, 0.0, 6.0]), axis=np.array([0.0, 0.0, -1.0]), outer_radius_mm=12.0)
    z_focus = 6.0 - (80.0 - 4.0 / 1.5)
    det = Plane(vertex_mm=np.array([0.0, 0.0, z_focus]), axis=np.array([0.0, 0.0, 1.0]), outer_radius_mm=3.0)
    parts = (_surface_part("lens_front", front, "glass"), _surface_part("lens_back", back, "glass"),
             _surface_part("det", det, None, role="detector"))
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": 1.5}]}, "glass")}
    src = CollimatedDisk(center_mm=[0.0, 0.0, 30.0], normal=[0, 0, -1.0], direction=[0, 0, -1.0], radius_mm=10.0)
    return Scene(parts), src, mats


def test_the_field_of_a_detector_at_a_singlets_focus_is_the_thin_lens_cone_about_its_axis():
    scene, src, mats = _focused_singlet()
    spec = make_spec(scene, src, 1000, seed=3, materials=mats,
                     options=TraceOptions(estimator=EstimatorOptions(delta_chain=4, tree_ends=True)))
    table = field_cone.build(spec, runtime().scene(spec))
    cone = table.cone
    assert cone is not None, table.why_none
    assert math.degrees(math.acos(-cone.axis[2])) < 0.1  # toward the lens, along -z
    thin = math.degrees(math.atan(3.0 / 80.0))
    assert thin < cone.half_angle_deg < field_cone.FIELD_MARGIN * 1.3 * thin, (cone.half_angle_deg, thin)


def test_no_field_without_an_analytic_interface(reflected_glint_scene):
    """The slab of test_tree_ends is meshed, not analytic: no cone, the draws as before."""
    sc, src, mats = reflected_glint_scene
    spec = make_spec(sc, src, 1000, seed=3, materials=mats, options=TraceOptions(estimator=replace(TREES, tree_ends=True)))
    assert field_cone.build(spec, runtime().scene(spec)).cone is None


@pytest.fixture(scope="module")
def reflected_glint_scene():
    return _scene(1.5)


@pytest.fixture(scope="module")
def glint_analog(reflected_glint_scene):
    return _run(reflected_glint_scene, 400_000, 4, ANALOG)


def test_end_draws_aimed_into_a_forced_cone_agree_with_the_analog_walk(reflected_glint_scene, glint_analog,
                                                                      monkeypatch):
    """A cone of 6 deg about the plate's glint down through the slab (plate x = 21, z = 30 to the slab's top at
    x = 42): the draws into it and the lobe's, weighed as one mixture, agree with the analog walk."""
    axis = np.array([21.0, 0.0, -30.0]) / math.hypot(21.0, 30.0)
    monkeypatch.setattr(field_cone, "build", lambda spec, scene: FieldTable(FieldCone(tuple(axis), 6.0)))
    aimed = []
    original = tree_ends.TreeEnds._into_field

    def counting(self, spec, mat, wi, tb, bb, nf, wo, weight, pdf, u):
        aimed.append(int(np.sum(u[:, 0] < tree_ends.END_FIELD_SHARE)))
        return original(self, spec, mat, wi, tb, bb, nf, wo, weight, pdf, u)

    monkeypatch.setattr(tree_ends.TreeEnds, "_into_field", counting)
    runtime().forget_tables()
    try:
        res = _run(reflected_glint_scene, 20_000, 5, replace(TREES, tree_ends=True))
    finally:
        runtime().forget_tables()
    assert sum(aimed) > 100
    assert_agrees_with_analog(res, glint_analog)
    assert_agrees_with_analog(res, glint_analog, "up")
