"""Directional-hemispherical reflectance quadrature (materials.albedo) against independent values:
Lambertian rd (exact), the smooth-surface TIS identity (PHYSICS §1), Gauss-Legendre over (theta_r, phi_r)
for a wide lobe, and scipy.integrate for a sampler's mass inside the disk."""
import math

import numpy as np
import pytest
from scipy import integrate, special

from materials import Abg, KCorrelation, Lambertian, directional_hemispherical_reflectance
from materials.albedo import integrate_over_disk, pdf_integral
from materials.base import directions_from_angles


def test_lambertian_albedo_is_rd_at_every_incidence():
    th = np.deg2rad(np.arange(0.0, 90.0, 1.0))
    rho = directional_hemispherical_reflectance(Lambertian(rd=0.37), th)
    assert rho.shape == th.shape
    np.testing.assert_allclose(rho[:-1], 0.37, rtol=1e-6)  # the documented accuracy
    np.testing.assert_allclose(rho[-1], 0.37, rtol=1e-5)  # 89 deg: the disk edge touches beta0


@pytest.mark.parametrize("lc_um", [1.0, 50.0, 500.0])
def test_narrow_lobes_keep_the_tis_identity(lc_um):
    """lc up to 500 um at 532 nm: lobe widths ~1e-4 in beta. TIS = R (4 pi sigma / lambda)^2."""
    lobe = KCorrelation(sigma_nm=3.0, lc_um=lc_um, s=2.4, r=0.05, wavelength_nm=532.0)
    tis = integrate_over_disk(lambda wi, wo: lobe.brdf(wi, wo) / wo[:, 2], 0.0)
    np.testing.assert_allclose(tis, 0.05 * (4 * math.pi * 3.0 / 532.0) ** 2, rtol=1e-8)


def _panels(edges, n):
    x, w = special.roots_legendre(n)
    nodes, weights = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        nodes.append(0.5 * (b - a) * (x + 1) + a)
        weights.append(0.5 * (b - a) * w)
    return np.concatenate(nodes), np.concatenate(weights)


def test_wide_lobe_albedo_matches_gauss_legendre_in_theta_phi():
    """Independent quadrature in (theta_r, phi_r) with sin(theta_r) dtheta dphi (scipy Legendre
    roots, panels split at the specular direction) instead of the beta disk."""
    lobe = KCorrelation(sigma_nm=20.0, lc_um=0.8, s=3.0, n=1.5, wavelength_nm=532.0)
    theta_i = np.deg2rad(45.0)
    t, wt = _panels(np.deg2rad([0.0, 30, 40, 45, 50, 60, 90]), 64)
    p, wp = _panels(np.deg2rad([-180.0, -40, -10, 0, 10, 40, 180]), 64)
    tt, pp = np.meshgrid(t, p, indexing="ij")
    wi, wo = directions_from_angles(theta_i, tt.ravel(), pp.ravel())
    g = lobe.brdf(wi, wo, "s") * np.cos(tt.ravel()) * np.sin(tt.ravel())
    ref = float(wt @ g.reshape(tt.shape) @ wp)
    rho = directional_hemispherical_reflectance(lobe, theta_i, "s")
    assert ref > 1e-3
    np.testing.assert_allclose(rho, ref, rtol=1e-6)


def test_pdf_of_an_exact_lobe_sampler_integrates_to_the_disk_fraction():
    """ABg g = 2 draws r about beta0 out to 1 + |beta0|: the pdf integral over the unit disk equals
    the proposal mass inside it, which scipy computes in polar coordinates about beta0."""
    model = Abg(a=1e-3, b=0.04, g=2.0)
    b = math.sin(np.deg2rad(60.0))
    r_max = 1 + b
    norm = math.pi * 0.04 * math.log(1 + r_max**2 / 0.04)  # PHYSICS §3 normaliser, s = 2, l^2 = B

    def mass(psi):
        r_edge = -b * math.cos(psi) + math.sqrt(1 - (b * math.sin(psi)) ** 2)
        return 0.5 * 0.04 * math.log(1 + r_edge**2 / 0.04)  # integral of r / (1 + r^2 / B) dr

    inside, _ = integrate.quad(mass, 0, 2 * math.pi, limit=200)
    np.testing.assert_allclose(pdf_integral(model, np.deg2rad(60.0)), inside / norm, rtol=1e-7)
