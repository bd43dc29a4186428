"""The side test of specular next-event estimation (straylight.engine.specular_reach): it refuses only
points that lie on no tangent plane's side they would need (checked against the tangent planes of a
dense grid of aperture points, the surfaces' own normals), it does refuse the points behind a lens
face, and the estimator's numbers are the same bits with the test as with every row solved."""
import math

import numpy as np
import pytest

from geometry.analytic import Asphere, Conic, Plane
from straylight.engine import specular_manifold as sm
from straylight.engine import specular_nee as sn
from straylight.engine import specular_reach as reach

def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


SURFACES = {
    "convex": Conic(vertex_mm=np.array([1.0, -2.0, 30.0]), axis=_unit([0.1, 0.0, 1.0]), radius_mm=-40.0,
                    outer_radius_mm=12.0),
    "concave_parabola": Conic(vertex_mm=np.array([0.0, 0.0, -5.0]), axis=_unit([0.0, 0.3, -1.0]),
                              radius_mm=60.0, conic=-1.0, outer_radius_mm=25.0, inner_radius_mm=4.0),
    "off_axis": Conic(vertex_mm=np.array([0.0, 0.0, 0.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=80.0,
                      outer_radius_mm=10.0, aperture_center_uv=(15.0, 5.0)),
    "plane": Plane(vertex_mm=np.array([0.0, 0.0, 6.0]), axis=np.array([0.0, 0.0, -1.0]), outer_radius_mm=12.0),
}


def _aperture_grid(surface, n=60):
    """Points and front normals of a polar grid over the clear aperture (rim included)."""
    lo, hi = surface.inner_radius_mm, surface.outer_radius_mm
    rho, phi = np.meshgrid(np.linspace(lo, hi, n), np.linspace(0.0, 2 * math.pi, 2 * n, endpoint=False))
    cu, cv = surface.aperture_center_uv
    uv = np.column_stack([(cu + rho * np.cos(phi)).ravel(), (cv + rho * np.sin(phi)).ravel()])
    return sm.surface_points(surface, uv)


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_refuses_only_points_on_no_tangent_plane_side(name):
    surface = SURFACES[name]
    test = reach.side_test(surface)
    X, N = _aperture_grid(surface)
    rng = np.random.default_rng(5)
    q = surface.vertex_mm + rng.uniform(-60.0, 60.0, (400, 3))
    side = np.einsum("qk,pk->qp", q, N) - np.einsum("pk,pk->p", X, N)[None, :]  # (Q - X) . n per pair
    for front in (True, False):
        may = reach.may_lie(test, front, q)
        some = (side > 0).any(axis=1) if front else (side < 0).any(axis=1)
        assert not (some & ~may).any(), name  # never refuses a point some grid point has on that side
        assert (~may).sum() > 20, name  # and refuses the points well behind (in front of) the surface
    # a ball: refused only when every point in it is refused
    centre = surface.vertex_mm - 40.0 * surface.axis
    if not reach.may_lie(test, True, centre[None, :], 5.0)[0]:
        ball = centre + 5.0 * rng.uniform(-1, 1, (300, 3)) / math.sqrt(3.0)
        assert not reach.may_lie(test, True, ball).any()


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_refuses_only_points_facing_away_from_every_aperture_point(name):
    surface = SURFACES[name]
    centre, radius = reach.aperture_ball(reach.side_test(surface))
    X, _N = _aperture_grid(surface)
    assert np.linalg.norm(X - centre, axis=1).max() <= radius  # the ball holds the aperture
    rng = np.random.default_rng(7)
    p = surface.vertex_mm + rng.uniform(-60.0, 60.0, (400, 3))
    n = rng.normal(size=(400, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    may = reach.may_face(p, n, centre, radius)
    ahead = (np.einsum("pk,qk->qp", X, n) - np.einsum("qk,qk->q", p, n)[:, None] > 0).any(axis=1)
    assert not (ahead & ~may).any() and (~may).sum() > 50


def test_no_test_for_an_asphere_or_a_conic_past_its_extent():
    asph = Asphere(vertex_mm=np.zeros(3), axis=np.array([0.0, 0.0, 1.0]), radius_mm=50.0, outer_radius_mm=10.0,
                   coefficients=(1e-5,))
    steep = Conic(vertex_mm=np.zeros(3), axis=np.array([0.0, 0.0, 1.0]), radius_mm=10.0, outer_radius_mm=10.0)
    assert reach.side_test(asph) is None and reach.side_test(steep) is None


def _without_reach(monkeypatch):
    monkeypatch.setattr(sn, "reaches", lambda seq, p, n_p, z: np.ones(len(p), dtype=bool))
    monkeypatch.setattr(sn, "reaches_ball", lambda seq, centre, radius: True)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_same_bits_as_solving_every_row(monkeypatch, k):
    """The singlet scene of test_specular_nee (a plate above the lens, the detector below: every single
    reflection off the front face is refused, most of the back face's), and for k = 3 its thick-mirror
    scene (the plate and the detector below the lens, "mirrors": the thick mirror from the front is
    refused): the detector tally, its error, the casts and the path records are the same bits with every
    row solved."""
    from dataclasses import replace

    from test_specular_nee import MANIFOLD, THICK, _lens_scene, _run, _thick_mirror_scene

    scene = _lens_scene() if k < 3 else _thick_mirror_scene()
    est = replace(MANIFOLD, specular_nee=k) if k < 3 else THICK
    a = _run(scene, 4000, 3, est, record_paths=True)
    _without_reach(monkeypatch)
    b = _run(scene, 4000, 3, est, record_paths=True)
    assert a.detectors["det"].power_w == b.detectors["det"].power_w > 0
    assert a.detectors["det"].stderr_w == b.detectors["det"].stderr_w
    assert a.shadow_rays == b.shadow_rays and len(a.paths) == len(b.paths)


def test_no_test_on_a_frame_built_on_a_non_unit_axis():
    skew = Conic(vertex_mm=np.zeros(3), axis=np.array([0.1, 0.0, 1.0]), radius_mm=-40.0, outer_radius_mm=12.0)
    assert reach.side_test(skew) is None
