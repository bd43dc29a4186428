"""Which materials get the lobe draws of ``vertex_lobe_sampling`` and ``second_vertex_lobe_sampling``
(straylight.engine.first_vertex.lobe_connection, straylight.engine.second_vertex; docs/engine.md,
"Lobe draws at the sampled vertices"), from the flags the materials declare."""
from __future__ import annotations

import numpy as np

from materials.flags import ComponentFlags, flags_of


def lobe_materials(spec) -> np.ndarray:
    """Per material of ``spec``: does it declare a peaked lobe (``ComponentFlags.GLOSSY``)? The lobe
    draws run only there: for a wide (diffuse) lobe the uniform detector point is already the
    better strategy, and the extra cast cost ~30 % CPU for nothing on the Lambertian benchmark tube.
    Chosen per material, so each vertex's weights still add to one."""
    return np.array([bool(flags_of(m) & ComponentFlags.GLOSSY) for m in spec.materials] + [False], dtype=bool)
