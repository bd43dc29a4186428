"""Sources and detector area sampling against their analytic moments (fixed seeds, 4-sigma bounds)."""
import math

import numpy as np
import pytest

from straylight.detectors import DetectorGeometry
from straylight.sources import (
    CollimatedDisk, LambertianDisk, PointSource, SourceError, orthonormal_basis, source_from_dict,
)

N = 200_000


def _u(seed=0):
    return np.random.default_rng(seed).random((N, 4))


def test_orthonormal_basis_is_right_handed():
    n = np.random.default_rng(1).normal(size=(1000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[0] = [0, 0, -1]
    t, b = orthonormal_basis(n)
    np.testing.assert_allclose(np.cross(t, b), n, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", t, n), 0, atol=1e-12)


def test_lambertian_disk_emits_a_cosine_distribution():
    """E[cos] = 2/3 and E[cos^2] = 1/2 for a cosine law; origins uniform: E[r^2] = R^2 / 2."""
    src = LambertianDisk([1, 2, 3], [0, 1, 0], 5.0)
    o, d = src.emit(_u())
    c = d[:, 1]
    assert np.all(c >= 0)
    for value, expected in ((c, 2 / 3), (c ** 2, 0.5)):
        assert abs(value.mean() - expected) < 4 * value.std() / math.sqrt(N)
    r2 = ((o - [1, 2, 3]) ** 2).sum(axis=1)
    np.testing.assert_allclose(o[:, 1], 2.0)
    assert abs(r2.mean() - 12.5) < 4 * r2.std() / math.sqrt(N)


def test_point_source_cone_is_uniform_in_solid_angle():
    """Within a cone of half angle a, cos(theta) is uniform on [cos a, 1]."""
    src = PointSource([0, 0, 0], axis=[1, 0, 0], half_angle_deg=30.0)
    _, d = src.emit(_u(2))
    c = d[:, 0]
    lo = math.cos(math.radians(30))
    assert c.min() >= lo - 1e-12
    assert abs(c.mean() - (1 + lo) / 2) < 4 * c.std() / math.sqrt(N)


def test_collimated_disk_keeps_its_direction():
    src = CollimatedDisk([0, 0, 10], [0, 0, -1], [0.1, 0, -1], 3.0)
    o, d = src.emit(_u(3))
    np.testing.assert_allclose(d, np.broadcast_to(src.direction, d.shape))
    assert np.hypot(o[:, 0], o[:, 1]).max() <= 3.0


def test_source_dict_errors_name_the_key():
    with pytest.raises(SourceError, match="radius_mm"):
        source_from_dict({"type": "lambertian_disk", "center_mm": [0, 0, 0], "normal": [0, 0, 1]})
    with pytest.raises(SourceError, match="unknown source type 'laser'"):
        source_from_dict({"type": "laser"})
    with pytest.raises(SourceError, match="radius_mm must be > 0"):
        source_from_dict({"type": "lambertian_disk", "center_mm": [0, 0, 0], "normal": [0, 0, 1], "radius_mm": -1})


def test_detector_area_sampling_is_uniform():
    """Triangles chosen in proportion to area (chi-square, 49 dof) and points inside them."""
    rng = np.random.default_rng(4)
    tri = rng.random((50, 3, 3)) * [10, 10, 0]
    geo = DetectorGeometry.from_triangles(tri)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    u = rng.random((N, 3))
    k = geo._pick_triangle(u[:, 0])
    expected = N * area / area.sum()
    chi2 = (((np.bincount(k, minlength=50) - expected) ** 2) / expected).sum()
    assert chi2 < 90  # 49 dof: P(chi2 > 90) ~ 3e-4
    pts, normals = geo.sample(u)
    assert abs(abs(normals[:, 2]).min() - 1) < 1e-12
    # mean of points = area-weighted centroid of the triangles
    centroid = (tri.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()
    err = pts.std(axis=0) / math.sqrt(N)
    assert np.all(np.abs(pts.mean(axis=0) - centroid)[:2] < 4 * err[:2])
