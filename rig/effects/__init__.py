"""Instrument-effect catalogue (CONTRACTS §3): one module per effect, registered by name.

``build_effect("angle_offset", offset_deg=0.1).wrap(forward)`` returns a forward model
with the same signature (:data:`rig.forward.Forward`); effects stack in order, and at
zero strength each is exactly the identity.
"""
from rig.effects.registry import EffectError, build_effect, effect_names, effect_types, register_effect
from rig.effects.angle_offset import AngleOffset
from rig.effects.arm_offset import ArmOffset
from rig.effects.sample_tilt import SampleTilt
from rig.effects.detector_aperture import DetectorAperture
from rig.effects.beam_divergence import BeamDivergence
from rig.effects.footprint_overfill import FootprintOverfill
from rig.effects.polarization_leakage import PolarizationLeakage
from rig.effects.stray_background import StrayBackground
from rig.effects.detector_nonlinearity import DetectorNonlinearity
from rig.effects.substrate_reflection import SubstrateReflection

CATALOGUE = (
    "angle_offset", "arm_offset", "sample_tilt", "detector_aperture", "beam_divergence",
    "footprint_overfill", "polarization_leakage", "stray_background", "detector_nonlinearity",
    "substrate_reflection",
)

__all__ = [
    "EffectError", "build_effect", "effect_names", "effect_types", "register_effect", "CATALOGUE",
    "AngleOffset", "ArmOffset", "SampleTilt", "DetectorAperture", "BeamDivergence", "FootprintOverfill",
    "PolarizationLeakage", "StrayBackground", "DetectorNonlinearity", "SubstrateReflection",
]
