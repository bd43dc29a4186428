"""Branch casts (split trees, eye chains) take the triangles from ``intersect_triangles`` and compute the
distance from the facet's plane themselves: the same triangles and the same bits as the path through
``intersect`` (which also computes plane distances that the cast then replaces)."""
import math

import numpy as np

from geometry.analytic import Plane
from straylight.engine.surface_geometry import _cast_with_distances, cast_branches
from straylight.intersect import EmbreeIntersector, ReferenceIntersector
from straylight.intersect._plane import triangle_planes
from straylight.intersect.exact_boundary import ExactBoundaryIntersector


def _disk_triangles(z_mm, radius_mm, n=24):
    """A fan of ``n`` triangles circumscribing a disk of ``radius_mm`` at height ``z_mm``."""
    r = radius_mm / math.cos(math.pi / n)
    phi = np.arange(n + 1) * 2 * math.pi / n
    rim = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n + 1, z_mm)], axis=1)
    centre = np.array([0.0, 0.0, z_mm])
    return np.array([[centre, rim[k], rim[k + 1]] for k in range(n)])


class _Scene:
    """What cast_branches reads of a CompiledScene."""

    def __init__(self, isect, triangles):
        v0, self.normals, _ = triangle_planes(triangles)
        self.isect = isect
        self.arrays = type("A", (), {"plane_d": np.einsum("ij,ij->i", self.normals, v0)})()


def _rays(n, seed):
    rng = np.random.default_rng(seed)
    origin = np.column_stack([rng.uniform(-12, 12, n), rng.uniform(-12, 12, n), np.full(n, 30.0)])
    d = np.column_stack([rng.normal(0, 0.3, n), rng.normal(0, 0.3, n), -np.ones(n)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]]  # edge-on to both planes
    origin[:3, 2] = 10.0  # in a plane of the disks
    return np.ascontiguousarray(origin), np.ascontiguousarray(d)


def test_branch_casts_match_the_intersect_path_bit_for_bit():
    tri = np.concatenate([_disk_triangles(10.0, 8.0), _disk_triangles(0.0, 10.0)])
    part = np.repeat([0, 1], 24)
    spec = type("S", (), {"triangle_part": part})()
    planes = {0: Plane(vertex_mm=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), outer_radius_mm=8.0,
                     inner_radius_mm=2.0)}
    origin, d = _rays(4000, 7)
    for isect in (EmbreeIntersector(tri), ExactBoundaryIntersector(EmbreeIntersector(tri), part, planes, 1e-6)):
        assert np.array_equal(isect.intersect_triangles(origin, d), isect.intersect(origin, d)[0])
        scene = _Scene(isect, tri)
        fast, slow = cast_branches(spec, scene, origin, d), _cast_with_distances(spec, scene, origin, d)
        assert len(fast.hit) > 1000 and len(fast.hit) < len(origin)
        for a, b in zip(fast, slow):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    # an intersector without intersect_triangles takes the path through intersect
    ref = _Scene(ReferenceIntersector(tri), tri)
    got, want = cast_branches(spec, ref, origin[:200], d[:200]), _cast_with_distances(spec, ref, origin[:200], d[:200])
    assert all(np.array_equal(a, b) for a, b in zip(got, want))
