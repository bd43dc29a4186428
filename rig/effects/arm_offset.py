"""Zero offset of the detector arm (CONTRACTS §3 ``arm_offset``).

The arm sits ``offset_deg`` further (signed in-plane angle, + toward larger theta_r on
the specular side) than its set-point; the sample is where it should be. The
specular peak moves by -offset in arm angle (PHYSICS §4: by d, not 2d).
"""
from __future__ import annotations

from dataclasses import dataclass

from rig.effects.registry import check_param, register_effect


@register_effect("arm_offset")
@dataclass(frozen=True)
class ArmOffset:
    """Detector-arm zero offset, degrees (true viewing angle = set-point + offset)."""

    offset_deg: float = 0.0

    fit_space = {"offset_deg": (-3.0, 3.0, "lin", (0.0,))}
    region = "specular_core"
    #: the effect whose signature is nearly the same (an arm offset a moves the specular peak by -a in arm angle, a stage offset d by 2d); the diagnosis checks which of
    #: the two the data prefer and reports them confounded when it cannot tell
    twin = "angle_offset"

    @staticmethod
    def twin_params(offset_deg):
        """The angle_offset that moves the specular peak as this one does (a start for the check)."""
        return {"offset_deg": -0.5 * offset_deg}

    def __post_init__(self):
        object.__setattr__(self, "offset_deg", check_param("arm_offset", "offset_deg", self.offset_deg, -45.0, 45.0))

    def wrap(self, forward):
        if self.offset_deg == 0.0:
            return forward
        d = self.offset_deg

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            return forward(theta_i, theta_r, phi_r, pol, config.replace(arm_offset_deg=config.arm_offset_deg + d), material)

        return wrapped
