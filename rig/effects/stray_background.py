"""Additive stray light / noise floor (CONTRACTS §3 ``stray_background``).

A constant *power* floor P_b at the detector reads, in the rig's BRDF units
``P / (P_i Omega cos theta_r)``, as ``level_per_sr / cos(theta_r)``: it rises toward
grazing viewing (PHYSICS §4; a constant BRDF-level floor would be indistinguishable
from the Lambertian term). ``level_per_sr`` is the floor's BRDF equivalent at normal
viewing. Added after the instrument: nothing else changes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.effects.registry import check_param, register_effect


@register_effect("stray_background")
@dataclass(frozen=True)
class StrayBackground:
    """Constant power floor, as its BRDF equivalent at theta_r = 0, 1/sr."""

    level_per_sr: float = 0.0

    fit_space = {"level_per_sr": (1e-9, 1.0, "log", (None,))}
    region = "wing"

    @staticmethod
    def starts_from_data(signal_per_sr):
        """Fit starts from the training readings x = BRDF cos(theta_r): 30 % and 3 % of their 5th
        percentile (a floor lies under the darkest readings)."""
        p5 = float(np.percentile(signal_per_sr, 5))
        return {"level_per_sr": [0.3 * p5, 0.03 * p5]}

    def __post_init__(self):
        object.__setattr__(self, "level_per_sr", check_param("stray_background", "level_per_sr", self.level_per_sr, 0.0, None))

    def wrap(self, forward):
        if self.level_per_sr == 0.0:
            return forward
        level = self.level_per_sr

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            cos_r = np.clip(np.cos(theta_r), 1e-6, None)
            return forward(theta_i, theta_r, phi_r, pol, config, material) + level / cos_r

        return wrapped
