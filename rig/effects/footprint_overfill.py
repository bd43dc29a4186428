"""Beam footprint larger than the sample at grazing incidence (CONTRACTS §3 ``footprint_overfill``).

The footprint along the plane of incidence is beam / cos(theta_i) (x1.41 at 45 deg,
x2.92 at 70, x5.76 at 80; PHYSICS §4). The part beyond the sample's edges is lost,
so every reading at that incidence drops by the same factor: a loss that grows
with theta_i and does not depend on the viewing angle.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from rig.effects.registry import check_param, register_effect


@register_effect("footprint_overfill")
@dataclass(frozen=True)
class FootprintOverfill:
    """The sample's true extent along the plane of incidence, mm (None: the rig's nominal)."""

    sample_width_mm: Optional[float] = None

    fit_space = {"sample_width_mm": (0.3, 100.0, "log", (3.0, 8.0))}
    region = "grazing"

    def __post_init__(self):
        object.__setattr__(self, "sample_width_mm",
                           check_param("footprint_overfill", "sample_width_mm", self.sample_width_mm, 1e-6, None, allow_none=True))

    def wrap(self, forward):
        if self.sample_width_mm is None:
            return forward
        w = self.sample_width_mm

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            return forward(theta_i, theta_r, phi_r, pol, config.replace(sample_width_mm=w), material)

        return wrapped
