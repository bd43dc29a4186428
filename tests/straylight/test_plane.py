"""``triangle_planes`` (written out on blocks for speed) gives numpy's own cross product, norm and
mean bit for bit: the engine's numbers (tests/straylight/test_engine_golden.py) were recorded with
``np.cross`` / ``np.linalg.norm`` / ``tri.mean(axis=1)``."""
import numpy as np

from straylight.intersect._plane import PLANE_BLOCK, triangle_planes


def _numpy_planes(tri):
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return tri[:, 0], n / np.where(length > 0, length, 1.0), tri.mean(axis=1)


def test_triangle_planes_equal_numpys_bit_for_bit():
    rng = np.random.default_rng(3)
    m = 2 * PLANE_BLOCK + 7  # a partial last block
    scale = 10.0 ** rng.uniform(-4, 4, size=(m, 1, 1))
    tri = rng.normal(size=(m, 3, 3)) * scale + rng.normal(size=(m, 1, 3)) * 1e3
    tri[:5] = tri[:5, :1]  # degenerate: three equal corners (zero normal)
    tri[5:10, 2] = tri[5:10, 1]  # two equal corners
    tri[10:15, 2] = 2 * tri[10:15, 1] - tri[10:15, 0]  # collinear
    got = triangle_planes(tri)
    want = _numpy_planes(tri)
    for g, w in zip(got, want):
        assert g.shape == (m, 3) and g.flags.c_contiguous
        assert np.array_equal(g.view(np.uint64), np.ascontiguousarray(w).view(np.uint64))
    assert np.all(got[1][:5] == 0.0)


def test_triangle_planes_of_a_float32_mesh_and_of_one_triangle():
    tri32 = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0.1, 0.2, 0.3], [1.7, -2.2, 0.9], [0.4, 3.3, -1.1]]],
                     dtype=np.float32)
    for tri in (tri32, tri32[:1]):
        got, want = triangle_planes(tri), _numpy_planes(tri.astype(np.float64))
        assert all(np.array_equal(g, w) for g, w in zip(got, want))
    assert np.array_equal(triangle_planes(tri32)[1][0], [0.0, 0.0, 1.0])
