"""Parametric CadQuery builders. Every builder returns named :class:`ShapePart` objects.

Lengths are in mm and angles in degrees at this edge (``_mm`` / ``_deg`` suffixes).
A part is either a closed ``"solid"`` or an open single-sided ``"sheet"`` (detectors),
whose sensitive side is the side its face normal points to.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from geometry.mesh import ROLES, GeometryError

KINDS = ("solid", "sheet")


@dataclass(frozen=True, eq=False)
class ShapePart:
    """One named CadQuery shape with the role it will have in a scene.

    name : unique part name ("wall", "vane_1", "detector", ...)
    shape : cadquery.Shape (a Solid, or a Face for a sheet), positioned in mm
    role : one of ``geometry.mesh.ROLES``
    kind : "solid" (closed, outward normals) or "sheet" (open, single-sided)
    """

    name: str
    shape: Any  # a cadquery.Shape (cadquery is optional: not imported for the annotation)
    role: str = "surface"
    kind: str = "solid"

    def __post_init__(self):
        if self.role not in ROLES:
            raise GeometryError(f"part {self.name!r}: unknown role {self.role!r}; expected one of {', '.join(ROLES)}")
        if self.kind not in KINDS:
            raise GeometryError(f"part {self.name!r}: unknown kind {self.kind!r}; expected one of {', '.join(KINDS)}")


def require_positive(**values):
    """Raise GeometryError naming the first parameter that is not a finite number > 0."""
    for key, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise GeometryError(f"{key} must be a finite number > 0, got {value!r}")


def frame_location(origin_mm, normal, x_dir):
    """cadquery Location mapping the local frame (x_dir, normal x x_dir, normal) at origin_mm to global."""
    import cadquery as cq

    plane = cq.Plane(origin=tuple(map(float, origin_mm)), xDir=tuple(map(float, x_dir)),
                     normal=tuple(map(float, normal)))
    return cq.Location(plane)


def placed(part: ShapePart, location) -> ShapePart:
    """A copy of ``part`` moved by a cadquery Location."""
    return ShapePart(part.name, part.shape.moved(location), part.role, part.kind)
