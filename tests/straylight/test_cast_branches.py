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


def test_refined_hits_are_written_bit_for_bit_as_the_numpy_twin_writes_them():
    """refine_on_surfaces (each part's rows in one compiled pass) against refine_on_surfaces_numpy on a
    sphere, a plane annulus and a part without a surface: hits inside and outside the clear aperture, from
    both sides, and self-hits on the ray's own last part (passing); every output bit for bit."""
    from geometry.analytic import Conic
    from straylight.engine.surface_geometry import (at_interfaces, at_interfaces_numpy, refine_on_surfaces,
                                                    refine_on_surfaces_numpy)

    up = np.array([0.0, 0.0, 1.0])
    surfaces = [Conic(np.zeros(3), up, -40.0, 0.0, 12.0),
                Plane(vertex_mm=np.array([0.0, 0.0, -5.0]), axis=-up, outer_radius_mm=10.0, inner_radius_mm=2.0), None]
    spec = type("S", (), {"part_surfaces": surfaces})()
    rng = np.random.default_rng(11)
    n = 600
    part = rng.integers(0, 3, n)
    origin = np.column_stack([rng.uniform(-14, 14, n), rng.uniform(-14, 14, n), rng.choice([20.0, -20.0], n)])
    d = np.column_stack([rng.normal(0, 0.2, n), rng.normal(0, 0.2, n), -np.sign(origin[:, 2])])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    z = np.where(part == 1, -5.0, 0.0)
    dist = (z - origin[:, 2]) / d[:, 2] + rng.normal(0, 0.01, n)
    last = np.where(rng.random(n) < 0.1, part, 5)
    dist[last == part] = 1e-9  # at the ray's own origin on its last part
    facing = rng.normal(size=(n, 3))
    front = rng.random(n) < 0.5
    got = refine_on_surfaces(spec, part, origin, d, dist, last, front.copy(), facing.copy())
    want = refine_on_surfaces_numpy(spec, part, origin, d, dist, last, front.copy(), facing.copy())
    passing, refined = want[4], want[3]
    assert passing.sum() > 20 and refined.sum() > 100 and (part == 2).sum() > 100
    for a, b in zip(got, want):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    # and at_interfaces (the facets' sides and the points around it): triangles met from both sides
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    scene = type("Sc", (), {"normals": normals})()
    tri, cos_in = rng.integers(0, 50, n), rng.normal(size=n)
    got = at_interfaces(spec, scene, part, tri, origin, d, dist, last, cos_in)
    want = at_interfaces_numpy(spec, scene, part, tri, origin, d, dist, last, cos_in)
    for a, b in zip(got, want):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
