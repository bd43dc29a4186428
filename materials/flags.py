"""What a material component is: :class:`ComponentFlags`, declared by every component class.

The tracer chooses how a surface interacts from these flags, never from component or material
names (straylight.engine.interactions.registry). The same idea as Mitsuba 3's ``BSDFFlags``
(``include/mitsuba/render/bsdf.h``) and pbrt-v4's ``BxDFFlags`` (``src/pbrt/bxdfs.h``): a
component says whether it is a smooth (delta) interface, a diffuse or glossy scatter lobe,
whether it transmits or polarizes; a material is the union of its components'. Every flag here is
read by the tracer (a flag nobody reads is not declared: emission is every absorbing side's, by
Kirchhoff, and edge diffraction is a part's, not a component's).

A component class declares ``flags = ComponentFlags.X | ComponentFlags.Y`` (a class attribute or
a property); :func:`materials.registry.register` refuses a class without it. A new kind of
surface physics (a thin film, a grating) is a component with its flags and coefficients; the
tracer needs a new interaction kind only for a new algorithm (docs/engine.md, "Capabilities").
"""
from __future__ import annotations

import enum


class ComponentFlags(enum.IntFlag):
    """Declared physics of a component (or, OR-ed, of a material)."""

    NONE = 0
    DIFFUSE = 1  # a wide scatter lobe (Lambertian-like): pdf > 0 over the hemisphere (a scatter lobe that
    # is not GLOSSY: no lobe draws for it; materials.registry.register checks every component is exactly
    # one of a scatter lobe and a delta interface)
    GLOSSY = 2  # a peaked scatter lobe (beta-centred, microfacet, particulate, tabulated)
    DELTA_REFLECTION = 4  # a smooth reflecting interface (a Dirac lobe: no pdf, no NEE)
    DELTA_TRANSMISSION = 8  # a smooth transmitting (refracting) interface
    POLARIZING = 16  # its coefficients depend on or change the polarization (Fresnel s/p)

    SCATTER = DIFFUSE | GLOSSY
    DELTA = DELTA_REFLECTION | DELTA_TRANSMISSION


def flags_of(model) -> ComponentFlags:
    """The flags of a component, a material or a composite (the union over its components).
    An object that declares none (e.g. a stand-in model in a test) is a plain scatterer."""
    declared = getattr(model, "flags", None)
    if declared is not None:
        return ComponentFlags(declared)
    comps = getattr(model, "components", None)
    if comps is not None:
        out = ComponentFlags.NONE
        for c in comps:
            out |= flags_of(c)
        return out
    return ComponentFlags.GLOSSY


def union(components) -> ComponentFlags:
    """OR of the flags of ``components``."""
    out = ComponentFlags.NONE
    for c in components:
        out |= flags_of(c)
    return out
