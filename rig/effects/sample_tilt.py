"""Sample normal tilted out of the plane of incidence (CONTRACTS §3 ``sample_tilt``).

The reflected beam leaves the plane of incidence by ~2 x tilt x cos(theta_i); the
specular peak drops once that exceeds the slit half-height over the arm
(PHYSICS §4: 2.5 mm / 200 mm = 12.5 mrad on the nominal rig). Wings are unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

from rig.effects.registry import check_param, register_effect


@register_effect("sample_tilt")
@dataclass(frozen=True)
class SampleTilt:
    """Out-of-plane tilt of the sample normal, degrees."""

    tilt_deg: float = 0.0

    # The peak is flat in tilt below the slit's half-height, so starts span the useful range.
    fit_space = {"tilt_deg": (0.0, 5.0, "lin", (0.3, 0.6, 1.2))}
    region = "specular_core"

    def __post_init__(self):
        object.__setattr__(self, "tilt_deg", check_param("sample_tilt", "tilt_deg", self.tilt_deg, -30.0, 30.0))

    def wrap(self, forward):
        if self.tilt_deg == 0.0:
            return forward
        t = self.tilt_deg

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            return forward(theta_i, theta_r, phi_r, pol, config.replace(sample_tilt_deg=config.sample_tilt_deg + t), material)

        return wrapped
