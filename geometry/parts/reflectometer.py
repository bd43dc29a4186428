"""The seed paper's bidirectional reflectometer as parts.

Lab frame (mm): the goniometer's rotation axis is the y axis through the origin; the plane of
incidence is the x-z plane; the fixed laser travels along -z and hits the origin (it comes from
+z, so the lab direction toward the source is +z). The sample's front face contains the
rotation axis; at incidence ``theta_i`` its normal is ``n = (sin theta_i, 0, cos theta_i)`` and its
in-plane axis ``x_s = (cos theta_i, 0, -sin theta_i)``, so the incidence is at ``phi_i = 180 deg``
in the sample frame (CONTRACTS §1).

The detector arm orbits in the plane of incidence. A viewing angle ``theta_r`` in the specular
half-plane (``phi_r = 0``) puts the arm along ``(sin a, 0, cos a)`` with ``a = theta_i + theta_r``;
in the backscatter half-plane (``phi_r = 180``) ``a = theta_i - theta_r``. At ``arm_mm`` along it
sits a blackened plate with a slit (``slit_width_mm`` in the plane of incidence, ``slit_height_mm``
along y) facing the sample, and ``detector_gap_mm`` behind the plate a detector sheet whose
sensitive side faces the sample.

Parts: "sample" (plate), "holder" (backing block behind the sample), "holder_post" (the
holder stick, a rod along -y), "slit_plate", "detector" (open sheet, role "detector").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.mesh import GeometryError
from geometry.parts import ShapePart, frame_location, placed, require_positive
from geometry.parts.detector import rectangular_detector
from geometry.parts.plate import rectangular_plate
from geometry.parts.stops import slit_plate


@dataclass(frozen=True)
class ReflectometerParams:
    """Nominal rig geometry (mm). Defaults: PHYSICS.md's plausible rig (arm 200, slit 0.2 x 5 mm);
    the sample is the paper's 500 um silicon wafer piece, one inch square."""

    arm_mm: float = 200.0
    slit_width_mm: float = 0.2
    slit_height_mm: float = 5.0
    slit_plate_width_mm: float = 25.0
    slit_plate_height_mm: float = 25.0
    slit_plate_thickness_mm: float = 1.0
    detector_gap_mm: float = 2.0
    detector_width_mm: float = 10.0
    detector_height_mm: float = 10.0
    sample_width_mm: float = 25.4
    sample_height_mm: float = 25.4
    sample_thickness_mm: float = 0.5
    holder_width_mm: float = 30.0
    holder_height_mm: float = 30.0
    holder_thickness_mm: float = 5.0
    post_radius_mm: float = 4.0
    post_length_mm: float = 80.0

    def __post_init__(self):
        require_positive(**{k: getattr(self, k) for k in self.__dataclass_fields__})
        if self.arm_mm <= max(self.sample_width_mm, self.holder_width_mm, self.holder_height_mm) / 2 * np.sqrt(2):
            raise GeometryError(f"arm_mm ({self.arm_mm}) is too short: the arm would cut the sample holder")


def arm_direction(theta_i: float, theta_r: float, phi_r: float = 0.0) -> np.ndarray:
    """Lab unit vector from the origin toward the slit (angles in radians, phi_r 0 or pi)."""
    if np.isclose(np.cos(phi_r), 1.0):
        a = theta_i + theta_r
    elif np.isclose(np.cos(phi_r), -1.0):
        a = theta_i - theta_r
    else:
        raise GeometryError(f"phi_r_deg must be 0 or 180 (the arm orbits in the plane of incidence), "
                            f"got {np.rad2deg(phi_r):g}")
    return np.array([np.sin(a), 0.0, np.cos(a)])


def sample_normal(theta_i: float) -> np.ndarray:
    """Lab unit normal of the sample at incidence theta_i (radians)."""
    return np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])


def build_reflectometer(theta_i_deg: float, theta_r_deg: float, phi_r_deg: float = 0.0,
                        params: ReflectometerParams = ReflectometerParams()) -> dict[str, ShapePart]:
    """Rig parts placed for one (theta_i, theta_r, phi_r) set-point; see the module docstring."""
    import cadquery as cq

    p = params
    if not (-90.0 < theta_i_deg < 90.0) or not (-90.0 <= theta_r_deg <= 90.0):
        raise GeometryError(f"theta_i_deg must be in (-90, 90) and theta_r_deg in [-90, 90], got "
                            f"{theta_i_deg}, {theta_r_deg}")
    theta_i, theta_r, phi_r = np.deg2rad([theta_i_deg, theta_r_deg, phi_r_deg])
    n = sample_normal(theta_i)
    x_s = np.array([np.cos(theta_i), 0.0, -np.sin(theta_i)])
    parts = [placed(rectangular_plate(p.sample_width_mm, p.sample_height_mm, p.sample_thickness_mm, name="sample"),
                    frame_location((0, 0, 0), n, x_s)),
             placed(rectangular_plate(p.holder_width_mm, p.holder_height_mm, p.holder_thickness_mm, name="holder"),
                    frame_location(-p.sample_thickness_mm * n, n, x_s))]
    # The holder stick: a rod along -y from the holder's lower edge, centred on the holder's mid-plane.
    post_top = -(p.sample_thickness_mm + p.holder_thickness_mm / 2) * n + np.array([0, -p.holder_height_mm / 2, 0])
    rod = cq.Solid.makeCylinder(p.post_radius_mm, p.post_length_mm, cq.Vector(*post_top), cq.Vector(0, -1, 0))
    parts.append(ShapePart("holder_post", rod, "surface", "solid"))

    w = arm_direction(theta_i, theta_r, phi_r)
    x_arm = np.array([w[2], 0.0, -w[0]])  # in the plane of incidence, across the arm: the slit's width
    plate = slit_plate(p.slit_plate_width_mm, p.slit_plate_height_mm, p.slit_plate_thickness_mm, p.slit_width_mm,
                       p.slit_height_mm, name="slit_plate")
    parts.append(placed(plate, frame_location(p.arm_mm * w, -w, x_arm)))
    back_mm = p.arm_mm + p.slit_plate_thickness_mm + p.detector_gap_mm
    parts.append(placed(rectangular_detector(p.detector_width_mm, p.detector_height_mm, name="detector"),
                        frame_location(back_mm * w, -w, x_arm)))
    return {part.name: part for part in parts}
