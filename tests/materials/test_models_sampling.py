"""Sampling helpers (materials.sampling): the radial inverse CDF of PHYSICS §3 against its own
inverse and against scipy's quadrature of the density (two implementations, one answer)."""
import math

import numpy as np
import pytest
from scipy import integrate, stats

from materials.sampling import (
    invert_cosine_hemisphere_sample,
    invert_radial_lobe_sample,
    radial_lobe_density,
    radial_lobe_norm,
    sample_cosine_hemisphere,
    sample_radial_lobe,
)


@pytest.mark.parametrize("s", [0.0, 1.0, 2.0, 2.0 + 1e-12, 2.6, 5.0])
def test_radial_lobe_normaliser_matches_scipy(s):
    l, r_max = 0.01, 1.7
    ref, _ = integrate.quad(lambda r: 2 * math.pi * r * (1 + r * r / l / l) ** (-s / 2), 0, r_max, points=[l, 10 * l], limit=200)
    np.testing.assert_allclose(radial_lobe_norm(l, s, r_max), ref, rtol=1e-8)


@pytest.mark.parametrize("s", [0.0, 2.0, 2.6, 4.0])
def test_radial_lobe_sample_round_trips_and_is_distributed_as_its_density(s):
    rng = np.random.default_rng(11)
    u = rng.random((20000, 2))
    l, r_max = 0.003, 1.5
    d = sample_radial_lobe(u, l, s, r_max)
    np.testing.assert_allclose(invert_radial_lobe_sample(d, l, s, r_max), u, atol=1e-9)
    # KS of the radius against the CDF integrated by scipy from the density
    r = np.hypot(d[:, 0], d[:, 1])
    probe = np.quantile(r, np.linspace(0.05, 0.95, 7))

    def cdf(x):
        val, _ = integrate.quad(
            lambda t: 2 * math.pi * t * radial_lobe_density(np.array([[t, 0.0]]), l, s, r_max)[0], 0, x, points=[l], limit=200
        )
        return val

    expected = np.array([cdf(x) for x in probe])
    empirical = np.array([(r <= x).mean() for x in probe])
    assert np.all(np.abs(empirical - expected) < 4 * np.sqrt(expected * (1 - expected) / len(r)))
    assert stats.kstest(invert_radial_lobe_sample(d, l, s, r_max)[:, 0], "uniform").pvalue > 1e-3


def test_cosine_hemisphere_round_trip():
    u = np.random.default_rng(5).random((1000, 2))
    w = sample_cosine_hemisphere(u)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(invert_cosine_hemisphere_sample(w), u, atol=1e-9)


def test_one_lobe_fast_path_is_the_broadcast_formula_bit_for_bit():
    """A lobe's scalar width and slope take one branch of the radial norm and draw (no np.where over
    both): the same bits as the broadcast formulation (forced here by a width of shape (1,)), near
    s = 2 and away from it, with zero, infinite and NaN r_max and edge uniforms."""
    rng = np.random.default_rng(12)
    n = 20_000
    r_max = 1.0 + rng.random(n)
    r_max[:10], r_max[10:20], r_max[20] = 0.0, np.inf, np.nan
    u2 = rng.random((n, 2))
    u2[:5], u2[5:10] = 0.0, 1.0 - 1e-16
    for l in (1e-4, 0.01, 0.3, 2.0):
        for s in (2.0, 2.0 + 1e-10, 2.3, 3.0, 1.5, 6.0):
            with np.errstate(all="ignore"):
                assert np.array_equal(radial_lobe_norm(l, s, r_max), radial_lobe_norm(np.full(1, l), s, r_max),
                                      equal_nan=True)
                assert np.array_equal(sample_radial_lobe(u2, l, s, r_max),
                                      sample_radial_lobe(u2, np.full(1, l), s, r_max), equal_nan=True)


@pytest.mark.parametrize("l, s", [(0.02, 2.4), (0.3, 3.0), (0.05, 2.0), (1e-4, 1.5)])
def test_compiled_lobe_direction_is_the_numpy_formulas(l, s):
    """A lobe's draws (composites' sample_direction): the compiled end of the radial draw and of the beta ->
    direction map gives :func:`lobe_direction_numpy`'s bits (signed zeros included): random incidences, normal and
    grazing incidence, uniforms 0 and next to 1, draws below the horizon, NaN directions and an empty batch."""
    from materials.sampling import lobe_direction, lobe_direction_numpy

    rng = np.random.default_rng(31)
    n = 100_000
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    wi[:10], wi[10:20] = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]
    wi[20:22] = np.nan
    u = rng.uniform(size=(n, 3))
    u[30:40, 1:], u[40:50, 1], u[50:60, 2] = 0.0, np.nextafter(1.0, 0.0), np.nextafter(1.0, 0.0)
    got, want = lobe_direction(wi, u, l, s), lobe_direction_numpy(wi, u, l, s)
    np.testing.assert_array_equal(got, want)
    assert np.array_equal(np.signbit(got), np.signbit(want))
    assert (want[:, 2] == 0).any() and (want[:, 2] > 0).any()
    assert lobe_direction(wi[:0], u[:0], l, s).shape == (0, 3)
