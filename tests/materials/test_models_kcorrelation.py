"""K-correlation lobe against independent references (PHYSICS §1).

* NIST SCATMECH golden table (Microroughness_BRDF_Model, ABC PSD, plus Lambertian 0.03).
* Dittman's K-correlation formula with constant R, written out here from PHYSICS §1.
* Total integrated scatter at normal incidence, R (4 pi sigma / lambda)^2 (Stover Eq. 2.8).
* The s = 2 branch as the limit s -> 2 (PHYSICS §1 values for the golden-table lobe).
"""
import math

import numpy as np
import pytest

from materials import KCorrelation, Lambertian, MaterialError
from materials.albedo import integrate_over_disk
from materials.base import directions_from_angles

# PHYSICS §1: lambda 0.532 um, n 1.5, sigma 0.010 um, Lc 2.0 um, s 2.6, + Lambertian Rd 0.03 (SCATMECH)
GOLDEN = np.array(
    [
        (10, 10.0, 1.50838e-01, 1.39687e-01),
        (10, 12.0, 8.31027e-02, 7.61502e-02),
        (10, 20.0, 1.32037e-02, 1.26139e-02),
        (45, 45.0, 1.70433e-01, 2.43528e-02),
        (45, 47.0, 1.21033e-01, 1.81363e-02),
        (45, 55.0, 2.02963e-02, 9.89642e-03),
        (80, 80.0, 6.63423e-02, 3.45205e-02),
        (80, 82.0, 5.69068e-02, 3.23008e-02),
    ]
)


def _golden_dirs():
    return directions_from_angles(np.deg2rad(GOLDEN[:, 0]), np.deg2rad(GOLDEN[:, 1]), 0.0)


@pytest.mark.parametrize("pol,col", [("s", 2), ("p", 3)])
def test_rayleigh_rice_matches_scatmech_golden_table(pol, col):
    lobe = KCorrelation(sigma_nm=10.0, lc_um=2.0, s=2.6, n=1.5, wavelength_nm=532.0)
    wi, wo = _golden_dirs()
    f = lobe.brdf(wi, wo, pol) + Lambertian(rd=0.03).brdf(wi, wo, pol)
    np.testing.assert_allclose(f, GOLDEN[:, col], rtol=1e-5, atol=0)


def test_unpolarized_is_the_mean_of_s_and_p():
    lobe = KCorrelation(sigma_nm=10.0, lc_um=2.0, s=2.6, n=1.5, wavelength_nm=532.0)
    wi, wo = directions_from_angles(np.deg2rad([10, 45, 80, 60]), np.deg2rad([12, 40, 85, 30]), np.deg2rad([0, 30, 90, 180]))
    np.testing.assert_allclose(lobe.brdf(wi, wo, "u"), 0.5 * (lobe.brdf(wi, wo, "s") + lobe.brdf(wi, wo, "p")), rtol=1e-14)


def _dittman(theta_i, theta_r, phi_r, sigma, lc_um, s, lam, r):
    """PHYSICS §1 Dittman K-correlation BRDF with dn = 2, exponent s/2 (written independently)."""
    b = 2 * math.pi * lc_um * 1e3
    dn = 2.0
    bx = np.sin(theta_r) * np.cos(phi_r) - np.sin(theta_i)
    by = np.sin(theta_r) * np.sin(phi_r)
    d2 = bx**2 + by**2
    cos = np.cos(theta_i) * np.cos(theta_r)
    if s == 2:
        k = 4 * math.pi * dn**2 * r * b**2 / lam**4 * sigma**2 / math.log(1 + (b / lam) ** 2)
        return k * cos / (1 + b**2 * d2 / lam**2)
    k = 2 * math.pi * dn**2 * r * b**2 / lam**4 * sigma**2 * (s - 2) / (1 - (1 + (b / lam) ** 2) ** (1 - s / 2))
    return k * cos / (1 + b**2 * d2 / lam**2) ** (s / 2)


@pytest.mark.parametrize("s", [1.5, 2.0, 2.6, 4.0])
def test_constant_r_is_dittmans_formula_in_and_out_of_plane(s):
    rng = np.random.default_rng(3)
    ti, tr, pr = rng.uniform(0, 1.5, 50), rng.uniform(0, 1.5, 50), rng.uniform(0, 2 * np.pi, 50)
    lobe = KCorrelation(sigma_nm=7.0, lc_um=3.0, s=s, r=0.05, weight=1.0, wavelength_nm=633.0)
    wi, wo = directions_from_angles(ti, tr, pr)
    expected = _dittman(ti, tr, pr, 7.0, 3.0, s, 633.0, 0.05)
    for pol in "spu":  # a constant R has no polarization dependence
        np.testing.assert_allclose(lobe.brdf(wi, wo, pol), expected, rtol=1e-12)
    half = KCorrelation(sigma_nm=7.0, lc_um=3.0, s=s, r=0.05, weight=0.5, wavelength_nm=633.0)
    np.testing.assert_allclose(half.brdf(wi, wo), 0.5 * expected, rtol=1e-12)


def test_s_equal_2_branch_is_the_limit():
    """PHYSICS §1: 0.054336 at s = 2.001, 0.054260 at 2.0001, 0.054251 at 2. Those values belong to a
    parameter set not given there; for the golden-table lobe at specular (sigma 10 nm, lc 2 um,
    532 nm) the relative steps ln f(s)/f(2) = (s - 2) ln(1 + (B/lambda)^2) / 4 + O((s-2)^2) are the
    ones these values show, so their ratios are checked (to their 5-digit rounding), plus the
    approach to the closed s = 2 formula."""
    wi, wo = directions_from_angles(np.deg2rad(30.0), np.deg2rad(30.0), 0.0)
    f = {s: KCorrelation(sigma_nm=10.0, lc_um=2.0, s=s, r=0.04, wavelength_nm=532.0).brdf(wi, wo)[0] for s in (2.001, 2.0001, 2.0)}
    assert f[2.0] > 0
    np.testing.assert_allclose(f[2.001] / f[2.0], 0.054336 / 0.054251, atol=3e-5)
    np.testing.assert_allclose(f[2.0001] / f[2.0], 0.054260 / 0.054251, atol=3e-5)
    np.testing.assert_allclose(f[2.0], _dittman(np.deg2rad(30), np.deg2rad(30), 0.0, 10.0, 2.0, 2, 532.0, 0.04), rtol=1e-12)
    # the general-s code just off 2 (no special branch) converges to the s = 2 branch
    for ds in (1e-6, 1e-7, -1e-7):
        g = KCorrelation(sigma_nm=10.0, lc_um=2.0, s=2 + ds, r=0.04, wavelength_nm=532.0).brdf(wi, wo)[0]
        assert abs(g / f[2.0] - 1) < 2 * abs(ds)


@pytest.mark.parametrize("s", [1.8, 2.0, 2.6, 3.5])
@pytest.mark.parametrize("lc_um", [0.5, 2.0, 50.0])
def test_total_integrated_scatter_at_normal_incidence(s, lc_um):
    """Dropping cos(theta_r) and integrating over |beta| < 1 gives R (4 pi sigma / lambda)^2 (PHYSICS §1)."""
    lobe = KCorrelation(sigma_nm=4.0, lc_um=lc_um, s=s, r=0.04, wavelength_nm=532.0)
    tis = integrate_over_disk(lambda wi, wo: lobe.brdf(wi, wo) / wo[:, 2], 0.0)
    expected = 0.04 * (4 * math.pi * 4.0 / 532.0) ** 2
    assert expected > 0
    np.testing.assert_allclose(tis, expected, rtol=1e-8)


def test_specular_value_is_fresnel_times_lobe_peak():
    """At specular Q_ss = R_s and Q_pp = R_p (PHYSICS §1), so f_n / f_r = R_s,p / r."""
    th = np.deg2rad([0.0, 10, 30, 45, 60, 70, 80])
    wi, wo = directions_from_angles(th, th, 0.0)
    with_n = KCorrelation(sigma_nm=5.0, lc_um=10.0, s=2.5, n=1.5, wavelength_nm=532.0)
    with_r = KCorrelation(sigma_nm=5.0, lc_um=10.0, s=2.5, r=1.0, wavelength_nm=532.0)
    rs = [0.0400, 0.0417, 0.0578, 0.0920, 0.1766, 0.2996, 0.5386]  # PHYSICS §1, n = 1.50
    rp = [0.0400, 0.0384, 0.0252, 0.0085, 0.0018, 0.0425, 0.2368]
    np.testing.assert_allclose(with_n.brdf(wi, wo, "s") / with_r.brdf(wi, wo), rs, atol=6e-5)
    np.testing.assert_allclose(with_n.brdf(wi, wo, "p") / with_r.brdf(wi, wo), rp, atol=6e-5)


def test_wavelength_comes_from_the_component_or_is_required():
    lobe = KCorrelation(sigma_nm=5.0, lc_um=10.0, s=2.5, n=1.5)
    wi, wo = directions_from_angles(0.3, 0.3, 0.0)
    with pytest.raises(MaterialError, match="wavelength_nm"):
        lobe.brdf(wi, wo)


@pytest.mark.parametrize(
    "kwargs,word",
    [
        (dict(sigma_nm=-1.0, lc_um=1.0, s=2.5, n=1.5), "sigma_nm"),
        (dict(sigma_nm=1.0, lc_um=0.0, s=2.5, n=1.5), "lc_um"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=-1.0, n=1.5), "'s'"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=2.5), "exactly one"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=2.5, n=1.5, r=0.1), "exactly one"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=2.5, r=1.5), "'r'"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=2.5, n=[1.5]), "'n'"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=2.5, n="glass"), "'n'"),
        (dict(sigma_nm=1.0, lc_um=1.0, s=2.5, n=1.5, weight=-2), "weight"),
    ],
)
def test_bad_parameters_are_refused_by_name(kwargs, word):
    with pytest.raises(MaterialError, match=word):
        KCorrelation(**kwargs)


def test_complex_index_round_trips_and_reduces_to_real():
    lobe = KCorrelation(sigma_nm=1.0, lc_um=1.0, s=2.5, n=[1.5, 0.2], wavelength_nm=532.0)
    assert lobe.to_dict()["n"] == [1.5, 0.2]
    assert KCorrelation(sigma_nm=1.0, lc_um=1.0, s=2.5, n=[1.5, 0.0]).n == 1.5
