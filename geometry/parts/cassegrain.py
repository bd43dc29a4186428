"""A built-in Cassegrain telescope made of analytic surfaces (CONTRACTS §6.1).

Light enters at +z and travels toward -z. Parts (names are what path reports show):

- ``primary``: paraboloid (k = -1), R = 2 f1, concave toward the sky, clear aperture
  ``primary_hole_radius_mm .. aperture_radius_mm``, vertex at z = 0; back side black.
- ``secondary``: convex hyperboloid facing the primary, k = -((m + 1) / (m - 1))^2, vertex at
  z = s; its foci are the prime focus (z = f1) and the Cassegrain focus (z = -b): a classical
  Cassegrain, aberration-free on axis. Back side black (the central obscuration).
- ``secondary_baffle``: a sleeve (cylinder) around the secondary reaching toward the sky.
- ``primary_baffle``: a tube through the primary's hole reaching toward the secondary.
- ``tube``: the main tube wall; ``vane_1 .. vane_N``: annular vanes on the wall (vane_1 nearest
  the primary); ``end_plate``: closes the tube behind the focal plane.
- ``focal_plane``: the detector, a disk at the Cassegrain focus facing the sky.
- optional ``filter_top`` / ``filter_bottom``: an uncoated plane-parallel filter (``n_bk7``) in the
  converging beam (``filter_thickness_mm > 0``), the source of the window ghosts.

Paraxial design (mirror equation with the secondary's virtual object at the prime focus):
``m = F / f1``, ``s = (m f1 - b) / (m + 1)``, ``p = f1 - s``, ``q = s + b``, ``|R2| = 2 p q / (q - p)``.
Defaults: D = 200 mm, f1 = 400 mm (F/2 primary), m = 4 (F/8 system, F = 1600 mm), b = 100 mm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from geometry.analytic import Conic, Cylinder, Plane, analytic_part
from geometry.mesh import GeometryError, Scene

# CONTRACTS §5.1 example: aluminium (n, k at 532 nm), 2 nm micro-roughness, IEST level 300
MIRROR_MATERIAL = "aluminium_mirror"
MIRROR_MATERIAL_TABLE: dict[str, Any] = {
    "name": MIRROR_MATERIAL, "wavelength_nm": 532.0,
    "description": "aluminium mirror at 532 nm with micro-roughness and IEST-STD-CC1246E level-300 particles",
    "components": [
        {"type": "specular", "n": [0.96, 6.69]},
        {"type": "k_correlation", "sigma_nm": 2.0, "lc_um": 10.0, "s": 3.0, "n": [0.96, 6.69]},
        {"type": "particulate", "level": 300},
    ],
}
BLACK_MATERIAL = "z302_sample_b"
FILTER_MATERIAL = "n_bk7"
FILTER_MATERIAL_TABLE = {"name": FILTER_MATERIAL, "wavelength_nm": 532.0,
                         "components": [{"type": "dielectric", "n": 1.5195}]}


@dataclass(frozen=True)
class CassegrainParams:
    """Parameters of :func:`cassegrain_scene` (mm)."""

    aperture_radius_mm: float = 100.0
    primary_focal_mm: float = 400.0
    magnification: float = 4.0
    back_focus_mm: float = 100.0
    primary_hole_radius_mm: float = 20.0
    secondary_margin_mm: float = 3.0
    secondary_baffle_length_mm: float = 50.0
    primary_baffle_radius_mm: float = 18.0
    primary_baffle_length_mm: float = 150.0
    tube_radius_mm: float = 110.0
    tube_front_mm: float = 450.0
    vane_count: int = 5
    vane_inner_radius_mm: float = 102.0
    detector_radius_mm: float = 8.0
    filter_thickness_mm: float = 0.0  # > 0: an uncoated plane-parallel filter in the converging beam
    filter_z_mm: float = -80.0  # its upper face
    filter_radius_mm: float = 10.0
    filter_index: float = 1.5195  # to refocus: the plate moves the focus by t (1 - 1/n)

    @classmethod
    def names(cls):
        return [f.name for f in fields(cls)]

    @property
    def secondary_z_mm(self) -> float:
        m, f1, b = self.magnification, self.primary_focal_mm, self.back_focus_mm
        return (m * f1 - b) / (m + 1.0)

    @property
    def secondary_radius_of_curvature_mm(self) -> float:
        p = self.primary_focal_mm - self.secondary_z_mm
        q = self.secondary_z_mm + self.back_focus_mm
        return 2.0 * p * q / (q - p)

    @property
    def secondary_conic(self) -> float:
        m = self.magnification
        return -((m + 1.0) / (m - 1.0)) ** 2

    @property
    def secondary_radius_mm(self) -> float:
        """Clear radius: the marginal on-axis cone at the secondary, plus the margin."""
        p = self.primary_focal_mm - self.secondary_z_mm
        return self.aperture_radius_mm * p / self.primary_focal_mm + self.secondary_margin_mm

    @property
    def focal_length_mm(self) -> float:
        return self.magnification * self.primary_focal_mm

    @property
    def focus_z_mm(self) -> float:
        """The Cassegrain focus (moved down by t (1 - 1/n) behind a filter)."""
        return -self.back_focus_mm - self.filter_thickness_mm * (1.0 - 1.0 / self.filter_index)


def cassegrain_scene(params: CassegrainParams = CassegrainParams(), *, mirror_material: str = MIRROR_MATERIAL,
                     black_material: str = BLACK_MATERIAL, tolerance_mm: float = 0.01) -> Scene:
    """The telescope as a :class:`geometry.mesh.Scene` of analytic parts (module docstring)."""
    p = params
    if not (p.magnification > 1 and p.primary_focal_mm > 0 and 0 < p.back_focus_mm):
        raise GeometryError("cassegrain: needs magnification > 1, primary_focal_mm > 0 and back_focus_mm > 0")
    z2 = p.secondary_z_mm
    if not 0 < z2 < p.primary_focal_mm:
        raise GeometryError(f"cassegrain: the secondary falls at z = {z2:g} mm, outside (0, primary_focal_mm)")
    up = np.array([0.0, 0.0, 1.0])
    down = -up
    o = np.zeros(3)
    r2 = p.secondary_radius_mm
    parts = [
        analytic_part("primary", Conic(o, up, 2.0 * p.primary_focal_mm, -1.0, p.aperture_radius_mm,
                                       p.primary_hole_radius_mm), mirror_material, "surface", black_material,
                      tolerance_mm),
        analytic_part("secondary", Conic(np.array([0.0, 0.0, z2]), down, -p.secondary_radius_of_curvature_mm,
                                         p.secondary_conic, r2, 0.0), mirror_material, "surface", black_material,
                      tolerance_mm),
        analytic_part("secondary_baffle", Cylinder(np.array([0.0, 0.0, z2 - 2.0]), up, r2 + 1.0,
                                                   p.secondary_baffle_length_mm), black_material, "surface",
                      None, tolerance_mm),
        analytic_part("primary_baffle", Cylinder(np.array([0.0, 0.0, -10.0]), up, p.primary_baffle_radius_mm,
                                                 p.primary_baffle_length_mm + 10.0), black_material, "surface",
                      None, tolerance_mm),
        analytic_part("tube", Cylinder(np.array([0.0, 0.0, p.focus_z_mm - 10.0]), up, p.tube_radius_mm,
                                       p.tube_front_mm - p.focus_z_mm + 10.0), black_material, "surface", None,
                      tolerance_mm),
    ]
    if p.vane_count:
        for i, z in enumerate(np.linspace(p.aperture_radius_mm * 0.2 + 20.0, p.tube_front_mm - 10.0, p.vane_count)):
            parts.append(analytic_part(f"vane_{i + 1}", Plane(np.array([0.0, 0.0, z]), up, math.inf, 0.0,
                                                              p.tube_radius_mm, p.vane_inner_radius_mm),
                                       black_material, "surface", None, tolerance_mm))
    if p.filter_thickness_mm > 0:
        top = np.array([0.0, 0.0, p.filter_z_mm])
        parts.append(analytic_part("filter_top", Plane(top, up, math.inf, 0.0, p.filter_radius_mm, 0.0),
                                   FILTER_MATERIAL, "surface", None, tolerance_mm))
        parts.append(analytic_part("filter_bottom", Plane(top - p.filter_thickness_mm * up, down, math.inf, 0.0,
                                                          p.filter_radius_mm, 0.0),
                                   FILTER_MATERIAL, "surface", None, tolerance_mm))
    parts.append(analytic_part("end_plate", Plane(np.array([0.0, 0.0, p.focus_z_mm - 10.0]), up, math.inf, 0.0,
                                                  p.tube_radius_mm, 0.0), black_material, "surface", None,
                               tolerance_mm))
    parts.append(analytic_part("focal_plane", Plane(np.array([0.0, 0.0, p.focus_z_mm]), up, math.inf, 0.0,
                                                    p.detector_radius_mm, 0.0), None, "detector", None,
                               tolerance_mm))
    return Scene(tuple(parts))
