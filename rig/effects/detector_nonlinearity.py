"""Detector / lock-in compression at high signal (CONTRACTS §3 ``detector_nonlinearity``).

The detected power is proportional to x = BRDF cos(theta_r); a saturating response
``x / (1 + x / x_sat)`` clips the peak at fixed *signal* level, not at fixed angle
(PHYSICS §4). ``saturation_per_sr`` is x_sat in BRDF x cos units (1/sr): the signal
whose reading is halved. ``inf`` (default) is the ideal linear detector.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.effects.registry import check_param, register_effect


@register_effect("detector_nonlinearity")
@dataclass(frozen=True)
class DetectorNonlinearity:
    """Saturation level of the detector chain, BRDF x cos(theta_r) units, 1/sr."""

    saturation_per_sr: float = math.inf

    fit_space = {"saturation_per_sr": (1e-3, 1e6, "log", (None,))}
    region = "specular_core"

    @staticmethod
    def starts_from_data(signal_per_sr):
        """Fit starts from the training readings x = BRDF cos(theta_r): 3x and 30x the largest."""
        top = float(np.max(signal_per_sr))
        return {"saturation_per_sr": [3.0 * top, 30.0 * top]}

    def __post_init__(self):
        object.__setattr__(self, "saturation_per_sr",
                           check_param("detector_nonlinearity", "saturation_per_sr", self.saturation_per_sr, 1e-12, None, allow_inf=True))

    def wrap(self, forward):
        if math.isinf(self.saturation_per_sr):
            return forward
        sat = self.saturation_per_sr

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            cos_r = np.clip(np.cos(theta_r), 1e-6, None)
            x = forward(theta_i, theta_r, phi_r, pol, config, material) * cos_r
            return x / (1.0 + x / sat) / cos_r

        return wrapped
