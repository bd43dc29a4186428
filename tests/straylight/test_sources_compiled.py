"""The compiled CollimatedDisk.emit against the closed-form disk map and its analytic moments."""
import math

import numpy as np
import pytest

from straylight.sources import CollimatedDisk, SourceError, orthonormal_basis

N = 100_000


def test_collimated_disk_matches_the_closed_form_map():
    """o = c + R sqrt(u0) (cos(2 pi u1) t + sin(2 pi u1) b), on a tilted disk, from a strided u view."""
    src = CollimatedDisk([1.0, -2.0, 30.0], [0.3, 0.1, -1.0], [0.2, 0.0, -1.0], 7.0)
    u = np.random.default_rng(4).random((N, 5))[:, 1:5]  # what the tracer passes: a column view
    o, d = src.emit(u)
    t, b = orthonormal_basis(src.normal)
    r = 7.0 * np.sqrt(u[:, 0])
    phi = 2 * np.pi * u[:, 1]
    expected = src.center_mm + (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b
    np.testing.assert_allclose(o, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(d, np.broadcast_to(src.direction, (N, 3)))
    rel = o - src.center_mm
    np.testing.assert_allclose(rel @ src.normal, 0.0, atol=1e-12)  # in the disk's plane
    r2 = (rel ** 2).sum(axis=1)
    assert r2.max() <= 49.0 * (1 + 1e-12)
    assert abs(r2.mean() - 49.0 / 2) < 4 * r2.std() / math.sqrt(N)  # uniform over the area: E[r^2] = R^2/2


def test_collimated_disk_rejects_bad_uniforms():
    src = CollimatedDisk([0, 0, 0], [0, 0, 1], [0, 0, -1], 1.0)
    with pytest.raises(SourceError, match="uniforms"):
        src.emit(np.zeros((4, 1)))
    o, d = src.emit(np.zeros((0, 4)))
    assert o.shape == d.shape == (0, 3)


def test_one_compiled_loop_for_strided_and_contiguous_uniforms():
    """emit() of a column view (the tracer's) and of a contiguous array (the checks') run the same compiled loop:
    numba types each array layout apart, and each is a kernel to load from the cache at every start (~3 ms)."""
    from materials.sampling import _COMPILED
    from straylight.sources import _collimated_loop

    src = CollimatedDisk([0, 0, 0], [0, 0, 1], [0, 0, -1], 1.0)
    u = np.random.default_rng(1).random((64, 5))
    strided, _ = src.emit(u[:, 1:])
    contiguous, _ = src.emit(np.ascontiguousarray(u[:, 1:]))
    src.emit(u[:1, 1:])  # one row: numba would type this view 'C'
    np.testing.assert_array_equal(strided, contiguous)
    assert len(_COMPILED[_collimated_loop].signatures) == 1, _COMPILED[_collimated_loop].signatures
