"""The engine's shortcuts for numpy calls give numpy's own bits (the walk's numbers must not move)."""
from __future__ import annotations

import numpy as np

from materials.mueller import cross_rows, norm_rows
from straylight.engine.material_groups import distinct


def test_distinct_is_np_unique():
    rng = np.random.default_rng(0)
    for a in (rng.integers(0, 7, 1000), rng.integers(-1, 3, 500), np.zeros(0, np.int64),
              rng.integers(0, 4, 300).astype(np.int16), np.array([5])):
        assert np.array_equal(distinct(a), np.unique(a))


def test_cross_and_norm_rows_are_numpys_bits():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(5000, 3)), rng.normal(size=(5000, 3))
    a[:10] = 0.0
    a[10:20, 1] = -0.0
    got, want = cross_rows(a, b), np.cross(a, b)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    assert np.array_equal(norm_rows(a), np.linalg.norm(a, axis=1))


def test_plane_distance_kernel_is_the_numpy_formula():
    from straylight.intersect._plane import plane_distance, plane_distance_numpy, triangle_planes

    rng = np.random.default_rng(2)
    v0, normal, centroid = triangle_planes(rng.normal(size=(300, 3, 3)) * 100)
    n = 20000
    tri = rng.integers(0, 300, n)
    o = rng.normal(size=(n, 3)) * 100
    d = rng.normal(size=(n, 3))
    d[:200] = np.cross(normal[tri[:200]], d[:200])  # edge-on: the centroid's projection
    d /= np.linalg.norm(d, axis=1)[:, None]
    o[200:300] = v0[tri[200:300]]  # on the plane: 0
    got, want = plane_distance(v0, normal, centroid, tri, o, d), plane_distance_numpy(v0, normal, centroid, tri, o, d)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))


def test_refusal_kernel_is_the_numpy_formula():
    """Rays aimed at a disk's covering polygon: the slivers outside the exact disk refused alike."""
    import math

    from geometry.analytic import Plane, analytic_part
    from geometry.mesh import Scene
    from straylight.intersect.embree import EmbreeIntersector
    from straylight.intersect.exact_boundary import ExactBoundaryIntersector, plane_parts

    disk = Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]), math.inf, 0.0, 5.0, 0.5)
    scene = Scene((analytic_part("disk", disk, "grey"),))
    ex = ExactBoundaryIntersector(EmbreeIntersector(scene.triangles_mm), scene.triangle_part,
                                  plane_parts([disk]), 1e-6)
    rng = np.random.default_rng(3)
    n = 20000
    target = np.column_stack([rng.uniform(-5.5, 5.5, (n, 2)), np.zeros(n)])
    o = target + np.column_stack([rng.normal(size=(n, 2)), np.full(n, 10.0)])
    d = target - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    tri = ex.inner.first_triangle(o, d)
    (r1, t1), (r2, t2) = ex._refused(tri, o, d), ex._refused_numpy(tri, o, d)
    assert r2.any() and (tri >= 0).any() and (tri < 0).any()
    assert np.array_equal(r1, r2) and np.array_equal(t1, t2)


def test_s_vector_and_stokes_rotation_kernels_are_the_numpy_formulas():
    from materials.mueller import rotate_stokes, rotate_stokes_numpy, s_vector, s_vector_numpy

    rng = np.random.default_rng(4)
    n = 20000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    nrm = rng.normal(size=(n, 3))
    nrm[:100] = d[:100]  # normal incidence: the d x x rule
    d[100:150] = [1.0, 0.0, 0.0]  # ... and d x y where d x x vanishes
    nrm[100:150] = [-1.0, 0.0, 0.0]
    got, want = s_vector(d, nrm), s_vector_numpy(d, nrm)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    S, e_to = rng.normal(size=(n, 4)), s_vector_numpy(d, rng.normal(size=(n, 3)))
    got, want = rotate_stokes(S, want, e_to, d), rotate_stokes_numpy(S, want, e_to, d)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))


def test_interface_mueller_product_is_einsum_over_the_matrix():
    """``apply_interface_mueller`` (no 4x4 matrix formed) gives einsum's bits over ``interface_mueller``,
    forward and transposed, signed zeros included: real and complex (total internal reflection,
    absorbing) amplitudes, zero amplitudes, zero and -0 Stokes components."""
    from materials.mueller import apply_interface_mueller, apply_interface_mueller_numpy

    rng = np.random.default_rng(4)
    n = 60_000
    a_s, a_p = rng.normal(size=n) + 1j * rng.normal(size=n), rng.normal(size=n) + 1j * rng.normal(size=n)
    a_s[:20_000], a_p[:20_000] = a_s[:20_000].real, a_p[:20_000].real  # a dielectric below TIR
    a_p[:300] = 0.0
    a_s[300:400] = 0.0
    S = rng.normal(size=(n, 4))
    S[:30_000:3, 2:] = 0.0
    S[1:30_000:3, 2] = -0.0
    S[2:30_000:3, :2] = -0.0
    S[::7, 0] = 0.0
    for transpose in (False, True):
        got = apply_interface_mueller(a_s, a_p, S, transpose)
        want = apply_interface_mueller_numpy(a_s, a_p, S, transpose)
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    assert not np.array_equal(apply_interface_mueller(a_s, a_p, S, True), apply_interface_mueller(a_s, a_p, S))
    assert apply_interface_mueller(a_s[:0], a_p[:0], S[:0]).shape == (0, 4)


def test_take_rows_is_fancy_indexing():
    """``take_rows`` (np.take along the rows) copies what ``a[index]`` copies: 2-D and 1-D, float, int and
    bool arrays, repeated, unordered and negative indices, empty; a boolean mask as numpy takes it."""
    from straylight.engine.vec3 import take_rows

    rng = np.random.default_rng(5)
    for a in (rng.normal(size=(500, 3)), rng.integers(-5, 5, size=(500, 8)), rng.normal(size=500),
              rng.random(500) < 0.5, rng.normal(size=(500, 4))[::2]):
        for index in (rng.integers(0, len(a), 300), np.array([len(a) - 1, -1, 0, 0, 3]), np.zeros(0, np.int64),
                      np.flatnonzero(rng.random(len(a)) < 0.3)):
            got = take_rows(a, index)
            assert got.dtype == a[index].dtype and np.array_equal(got, a[index])
        mask = rng.random(len(a)) < 0.5
        assert np.array_equal(take_rows(a, mask), a[mask])
