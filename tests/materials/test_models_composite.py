"""Composite (seed paper Eq. 2 sum of components) and its one-sample MIS sampler (PHYSICS §3)."""
import numpy as np
import pytest

from materials import Composite, KCorrelation, Lambertian, MaterialError
from materials.albedo import directional_hemispherical_reflectance
from materials.base import directions_from_angles


@pytest.fixture(scope="module")
def three():
    return Composite.example()


def test_brdf_is_the_sum_of_components(three):
    rng = np.random.default_rng(4)
    wi, wo = directions_from_angles(rng.uniform(0, 1.5, 300), rng.uniform(0, 1.5, 300), rng.uniform(0, 6.3, 300))
    for pol in "sp":
        expected = sum(c.brdf(wi, wo, pol) for c in three.components)
        np.testing.assert_allclose(three.brdf(wi, wo, pol), expected, rtol=1e-14)


@pytest.mark.parametrize("pol", ["s", "p"])
def test_selection_probabilities_follow_component_albedos(three, pol):
    th = np.deg2rad([5.0, 33.0, 61.0, 80.0])
    alb = np.array([directional_hemispherical_reflectance(c, th, pol) for c in three.components]).T
    expected = alb / alb.sum(axis=1, keepdims=True)
    p = three.selection_probabilities(th, pol)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(p, expected, atol=0.01)  # table interpolation + 0.1 % floor


def test_sample_weight_is_f_cos_over_the_mixture_pdf(three):
    n = 5000
    wi, _ = directions_from_angles(np.full(n, np.deg2rad(40.0)), 0.0, 0.0)
    s = three.sample(wi, np.random.default_rng(8).random((n, 3)), "s")
    ok = s.weight > 0
    assert ok.sum() > 0.9 * n
    mix = three.pdf(wi[ok], s.wo[ok], "s")
    np.testing.assert_allclose(s.pdf_per_sr[ok], mix, rtol=1e-12)
    np.testing.assert_allclose(s.weight[ok], three.brdf(wi[ok], s.wo[ok], "s") * s.wo[ok, 2] / mix, rtol=1e-12)


def test_first_uniform_chooses_the_component(three):
    """u[:, 0] below p_0 picks the Lambertian: its draws spread over the disk, far from beta0."""
    n = 2000
    wi, _ = directions_from_angles(np.full(n, np.deg2rad(30.0)), 0.0, 0.0)
    p0 = three.selection_probabilities(np.deg2rad(30.0), "u")[0, 0]
    u = np.random.default_rng(1).random((n, 3))
    u[:, 0] = 0.5 * p0
    d = three.sample(wi, u).wo[:, :2] + wi[:, :2]
    assert np.median(np.hypot(d[:, 0], d[:, 1])) > 0.3
    u[:, 0] = 1 - 1e-9  # the last (glossy) lobe: draws within a few widths of beta0
    d = three.sample(wi, u).wo[:, :2] + wi[:, :2]
    assert np.median(np.hypot(d[:, 0], d[:, 1])) < 0.05


def test_composite_needs_three_uniforms_and_components(three):
    wi, _ = directions_from_angles(np.zeros(3), 0.0, 0.0)
    with pytest.raises(ValueError, match="shape"):
        three.sample(wi, np.zeros((3, 2)))
    with pytest.raises(MaterialError):
        Composite(())


def test_zero_albedo_component_is_still_unbiased():
    """A zero-reflectance component gets only the floor probability; the estimator stays exact."""
    comp = Composite((Lambertian(rd=0.0), KCorrelation(sigma_nm=3, lc_um=5, s=2.5, r=0.05, wavelength_nm=532.0)))
    n = 40000
    wi, _ = directions_from_angles(np.full(n, 0.3), 0.0, 0.0)
    s = comp.sample(wi, np.random.default_rng(2).random((n, 3)))
    rho = directional_hemispherical_reflectance(comp, 0.3)
    se = s.weight.std() / np.sqrt(n)
    assert rho > 0
    assert abs(s.weight.mean() - rho) < 4 * se + 1e-6 * rho


@pytest.mark.parametrize("k", [1, 2, 3, 5, 7, 9])
def test_compiled_selection_probabilities_are_numpys_bits(k):
    """The compiled pass (np.clip, np.interp's interval and formula, the row sum, the floor) gives the
    numpy formulation's bits: random angles, the table's nodes and their neighbours, out of range,
    K up to 7 (numpy's row sum is left to right there; from 8 on, and with NaN, numpy itself)."""
    comps = tuple(KCorrelation(sigma_nm=2.0 + i, lc_um=3.0 + 7 * i, s=2.2 + 0.1 * i, n=1.5, wavelength_nm=532.0)
                  if i % 2 else Lambertian(rd=0.01 * (i + 1)) for i in range(k))
    comp = Composite(comps)
    nodes = np.deg2rad(np.linspace(0.0, 90.0, 37))
    th = np.concatenate([np.random.default_rng(k).uniform(-0.3, 1.9, 20_000), nodes, np.nextafter(nodes, -1.0),
                         np.nextafter(nodes, 3.0), [-0.0, np.pi / 2, np.inf, -np.inf]])
    for pol in "usp":
        got, want = comp.selection_probabilities(th, pol), comp.selection_probabilities_numpy(th, pol)
        assert np.array_equal(got, want)
        np.testing.assert_allclose(got.sum(axis=1), 1.0, rtol=1e-12)
    with_nan = np.array([0.3, np.nan, 1.0])
    assert np.array_equal(comp.selection_probabilities(with_nan), comp.selection_probabilities_numpy(with_nan),
                          equal_nan=True)


def test_lobes_sharing_pair_geometry_give_each_lobe_alone_bit_for_bit():
    """A composite's K-correlation lobes share one PairGeometry (Bragg offset, azimuth, Rayleigh-Rice
    factor per index, shapes, aperture test): its brdf, pdf, brdf_pdf and sample weights equal, to the
    bit, the sums of each component evaluated alone (its own arrays), in component order; two lobes of one
    index and slope read one Rayleigh-Rice factor."""
    from materials.base import PairGeometry

    comp = Composite((Lambertian(rd=0.02),
                      KCorrelation(sigma_nm=2.0, lc_um=40.0, s=2.4, n=1.55, wavelength_nm=532.0),
                      KCorrelation(sigma_nm=20.0, lc_um=3.0, s=3.0, n=1.55, weight=0.5, wavelength_nm=532.0),
                      KCorrelation(sigma_nm=9.0, lc_um=0.5, s=2.0, n=(1.5, 0.3), wavelength_nm=532.0),
                      KCorrelation(sigma_nm=9.0, lc_um=7.0, s=2.2, r=0.2, wavelength_nm=532.0)))
    rng = np.random.default_rng(9)
    n = 20_000
    wi, wo = (rng.normal(size=(n, 3)) for _ in range(2))
    wi[:, 2] = np.abs(wi[:, 2])
    wi, wo = wi / np.linalg.norm(wi, axis=1)[:, None], wo / np.linalg.norm(wo, axis=1)[:, None]
    wo[:50] = [0.0, 0.0, 1.0]
    for pol in "usp":
        alone_f = comp.components[0].brdf(wi, wo, pol)
        for c in comp.components[1:]:
            alone_f = alone_f + c.brdf(wi, wo, pol)
        p = comp.selection_probabilities(np.arccos(np.clip(wi[:, 2], -1, 1)), pol)
        alone_pdf = np.zeros(n)
        for k, c in enumerate(comp.components):
            alone_pdf += p[:, k] * c.pdf(wi, wo, pol)
        f, pdf = comp.brdf_pdf(wi, wo, pol)
        assert np.array_equal(f, alone_f) and np.array_equal(comp.brdf(wi, wo, pol), alone_f)
        assert np.array_equal(pdf, alone_pdf) and np.array_equal(comp.pdf(wi, wo, pol), alone_pdf)
        u = rng.random((n, 3))
        smp = comp.sample(wi, u, pol)
        mix = np.zeros(n)
        for k, c in enumerate(comp.components):
            mix += p[:, k] * c.pdf(wi, smp.wo, pol)
        f_s = sum((c.brdf(wi, smp.wo, pol) for c in comp.components[1:]), comp.components[0].brdf(wi, smp.wo, pol))
        good = (smp.wo[:, 2] > 0) & (wi[:, 2] > 0) & (mix > 0)
        assert np.array_equal(smp.weight, np.where(good, f_s * smp.wo[:, 2] / np.where(good, mix, 1.0), 0.0))
    g = PairGeometry(wi, wo)
    comp.brdf(wi, wo, "u", g)
    assert sum(1 for key in g._made if key[0] == "rayleigh_rice") == 2  # n = 1.55 once, (1.5, 0.3) once
