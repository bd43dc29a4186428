"""Angular spread of the incident beam (CONTRACTS §3 ``beam_divergence``).

A Gaussian in-plane spread of the incidence direction, ``sigma_mrad``, added in
quadrature to the rig's own ``beam_divergence_mrad``. On a mirror-like sample it
widens the core like a wider aperture would; unlike the aperture it acts on the
incidence, so its footprint on the data grows as the lobe narrows (confounded with
``detector_aperture`` in the core).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from rig.effects.registry import check_param, register_effect


@register_effect("beam_divergence")
@dataclass(frozen=True)
class BeamDivergence:
    """Extra Gaussian sigma of the incidence direction, mrad."""

    sigma_mrad: float = 0.0

    fit_space = {"sigma_mrad": (0.0, 30.0, "lin", (2.0, 6.0))}
    region = "specular_core"

    def __post_init__(self):
        object.__setattr__(self, "sigma_mrad", check_param("beam_divergence", "sigma_mrad", self.sigma_mrad, 0.0, None))

    def wrap(self, forward):
        if self.sigma_mrad == 0.0:
            return forward
        s = self.sigma_mrad

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            total = math.hypot(config.beam_divergence_mrad, s)
            return forward(theta_i, theta_r, phi_r, pol, config.replace(beam_divergence_mrad=total), material)

        return wrapped
