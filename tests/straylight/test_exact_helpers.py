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
