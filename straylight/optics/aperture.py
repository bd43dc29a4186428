"""Clear apertures of imported surfaces (docs/optics.md): a disk or annulus about the surface's axis, or, for an
off-axis segment, about its own centre ``aperture_offset_mm`` (the surface's own x, y), clipped to the rectangle
``aperture_half_widths_mm`` when the file gives one (CODE V ``REX``/``REY``/``ADX``/``ADY``, Zemax ``SQAP``/``OBDC``).
"""
from __future__ import annotations

import math

import numpy as np


def is_off_axis(s) -> bool:
    """The aperture is not the plain disk about the vertex (decentred or rectangular)."""
    return bool(s.aperture_offset_mm != (0.0, 0.0) or s.aperture_half_widths_mm)


def axes(s):
    """(x, y) unit axes of the surface's own frame in the scene frame."""
    z = np.asarray(s.local_z, float)
    x = np.asarray(s.local_x, float) if s.local_x is not None else None
    if x is None:
        helper = np.eye(3)[int(np.argmin(np.abs(z)))]
        x = helper - np.dot(helper, z) * z
        x /= np.linalg.norm(x)
    return x, np.cross(z, x)


def centre_mm(s) -> np.ndarray:
    """The aperture's centre on the plane through the vertex normal to the axis (scene frame, mm)."""
    dx, dy = s.aperture_offset_mm
    if not (dx or dy):
        return np.asarray(s.vertex_mm, float)
    x, y = axes(s)
    return np.asarray(s.vertex_mm, float) + dx * x + dy * y


def inside(s, x_mm, y_mm, hole_mm: float = 0.0):
    """Whether the point (x, y) of the surface's own frame is in the clear aperture (outside a hole of
    ``hole_mm`` about the aperture's centre); ``x_mm``, ``y_mm`` floats (a bool back) or arrays (a bool array)."""
    dx, dy = s.aperture_offset_mm
    if isinstance(x_mm, np.ndarray) or isinstance(y_mm, np.ndarray):
        u, v = np.asarray(x_mm, dtype=np.float64) - dx, np.asarray(y_mm, dtype=np.float64) - dy
        r = np.hypot(u, v)
        ok = (r <= s.semi_diameter_mm) & (r >= hole_mm)
        if s.aperture_half_widths_mm:
            hx, hy = s.aperture_half_widths_mm
            ok &= (np.abs(u) <= hx) & (np.abs(v) <= hy)
        return ok
    u, v = x_mm - dx, y_mm - dy
    r = math.hypot(u, v)
    if r > s.semi_diameter_mm or r < hole_mm:
        return False
    if s.aperture_half_widths_mm:
        hx, hy = s.aperture_half_widths_mm
        return abs(u) <= hx and abs(v) <= hy
    return True


def rho_range_mm(s) -> tuple[float, float]:
    """(smallest, largest) distance from the axis over the clear aperture."""
    off = math.hypot(*s.aperture_offset_mm)
    sd = float(s.semi_diameter_mm or 0.0)
    return (max(0.0, off - sd), off + sd) if off else (0.0, sd)


def scene_keys(s) -> dict:
    """The scene's ``aperture_center_mm`` / ``aperture_half_widths_mm`` / ``aperture_x_axis`` of surface ``s``."""
    d: dict = {}
    if s.aperture_offset_mm != (0.0, 0.0):
        d["aperture_center_mm"] = [round(float(v), 10) + 0.0 for v in centre_mm(s)]
    if s.aperture_half_widths_mm:
        d["aperture_half_widths_mm"] = [float(h) for h in s.aperture_half_widths_mm]
        d["aperture_x_axis"] = [round(float(v), 12) + 0.0 for v in axes(s)[0]]
    return d
