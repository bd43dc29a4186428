"""Zero offset of the sample stage (CONTRACTS §3 ``angle_offset``).

The sample normal is turned by ``offset_deg`` from where the stage believes it is:
true incidence = set-point + offset, and the arm angle, measured from the believed
normal, is off by -offset. The specular peak therefore moves by 2 x offset in arm
angle (PHYSICS §4), and the residual is antisymmetric about specular.
"""
from __future__ import annotations

from dataclasses import dataclass

from rig.effects.registry import check_param, register_effect


@register_effect("angle_offset")
@dataclass(frozen=True)
class AngleOffset:
    """Sample-stage zero offset, degrees (true incidence = set-point + offset)."""

    offset_deg: float = 0.0

    fit_space = {"offset_deg": (-3.0, 3.0, "lin", (0.0,))}
    region = "specular_core"
    #: the effect whose signature is nearly the same (a stage offset d moves the specular peak by 2d in arm angle, an arm offset a by -a); the diagnosis checks which of
    #: the two the data prefer and reports them confounded when it cannot tell
    twin = "arm_offset"

    @staticmethod
    def twin_params(offset_deg):
        """The arm_offset that moves the specular peak as this one does (a start for the check)."""
        return {"offset_deg": -2.0 * offset_deg}

    def __post_init__(self):
        object.__setattr__(self, "offset_deg", check_param("angle_offset", "offset_deg", self.offset_deg, -45.0, 45.0))

    def wrap(self, forward):
        if self.offset_deg == 0.0:
            return forward
        d = self.offset_deg

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            return forward(theta_i, theta_r, phi_r, pol, config.replace(stage_offset_deg=config.stage_offset_deg + d), material)

        return wrapped
