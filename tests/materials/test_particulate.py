"""The ``particulate`` component: Mie scatter of an IEST-STD-CC1246E particle population.

References: miepython (S. Prahl) evaluated directly for one particle size; IEST-STD-CC1246E's
percent-area-coverage relation ``log10 PAC = -7.245 + 0.926 log10^2 L``; the closed-form
integral of the size law (Gaussian in log10 x) for the coverage of circular particles.
"""
import math
import os

import numpy as np
import pytest

from materials import MaterialError, load_material
from materials.albedo import directional_hemispherical_reflectance
from materials.base import directions_from_angles
from materials.particulate import Particulate, cc1246_pac_percent, percent_area_coverage

DEG = np.pi / 180


def _coverage_closed_form_percent(level, slope, area_m2):
    """Integral over all sizes of pi x^2 / 4 dN for log10 N(>x) = s (log^2 L - log^2 x):
    with u = log10 x, -dN/du = 2 s u ln10 N; integrating x^2 N by parts gives
    2 ln10 sqrt(pi / (s ln10)) 10^(s log^2 L + 1/s) um^2 per area."""
    lg = math.log10(level)
    um2 = 2 * math.log(10) * math.sqrt(math.pi / (slope * math.log(10))) * 10 ** (slope * lg * lg + 1 / slope)
    return 100 * (math.pi / 4) * um2 * 1e-12 / area_m2


def test_standard_pac_relation_is_the_area_integral_per_square_foot():
    """The constant -7.245 is the closed-form coverage of the 0.926 law counted per ft^2 (the unit of
    MIL-STD-1246, replaced by 0.1 m^2 in CC1246D with the PAC relation kept): this ties the
    standard's relation to the law the model integrates."""
    for level in (50, 300, 1000):
        closed = _coverage_closed_form_percent(level, 0.926, 0.3048**2)
        assert abs(math.log10(closed / cc1246_pac_percent(level))) < 1e-3


@pytest.mark.parametrize("level", [100, 300, 500, 1000])
def test_model_pac_against_the_standard(level):
    """Model PAC (quadrature from 1 um up to N(>x) = 1e-3, counts per 0.1 m^2) = the standard's
    relation x (1 ft^2 / 0.1 m^2 = 0.9290), within 0.5 % (the truncated tails)."""
    pac = percent_area_coverage(level)
    ratio = pac / cc1246_pac_percent(level)
    assert abs(ratio / (0.3048**2 / 0.1) - 1) < 5e-3
    assert abs(pac / _coverage_closed_form_percent(level, 0.926, 0.1) - 1) < 5e-3


def test_brdf_of_one_particle_size_against_miepython():
    """BRDF of 1-um spheres (n = 1.5), 0.01 per mm^2, computed directly with miepython at the four
    path angles: f = a_i a_r n_A pi r^2 [i(T1) + R_i i(T2) + R_r i(T3) + R_i R_r i(T4)] / (cos_i cos_r),
    i = miepython.i_unpolarized(norm='qsca'), over a constant-reflectance substrate r = 0.8."""
    os.environ.setdefault("MIEPYTHON_USE_JIT", "1")
    import miepython

    n_a, d_um, lam_nm, R = 1e-2, 1.0, 532.0, 0.8
    model = Particulate.single_size(d_um, n_a, wavelength_nm=lam_nm, substrate_r=R)
    th_i = np.array([0.0, 20.0, 50.0, 70.0, 30.0]) * DEG
    th_r = np.array([10.0, 35.0, 50.0, 10.0, 60.0]) * DEG
    ph_r = np.array([0.0, 180.0, 0.0, 90.0, 45.0]) * DEG
    wi, wo = directions_from_angles(th_i, th_r, ph_r)
    kin, ksp = -wi, -wi * [1, 1, -1]
    wom = wo * [1, 1, -1]
    x = np.pi * d_um / (lam_nm * 1e-3)
    sigma = lambda a, b: miepython.i_unpolarized(1.5, x, np.sum(a * b, axis=1), norm="qsca")  # noqa: E731
    area_mm2 = np.pi * (d_um * 1e-3) ** 2 / 4
    s = sigma(kin, wo) + R * sigma(ksp, wo) + R * sigma(kin, wom) + R * R * sigma(ksp, wom)
    tau_i, tau_r = (n_a * area_mm2 * miepython.efficiencies_mx(1.5, x)[0] / w[:, 2] for w in (wi, wo))
    atten = (1 - np.exp(-tau_i)) / tau_i * (1 - np.exp(-tau_r)) / tau_r
    expected = n_a * area_mm2 * s / (wi[:, 2] * wo[:, 2]) * atten
    np.testing.assert_allclose(model.brdf(wi, wo), expected, rtol=2e-3)


def test_sampling_is_unbiased_against_quadrature():
    """mean(sample weight) = directional-hemispherical reflectance by quadrature (4 sigma)."""
    model = Particulate.single_size(2.0, 1e-2, wavelength_nm=532.0, substrate_r=0.9)
    rng = np.random.default_rng(1)
    for th in (10.0, 60.0):
        n = 200_000
        wi = np.tile([-np.sin(th * DEG), 0.0, np.cos(th * DEG)], (n, 1))
        smp = model.sample(wi, rng.random((n, 3)))
        est, err = smp.weight.mean(), smp.weight.std() / np.sqrt(n)
        ref = directional_hemispherical_reflectance(model, np.array([th * DEG]), "u")[0]
        assert est > 0 and abs(est - ref) < 4 * err + 2e-3 * ref, (th, est, err, ref)
        # the pdf is the density of the draws: f cos / pdf reproduces brdf
        ok = smp.weight > 0
        f = model.brdf(wi[ok][:100], smp.wo[ok][:100])
        np.testing.assert_allclose(smp.weight[ok][:100], f * smp.wo[ok][:100, 2] / model.pdf(wi[ok][:100], smp.wo[ok][:100]))


def test_particulate_in_a_mirror_material_and_its_errors():
    """A level-300 mirror: the particles see the mirror's own index; the lobe's rho stays small
    (PAC 0.025 %) and comes out of the specular part; bad keys are one-line errors."""
    m = load_material({"name": "al", "wavelength_nm": 532.0, "components": [
        {"type": "specular", "n": [0.96, 6.69]}, {"type": "particulate", "level": 300}]})
    p = m.lobes[0]
    assert p.substrate_n == (0.96, 6.69)
    assert 0.02 < p.percent_area_coverage < 0.03
    th = np.deg2rad([0.0, 45.0, 80.0])
    rho = m.albedo(th, "u")
    assert np.all(rho > 2e-4) and np.all(rho < 0.01)
    for bad, key in (({"type": "particulate", "level": 300, "lvl": 1}, "lvl"),
                     ({"type": "particulate", "level": 0.5}, "level"),
                     ({"type": "particulate"}, "level")):
        with pytest.raises(MaterialError, match=key):
            load_material({"name": "x", "wavelength_nm": 532.0, "components": [bad]})
