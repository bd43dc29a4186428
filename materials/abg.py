"""ABg scatter model (Zemax, FRED): ``f = A / (B + |beta - beta0|^g)`` in 1/sr.

No cos factors (PHYSICS §2). g = 0 is a constant BRDF A / (B + 1) (Lambertian with
rho = pi A / (B + 1)); far from specular the log-log slope is -g. Since
|beta - beta0| = |wo_xy + wi_xy| is symmetric in wi, wo, this form is reciprocal.

Parameters
----------
a : float
    A, 1/sr (>= 0).
b : float
    B (> 0), dimensionless; sets the flat top, of width ~ B^(1/g) in beta.
g : float
    Slope, >= 0.

Validity: an empirical fit; nothing prevents rho > 1 (FRED: A / B times the projected
solid angle of the specular direction must stay below 1), so materials are checked
with the directional-hemispherical reflectance (materials.material).

Sampling: the radial proposal ``(1 + r^2 / l^2)^(-g/2)`` with ``l = B^(1/g)``, which
is exact for g = 2 (``r = sqrt(B [(1 + Rmax^2/B)^u - 1])``, PHYSICS §3) and has the
same core width and tail slope otherwise; the weight ``f cos / pdf`` corrects the rest.
g = 0: uniform over the disk r <= 1 + |beta0|.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from materials.base import Sample, check_polarization, lobe_inputs
from materials.fit_params import FitParam
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import check_real, lobe_direction, lobe_pdf, lobe_sample, set_fields


@register("abg")
@dataclass(frozen=True)
class Abg:
    """ABg model, f = A / (B + |beta - beta0|^g) (CONTRACTS §5 ``abg``)."""

    a: float
    b: float
    g: float

    flags = ComponentFlags.GLOSSY
    reciprocal = True
    #: fitted parameters (materials.fit_params)
    fit_params = (
        FitParam("a", 1e-10, 1e4, True, 1e-3, (1e-5, 1e-1)),
        FitParam("b", 1e-10, 1.0, True, 1e-4, (1e-6, 1e-2)),
        FitParam("g", 0.0, 4.0, False, 2.0, (1.0, 3.0)),
    )

    def __post_init__(self):
        set_fields(
            self,
            a=check_real("abg", "a", self.a, lo=0.0),
            b=check_real("abg", "b", self.b, lo=0.0, lo_open=True),
            g=check_real("abg", "g", self.g, lo=0.0),
        )

    @classmethod
    def example(cls) -> "Abg":
        return cls(a=0.001, b=0.0001, g=2.0)

    @cached_property
    def width(self) -> float:
        """Proposal width l = B^(1/g) in beta (1 for g = 0, where the shape is flat)."""
        return 1.0 if self.g == 0 else float(self.b ** (1.0 / self.g))

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """BRDF in 1/sr (no cos). wi, wo : (n, 3) unit vectors."""
        wi, wo, above, d = lobe_inputs(wi, wo, polarization)
        x = np.hypot(d[:, 0], d[:, 1])
        return np.where(above, self.a / (self.b + x**self.g), 0.0)

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        check_polarization(polarization)
        return lobe_sample(self, wi, u, polarization, self.width, self.g)

    def sample_direction(self, wi, u) -> np.ndarray:
        """The directions ``sample`` would draw, without weights (used by composites)."""
        return lobe_direction(wi, u, self.width, self.g)

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        return lobe_pdf(wi, wo, self.width, self.g)

    def to_dict(self) -> dict:
        return {"type": "abg", "a": self.a, "b": self.b, "g": self.g}
