"""The thermal walks see an analytic plane part as its exact annulus (CONTRACTS §6.4) through the
engine's ExactBoundaryIntersector, for their casts and for forward NEE's shadow rays alike.

The annulus' covering mesh (geometry.analytic.Plane.mesh) has its inner polygon inscribed in the
hole, so it adds slivers inside the hole, between each chord and the circle: rays through a sliver
must pass (the mesh alone stops them: checked, so the test is not vacuous), rays through the annulus
must stop.
"""
import math

import numpy as np
import pytest

from geometry.analytic import Plane, analytic_part
from geometry.mesh import Scene
from straylight.intersect.exact_boundary import ExactBoundaryIntersector
from straylight.thermal.model import thermal_scene
from straylight.thermal.sampling import AreaSampler
from straylight.thermal.walk import cast

R_IN, R_OUT, Z_STOP = 10.0, 30.0, 20.0


@pytest.fixture(scope="module")
def scene():
    # tolerance 1 mm: the coarsest covering mesh (24 sides), the widest slivers (r_in (1 - cos(pi/24)) = 0.086 mm)
    stop = analytic_part("stop", Plane(np.array([0.0, 0.0, Z_STOP]), np.array([0.0, 0.0, -1.0]), math.inf, 0.0, R_OUT,
                                       R_IN), role="absorber", tolerance_mm=1.0)
    det = analytic_part("det", Plane(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), math.inf, 0.0, 40.0),
                        role="detector", tolerance_mm=1.0)
    return thermal_scene(Scene((det, stop)), {}), stop


def _sliver_points(stop):
    """Points of the plane z = Z_STOP halfway between each chord of the inscribed hole polygon and the
    circle (inside the hole, on the mesh), and the same directions at R_IN + 0.05 (on the annulus)."""
    v = stop.vertices_mm
    rho = np.hypot(v[:, 0], v[:, 1])
    ring = v[np.abs(rho - R_IN) < 1e-9]
    ring = ring[np.argsort(np.arctan2(ring[:, 1], ring[:, 0]))]
    mid = 0.5 * (ring + np.roll(ring, -1, axis=0))
    unit = mid[:, :2] / np.hypot(mid[:, 0], mid[:, 1])[:, None]
    r_sliver = 0.5 * (np.hypot(mid[0, 0], mid[0, 1]) + R_IN)
    z = np.full((len(mid), 1), Z_STOP)
    return np.hstack([r_sliver * unit, z]), np.hstack([(R_IN + 0.05) * unit, z])


def test_casts_pass_the_slivers_and_stop_on_the_annulus(scene):
    ts, stop = scene
    assert isinstance(ts.intersector, ExactBoundaryIntersector)
    in_sliver, on_annulus = _sliver_points(stop)
    n = len(in_sliver)
    assert n == 24
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    o_sliver = in_sliver + [0.0, 0.0, 20.0]
    o_annulus = on_annulus + [0.0, 0.0, 20.0]
    stop_index, det_index = ts.part_index("stop"), ts.part_index("det")
    # the mesh alone stops the sliver rays on the stop's triangles
    raw = np.asarray(ts.intersector.inner.first_triangle(o_sliver, d))
    assert np.all(ts.triangle_part[raw] == stop_index)
    assert np.all(cast(ts, o_sliver, d).part == det_index)
    hit = cast(ts, o_annulus, d)
    assert np.all(hit.part == stop_index)
    np.testing.assert_allclose(hit.point[:, 2], Z_STOP, atol=1e-9)


def test_shadow_rays_pass_the_slivers(scene):
    ts, stop = scene
    in_sliver, on_annulus = _sliver_points(stop)
    d = np.tile([0.0, 0.0, -1.0], (len(in_sliver), 1))
    tmax = np.full(len(d), 39.0)  # from z = 40 to just above the detector
    assert np.all(np.asarray(ts.intersector.inner.occluded(in_sliver + [0, 0, 20.0], d, tmax)))
    assert not np.any(ts.intersector.occluded(in_sliver + [0, 0, 20.0], d, tmax))
    assert np.all(ts.intersector.occluded(on_annulus + [0, 0, 20.0], d, tmax))


def test_plane_part_area_and_samples_are_the_exact_annulus(scene):
    ts, _ = scene
    p = ts.part_index("stop")
    assert ts.part_area_mm2(p) == pytest.approx(math.pi * (R_OUT ** 2 - R_IN ** 2), rel=1e-15)
    pts, nrm = AreaSampler.of_part(ts, p).sample(np.random.default_rng(1).random((20_000, 3)))
    rho = np.hypot(pts[:, 0], pts[:, 1])
    assert rho.min() >= R_IN - 1e-12 and rho.max() <= R_OUT + 1e-12
    np.testing.assert_allclose(pts[:, 2], Z_STOP, atol=1e-12)
    np.testing.assert_allclose(nrm, np.tile([0.0, 0.0, -1.0], (len(nrm), 1)))
    # uniform in area: the fraction inside rho^2 <= (R_IN^2 + R_OUT^2) / 2 is 1/2; binomial sigma 0.0035
    assert abs(np.mean(rho ** 2 <= 0.5 * (R_IN ** 2 + R_OUT ** 2)) - 0.5) < 4 * 0.0036
