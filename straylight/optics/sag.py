"""Sag of an imported surface along its own +z (lens-file convention; docs/optics.md)."""
from __future__ import annotations

import math

import numpy as np


def sag_mm(s, rho):
    """Sag of surface ``s`` at ``rho`` along its own +z (lens-file convention): the conic's
    c rho^2 / (1 + sqrt(1 - (1 + k) c^2 rho^2)) plus the even polynomial (a_i rho^(2i + 4)) and any other
    power terms (a_p |rho|^p). ``rho`` a float (a float back) or an array (an array back)."""
    if isinstance(rho, np.ndarray):
        return _sag_array(s, rho)
    h = 0.0
    if s.radius_mm:
        c = 1.0 / s.radius_mm
        arg = 1.0 - (1.0 + s.conic) * c * c * rho * rho
        h = c * rho * rho / (1.0 + math.sqrt(max(arg, 0.0)))
    for i, a in enumerate(s.coefficients):
        h += a * rho ** (2 * i + 4)
    for p, a in getattr(s, "power_terms", ()):
        h += a * abs(rho) ** p
    return h


def _sag_array(s, rho: np.ndarray) -> np.ndarray:
    """:func:`sag_mm` at every element of ``rho``."""
    rho = np.asarray(rho, dtype=np.float64)
    h = np.zeros_like(rho)
    if s.radius_mm:
        c = 1.0 / s.radius_mm
        arg = 1.0 - (1.0 + s.conic) * c * c * rho * rho
        h = c * rho * rho / (1.0 + np.sqrt(np.maximum(arg, 0.0)))
    for i, a in enumerate(s.coefficients):
        h = h + a * rho ** (2 * i + 4)
    for p, a in getattr(s, "power_terms", ()):
        h = h + a * np.abs(rho) ** p
    return h
