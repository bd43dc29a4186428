"""GGX microfacet lobe: Fresnel table, normalisation, reciprocity, energy, sampler vs quadrature."""
import numpy as np
import pytest

from materials.base import directions_from_angles
from materials.microfacet import Microfacet, fresnel_rs_rp
from materials.registry import build_component


def _hemisphere(n_theta=300, n_phi=300):
    """Midpoint grid over the upper hemisphere: directions (m, 3) and solid-angle weights (m,)."""
    t = (np.arange(n_theta) + 0.5) * (np.pi / 2) / n_theta
    p = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    T, P = np.meshgrid(t, p, indexing="ij")
    w = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    d_omega = (np.sin(T) * (np.pi / 2 / n_theta) * (2 * np.pi / n_phi)).ravel()
    return w, d_omega


def _rho_quadrature(model, theta_i, polarization="u"):
    wo, d_omega = _hemisphere()
    wi = np.tile([-np.sin(theta_i), 0.0, np.cos(theta_i)], (len(wo), 1))
    return float(np.sum(model.brdf(wi, wo, polarization) * wo[:, 2] * d_omega))


def test_fresnel_matches_physics_table():
    # PHYSICS §1, n = 1.50 at 0, 10, 30, 45, 60, 70, 80 deg
    th = np.radians([0, 10, 30, 45, 60, 70, 80])
    rs, rp = fresnel_rs_rp(np.cos(th), 1.5)
    np.testing.assert_allclose(rs, [0.0400, 0.0417, 0.0578, 0.0920, 0.1766, 0.2996, 0.5386], atol=6e-5)
    np.testing.assert_allclose(rp, [0.0400, 0.0384, 0.0252, 0.0085, 0.0018, 0.0425, 0.2368], atol=6e-5)


@pytest.mark.parametrize("alpha", [0.1, 0.5])
@pytest.mark.parametrize("theta_i_deg", [0.0, 60.0, 85.0])
def test_visible_normals_are_normalised(alpha, theta_i_deg):
    """Heitz 2014 Eq. 20: integral of G1(wi) max(0, wi.h) D(h) dh / cos(theta_i) = 1 (checks D with Lambda)."""
    m = Microfacet(alpha=alpha)
    h, d_omega = _hemisphere(800, 200)
    ti = np.radians(theta_i_deg)
    wi = np.array([-np.sin(ti), 0.0, np.cos(ti)])
    g1 = 1.0 / (1.0 + m.smith_lambda(np.cos(ti)))
    total = np.sum(g1 * np.maximum(0.0, h @ wi) * m.distribution(h[:, 2]) * d_omega) / np.cos(ti)
    assert total == pytest.approx(1.0, abs=3e-3)


def _random_up(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_reciprocity_and_non_negativity():
    """Unpolarized: reciprocal for any directions. s and p: reciprocal in the plane of incidence
    (out of it a polarized reading without analyser need not be, as for Rayleigh-Rice Q_s)."""
    rng = np.random.default_rng(1)
    m = Microfacet(alpha=0.35, n=[1.6, 0.2])
    a, b = _random_up(rng, 2000), _random_up(rng, 2000)
    f_ab, f_ba = m.brdf(a, b, "u"), m.brdf(b, a, "u")
    assert np.all(f_ab >= 0) and f_ab.max() > 0
    np.testing.assert_allclose(f_ab, f_ba, rtol=1e-12)
    t_i, t_r = rng.uniform(0, 1.5, 500), rng.uniform(0, 1.5, 500)
    wi, wo = directions_from_angles(t_i, t_r, 0.0)
    back_i, back_o = directions_from_angles(t_r, t_i, 0.0)
    for pol in "sp":
        f1, f2 = m.brdf(wi, wo, pol), m.brdf(back_i, back_o, pol)
        assert np.all(f1 > 0)
        np.testing.assert_allclose(f1, f2, rtol=1e-12)


def test_polarization_in_plane_is_facet_fresnel_and_s_equals_p_at_normal_incidence():
    m = Microfacet(alpha=0.3, n=1.5)
    # in the plane of incidence the facet's s is the sample's s: f_s / f_u = 2 R_s / (R_s + R_p)
    wi, wo = directions_from_angles(np.radians(60.0), np.radians(20.0), 0.0)
    h = (wi + wo) / np.linalg.norm(wi + wo)
    rs, rp = fresnel_rs_rp(np.sum(wi * h), 1.5)
    assert m.brdf(wi, wo, "s")[0] / m.brdf(wi, wo, "u")[0] == pytest.approx(2 * rs / (rs + rp), rel=1e-12)
    # at normal incidence the hemisphere has no preferred plane: rho_s = rho_p
    rho_s, rho_p = _rho_quadrature(m, 0.0, "s"), _rho_quadrature(m, 0.0, "p")
    assert rho_s > 0.01 and rho_s == pytest.approx(rho_p, rel=1e-6)


@pytest.mark.parametrize("theta_i_deg", [0.0, 45.0, 80.0])
def test_energy_below_one_even_for_a_perfect_conductor(theta_i_deg):
    # F ~ 1 (n = 1 + 60i); single-scatter GGX can only lose energy: rho <= 1.
    # At normal incidence the visible normals have CDF P(tan theta_h < t) = t^2 / (alpha^2 + t^2)
    # (GGX slope distribution), and facets tilted beyond 45 deg reflect below the horizon,
    # so rho(0) <= 1 / (1 + alpha^2); shadowing of wo removes a little more.
    alpha = 0.2
    m = Microfacet(alpha=alpha, n=[1.0, 60.0])
    rho = _rho_quadrature(m, np.radians(theta_i_deg))
    assert 0.5 < rho < 1.0
    if theta_i_deg == 0.0:
        assert 0.97 / (1 + alpha**2) < rho < 1.0 / (1 + alpha**2)


def test_sampler_weight_mean_matches_quadrature():
    """MC mean of weights = rho (quadrature); tolerance 4 standard errors of the run, fixed seed."""
    m = Microfacet(alpha=0.4, n=1.5)
    ti = np.radians(70.0)
    n = 200_000
    u = np.random.default_rng(7).random((n, 3))
    wi = np.tile([-np.sin(ti), 0.0, np.cos(ti)], (n, 1))
    s = m.sample(wi, u, "s")
    rho = _rho_quadrature(m, ti, "s")
    assert rho > 0.05
    sem = s.weight.std(ddof=1) / np.sqrt(n)
    assert abs(s.weight.mean() - rho) < 4 * sem + 2e-4 * rho  # + quadrature error
    # pdf returned equals pdf() and integrates to the fraction of draws above the horizon
    good = s.weight > 0
    np.testing.assert_allclose(s.pdf_per_sr[good], m.pdf(wi[good], s.wo[good]), rtol=1e-10)
    wo, d_omega = _hemisphere()
    pdf_mass = np.sum(m.pdf(np.tile(wi[0], (len(wo), 1)), wo) * d_omega)
    frac = good.mean()
    assert abs(pdf_mass - frac) < 4 * np.sqrt(frac * (1 - frac) / n) + 2e-3


def test_peak_lies_beyond_specular_at_grazing():
    m = Microfacet(alpha=0.3, n=1.5)
    f = m.brdf(*directions_from_angles(np.radians(70.0), np.radians([70.0, 75.0, 80.0]), 0.0))
    assert f[1] > f[0] and f[2] > f[1]


def test_registry_round_trip_and_bad_parameters():
    m = build_component({"type": "microfacet", "alpha": 0.2, "n": [1.5, 0.01], "weight": 0.5})
    assert build_component(m.to_dict()).to_dict() == m.to_dict()
    with pytest.raises(ValueError, match="alpha"):
        Microfacet(alpha=-1.0)
