"""Compiled cosine-hemisphere draws (materials.sampling) against the closed-form map and the cosine law."""
import math

import numpy as np
import pytest

from materials import Lambertian
from materials.sampling import sample_cosine_hemisphere, sample_cosine_hemisphere_weighted

N = 100_000


def test_cosine_draws_match_the_disk_map():
    """PHYSICS §3: uniform in the unit beta disk, r = sqrt(u0), phi = 2 pi u1, w_z = sqrt(1 - r^2)."""
    u = np.random.default_rng(5).random((N, 3))[:, 1:]
    w = sample_cosine_hemisphere(u)
    r = np.sqrt(u[:, 0])
    phi = 2 * np.pi * u[:, 1]
    np.testing.assert_allclose(w[:, 0], r * np.cos(phi), rtol=0, atol=1e-15)
    np.testing.assert_allclose(w[:, 1], r * np.sin(phi), rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    c = w[:, 2]
    for value, expected in ((c, 2 / 3), (c ** 2, 0.5)):  # cosine law: E[cos] = 2/3, E[cos^2] = 1/2
        assert abs(value.mean() - expected) < 4 * value.std() / math.sqrt(N)


def test_weighted_draws_weight_and_pdf():
    rng = np.random.default_rng(6)
    wi = rng.normal(size=(N, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    u = rng.random((N, 2))
    s = sample_cosine_hemisphere_weighted(wi, u, 0.25)
    np.testing.assert_array_equal(s.wo, sample_cosine_hemisphere(u))
    up = wi[:, 2] > 0
    assert 0.4 < up.mean() < 0.6
    np.testing.assert_array_equal(s.weight, np.where(up, 0.25, 0.0))
    np.testing.assert_allclose(s.pdf_per_sr, np.where(up, s.wo[:, 2] / np.pi, 0.0), rtol=1e-15, atol=0)
    one = sample_cosine_hemisphere_weighted(np.array([[0.0, 0.0, 1.0]]), u[:3], 0.5)  # (1, 3) wi broadcasts
    np.testing.assert_array_equal(one.weight, 0.5)
    with pytest.raises(ValueError, match="wi"):
        sample_cosine_hemisphere_weighted(wi[:2], u[:3], 0.5)


def test_lambertian_sample_albedo():
    """E[weight] over the hemisphere = rd (seed paper Eq. 2: a Lambertian DHR is rd at every incidence)."""
    u = np.random.default_rng(7).random((N, 3))
    wi = np.tile([math.sin(1.0), 0.0, math.cos(1.0)], (N, 1))
    s = Lambertian(0.3).sample(wi, u)
    assert np.all(s.weight == 0.3)
    np.testing.assert_allclose(Lambertian(0.3).pdf(wi, s.wo), s.pdf_per_sr, rtol=1e-15)


def test_one_compiled_loop_for_any_layout_of_the_uniforms():
    """A column view of (n, 3) uniforms (Lambertian's ``direction_uniforms``) and a contiguous (n, 2) array run
    the same compiled loop (numba types each layout apart: another kernel to load at each start)."""
    from materials.sampling import _COMPILED, _cosine_hemisphere_loop

    u = np.random.default_rng(3).random((50, 3))
    a = sample_cosine_hemisphere(u[:, 1:])
    b = sample_cosine_hemisphere(np.ascontiguousarray(u[:, 1:]))
    np.testing.assert_array_equal(a, b)
    assert len(_COMPILED[_cosine_hemisphere_loop].signatures) == 1, _COMPILED[_cosine_hemisphere_loop].signatures
