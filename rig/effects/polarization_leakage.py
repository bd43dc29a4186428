"""The other polarization leaks into the incident beam (CONTRACTS §3 ``polarization_leakage``).

An s (p) set-point actually illuminates with (1 - fraction) s + fraction p (and the
reverse). The detector has no analyser, so the reading is the same mixture of the two
readings. Near Brewster's angle the p curve is filled in to ~fraction x R_s (PHYSICS §4).
Unpolarized set-points are unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.effects.registry import check_param, register_effect


@register_effect("polarization_leakage")
@dataclass(frozen=True)
class PolarizationLeakage:
    """Fraction of the incident power in the other linear polarization (0..0.5)."""

    fraction: float = 0.0

    fit_space = {"fraction": (1e-5, 0.5, "log", (3e-3, 3e-2))}
    region = "specular_core"

    def __post_init__(self):
        object.__setattr__(self, "fraction", check_param("polarization_leakage", "fraction", self.fraction, 0.0, 1.0))

    def wrap(self, forward):
        if self.fraction == 0.0:
            return forward
        e = self.fraction

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            pol = np.asarray(pol)
            out = forward(theta_i, theta_r, phi_r, pol, config, material)
            swap = np.where(pol == "s", "p", np.where(pol == "p", "s", pol))
            mixed = np.flatnonzero(pol != "u")
            if mixed.size:
                other = forward(theta_i[mixed], theta_r[mixed], phi_r[mixed], swap[mixed], config, material)
                out = np.array(out, float)
                out[mixed] = (1.0 - e) * out[mixed] + e * other
            return out

        return wrapped
