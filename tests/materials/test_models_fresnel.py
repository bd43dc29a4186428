"""Fresnel reflectance and Rayleigh-Rice polarization factors (PHYSICS §1; Born & Wolf §1.5)."""
import numpy as np
import pytest

from materials import fresnel_reflectance, polarization_factor
from materials.fresnel import scatter_azimuth

ANGLES_DEG = [0, 10, 30, 45, 60, 70, 80]
RS = [0.0400, 0.0417, 0.0578, 0.0920, 0.1766, 0.2996, 0.5386]  # PHYSICS §1, n = 1.50
RP = [0.0400, 0.0384, 0.0252, 0.0085, 0.0018, 0.0425, 0.2368]


def test_fresnel_check_values():
    th = np.deg2rad(ANGLES_DEG)
    np.testing.assert_allclose(fresnel_reflectance(th, 1.5, "s"), RS, atol=5e-5)
    np.testing.assert_allclose(fresnel_reflectance(th, 1.5, "p"), RP, atol=5e-5)
    np.testing.assert_allclose(fresnel_reflectance(th, 1.5, "u"), 0.5 * (np.array(RS) + np.array(RP)), atol=5e-5)


def test_brewster_angle_and_metal_normal_incidence():
    assert fresnel_reflectance(np.arctan(1.55), 1.55, "p") < 1e-25
    n, k = 0.96, 6.69  # ((n-1)^2 + k^2) / ((n+1)^2 + k^2) at normal incidence, any textbook
    expected = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    np.testing.assert_allclose(fresnel_reflectance(0.0, complex(n, k), "s"), expected, rtol=1e-12)
    np.testing.assert_allclose(fresnel_reflectance(0.0, [n, k], "p"), expected, rtol=1e-12)


def _in_plane(theta_i, theta_r, cos_phi, n):
    """PHYSICS §1 in-plane Q_ss, Q_pp, written out independently."""
    eps = complex(n) ** 2
    qi = np.sqrt(eps - np.sin(theta_i) ** 2 + 0j)
    qr = np.sqrt(eps - np.sin(theta_r) ** 2 + 0j)
    ci, cr = np.cos(theta_i), np.cos(theta_r)
    qss = np.abs((eps - 1) * cos_phi / ((ci + qi) * (cr + qr))) ** 2
    qpp = np.abs(
        (eps - 1) * (qi * qr * cos_phi - eps * np.sin(theta_i) * np.sin(theta_r)) / ((eps * ci + qi) * (eps * cr + qr))
    ) ** 2
    return qss, qpp


@pytest.mark.parametrize("n", [1.5, complex(1.6, 0.05), complex(0.96, 6.69)])
@pytest.mark.parametrize("cos_phi", [1.0, -1.0])
def test_in_plane_polarization_factors(n, cos_phi):
    ti = np.deg2rad(np.array([5.0, 30, 45, 70, 85]))
    tr = np.deg2rad(np.array([12.0, 3, 60, 20, 80]))
    qss, qpp = _in_plane(ti, tr, cos_phi, n)
    args = (np.cos(ti), np.cos(tr), np.full(5, cos_phi), np.zeros(5), n)
    np.testing.assert_allclose(polarization_factor(*args, "s"), qss, rtol=1e-12)
    np.testing.assert_allclose(polarization_factor(*args, "p"), qpp, rtol=1e-12)


@pytest.mark.parametrize("n", [1.5, complex(2.0, 0.5)])
def test_specular_factor_equals_fresnel(n):
    th = np.deg2rad(np.array(ANGLES_DEG, float))
    c = np.cos(th)
    one, zero = np.ones_like(th), np.zeros_like(th)
    for pol in "spu":
        np.testing.assert_allclose(
            polarization_factor(c, c, one, zero, n, pol), fresnel_reflectance(th, n, pol), rtol=1e-12
        )


def test_cross_polarized_terms_fill_out_of_plane():
    """At phi_r = 90 deg the co-polarized ss term vanishes (cos phi = 0); s incidence reads |ps|^2 > 0."""
    ci, cr = np.array([np.cos(0.5)]), np.array([np.cos(0.7)])
    q_s = polarization_factor(ci, cr, np.array([0.0]), np.array([1.0]), 1.5, "s")
    eps = 2.25
    qr = np.sqrt(eps - np.sin(0.7) ** 2)
    qi = np.sqrt(eps - np.sin(0.5) ** 2)
    ps = (eps - 1) * qr / ((ci + qi) * (eps * cr + qr))
    np.testing.assert_allclose(q_s, ps**2, rtol=1e-12)
    assert q_s[0] > 0


def test_scatter_azimuth_is_measured_from_the_specular_half_plane():
    wi = np.array([[-np.sin(0.4) * np.cos(0.3), -np.sin(0.4) * np.sin(0.3), np.cos(0.4)]])  # incidence azimuth 0.3 + pi
    phi = 0.3 + 0.25
    wo = np.array([[np.sin(0.9) * np.cos(phi), np.sin(0.9) * np.sin(phi), np.cos(0.9)]])
    c, s = scatter_azimuth(wi, wo)
    np.testing.assert_allclose([c[0], s[0]], [np.cos(0.25), np.sin(0.25)], rtol=1e-12)
