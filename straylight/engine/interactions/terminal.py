"""The terminal interactions, tallied by the hit stage (straylight.engine.hits) in the same pass
that finds the hit point: ``detection`` (count the walk hit, with its MIS share against NEE) and
``absorption``. Registered so that every part has a named kind."""
from __future__ import annotations

from straylight.engine.interactions.registry import Capability, Interaction, register_interaction


@register_interaction
class Detection(Interaction):
    name = "detection"
    roles = ("detector",)
    terminal = True
    capabilities = Capability.NONE


@register_interaction
class Absorption(Interaction):
    name = "absorption"
    roles = ("absorber",)
    terminal = True
    capabilities = Capability.NONE
