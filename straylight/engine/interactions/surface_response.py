"""``surface_response``: what a ``surface`` part does with a ray, one kind for every material --
scatter lobes, Fresnel interfaces, or both -- chosen per hit from the flags its components declare
(materials.flags.ComponentFlags), never from a name. Combined physics (a coated mirror that
scatters, a lens with a rough face) is a material with several components, not a new kind.

Per material, from its flags (:func:`material_class`, :meth:`SurfaceResponse.capabilities_for`):

============  =============================  ==========================================================
class         flags                          algorithm, and what the estimators may do there
============  =============================  ==========================================================
``scatter``   no ``DELTA`` component         :class:`~straylight.engine.interactions.brdf_scatter.BrdfScatter`
                                             (the material samples the new direction): NEE,
                                             FIRST_VERTEX, SECOND_VERTEX, TARGET_MIS
``Fresnel``   a ``DELTA_REFLECTION`` or      :class:`~straylight.engine.interactions.optical_surface.OpticalSurface`
              ``DELTA_TRANSMISSION``         (exact surface, Fresnel s/p branches, lobes, bulk
              component                      absorption): NEE (from the lobes), REFLECTION_SPLIT,
                                             DELTA_CHAIN
(any)         a ``POLARIZING`` component     + POLARIZES (estimators that evaluate vertices
                                             unpolarized stay out: second_vertex.unsupported)
============  =============================  ==========================================================

The two algorithms are plain :class:`~straylight.engine.interactions.registry.Handler` classes (not
registered kinds). The walk asks each part's handler (:meth:`SurfaceResponse.handler_for`) and runs
the hits of an event grouped by handler, in the order the parts first use them
(straylight.engine.walk); :meth:`SurfaceResponse.interact` does the same dispatch for any selection.
"""
from __future__ import annotations

import numpy as np

from materials.flags import ComponentFlags, flags_of
from straylight.engine.event import combined_outgoing
from straylight.engine.interactions.brdf_scatter import BrdfScatter
from straylight.engine.interactions.optical_surface import OpticalSurface
from straylight.engine.interactions.registry import Capability, Interaction, handler, register_interaction

SCATTER = "scatter"  # no delta component: the material samples every outgoing direction
FRESNEL = "Fresnel"  # a smooth (delta) interface, with or without scatter lobes

#: What the estimators may do at a vertex, per material class (the rule the registry answers with;
#: docs/engine.md, "Capabilities"). A Fresnel surface gets NEE from its lobes but no area sampling
#: (exact normals; the Fresnel split is the walk's), and the strategies that act at interfaces.
CAPABILITIES = {
    SCATTER: Capability.NEE | Capability.FIRST_VERTEX | Capability.SECOND_VERTEX | Capability.TARGET_MIS,
    FRESNEL: Capability.NEE | Capability.REFLECTION_SPLIT | Capability.DELTA_CHAIN,
}
#: Added where a component declares ``ComponentFlags.POLARIZING``.
POLARIZING_CAPABILITIES = Capability.POLARIZES
ALGORITHMS = {SCATTER: BrdfScatter, FRESNEL: OpticalSurface}


def material_class(material) -> str:
    """``"Fresnel"`` for a material with a delta component, else ``"scatter"`` (also for a part
    without a material, or a stand-in model that declares no flags: a plain scatterer)."""
    flags = flags_of(material) if material is not None else ComponentFlags.NONE
    return FRESNEL if flags & ComponentFlags.DELTA else SCATTER


@register_interaction
class SurfaceResponse(Interaction):
    name = "surface_response"
    roles = ("surface",)  # the default (and only) kind of surface parts
    material_classes = (SCATTER, FRESNEL)
    capabilities = Capability.NONE  # per material: capabilities_for

    def material_class(self, material=None) -> str:
        return material_class(material)

    def capabilities_for(self, material=None) -> Capability:
        out = CAPABILITIES[self.material_class(material)]
        if material is not None and flags_of(material) & ComponentFlags.POLARIZING:
            out |= POLARIZING_CAPABILITIES
        return out

    def handler_for(self, material=None):
        return handler(ALGORITHMS[self.material_class(material)], self.label(material), self.capabilities_for(material))

    def interact(self, event, selection):
        """The hits ``event.hits.continuing[selection]``, each by its part's handler (grouped by
        handler in the order the parts first use them, as the walk does)."""
        per_part = event.capabilities.handlers
        order = []
        for h in per_part:
            if h not in order:
                order.append(h)
        index = np.array([order.index(h) for h in per_part], dtype=np.int64)
        sel = np.arange(len(event.hits.continuing))[selection]
        k = index[event.hits.part[event.hits.continuing[sel]]]
        groups = np.unique(k)
        if len(groups) == 1:
            return order[groups[0]].interact(event, sel)
        return combined_outgoing(len(sel), [(np.flatnonzero(k == u), order[u].interact(event, sel[k == u]))
                                            for u in groups])
