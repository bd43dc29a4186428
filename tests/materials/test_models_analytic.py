"""Lambertian, ABg, Harvey-Shack and tabulated models against closed forms (PHYSICS §2, STYLE §2)."""
import math

import numpy as np
import pytest

from materials import Abg, HarveyShack, KCorrelation, Lambertian, MaterialError, Tabulated
from materials.albedo import directional_hemispherical_reflectance
from materials.base import directions_from_angles


def _pairs(n=500, seed=1):
    rng = np.random.default_rng(seed)
    return directions_from_angles(rng.uniform(0, 1.5, n), rng.uniform(0, 1.5, n), rng.uniform(0, 2 * np.pi, n))


def test_lambertian_is_rd_over_pi_and_samples_with_weight_rd():
    wi, wo = _pairs()
    np.testing.assert_allclose(Lambertian(rd=0.2).brdf(wi, wo), 0.2 / math.pi, rtol=1e-15)
    s = Lambertian(rd=0.2).sample(wi, np.random.default_rng(0).random((len(wi), 3)))
    np.testing.assert_allclose(s.weight, 0.2, rtol=1e-15)
    np.testing.assert_allclose(s.pdf_per_sr, s.wo[:, 2] / math.pi, rtol=1e-15)


@pytest.mark.parametrize("rd", [-0.1, 1.0, 1.5, float("nan"), "0.1"])
def test_lambertian_rd_outside_unit_interval_is_refused(rd):
    with pytest.raises(MaterialError, match="rd"):
        Lambertian(rd=rd)


def test_abg_with_g_zero_is_lambertian():
    """g = 0: f = A / (B + 1), rho = pi A / (B + 1) (STYLE §2)."""
    model = Abg(a=0.002, b=0.05, g=0.0)
    wi, wo = _pairs()
    np.testing.assert_allclose(model.brdf(wi, wo), 0.002 / 1.05, rtol=1e-14)
    rho = directional_hemispherical_reflectance(model, np.deg2rad([0.0, 30, 60, 85]))
    np.testing.assert_allclose(rho, math.pi * 0.002 / 1.05, rtol=1e-8)


@pytest.mark.parametrize("g", [1.0, 1.7, 2.0, 3.0])
def test_abg_log_log_slope_far_from_specular_is_minus_g(g):
    model = Abg(a=1e-3, b=1e-8, g=g)
    x = np.array([0.3, 0.6])  # |beta - beta0| in the plane at normal incidence
    wi, wo = directions_from_angles(0.0, np.arcsin(x), 0.0)
    f = model.brdf(wi, wo)
    slope = np.diff(np.log(f)) / np.diff(np.log(x))
    np.testing.assert_allclose(slope, -g, rtol=1e-6)


def test_abg_with_g_two_equals_harvey_shack_and_samples_exactly():
    """PHYSICS §2: ABg = Harvey-Shack for g = 2 with B = l^2, A = b0 l^2, s = -2."""
    b0, l = 30.0, 0.02
    wi, wo = _pairs()
    np.testing.assert_allclose(Abg(a=b0 * l * l, b=l * l, g=2.0).brdf(wi, wo), HarveyShack(b0=b0, l=l, s=-2.0).brdf(wi, wo), rtol=1e-12)
    # exact sampler: constant weight above the horizon (the normaliser times A/B)
    wi, _ = directions_from_angles(np.full(1000, 0.5), 0.0, 0.0)
    s = Abg(a=b0 * l * l, b=l * l, g=2.0).sample(wi, np.random.default_rng(2).random((1000, 3)))
    w = s.weight[s.weight > 0]
    assert w.size > 500  # sanity: most draws land above the horizon (s = 2 tails reach beyond it)
    np.testing.assert_allclose(w, w[0], rtol=1e-9)


def test_harvey_shack_is_the_k_correlation_shape_without_cosines():
    """PHYSICS §2: l = lambda / B, S = -s, b0 = Dittman prefactor (x R) times the cosines."""
    lobe = KCorrelation(sigma_nm=6.0, lc_um=4.0, s=2.8, r=0.05, wavelength_nm=532.0)
    b = 2 * math.pi * 4.0e3
    wi, wo = _pairs()
    b0 = lobe.brdf(*directions_from_angles(0.0, 0.0, 0.0))[0]  # prefactor R at normal incidence
    hs = HarveyShack(b0=b0, l=532.0 / b, s=-2.8)
    np.testing.assert_allclose(lobe.brdf(wi, wo), hs.brdf(wi, wo) * wi[:, 2] * wo[:, 2], rtol=1e-12)


@pytest.mark.parametrize(
    "cls,kwargs,word",
    [
        (Abg, dict(a=-1.0, b=0.1, g=2.0), "'a'"),
        (Abg, dict(a=1.0, b=0.0, g=2.0), "'b'"),
        (Abg, dict(a=1.0, b=0.1, g=-1.0), "'g'"),
        (HarveyShack, dict(b0=-1.0, l=0.1, s=-2.0), "b0"),
        (HarveyShack, dict(b0=1.0, l=0.0, s=-2.0), "'l'"),
    ],
)
def test_bad_parameters_are_refused_by_name(cls, kwargs, word):
    with pytest.raises(MaterialError, match=word):
        cls(**kwargs)


# ------------------------------------------------------------------------- tabulated


def _table():
    ti = np.array([10.0, 40.0, 70.0])
    tr = np.array([-60.0, -20.0, 0.0, 20.0, 50.0, 80.0])
    f = 10.0 ** np.arange(ti.size * tr.size).reshape(ti.size, tr.size) / 1e9
    return ti, tr, f


def test_tabulated_reproduces_nodes_and_interpolates_log_linearly():
    ti, tr, f = _table()
    model = Tabulated(theta_i_deg=list(ti), theta_r_deg=list(tr), brdf_per_sr=f.tolist())
    t_i, t_r = np.meshgrid(ti, tr, indexing="ij")
    # signed theta_r < 0 is the backscatter half-plane, phi_r = 180 deg
    wi, wo = directions_from_angles(np.deg2rad(t_i.ravel()), np.deg2rad(np.abs(t_r.ravel())), np.where(t_r.ravel() < 0, np.pi, 0.0))
    np.testing.assert_allclose(model.brdf(wi, wo), f.ravel(), rtol=1e-12)
    # halfway between theta_r nodes 20 and 50 at theta_i = 40: geometric mean (log-linear)
    wi, wo = directions_from_angles(np.deg2rad(40.0), np.deg2rad(35.0), 0.0)
    np.testing.assert_allclose(model.brdf(wi, wo), math.sqrt(f[1, 3] * f[1, 4]), rtol=1e-12)
    # outside the table: edge value held
    wi, wo = directions_from_angles(np.deg2rad(85.0), np.deg2rad(85.0), 0.0)
    np.testing.assert_allclose(model.brdf(wi, wo), f[2, 5], rtol=1e-12)


def test_tabulated_out_of_plane_uses_the_in_plane_value_at_the_same_bragg_offset():
    ti, tr, f = _table()
    model = Tabulated(theta_i_deg=list(ti), theta_r_deg=list(tr), brdf_per_sr=f.tolist())
    theta_i = np.deg2rad(40.0)
    wi, _ = directions_from_angles(theta_i, 0.0, 0.0)
    d = 0.3  # |beta - beta0|, offset at 60 deg from the specular azimuth (positive along it)
    beta = np.array([np.sin(theta_i) + d * np.cos(1.0), d * np.sin(1.0)])
    wo = np.array([[beta[0], beta[1], np.sqrt(1 - beta @ beta)]])
    wi_in, wo_in = directions_from_angles(theta_i, np.arcsin(np.sin(theta_i) + d), 0.0)
    np.testing.assert_allclose(model.brdf(wi, wo), model.brdf(wi_in, wo_in), rtol=1e-12)


def test_tabulated_s_and_p_tables():
    ti, tr, f = _table()
    model = Tabulated(theta_i_deg=list(ti), theta_r_deg=list(tr), brdf_s_per_sr=(2 * f).tolist(), brdf_p_per_sr=f.tolist())
    wi, wo = directions_from_angles(np.deg2rad(40.0), np.deg2rad(20.0), 0.0)
    assert model.brdf(wi, wo, "s")[0] == pytest.approx(2 * f[1, 3])
    assert model.brdf(wi, wo, "u")[0] == pytest.approx(1.5 * f[1, 3])


@pytest.mark.parametrize(
    "kwargs,word",
    [
        (dict(theta_i_deg=[10, 5], theta_r_deg=[0, 1], brdf_per_sr=[[1, 1], [1, 1]]), "increasing"),
        (dict(theta_i_deg=[10], theta_r_deg=[0, 100], brdf_per_sr=[[1, 1]]), "theta_r_deg"),
        (dict(theta_i_deg=[10], theta_r_deg=[0, 1], brdf_per_sr=[[1, 1, 1]]), "shape"),
        (dict(theta_i_deg=[10], theta_r_deg=[0, 1], brdf_per_sr=[[1, -1]]), ">= 0"),
        (dict(theta_i_deg=[10], theta_r_deg=[0, 1]), "needs"),
        (dict(theta_i_deg=[10], theta_r_deg=[0, 1], brdf_s_per_sr=[[1, 1]]), "both"),
    ],
)
def test_tabulated_bad_tables_are_refused(kwargs, word):
    with pytest.raises(MaterialError, match=word):
        Tabulated(**kwargs)


def test_tabulated_proposal_width_is_the_half_width_at_half_maximum():
    """Rows f = 1 / (1 + (d / w)^2), d = sin(theta_r) - sin(theta_i): HWHM in beta is w."""
    ti = np.array([20.0, 40.0])
    tr = np.linspace(-89.0, 89.0, 17801)  # 0.01-deg steps resolve w = 0.01
    d = np.sin(np.deg2rad(tr))[None, :] - np.sin(np.deg2rad(ti))[:, None]
    model = Tabulated(theta_i_deg=list(ti), theta_r_deg=list(tr), brdf_per_sr=(1 / (1 + (d / 0.01) ** 2)).tolist())
    assert model.proposal_width == pytest.approx(0.01, rel=0.02)
