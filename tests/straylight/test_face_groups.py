"""The packed-key face grouping of the vertex tables gives numpy's row-unique ids exactly (the tables,
hence every traced number, stay bit-identical)."""
import numpy as np
import pytest

from straylight.engine.face_groups import dense_row_ids


@pytest.mark.parametrize("n", [1, 7, 5000])
def test_dense_row_ids_equal_row_unique(n):
    rng = np.random.default_rng(n)
    key = np.concatenate([rng.integers(0, 60, (n, 1)), rng.integers(-8, 9, (n, 3))], axis=1).astype(np.int64)
    assert np.array_equal(dense_row_ids(key), np.unique(key, axis=0, return_inverse=True)[1].ravel())


def test_wide_keys_fall_back_to_the_row_sort():
    key = np.array([[2**40, -(2**40)], [-(2**40), 2**40], [2**40, -(2**40)], [0, 0]], dtype=np.int64)
    assert np.array_equal(dense_row_ids(key), [2, 0, 2, 1])


def test_no_rows():
    assert dense_row_ids(np.zeros((0, 4), np.int64)).shape == (0,)
