"""Light reflected by the substrate under a semi-transparent coating (CONTRACTS §3 ``substrate_reflection``).

Part of the beam crosses the coating, reflects off the (smooth) substrate and comes
back out near the specular direction, blurred by the coating: an extra specular
lobe with a fast (Gaussian) fall-off, unlike the power-law tails of a roughness
lobe (PHYSICS §4: "extra specular energy or a ghost lobe"). In projected
coordinates (cos theta_r dOmega = d beta_x d beta_y, PHYSICS §3)::

    f_sub = attenuation / (2 pi w^2) exp(-|beta - beta0|^2 / (2 w^2))

with w = lobe_width_deg (radians) x cos(theta_i), so the lobe returns the fraction
``attenuation`` of the incident power (less what falls below the horizon) and is
``lobe_width_deg`` wide in viewing angle. It is added to the material before the
instrument averaging.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.effects.registry import check_param, register_effect
from rig.node_integrals import cached_integral


@dataclass(frozen=True, eq=False)
class _WithSubstrate:
    """A material plus the substrate's ghost lobe (Brdf protocol: brdf only)."""

    material: object
    attenuation: float
    width_rad: float

    def brdf_geom(self, geom, polarization="u"):
        """Same as :meth:`brdf` from cached node geometry (rig.diagnose.node_geometry)."""
        base = self.material.brdf_geom(geom, polarization)
        w = self.width_rad * np.clip(geom["cos_i"], 1e-6, None)
        lobe = self.attenuation / (2 * math.pi * w**2) * np.exp(-0.5 * geom["r2"] / w**2)
        return base + np.where(geom["above"], lobe, 0.0)

    def reading_geom(self, geom, weight, polarization="u"):
        """Instrument reading from cached node geometry (rig.diagnose.NodeCache); the ghost
        lobe's integral is cached per width (its amplitude is linear)."""
        def unit_lobe():
            w = self.width_rad * np.clip(geom["cos_i"], 1e-6, None)
            return np.where(geom["above"], np.exp(-0.5 * geom["r2"] / w**2) / (2 * math.pi * w**2), 0.0)

        base = self.material.reading_geom(geom, weight, polarization)
        return base + self.attenuation * cached_integral(geom, weight, ("substrate", self.width_rad), unit_lobe)

    @property
    def supports_geom(self) -> bool:
        return getattr(self.material, "supports_geom", False)

    def brdf(self, wi, wo, polarization="u"):
        base = self.material.brdf(wi, wo, polarization)
        d = np.asarray(wo)[:, :2] + np.asarray(wi)[:, :2]
        w = self.width_rad * np.clip(wi[:, 2], 1e-6, None)
        lobe = self.attenuation / (2 * math.pi * w**2) * np.exp(-0.5 * (d[:, 0] ** 2 + d[:, 1] ** 2) / w**2)
        return base + np.where((wo[:, 2] > 0) & (wi[:, 2] > 0), lobe, 0.0)


@register_effect("substrate_reflection")
@dataclass(frozen=True)
class SubstrateReflection:
    """Ghost specular lobe from the substrate: power fraction ``attenuation`` (0..1),
    Gaussian sigma ``lobe_width_deg`` in viewing angle."""

    attenuation: float = 0.0
    lobe_width_deg: float = 0.5

    fit_space = {
        "attenuation": (1e-7, 0.5, "log", (None,)),
        "lobe_width_deg": (0.05, 10.0, "log", (0.3, 1.5)),
    }
    region = "shoulder"

    def __post_init__(self):
        object.__setattr__(self, "attenuation", check_param("substrate_reflection", "attenuation", self.attenuation, 0.0, 1.0))
        object.__setattr__(self, "lobe_width_deg",
                           check_param("substrate_reflection", "lobe_width_deg", self.lobe_width_deg, 1e-6, 90.0))

    def wrap(self, forward):
        if self.attenuation == 0.0:
            return forward
        att = self.attenuation
        width = math.radians(self.lobe_width_deg)

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            return forward(theta_i, theta_r, phi_r, pol, config, _WithSubstrate(material, att, width))

        return wrapped
