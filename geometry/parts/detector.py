"""Detectors: open single-sided sheets at z = 0 whose sensitive side faces +z.

A sheet is one planar CadQuery face; tessellated, its triangles are counter-clockwise
seen from +z (normals +z). The tracer counts what hits the sheet; its back is the
same surface, so a detector should sit where light cannot reach it from behind
(as in the reference tube, where it fills the end plate's hole).
"""
from __future__ import annotations

from geometry.parts import ShapePart, require_positive


def disk_detector(radius_mm: float, *, name: str = "detector") -> ShapePart:
    """Disk r < ``radius_mm`` in the plane z = 0, normal +z."""
    import cadquery as cq

    require_positive(radius_mm=radius_mm)
    face = cq.Face.makeFromWires(cq.Wire.makeCircle(radius_mm, cq.Vector(0, 0, 0), cq.Vector(0, 0, 1)))
    return ShapePart(name, face, "detector", "sheet")


def rectangular_detector(width_mm: float, height_mm: float, *, name: str = "detector") -> ShapePart:
    """Rectangle ``width_mm`` (x) by ``height_mm`` (y) centred at the origin in z = 0, normal +z."""
    import cadquery as cq

    require_positive(width_mm=width_mm, height_mm=height_mm)
    # makePlane(length, width) puts `length` along y and `width` along x.
    face = cq.Face.makePlane(height_mm, width_mm, cq.Vector(0, 0, 0), cq.Vector(0, 0, 1))
    return ShapePart(name, face, "detector", "sheet")
