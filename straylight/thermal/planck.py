"""Planck's law: spectral and band radiance of a blackbody, vacuum wavelengths.

Spectral radiance (W m^-2 sr^-1 m^-1)::

    B_lambda(T) = 2 h c^2 / lambda^5 / (exp(x) - 1),   x = h c / (lambda k T)

Band radiance B_band(T) = integral of B_lambda over [lo, hi], from the blackbody fraction
F(0 -> lambda) of the total radiance sigma T^4 / pi::

    F = (15 / pi^4) sum_n exp(-n x) / n (x^3 + 3 x^2 / n + 6 x / n^2 + 6 / n^3)       (x >= 1/2)
    F = 1 - (15 / pi^4) (x^3/3 - x^4/8 + x^5/60 - x^7/5040 + x^9/272160 - ...)        (x < 1/2)

(Siegel & Howell, *Thermal Radiation Heat Transfer*, the series for the blackbody functions;
the small-x branch is the Bernoulli expansion sum_k B_k x^(k+3) / (k! (k+3)) of
integral_0^x t^3 / (e^t - 1) dt, whose terms fall by (x / 2 pi)^2 < 0.007: below 1e-15 at k = 14.) Checked against an adaptive quadrature of B_lambda and
against Stefan-Boltzmann (tests/straylight/test_thermal_planck.py, benchmarks/thermal.py).
"""
from __future__ import annotations

from math import factorial

import numpy as np
from scipy import constants

H = constants.h
C = constants.c
K_B = constants.k
C2_M_K = H * C / K_B  # second radiation constant, m K
SIGMA = constants.Stefan_Boltzmann


def spectral_radiance_w_m2_sr_um(wavelength_um, temperature_k):
    """B_lambda in W m^-2 sr^-1 um^-1 (0 at T = 0)."""
    lam = np.asarray(wavelength_um, float) * 1e-6
    t = np.asarray(temperature_k, float)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        x = C2_M_K / (lam * t)
        b = 2.0 * H * C * C / lam ** 5 / np.expm1(x)
    return np.where(t > 0, b, 0.0) * 1e-6


def _fraction_below(x):
    """Blackbody fraction F(0 -> lambda) at x = c2 / (lambda T) (array)."""
    from scipy.special import bernoulli

    x = np.asarray(x, float)
    out = np.empty_like(x)
    big = x >= 0.5
    xb = np.minimum(x[big], 1e4)  # beyond, F underflows to 0 anyway (exp(-1e4))
    acc = np.zeros_like(xb)
    for n in range(1, 90):  # exp(-0.5 * 90) < 3e-20: converged for x >= 1/2
        acc += np.exp(-n * xb) / n * (xb ** 3 + 3 * xb ** 2 / n + 6 * xb / n ** 2 + 6.0 / n ** 3)
    out[big] = 15.0 / np.pi ** 4 * acc
    xs = x[~big]
    b = bernoulli(16)
    b[1] = -0.5  # the expansion of t / (e^t - 1)
    series = sum(b[k] * xs ** (k + 3) / (factorial(k) * (k + 3)) for k in range(17))
    out[~big] = 1.0 - 15.0 / np.pi ** 4 * series
    return out


def band_radiance_w_m2_sr(lo_um, hi_um, temperature_k):
    """B_band = integral_lo^hi B_lambda d lambda in W m^-2 sr^-1 (broadcast over the arguments)."""
    lo, hi, t = np.broadcast_arrays(np.asarray(lo_um, float), np.asarray(hi_um, float),
                                    np.asarray(temperature_k, float))
    total = SIGMA * t ** 4 / np.pi
    with np.errstate(divide="ignore", invalid="ignore"):
        x_lo = np.where(t > 0, C2_M_K / (lo * 1e-6 * t), np.inf)
        x_hi = np.where(t > 0, C2_M_K / (hi * 1e-6 * t), np.inf)
    f_lo = np.where(np.isinf(x_lo), 0.0, _fraction_below(np.where(np.isinf(x_lo), 50.0, x_lo)))
    f_hi = np.where(np.isinf(x_hi), 0.0, _fraction_below(np.where(np.isinf(x_hi), 50.0, x_hi)))
    out = total * (f_hi - f_lo)
    return float(out) if out.ndim == 0 else out


def check_band(lo_um, hi_um) -> tuple[float, float]:
    """(lo, hi) as floats; a one-line error unless 0 < lo < hi."""
    try:
        lo, hi = float(lo_um), float(hi_um)
    except (TypeError, ValueError):
        raise ValueError(f"--band-um: two numbers expected, got {lo_um!r} {hi_um!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"--band-um: need 0 < LO < HI (micrometres), got {lo_um!r} {hi_um!r}")
    return lo, hi
