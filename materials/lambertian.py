"""Ideal diffuse reflector.

``f = rd / pi`` (1/sr) for wi and wo above the horizon; its directional-
hemispherical reflectance is ``rd`` at every incidence angle (seed paper Eq. 2,
diffuse term; PHYSICS §2). Sampled exactly: uniform in the unit beta disk
(cosine-weighted hemisphere), weight ``rd``.

Parameters
----------
rd : float
    Hemispherical (diffuse) reflectance, 0 <= rd < 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.base import Sample, check_polarization
from materials.fit_params import FitParam
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import (
    check_real,
    direction_uniforms,
    sample_cosine_hemisphere,
    sample_cosine_hemisphere_weighted,
    set_fields,
)

@register("lambertian")
@dataclass(frozen=True)
class Lambertian:
    """Ideal diffuse reflector, f = rd / pi (CONTRACTS §5)."""

    rd: float

    #: fitted parameters (materials.fit_params): the albedo, its start from the scan's low quantile
    fit_params = (FitParam("rd", 1e-6, 0.99, True),)

    flags = ComponentFlags.DIFFUSE
    reciprocal = True

    def __post_init__(self):
        set_fields(self, rd=check_real("lambertian", "rd", self.rd, lo=0.0, hi=1.0, hi_open=True))

    @classmethod
    def example(cls) -> "Lambertian":
        return cls(rd=0.03)

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """BRDF in 1/sr (no cos). wi, wo : (n, 3) unit vectors, sample frame."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return np.where(above, self.rd / np.pi, 0.0)

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """Cosine-weighted draw; weight f cos / pdf = rd."""
        check_polarization(polarization)
        return sample_cosine_hemisphere_weighted(wi, direction_uniforms(u), self.rd)

    def sample_direction(self, wi, u) -> np.ndarray:
        """The directions ``sample`` would draw, without weights (used by composites)."""
        return sample_cosine_hemisphere(direction_uniforms(u))

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """cos(theta_r) / pi per sr above the horizon."""
        cos_r = np.asarray(wo, float)[:, 2]
        return np.where((np.asarray(wi, float)[:, 2] > 0) & (cos_r > 0), cos_r / np.pi, 0.0)

    def to_dict(self) -> dict:
        return {"type": "lambertian", "rd": self.rd}
