"""Planck band radiance (straylight.thermal.planck) against an adaptive quadrature of Planck's law
and against Stefan-Boltzmann (sigma T^4 / pi for the whole spectrum)."""
import numpy as np
import pytest
from scipy.integrate import quad

from straylight.thermal.planck import (
    SIGMA,
    band_radiance_w_m2_sr,
    check_band,
    spectral_radiance_w_m2_sr_um,
)


def _planck_um(lam_um, t):
    """Planck's law written out here, independently of the module (CODATA constants)."""
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    lam = lam_um * 1e-6
    return 2 * h * c * c / lam ** 5 / np.expm1(h * c / (lam * k * t)) * 1e-6


@pytest.mark.parametrize("lo,hi,t", [(8, 12, 300), (3, 5, 300), (8, 12, 77), (1, 30, 3000), (0.5, 0.6, 5800),
                                     (100, 1000, 300), (0.3, 2.5, 1000), (7.5, 13.5, 250)])
def test_band_radiance_matches_quadrature(lo, hi, t):
    ref = quad(lambda x: _planck_um(x, t), lo, hi, epsrel=1e-12, limit=500)[0]
    assert band_radiance_w_m2_sr(lo, hi, t) == pytest.approx(ref, rel=1e-9)


def test_whole_spectrum_is_stefan_boltzmann():
    for t in (77.0, 300.0, 5800.0):
        assert band_radiance_w_m2_sr(1e-3, 1e7, t) == pytest.approx(5.670374419e-8 * t ** 4 / np.pi, rel=1e-9)
    assert SIGMA == pytest.approx(5.670374419e-8)


def test_spectral_radiance_and_zero_kelvin():
    assert spectral_radiance_w_m2_sr_um(10.0, 300.0) == pytest.approx(_planck_um(10.0, 300.0), rel=1e-12)
    assert band_radiance_w_m2_sr(8, 12, 0.0) == 0.0
    # the two branches of the series meet (x = 1/2 at lambda T = 28775 um K)
    lam = 28775.5 / 300.0
    a = band_radiance_w_m2_sr(lam * 0.999, lam, 300.0)
    b = quad(lambda x: _planck_um(x, 300.0), lam * 0.999, lam, epsrel=1e-13)[0]
    assert a == pytest.approx(b, rel=1e-7)


@pytest.mark.parametrize("band", [(12, 8), (0, 5), (-1, 2), (float("nan"), 3)])
def test_bad_band_is_one_line_error(band):
    with pytest.raises(ValueError, match="band-um"):
        check_band(*band)
