"""Thin-film coatings (CONTRACTS 5.1 ``coating``) against independent references.

- the closed form of a quarter-wave layer at normal incidence (Macleod, Thin-Film Optical Filters §3.2);
- the Airy summation of a single layer's multiple reflections (Born & Wolf §7.6.1), a formalism
  independent of the characteristic matrices, for s and p at 45 deg, lossless and absorbing;
- no layers = the bare Fresnel interface (materials.fresnel);
- the tracer: a window's transmission (1 - R) / (1 + R) (incoherent series), bare and coated.
"""
import numpy as np
import pytest

from materials import MaterialError
from materials.fresnel import fresnel_amplitudes
from materials.material import load_material
from materials.thin_film import quarter_wave_reflectance, stack_amplitudes


def _interface(Ni, ci, Nj, cj):
    """Textbook Fresnel amplitudes i -> j (s, p) from N cos(theta) on each side, in the basis of
    materials.fresnel (r_p = -r_s at normal incidence): Born & Wolf eq. 1.5.20-21."""
    rs = (Ni * ci - Nj * cj) / (Ni * ci + Nj * cj)
    rp = (Nj * ci - Ni * cj) / (Nj * ci + Ni * cj)
    ts = 2 * Ni * ci / (Ni * ci + Nj * cj)
    tp = 2 * Ni * ci / (Nj * ci + Ni * cj)
    return (rs, ts), (rp, tp)


def _airy_single_layer(cos0, n0, n1, n2, d_nm, lam_nm):
    """r and T (s, p) of one layer on a lossless substrate by summing its multiple reflections
    (Born & Wolf eq. 7.6.58, written out here independently of the characteristic matrices)."""
    sin0 = np.sqrt(1 - cos0**2)
    cos1 = np.sqrt(1 - (n0 * sin0 / n1) ** 2 + 0j)
    if cos1.imag * n1.real < 0 or (n1 * cos1).imag < 0:
        cos1 = -cos1
    cos2 = np.sqrt(1 - (n0 * sin0 / n2) ** 2 + 0j)
    beta = 2 * np.pi * n1 * d_nm * cos1 / lam_nm
    out = []
    for (r01, t01), (r12, t12) in zip(_interface(n0, cos0, n1, cos1), _interface(n1, cos1, n2, cos2)):
        e = np.exp(2j * beta)
        r = (r01 + r12 * e) / (1 + r01 * r12 * e)
        t = t01 * t12 * np.exp(1j * beta) / (1 + r01 * r12 * e)
        out.append((r, np.real(n2 * cos2) / (n0 * cos0) * abs(t) ** 2))
    return out


def test_quarter_wave_mgf2_on_bk7_reflects_1_28_percent():
    lam = 550.0
    rs, rp, Ts, Tp, _, _ = stack_amplitudes(np.array([1.0]), 1.0, 1.5168, [(1.38, 0.0, lam / (4 * 1.38))], lam)
    assert abs(rs[0]) ** 2 == pytest.approx(quarter_wave_reflectance(1.0, 1.38, 1.5168), rel=1e-12)
    assert abs(rs[0]) ** 2 == pytest.approx(0.0128, abs=0.00005)
    assert Ts[0] + abs(rs[0]) ** 2 == pytest.approx(1.0, abs=1e-12)


def test_no_layers_is_the_bare_fresnel_interface():
    c = np.linspace(0.05, 1.0, 9)
    for n_sub in (1.5168, complex(0.96, 6.69)):
        rs, rp, Ts, Tp, _, _ = stack_amplitudes(c, 1.0, n_sub, [], 532.0)
        a = fresnel_amplitudes(c, n_sub)
        assert np.allclose(rs, a[0], atol=1e-12) and np.allclose(rp, a[1], atol=1e-12)


@pytest.mark.parametrize("n1", [1.38, complex(2.0, 0.3)])
def test_single_layer_at_45_deg_matches_the_airy_summation(n1):
    c = np.cos(np.radians(45.0))
    n1r, k1 = (n1.real, n1.imag) if isinstance(n1, complex) else (n1, 0.0)
    rs, rp, Ts, Tp, _, _ = stack_amplitudes(np.array([c]), 1.0, 1.52, [(n1r, k1, 87.0)], 600.0)
    (ras, Tas), (rap, Tap) = _airy_single_layer(c, 1.0, complex(n1), 1.52, 87.0, 600.0)
    assert rs[0] == pytest.approx(ras, abs=1e-12)
    assert rp[0] == pytest.approx(rap, abs=1e-12)
    assert Ts[0] == pytest.approx(Tas, abs=1e-12)
    assert Tp[0] == pytest.approx(Tap, abs=1e-12)
    A_s = 1 - abs(rs[0]) ** 2 - Ts[0]
    if k1 == 0:
        assert A_s == pytest.approx(0.0, abs=1e-12)
    else:  # an absorbing layer takes its share, R + T + A = 1 with A from the independent T
        assert A_s == pytest.approx(1 - abs(ras) ** 2 - Tas, abs=1e-12) and A_s > 0.01


def test_material_files_take_coatings_by_name_or_layers():
    named = load_material({"name": "ar", "wavelength_nm": 550.0,
                           "components": [{"type": "dielectric", "n": 1.5168, "coating": "mgf2_quarter_wave"}]})
    layers = load_material({"name": "ar2", "wavelength_nm": 550.0, "components": [
        {"type": "dielectric", "n": 1.5168, "coating": [{"n": 1.38, "thickness_nm": 550.0 / (4 * 1.38)}]}]})
    for m in (named, layers):
        coef = m.smooth_coefficients(np.array([1.0]))
        assert coef.R_s[0] == pytest.approx(0.012835, abs=2e-6)
        assert coef.R_s[0] + coef.T_s[0] == pytest.approx(1.0, abs=1e-12)
    again = load_material(named.to_dict())
    assert again.smooth_coefficients(np.array([0.6])).R_p[0] == pytest.approx(named.smooth_coefficients(np.array([0.6])).R_p[0])
    mirror = load_material({"name": "m", "wavelength_nm": 532.0, "components": [
        {"type": "specular", "n": [0.96, 6.69], "coating": "protected_aluminium"}]})
    bare = load_material({"name": "b", "wavelength_nm": 532.0, "components": [{"type": "specular", "n": [0.96, 6.69]}]})
    # a half-wave overcoat is an absentee layer at its design wavelength: the bare mirror's reflectance
    assert mirror.smooth_coefficients(np.array([1.0])).R_s[0] == pytest.approx(bare.smooth_coefficients(np.array([1.0])).R_s[0], abs=1e-9)
    broad = load_material({"name": "bb", "wavelength_nm": 550.0,
                           "components": [{"type": "dielectric", "n": 1.52, "coating": "broadband_ar"}]})
    assert broad.smooth_coefficients(np.array([1.0])).reflectance("u")[0] < 0.005


@pytest.mark.parametrize("bad, words", [
    ({"type": "dielectric", "n": 1.5, "coating": "unobtainium"}, "unknown coating"),
    ({"type": "dielectric", "n": 1.5, "coating": [{"n": 1.38}]}, "thickness_nm"),
    ({"type": "specular", "r": 0.9, "coating": "protected_aluminium"}, "needs the substrate index"),
])
def test_bad_coatings_are_refused_by_name(bad, words):
    with pytest.raises(MaterialError, match=words):
        load_material({"name": "x", "wavelength_nm": 550.0, "components": [bad]})


def _traced_window(coating, source_wavelength_nm=None, extra_source_nm=None):
    """The detector power of a window (n = 1.5, both faces alike, material at 550 nm) lit at normal incidence."""
    import math

    from geometry.analytic import Plane, analytic_part
    from geometry.mesh import Scene
    from straylight.sources import CollimatedDisk
    from straylight.trace import EstimatorOptions, TraceOptions, trace

    comp = {"type": "dielectric", "n": 1.5}
    if coating:
        comp["coating"] = coating
    glass = load_material({"name": "glass", "wavelength_nm": 550.0, "components": [comp]})
    up = np.array([0.0, 0.0, 1.0])
    top = analytic_part("top", Plane(np.array([0, 0, 10.0]), up, math.inf, 0.0, 100.0, 0.0), "glass")
    bottom = analytic_part("bottom", Plane(np.zeros(3), -up, math.inf, 0.0, 100.0, 0.0), "glass")
    det = analytic_part("det", Plane(np.array([0, 0, -20.0]), up, math.inf, 0.0, 300.0, 0.0), None, "detector")
    waves = [source_wavelength_nm] + ([extra_source_nm] if extra_source_nm is not None else [])
    src = [CollimatedDisk(center_mm=np.array([0, 0, 60.0]), normal=-up, direction=-up, radius_mm=5.0,
                          wavelength_nm=w) for w in waves]
    res = trace(Scene((top, bottom, det)), src, 100_000, seed=5, materials={"glass": glass},
                options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    return res.detectors["det"]


@pytest.mark.parametrize("coating, R", [(None, 0.04), ("mgf2_quarter_wave", ((1.5 - 1.38**2) / (1.5 + 1.38**2)) ** 2)])
def test_traced_window_transmits_one_minus_r_over_one_plus_r(coating, R):
    """A non-absorbing window with equal faces transmits (1 - R) / (1 + R) of the incoherent series;
    R is 4 % bare (n = 1.5) and the quarter-wave closed form coated (at normal incidence)."""
    d = _traced_window(coating)
    expected = (1 - R) / (1 + R)
    assert abs(d.power_w - expected) < 4 * d.stderr_w + 1e-9, (d.power_w, d.stderr_w, expected)


@pytest.mark.parametrize("lam_nm", [450.0, 1100.0])
def test_a_coating_is_traced_at_the_source_wavelength(lam_nm):
    """The material is given at 550 nm (the layer a quarter wave there); the source at lam_nm traces the same
    physical layer at lam_nm: R from the Airy summation of one layer (independent of the characteristic
    matrices) at lam_nm, the window (1 - R) / (1 + R), 4 sigma; and clearly not the 550 nm value."""
    (r, _), _ = _airy_single_layer(1.0, 1.0, 1.38, 1.5, 550.0 / (4 * 1.38), lam_nm)
    R = abs(r) ** 2
    d = _traced_window("mgf2_quarter_wave", lam_nm)
    expected = (1 - R) / (1 + R)
    assert abs(d.power_w - expected) < 4 * d.stderr_w, (d.power_w, d.stderr_w, expected)
    R550 = ((1.5 - 1.38**2) / (1.5 + 1.38**2)) ** 2
    assert abs(d.power_w - (1 - R550) / (1 + R550)) > 10 * d.stderr_w


def test_sources_of_two_wavelengths_with_a_coating_are_refused():
    from straylight.trace import TraceError

    with pytest.raises(TraceError, match="one wavelength"):
        _traced_window("mgf2_quarter_wave", 450.0, 650.0)
    assert _traced_window(None, 450.0, 650.0).power_w > 0  # no coating: nothing depends on the wavelength
