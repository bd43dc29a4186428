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
