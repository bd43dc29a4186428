"""Materials at another wavelength and Kirchhoff emissivity (materials.wavelength; CONTRACTS §7). Golden values from formulas written here (PHYSICS §1), not from the code under test."""
import math

import numpy as np
import pytest
from scipy.integrate import quad

from materials import load_material
from materials.wavelength import (
    at_wavelength,
    emissivity,
    hemispherical_emissivity,
    wavelength_dependent,
)


def _abc_a(sigma_nm, lc_um, s, lam_nm):
    """A of the band-limited ABC PSD (PHYSICS §1), um^4 with B and lambda in um."""
    b = 2 * math.pi * lc_um
    lam = lam_nm * 1e-3
    sig = sigma_nm * 1e-3
    return sig ** 2 * b ** 2 * (s - 2) / (2 * math.pi * (1 - (1 + (b / lam) ** 2) ** (1 - s / 2)))


def test_k_correlation_keeps_its_psd_at_a_new_wavelength():
    m = load_material({"wavelength_nm": 532.0, "components": [
        {"type": "k_correlation", "sigma_nm": 20.0, "lc_um": 4.0, "s": 3.0, "r": 0.5}]}, name="k")
    m10 = at_wavelength(m, 10_000.0)
    a = _abc_a(20.0, 4.0, 3.0, 532.0)
    b = 2 * math.pi * 4.0
    lam = 10.0
    # Rayleigh-Rice with the same PSD at 10 um, normal incidence, theta_r = 20 deg, R = 0.5
    th = math.radians(20.0)
    f = math.sin(th) / lam
    ref = 16 * math.pi ** 2 / lam ** 4 * 1.0 * math.cos(th) * 0.5 * a / (1 + (b * f) ** 2) ** 1.5
    wi = np.array([[0.0, 0.0, 1.0]])
    wo = np.array([[math.sin(th), 0.0, math.cos(th)]])
    assert m10.brdf(wi, wo, "u")[0] == pytest.approx(ref, rel=1e-9)
    # its roughness is the PSD integrated to 1/lambda
    sig2 = 2 * math.pi * quad(lambda x: x * a / (1 + (b * x) ** 2) ** 1.5, 0, 1 / lam)[0]
    assert m10.components[0].sigma_nm == pytest.approx(math.sqrt(sig2) * 1e3, rel=1e-9)
    assert wavelength_dependent(m) and m10.wavelength_nm == 10_000.0


def test_constant_components_stay_constant():
    m = load_material({"components": [{"type": "lambertian", "rd": 0.3}, {"type": "specular", "n": 1.5}]}, name="c")
    assert not wavelength_dependent(m)
    assert at_wavelength(m, 9000.0) is m


def test_kirchhoff_emissivity():
    lam = load_material({"components": [{"type": "lambertian", "rd": 0.3}]}, name="l")
    th = np.radians([0.0, 45.0, 80.0])
    assert emissivity(lam, th) == pytest.approx(0.7, abs=2e-3)
    # a smooth dielectric: 1 - R - T = 0 (nothing absorbed at the surface)
    glass = load_material({"components": [{"type": "dielectric", "n": 1.5}]}, name="g")
    assert emissivity(glass, th) == pytest.approx(0.0, abs=1e-12)
    # a metal mirror: 1 - Fresnel R (n = 1.5 real as a check value: R = 0.04 at normal incidence, PHYSICS §1)
    mirror = load_material({"components": [{"type": "specular", "n": 1.5}]}, name="m")
    assert emissivity(mirror, np.radians([0.0]))[0] == pytest.approx(0.96, abs=1e-4)
    assert emissivity(mirror, np.radians([80.0]))[0] == pytest.approx(1 - 0.5 * (0.5386 + 0.2368), abs=1e-3)
    grid = np.linspace(0, np.pi / 2, 721)
    assert hemispherical_emissivity(np.full(grid.shape, 0.7), grid) == pytest.approx(0.7, rel=1e-5)
