"""Stops: annular plates (aperture stop, field stop) and a plate with a rectangular slit.

Every stop is a plate whose front face (toward the incoming light, +z) is at
``front_z_mm`` and which occupies ``front_z_mm - thickness_mm <= z <= front_z_mm``.
"""
from __future__ import annotations

from geometry.mesh import GeometryError
from geometry.parts import ShapePart, require_positive


def annular_plate(inner_radius_mm: float, outer_radius_mm: float, thickness_mm: float, front_z_mm: float = 0.0, *,
                  name: str = "stop", role: str = "surface") -> ShapePart:
    """Flat annulus ``inner_radius_mm < r < outer_radius_mm`` on the z axis."""
    import cadquery as cq

    require_positive(inner_radius_mm=inner_radius_mm, thickness_mm=thickness_mm)
    if not outer_radius_mm > inner_radius_mm:
        raise GeometryError(f"{name}: outer_radius_mm ({outer_radius_mm}) must exceed "
                            f"inner_radius_mm ({inner_radius_mm})")
    solid = (cq.Workplane("XY").workplane(offset=front_z_mm - thickness_mm)
             .circle(outer_radius_mm).circle(inner_radius_mm).extrude(thickness_mm).val())
    return ShapePart(name, solid, role, "solid")


def aperture_stop(radius_mm: float, outer_radius_mm: float, thickness_mm: float = 1.0, front_z_mm: float = 0.0, *,
                  name: str = "aperture_stop") -> ShapePart:
    """Entrance aperture stop: an annular plate with a hole of ``radius_mm``."""
    return annular_plate(radius_mm, outer_radius_mm, thickness_mm, front_z_mm, name=name)


def field_stop(radius_mm: float, outer_radius_mm: float, thickness_mm: float = 1.0, front_z_mm: float = 0.0, *,
               name: str = "field_stop") -> ShapePart:
    """Field stop (end plate) in front of the focal plane: an annular plate with a hole of ``radius_mm``."""
    return annular_plate(radius_mm, outer_radius_mm, thickness_mm, front_z_mm, name=name)


def slit_plate(width_mm: float, height_mm: float, thickness_mm: float, slit_width_mm: float, slit_height_mm: float, *,
               name: str = "slit_plate", role: str = "surface") -> ShapePart:
    """Rectangular plate (``width_mm`` along x, ``height_mm`` along y) with a centred rectangular slit.

    The slit is ``slit_width_mm`` along x by ``slit_height_mm`` along y; front face at z = 0.
    """
    import cadquery as cq

    require_positive(width_mm=width_mm, height_mm=height_mm, thickness_mm=thickness_mm,
                     slit_width_mm=slit_width_mm, slit_height_mm=slit_height_mm)
    if slit_width_mm >= width_mm or slit_height_mm >= height_mm:
        raise GeometryError(f"{name}: the slit ({slit_width_mm} x {slit_height_mm} mm) must fit inside the plate "
                            f"({width_mm} x {height_mm} mm)")
    solid = (cq.Workplane("XY").workplane(offset=-thickness_mm)
             .rect(width_mm, height_mm).rect(slit_width_mm, slit_height_mm).extrude(thickness_mm).val())
    return ShapePart(name, solid, role, "solid")
