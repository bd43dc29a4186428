"""True slit width differs from nominal (CONTRACTS §3 ``detector_aperture``).

A wider slit averages the BRDF over a wider in-plane angle: the core drops and
widens, the shoulders rise, the peak's area is kept (PHYSICS §4). Averaging leaves
a BRDF that is linear in the viewing angle unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from rig.effects.registry import check_param, register_effect


@register_effect("detector_aperture")
@dataclass(frozen=True)
class DetectorAperture:
    """The slit's true width in the plane of incidence, mm (None: the rig's nominal width)."""

    width_mm: Optional[float] = None

    # up to a 25 mm detector with no slit in front (a 10 mm photodiode acting as the aperture must
    # lie inside the range: an effect fitted at a bound is never selected)
    fit_space = {"width_mm": (0.02, 25.0, "log", (0.5, 2.0))}
    region = "specular_core"

    def __post_init__(self):
        object.__setattr__(self, "width_mm", check_param("detector_aperture", "width_mm", self.width_mm, 1e-6, None, allow_none=True))

    def wrap(self, forward):
        if self.width_mm is None:
            return forward
        w = self.width_mm

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            return forward(theta_i, theta_r, phi_r, pol, config.replace(slit_width_mm=w), material)

        return wrapped
