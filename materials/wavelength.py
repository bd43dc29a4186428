"""Materials at another wavelength, and their emissivity by Kirchhoff's law (CONTRACTS §7).

- ``k_correlation``: the lobe keeps its surface spectrum. Its ABC PSD is fixed by ``sigma_nm``,
  ``lc_um`` and ``s`` at the file's wavelength lambda0 (PHYSICS §1: sigma is band-limited to
  0 <= f <= 1/lambda0); at lambda the same PSD band-limited to 1/lambda has::

      sigma(lambda)^2 = sigma0^2 g(lambda) / g(lambda0),
      g = [1 - (1 + (B/lambda)^2)^(1 - s/2)] / (s - 2)    (s = 2: ln(1 + (B/lambda)^2) / 2),  B = 2 pi lc

  so the lobe built from ``sigma(lambda)`` at lambda *is* Rayleigh-Rice of the same PSD at lambda
  (BRDF = 16 pi^2 / lambda^4 cos cos Q S2(|beta - beta0| / lambda)).
- ``particulate``: Mie scattering recomputed at the new wavelength.
- every other component (lambertian, abg, harvey_shack, tabulated, microfacet, specular,
  dielectric): wavelength-independent; an index ``n`` given as a number stays constant.

Emissivity (Kirchhoff): epsilon(lambda, theta) = 1 - rho(lambda, theta) - T(lambda, theta), rho the
directional-hemispherical reflectance of all components (scatter lobes plus the specular part),
T the transmittance of a ``dielectric``; unpolarized (the mean of s and p).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from materials.albedo import directional_hemispherical_reflectance
from materials.material import Material

WAVELENGTH_DEPENDENT = ("k_correlation", "particulate")


def _type(c) -> str:
    return getattr(c, "type_name", None) or c.to_dict().get("type", type(c).__name__)


def _psd_band(lc_um: float, s: float, wavelength_nm: float) -> float:
    """g(lambda) of the module docstring (B and lambda in um)."""
    x = (2.0 * math.pi * lc_um / (wavelength_nm * 1e-3)) ** 2
    a = 1.0 - 0.5 * s
    if abs(a) < 1e-9:
        return 0.5 * math.log1p(x)
    return -math.expm1(a * math.log1p(x)) / (s - 2.0)


def sigma_at_wavelength_nm(sigma_nm: float, lc_um: float, s: float, from_nm: float, to_nm: float) -> float:
    """rms roughness of the same ABC PSD band-limited to 1/``to_nm`` instead of 1/``from_nm``."""
    return float(sigma_nm) * math.sqrt(_psd_band(lc_um, s, to_nm) / _psd_band(lc_um, s, from_nm))


def _coated(c) -> bool:
    return getattr(c, "coating", None) is not None


def wavelength_dependent(material) -> bool:
    """Does any component change with wavelength (so that a band needs several traced wavelengths)?
    A coated ``specular`` or ``dielectric`` does: its layers' phase thicknesses scale with 1/lambda."""
    return any(_type(c) in WAVELENGTH_DEPENDENT or _coated(c) for c in getattr(material, "components", ()))


def at_wavelength(material, wavelength_nm: float):
    """The material evaluated at ``wavelength_nm`` (module docstring); the material itself when
    nothing in it depends on wavelength."""
    if not wavelength_dependent(material):
        return material
    lam = float(wavelength_nm)
    comps = []
    for c in material.components:
        kind = _type(c)
        if kind == "k_correlation":
            lam0 = c.wavelength_nm if c.wavelength_nm is not None else material.wavelength_nm
            c = dataclasses.replace(c, sigma_nm=sigma_at_wavelength_nm(c.sigma_nm, c.lc_um, c.s, lam0, lam),
                                    wavelength_nm=lam)
        elif kind == "particulate" or _coated(c):
            c = dataclasses.replace(c, wavelength_nm=lam)  # a coating keeps its physical thicknesses
        comps.append(c)
    return Material(name=material.name, wavelength_nm=lam, components=tuple(comps),
                    description=material.description, provenance=material.provenance)


#: (id(material), wavelength) -> (material, its coatings at that wavelength): the same object for the same
#: input, so the tracer's tables, kept by the materials' identity, stay valid across calls
_COATINGS_AT: dict = {}


def coatings_at(material, wavelength_nm: float):
    """``material`` with every coated ``specular`` / ``dielectric`` component evaluated at ``wavelength_nm``
    (the traced wavelength, CONTRACTS 5.1: a coating keeps its physical thicknesses, its phase thicknesses
    scale with 1 / lambda); the material itself when it has no coating or its coatings are already there.
    Scatter lobes keep the material's wavelength (``trace`` and ``pst``; ``thermal`` evaluates them too:
    :func:`at_wavelength`)."""
    comps = getattr(material, "components", None)
    lam = float(wavelength_nm)
    if not comps or not any(_coated(c) and getattr(c, "wavelength_nm", None) != lam for c in comps):
        return material
    key = (id(material), lam)
    hit = _COATINGS_AT.get(key)
    if hit is not None and hit[0] is material:
        return hit[1]
    out = dataclasses.replace(material, components=tuple(
        dataclasses.replace(c, wavelength_nm=lam) if _coated(c) else c for c in comps))
    _COATINGS_AT[key] = (material, out)
    return out


def emissivity(material, theta_rad) -> np.ndarray:
    """epsilon(theta) = 1 - rho(theta) - T(theta) on the front side, unpolarized (Kirchhoff), clipped to [0, 1].

    ``material``: a :class:`materials.material.Material` or any Brdf (then rho is its quadrature albedo)."""
    th = np.atleast_1d(np.asarray(theta_rad, float))
    if hasattr(material, "reflectance") and hasattr(material, "transmittance"):
        rho = material.reflectance(th, "u") + material.transmittance(th, "u")
    else:
        rho = 0.5 * (directional_hemispherical_reflectance(material, th, "s")
                     + directional_hemispherical_reflectance(material, th, "p"))
    return np.clip(1.0 - rho, 0.0, 1.0)


def hemispherical_emissivity(eps_of_theta, theta_rad) -> float:
    """epsilon_h = 2 integral_0^{pi/2} epsilon(theta) cos sin d theta over [0, pi/2] (trapezoid on the
    given grid, normalised by the same rule's integral of 2 cos sin, so a constant is exact)."""
    th = np.asarray(theta_rad, float)
    w = np.sin(2.0 * th)  # 2 cos sin
    return float(np.trapezoid(np.asarray(eps_of_theta, float) * w, th) / np.trapezoid(w, th))
