"""Surface interactions, the engine's extension point (registry.py; docs/engine.md, "How to add
an interaction kind"). Importing this package registers the built-in kinds."""
from straylight.engine.interactions import brdf_scatter, delta_reflection, optical_surface, terminal  # noqa: F401 - registers them
from straylight.engine.interactions.registry import (  # noqa: F401 - re-exported
    INTERACTIONS, Capability, Interaction, PartCapabilities, get_interaction, kind_for, part_kinds, parts_with,
    register_interaction)
