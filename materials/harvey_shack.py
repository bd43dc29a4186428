"""Harvey-Shack ("modified three-term Harvey", FRED): ``f = b0 (1 + (|beta - beta0| / l)^2)^(s/2)``.

No cos factors (PHYSICS §2). It is the K-correlation shape with ``l = lambda / B``,
``s = -s_K`` and b0 the Dittman prefactor times the cosines; ABg equals it only for
g = 2 (B_ABg = l^2, A = b0 l^2). Symmetric in wi, wo, hence reciprocal.

Parameters
----------
b0 : float
    BRDF at specular, 1/sr (>= 0).
l : float
    Shoulder (roll-off) width in beta units (> 0).
s : float
    Log-log slope far from specular (usually negative, e.g. -2).

Validity: empirical; rho may exceed 1 for large b0 (checked per material).

Sampling: the radial inverse CDF of PHYSICS §3 with slope -s about beta0 (exact for
this shape); weight ``b0 * norm`` above the horizon, 0 below.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.base import Sample, check_polarization, lobe_inputs
from materials.fit_params import FitParam
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import check_real, lobe_direction, lobe_pdf, lobe_sample, set_fields


@register("harvey_shack")
@dataclass(frozen=True)
class HarveyShack:
    """Harvey-Shack model (CONTRACTS §5 ``harvey_shack``)."""

    b0: float
    l: float  # noqa: E741 - the CONTRACTS key
    s: float

    flags = ComponentFlags.GLOSSY
    reciprocal = True
    #: fitted parameters (materials.fit_params)
    fit_params = (
        FitParam("b0", 1e-6, 1e8, True, 10.0, (0.1, 1e4)),
        FitParam("l", 1e-5, 1.0, True, 0.01, (1e-4, 0.1)),
        FitParam("s", -8.0, 0.0, False, -2.0, (-4.0, -1.0)),
    )

    def __post_init__(self):
        set_fields(
            self,
            b0=check_real("harvey_shack", "b0", self.b0, lo=0.0),
            l=check_real("harvey_shack", "l", self.l, lo=0.0, lo_open=True),
            s=check_real("harvey_shack", "s", self.s),
        )

    @classmethod
    def example(cls) -> "HarveyShack":
        return cls(b0=10.0, l=0.01, s=-2.0)

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """BRDF in 1/sr (no cos). wi, wo : (n, 3) unit vectors."""
        wi, wo, above, d = lobe_inputs(wi, wo, polarization)
        r2 = d[:, 0] ** 2 + d[:, 1] ** 2
        return np.where(above, self.b0 * np.exp(0.5 * self.s * np.log1p(r2 / self.l**2)), 0.0)

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        check_polarization(polarization)
        return lobe_sample(self, wi, u, polarization, self.l, -self.s)

    def sample_direction(self, wi, u) -> np.ndarray:
        """The directions ``sample`` would draw, without weights (used by composites)."""
        return lobe_direction(wi, u, self.l, -self.s)

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        return lobe_pdf(wi, wo, self.l, -self.s)

    def to_dict(self) -> dict:
        return {"type": "harvey_shack", "b0": self.b0, "l": self.l, "s": self.s}
