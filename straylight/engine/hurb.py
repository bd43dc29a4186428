"""Heisenberg uncertainty ray bending (HURB): the deflection law of edge diffraction.

A ray that passes a diffracting edge at distance ``delta_b`` (seen along the ray) is bent
(Freniere, Gregory and Hassler, Proc. SPIE 3780, 1999; Coffey et al. 1998): its position across
the edge is known to ``delta_b``, so its transverse wave number is uncertain by
``Delta k_b = gamma / (2 delta_b)`` (Heisenberg, ``Delta x Delta p >= hbar / 2``), and

    tan(theta_b) ~ Normal(0, tan sigma_b),   tan sigma_b = gamma / (2 k delta_b),   k = 2 pi / lambda

across the edge (direction ``b``, perpendicular to the ray, from the edge toward the ray), and
likewise along the edge with the ellipse's other semi-axis ``delta_a`` (the 2-D form: for a hole of
radius R, ``delta_a = sqrt(delta_b R)``, the ellipse matching the rim's curvature; a straight edge has
``delta_a = inf``, the 1-D law). New direction: normalise ``s + b tan(theta_b) + a tan(theta_a)``,
``a = s x b`` (tangents, not angles, are Gaussian: the ray stays in the forward half-space).

``gamma``: Freniere's uncertainty product gives gamma = 1. With it the power bent beyond a wide
angle is sqrt(pi / 2) = 1.25 times the wave-optics value; we take gamma = sqrt(2 / pi) (0.80), which
makes the 1-D law's wide-angle envelope equal the exact one: a half-plane's deep-shadow irradiance
z / (2 pi k x^2) (Fresnel knife edge, 1 / (2 pi^2 w^2)) and a slit's or a hole's mean Fraunhofer
tail. docs/diffraction.md gives the derivation and the checks. The deflection keeps the ray's
power: the ledger is untouched.
"""
from __future__ import annotations

import math

import numpy as np

METHOD = "HURB (Heisenberg uncertainty ray bending, Freniere et al. 1999)"  # the method's name in help and pst.json
GAMMA = math.sqrt(2.0 / math.pi)  # default uncertainty factor (module docstring)
FRENIERE_GAMMA = 1.0  # Freniere et al. 1999


def wave_number_per_mm(wavelength_nm: float) -> float:
    return 2.0 * math.pi / (float(wavelength_nm) * 1e-6)


def tan_sigma(delta_mm, wavelength_nm: float, gamma: float = GAMMA):
    """tan sigma = gamma / (2 k delta) (0 where delta is inf)."""
    k = wave_number_per_mm(wavelength_nm)
    delta = np.asarray(delta_mm, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(delta), gamma / (2.0 * k * delta), 0.0)


def gaussian_pair(u0, u1):
    """Two independent standard normals per row from two uniforms (Box-Muller)."""
    r = np.sqrt(-2.0 * np.log1p(-np.asarray(u0, dtype=np.float64)))
    phi = 2.0 * np.pi * np.asarray(u1, dtype=np.float64)
    return r * np.cos(phi), r * np.sin(phi)


def deflect(direction, b, delta_b_mm, delta_a_mm, wavelength_nm: float, u0, u1, gamma: float = GAMMA):
    """HURB-deflected unit directions (n, 3) (module docstring). ``b``: (n, 3) unit, perpendicular
    to ``direction``; ``u0, u1``: uniforms."""
    s = np.asarray(direction, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = np.cross(s, b)
    g_b, g_a = gaussian_pair(u0, u1)
    tb = tan_sigma(delta_b_mm, wavelength_nm, gamma) * g_b
    ta = tan_sigma(delta_a_mm, wavelength_nm, gamma) * g_a
    out = s + tb[:, None] * b + ta[:, None] * a
    return out / np.linalg.norm(out, axis=1, keepdims=True)
