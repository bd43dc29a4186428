"""Instrument effects (rig.effects, CONTRACTS §3): identity at zero strength and one
analytic signature each (PHYSICS §4 table)."""
import dataclasses
import math

import numpy as np
import pytest
from scipy.special import erf

from materials.kcorrelation import KCorrelation
from materials.lambertian import Lambertian
from rig.effects import CATALOGUE, EffectError, build_effect, effect_names, effect_types
from rig.forward import instrument_forward, predict_brdf
from rig.instrument import NOMINAL


class GaussLobe:
    """f = rho / (2 pi w^2) exp(-|beta - beta0|^2 / (2 w^2)); integral f cos dOmega = rho."""

    def __init__(self, w, rho=1.0):
        self.w, self.rho = w, rho

    def brdf(self, wi, wo, polarization="u"):
        d = wo[:, :2] + wi[:, :2]
        g = self.rho / (2 * math.pi * self.w**2) * np.exp(-0.5 * (d**2).sum(1) / self.w**2)
        return np.where(wo[:, 2] > 0, g, 0.0)


class Sloped:
    """f cos(theta_o) = a + b wo_x: linear in the projected viewing direction."""

    def brdf(self, wi, wo, polarization="u"):
        return (0.05 + 0.02 * wo[:, 0]) / np.clip(wo[:, 2], 1e-9, None)


STRONG = {
    "angle_offset": dict(offset_deg=0.1),
    "arm_offset": dict(offset_deg=0.1),
    "sample_tilt": dict(tilt_deg=0.5),
    "detector_aperture": dict(width_mm=1.0),
    "beam_divergence": dict(sigma_mrad=3.0),
    "footprint_overfill": dict(sample_width_mm=3.0),
    "polarization_leakage": dict(fraction=0.02),
    "stray_background": dict(level_per_sr=1e-3),
    "detector_nonlinearity": dict(saturation_per_sr=2.0),
    "substrate_reflection": dict(transmittance=0.3, lobe_width_deg=0.5),
}


def _peak_deg(material, ti, effects, half_range=1.0, n=801):
    tr = np.linspace(ti - half_range, ti + half_range, n)
    y = predict_brdf(material, ti, tr, 0.0, "s", effects=effects)
    j = int(np.argmax(y))
    # parabola through the three highest samples of log(y)
    a, b, c = np.log(y[j - 1:j + 2])
    step = tr[1] - tr[0]
    return tr[j] + 0.5 * step * (a - c) / (a - 2 * b + c)


def test_catalogue_names_are_exactly_registered():
    """CONTRACTS §3: these names must exist."""
    assert set(CATALOGUE) <= set(effect_names())
    assert set(STRONG) == set(CATALOGUE)


@pytest.mark.parametrize("name", CATALOGUE)
def test_zero_strength_is_exact_identity(name):
    effect = effect_types()[name]()
    assert effect.wrap(instrument_forward) is instrument_forward
    mat = KCorrelation(sigma_nm=3.0, lc_um=10.0, s=2.5, n=1.5, wavelength_nm=532.0)
    tr = np.array([-40.0, 29.5, 30.0, 30.3, 70.0])
    np.testing.assert_array_equal(predict_brdf(mat, 30.0, tr, 0.0, "p", effects=[effect]),
                                  predict_brdf(mat, 30.0, tr, 0.0, "p"))


@pytest.mark.parametrize("name", CATALOGUE)
def test_nonzero_strength_changes_the_reading(name):
    """Sanity for the identity test: each effect at STRONG does change a scan."""
    mat = KCorrelation(sigma_nm=3.0, lc_um=10.0, s=2.5, n=1.5, wavelength_nm=532.0)
    ti = 80.0 if name == "footprint_overfill" else 30.0
    tr = np.array([-40.0, ti - 0.3, ti, ti + 0.3, 70.0])
    effect = build_effect(name, **STRONG[name])
    a = predict_brdf(mat, ti, tr, 0.0, "p", effects=[effect])
    b = predict_brdf(mat, ti, tr, 0.0, "p")
    assert np.max(np.abs(a / b - 1)) > 1e-3


def test_stage_offset_moves_peak_by_twice_arm_offset_by_once():
    """PHYSICS §4: a sample offset d moves the peak by 2d, an arm offset by d."""
    lobe = GaussLobe(2e-3)
    ti, d = 30.0, 0.1
    p0 = _peak_deg(lobe, ti, [])
    assert p0 == pytest.approx(ti, abs=2e-3)
    assert _peak_deg(lobe, ti, [build_effect("angle_offset", offset_deg=d)]) - p0 == pytest.approx(2 * d, abs=3e-3)
    # true viewing angle = set-point + d: the peak is reached d earlier
    assert _peak_deg(lobe, ti, [build_effect("arm_offset", offset_deg=d)]) - p0 == pytest.approx(-d, abs=3e-3)


def test_offsets_compose_additively():
    lobe = GaussLobe(2e-3)
    two = [build_effect("angle_offset", offset_deg=0.05), build_effect("angle_offset", offset_deg=0.05)]
    one = [build_effect("angle_offset", offset_deg=0.1)]
    tr = np.linspace(29.5, 30.5, 11)
    np.testing.assert_allclose(predict_brdf(lobe, 30.0, tr, effects=two), predict_brdf(lobe, 30.0, tr, effects=one), rtol=1e-12)


def test_aperture_averaging_leaves_a_linear_brdf_unchanged():
    """Averaging over a wider symmetric slit leaves f cos linear in beta_x unchanged
    (to second order in the ~10 mrad aperture), but changes a curved (lobe) BRDF."""
    wide = [build_effect("detector_aperture", width_mm=5.0)]
    tr = np.array([-60.0, -20.0, 0.0, 25.0, 50.0, 75.0])
    np.testing.assert_allclose(predict_brdf(Sloped(), 30.0, tr, effects=wide), predict_brdf(Sloped(), 30.0, tr), rtol=1e-4)
    lobe = GaussLobe(2e-3)
    assert predict_brdf(lobe, 30.0, 30.0, effects=wide) < 0.8 * predict_brdf(lobe, 30.0, 30.0)


def test_stray_background_adds_its_level_over_cos_and_nothing_else():
    """A constant power floor reads level / cos(theta_r) in BRDF units (PHYSICS §4)."""
    mat = KCorrelation(sigma_nm=3.0, lc_um=10.0, s=2.5, n=1.5, wavelength_nm=532.0)
    tr = np.array([-80.0, -30.0, 0.0, 29.9, 30.0, 60.0, 85.0])
    level = 3e-4
    diff = (predict_brdf(mat, 30.0, tr, effects=[build_effect("stray_background", level_per_sr=level)])
            - predict_brdf(mat, 30.0, tr))
    np.testing.assert_allclose(diff, level / np.cos(np.radians(tr)), rtol=1e-9)


def test_polarization_leakage_fills_p_at_brewster():
    """Near Brewster (56.3 deg for n = 1.5) R_p ~ 0, so with leakage e the p reading
    becomes ~ e x the s reading (PHYSICS §4); s barely changes."""
    mat = KCorrelation(sigma_nm=3.0, lc_um=10.0, s=2.5, n=1.5, wavelength_nm=532.0)
    ti = math.degrees(math.atan(1.5))
    e = 0.01
    leak = [build_effect("polarization_leakage", fraction=e)]
    p0, s0 = predict_brdf(mat, ti, ti, 0.0, ["p", "s"])
    p1, s1 = predict_brdf(mat, ti, ti, 0.0, ["p", "s"], effects=leak)
    assert p0 < 1e-3 * s0  # sanity: p is dark at Brewster
    assert p1 == pytest.approx((1 - e) * p0 + e * s0, rel=1e-9)
    assert p1 > 10 * p0
    assert s1 == pytest.approx(s0, rel=0.011)
    u0 = predict_brdf(mat, ti, ti, 0.0, "u")
    assert predict_brdf(mat, ti, ti, 0.0, "u", effects=leak) == u0


def test_sample_tilt_halves_the_peak_when_the_beam_reaches_the_slit_edge():
    """The reflected beam leaves the plane by 2 tilt cos(theta_i) (PHYSICS §4); when that
    reaches the slit half-height, about half the beam's height profile is inside:
    (erf(H / (sqrt(2) s)) + erf(0)) / 2 with s the beam sigma (narrow lobe)."""
    lobe = GaussLobe(5e-4)
    ti = 30.0
    cfg = NOMINAL
    tilt = math.degrees((cfg.slit_height_mm / 2 / cfg.arm_mm) / (2 * math.cos(math.radians(ti))))
    flat = predict_brdf(lobe, ti, ti)
    half = predict_brdf(lobe, ti, ti, effects=[build_effect("sample_tilt", tilt_deg=tilt)])
    small = predict_brdf(lobe, ti, ti, effects=[build_effect("sample_tilt", tilt_deg=tilt / 4)])
    spread = math.hypot(cfg.beam_sigma_mm, cfg.arm_mm * 5e-4)
    expected = 0.5 * erf(cfg.slit_height_mm / (math.sqrt(2) * spread))
    assert half / flat == pytest.approx(expected, abs=0.02)
    assert small / flat == pytest.approx(1.0, abs=0.01)


def test_beam_divergence_adds_its_variance_to_the_response():
    """A Gaussian incidence spread sigma_d shifts the specular ray by the same angle, so the
    in-plane variance of a narrow lobe's response grows by sigma_d^2."""
    lobe = GaussLobe(1e-3)
    ti = 30.0
    tr = np.linspace(ti - 2.0, ti + 2.0, 1601)
    x = np.radians(tr)

    def var(effects):
        y = predict_brdf(lobe, ti, tr, effects=effects) * np.cos(x)
        m = np.trapezoid(x * y, x) / np.trapezoid(y, x)
        return np.trapezoid((x - m) ** 2 * y, x) / np.trapezoid(y, x)

    sd = 4e-3
    grown = var([build_effect("beam_divergence", sigma_mrad=sd * 1e3)]) - var([])
    assert grown == pytest.approx(sd**2, rel=0.03)


def test_overfill_effect_is_the_sample_width():
    rd = 0.05
    got = predict_brdf(Lambertian(rd), 80.0, 30.0, effects=[build_effect("footprint_overfill", sample_width_mm=3.0)])
    frac = erf(3.0 * math.cos(math.radians(80.0)) / (2 * math.sqrt(2) * NOMINAL.beam_sigma_mm))
    assert got == pytest.approx(rd / math.pi * frac, rel=2e-4)


def test_nonlinearity_compresses_signal_not_angle():
    """Reading x cos = x / (1 + x / sat) of the linear signal x = reading x cos."""
    mat = KCorrelation(sigma_nm=3.0, lc_um=10.0, s=2.5, n=1.5, wavelength_nm=532.0)
    tr = np.array([-70.0, 0.0, 29.8, 30.0, 30.2, 80.0])
    sat = 0.02
    lin = predict_brdf(mat, 30.0, tr) * np.cos(np.radians(tr))
    got = predict_brdf(mat, 30.0, tr, effects=[build_effect("detector_nonlinearity", saturation_per_sr=sat)])
    np.testing.assert_allclose(got * np.cos(np.radians(tr)), lin / (1 + lin / sat), rtol=1e-9)
    assert lin.max() > sat  # sanity: the peak is actually compressed


def test_substrate_reflection_adds_its_power_fraction():
    """The ghost lobe returns the fraction G of the power: the area of reading x cos over
    arm angle grows by G x L / H times the fraction of the out-of-plane spread
    (beam and lobe, w = width x cos(theta_i) in beta) inside the slit height. G from rig.synth's
    own implementation (complex Snell + textbook Fresnel amplitudes)."""
    from rig.synth import _ghost_fraction

    ti = 30.0
    tr = np.linspace(ti - 4.0, ti + 4.0, 1601)
    x = np.radians(tr)
    lam = Lambertian(0.02)
    n2 = complex(4.15, 0.044)
    att = 0.5 * sum(_ghost_fraction(math.radians(ti), pol, 1.5, 0.2, n2) for pol in "sp")
    sub = [build_effect("substrate_reflection", transmittance=0.2, lobe_width_deg=0.3, coating_n=1.5)]
    extra = np.trapezoid((predict_brdf(lam, ti, tr, effects=sub) - predict_brdf(lam, ti, tr)) * np.cos(x), x)
    spread = math.hypot(NOMINAL.beam_sigma_mm, NOMINAL.arm_mm * math.radians(0.3) * math.cos(math.radians(ti)))
    inside = erf(NOMINAL.slit_height_mm / 2 / (math.sqrt(2) * spread))
    assert inside < 0.995  # the correction matters at this width
    assert extra == pytest.approx(att * NOMINAL.arm_mm / NOMINAL.slit_height_mm * inside, rel=0.003)


def test_build_effect_errors_name_the_problem():
    with pytest.raises(EffectError, match="unknown effect 'nope'"):
        build_effect("nope")
    with pytest.raises(EffectError, match="offset"):
        build_effect("angle_offset", offset=1.0)
    with pytest.raises(EffectError, match="fraction"):
        build_effect("polarization_leakage", fraction=-0.1)


def test_effects_are_frozen_dataclasses_with_unit_suffixes():
    units = ("_deg", "_mm", "_mrad", "_per_sr")
    for name in CATALOGUE:
        cls = effect_types()[name]
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
        for f in dataclasses.fields(cls):
            assert f.name.endswith(units) or f.name in ("fraction", "transmittance") or f.name in cls.fixed, (name, f.name)
            assert f.name in cls.fit_space or f.name in cls.fixed


def test_substrate_ghost_physics():
    """Ghost fraction G (rig.effects.substrate_reflection): at normal incidence by hand,
    G = T^2 R12 A / (1 - R01 R12 A) with R01 = ((n1 - 1)/(n1 + 1))^2, R12 = |(n1 - n2)/(n1 + n2)|^2
    (n1 1.5, n2 4.15 + 0.044i: R01 0.04, R12 7.024436/31.924436); attenuation there and back
    (G ~ t^2 for a dark coating); no Brewster zero in p (the coating's own p reflectance vanishes
    at 56.31 deg, the ghost does not)."""
    from rig.effects.substrate_reflection import ghost_fraction

    r01, r12 = 0.04, 7.024436 / 31.924436
    assert ghost_fraction(1.0, "s", 1.5, 1.0) == pytest.approx((0.96**2 * r12) / (1 - r01 * r12), rel=1e-6)
    assert ghost_fraction(1.0, "p", 1.5, 0.5) == pytest.approx(0.96**2 * r12 * 0.25 / (1 - r01 * r12 * 0.25), rel=1e-6)
    assert ghost_fraction(1.0, "u", 1.5, 0.01) / ghost_fraction(1.0, "u", 1.5, 0.001) == pytest.approx(100.0, rel=1e-3)
    # the slant path: at 60 deg in a 1.5 coating cos(theta_t) = sqrt(1 - 0.75 / 2.25)
    cos_t = math.sqrt(1 - 0.75 / 2.25)
    lo, hi = ghost_fraction(0.5, "s", 1.5, 0.01), ghost_fraction(0.5, "s", 1.5, 0.001)
    assert lo / hi == pytest.approx(10.0 ** (2 / cos_t), rel=1e-3)
    brewster = math.cos(math.atan(1.5))
    assert ghost_fraction(brewster, "p", 1.5, 1.0) > 0.5 * ghost_fraction(1.0, "p", 1.5, 1.0)
