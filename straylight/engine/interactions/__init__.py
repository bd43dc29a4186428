"""Surface interactions, the engine's extension point (registry.py; docs/engine.md, "How to add
an interaction kind"). Importing this package registers the built-in kinds."""
from straylight.engine.interactions import delta_reflection, surface_response, terminal  # noqa: F401 - registers them
from straylight.engine.interactions.registry import (  # noqa: F401 - re-exported
    INTERACTIONS, Capability, Handler, Interaction, PartCapabilities, get_interaction, kind_for, kinds_with,
    part_handlers, part_kinds, parts_with, register_interaction)
