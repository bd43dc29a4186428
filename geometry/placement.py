"""Placing a part given in its own frame (CONTRACTS §6.4): ``rotate_deg`` about the origin, then
``translate_mm``.

A STEP file exported per part (each in its own frame, as most repositories ship them) is placed
by a rigid motion ``x' = R x + t``: R the rotation by ``angle`` degrees about ``axis`` (right hand,
Rodrigues' formula ``R = c I + s [k]x + (1 - c) k k^T``), t the translation. It applies alike to a
mesh's vertices and to an analytic surface's vertex and axis (CONTRACTS §6.1), so a mesh and its
optical prescription stay together; a proper rotation (det R = +1) keeps each triangle's winding,
so outward normals stay outward.

cos and sin of a multiple of 90 deg are exact (0, +-1), so a part turned by 90 deg lands on the
same coordinates as the part modelled there: the quarter turns CAD assemblies are full of do not
add 6e-17 mm of noise.

References: O. Rodrigues (1840); e.g. Murray, Li & Sastry, *A Mathematical Introduction to
Robotic Manipulation* (1994), eq. 2.14.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from geometry.mesh import GeometryError, Part

PLACEMENT_KEYS = ("rotate_deg", "translate_mm")
ROTATE_KEYS = ("axis", "angle")


def cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    """(cos, sin) of an angle in degrees, exact at multiples of 90 deg."""
    quarter, rest = divmod(float(angle_deg), 90.0)
    if rest == 0.0:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(quarter) % 4]
    a = math.radians(angle_deg)
    return math.cos(a), math.sin(a)


def rotation_matrix(axis, angle_deg: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_deg`` about the unit vector along ``axis`` (right hand, Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    c, s = cos_sin_deg(angle_deg)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return c * np.eye(3) + s * cross + (1.0 - c) * np.outer(k, k)


@dataclass(frozen=True, eq=False)
class Placement:
    """The rigid motion ``x' = rotation x + translation_mm`` of one scene-file part."""

    rotation: np.ndarray
    translation_mm: np.ndarray

    def points(self, points_mm) -> np.ndarray:
        """(n, 3) points moved."""
        return np.asarray(points_mm, dtype=np.float64) @ self.rotation.T + self.translation_mm

    def directions(self, dirs) -> np.ndarray:
        """(n, 3) directions (normals, axes) turned."""
        return np.asarray(dirs, dtype=np.float64) @ self.rotation.T

    def surface(self, surface):
        """An analytic surface (geometry.analytic) with its vertex moved and its axis turned."""
        axis = self.directions(surface.axis[None])[0]
        return replace(surface, vertex_mm=self.points(surface.vertex_mm[None])[0], axis=axis / np.linalg.norm(axis))

    def part(self, part: Part) -> Part:
        """The part moved: vertices, and its analytic surface if it has one; same faces, names and tags."""
        surface = None if part.surface is None else self.surface(part.surface)
        return Part(part.name, self.points(part.vertices_mm), part.faces, part.material, part.role,
                    dict(part.meta, placement=self.as_dict()), surface, part.back_material)

    def as_dict(self) -> dict:
        return {"rotation": self.rotation.tolist(), "translation_mm": self.translation_mm.tolist()}


def _finite_vector(value, what: str, where: str) -> np.ndarray:
    ok = isinstance(value, (list, tuple)) and len(value) == 3 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)
    v = np.asarray(value, dtype=np.float64) if ok else None
    if v is None or not np.all(np.isfinite(v)):
        raise GeometryError(f"{where}: {what} must be three numbers [x, y, z], got {value!r}")
    return v


def placement_of(entry: dict, where: str) -> Placement | None:
    """The :class:`Placement` of a ``[[part]]`` entry's ``rotate_deg`` / ``translate_mm`` (None without
    either); one-line errors naming the entry."""
    if not any(key in entry for key in PLACEMENT_KEYS):
        return None
    rotation = np.eye(3)
    if "rotate_deg" in entry:
        rot = entry["rotate_deg"]
        if not isinstance(rot, dict) or set(rot) != set(ROTATE_KEYS):
            raise GeometryError(f"{where}: rotate_deg must be a table {{axis = [x, y, z], angle = degrees}}, "
                                f"got {rot!r}")
        axis = _finite_vector(rot["axis"], "rotate_deg axis", where)
        if np.linalg.norm(axis) == 0:
            raise GeometryError(f"{where}: rotate_deg axis must not be zero")
        angle = rot["angle"]
        if isinstance(angle, bool) or not isinstance(angle, (int, float)) or not math.isfinite(angle):
            raise GeometryError(f"{where}: rotate_deg angle must be a number of degrees, got {angle!r}")
        rotation = rotation_matrix(axis, float(angle))
    shift = _finite_vector(entry["translate_mm"], "translate_mm", where) if "translate_mm" in entry \
        else np.zeros(3)
    from geometry.limits import coordinate_limit_message

    message = coordinate_limit_message(float(np.abs(shift).max()), "translate_mm")
    if message:
        raise GeometryError(f"{where}: {message}")
    return Placement(rotation, shift)
