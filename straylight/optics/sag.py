"""Sag of an imported surface along its own +z (lens-file convention; docs/optics.md)."""
from __future__ import annotations

import math


def sag_mm(s, rho: float) -> float:
    """Sag of surface ``s`` at ``rho`` along its own +z (lens-file convention)."""
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
