"""Generic sample plates: rectangular or circular, front face at z = 0 facing +z.

The plate occupies ``-thickness_mm <= z <= 0``; move it into place with
:func:`geometry.parts.placed` and :func:`geometry.parts.frame_location`.
"""
from __future__ import annotations

from geometry.parts import ShapePart, require_positive


def rectangular_plate(width_mm: float, height_mm: float, thickness_mm: float, *, name: str = "plate",
                      role: str = "surface") -> ShapePart:
    """Box of ``width_mm`` (x) by ``height_mm`` (y) by ``thickness_mm`` (z), centred on the z axis."""
    import cadquery as cq

    require_positive(width_mm=width_mm, height_mm=height_mm, thickness_mm=thickness_mm)
    solid = cq.Solid.makeBox(width_mm, height_mm, thickness_mm, cq.Vector(-width_mm / 2, -height_mm / 2, -thickness_mm))
    return ShapePart(name, solid, role, "solid")


def circular_plate(radius_mm: float, thickness_mm: float, *, name: str = "plate", role: str = "surface") -> ShapePart:
    """Disk of ``radius_mm`` and ``thickness_mm``, axis z, front face at z = 0."""
    import cadquery as cq

    require_positive(radius_mm=radius_mm, thickness_mm=thickness_mm)
    solid = cq.Solid.makeCylinder(radius_mm, thickness_mm, cq.Vector(0, 0, -thickness_mm))
    return ShapePart(name, solid, role, "solid")
