"""What keeps the light from the detector, said when a result is zero.

Two causes a user can fix, both found from the scene alone:

- an **opaque optic**: a part named like a lens, window, filter, prism... (its own name or an alias) whose
  materials (front and back) transmit nothing: it needs a ``dielectric`` component (CONTRACTS 5.1);
- a **closed detector**: every line of sight from the detector's centre into the half-space toward the
  entrance (a fan of directions within 80 deg) ends on a part that neither transmits nor reflects
  specularly (a mount or cover closed over the sensor); the parts met first are named.

Both are hints, not proofs: the tracer's numbers stand as they are.
"""
from __future__ import annotations

import re

import numpy as np

OPTIC_WORDS = re.compile(r"lens|window|filter|prism|glass|objective|eyepiece|corrector|meniscus|doublet|"
                         r"singlet|achromat|plate_?glass|dichroic|beam_?splitter", re.IGNORECASE)
FAN_HALF_ANGLE_DEG = 80.0
FAN_RAYS = 400


def _flags(model) -> int:
    from materials.flags import flags_of

    return int(flags_of(model)) if model is not None else 0


def _sides(setup, part):
    materials = setup.materials or {}
    return [materials.get(name) for name in (part.material, getattr(part, "back_material", None)) if name]


def _transmits(setup, part) -> bool:
    from materials.flags import ComponentFlags

    return any(_flags(m) & ComponentFlags.DELTA_TRANSMISSION for m in _sides(setup, part))


def _clear_or_specular(setup, part) -> bool:
    from materials.flags import ComponentFlags

    if part.role == "mirror":
        return True
    return any(_flags(m) & (ComponentFlags.DELTA_TRANSMISSION | ComponentFlags.DELTA_REFLECTION)
               for m in _sides(setup, part))


def opaque_optics(setup) -> list[str]:
    """Hints for parts named like optics whose materials do not transmit."""
    scene = setup.scene
    out = []
    for part in scene.parts:
        if part.role in ("detector",):
            continue
        names = scene.names_of(part) if hasattr(scene, "names_of") else (part.name,)
        if not any(OPTIC_WORDS.search(n.rsplit("/", 1)[-1]) for n in names):
            continue
        if part.role in ("absorber", "mirror") or not _transmits(setup, part):
            solid = part.meta.get("solid")
            where = (f'[part.solids."{solid}"] material = "GLASS"' if solid else f'material = "GLASS" on part {part.name!r}')
            out.append(f"part {part.name!r} is named like an optic but is opaque (material {part.material!r}, role "
                       f"{part.role}): no light passes it. Give it a dielectric material: {where} with "
                       f'[material.GLASS] components = [{{type = "dielectric", n = 1.5168}}] (docs/reference/material.md)')
    return out


def closed_detector(setup) -> str | None:
    """A hint if every line of sight from the detector toward the entrance ends on an opaque, non-specular part."""
    from straylight.intersect.embree import EmbreeIntersector

    scene = setup.scene
    det = scene.part(setup.detector)
    others = [i for i, p in enumerate(scene.parts) if p.name != det.name]
    if not others:
        return None
    tri_part = scene.triangle_part
    keep = np.isin(tri_part, others)
    centre = det.vertices_mm[det.faces].reshape(-1, 3).mean(axis=0)
    toward = setup.entrance.center_mm if setup.entrance is not None else setup.beam.center_mm
    axis = np.asarray(toward, dtype=float) - centre
    if not np.linalg.norm(axis) > 0:
        return None
    axis /= np.linalg.norm(axis)
    dirs = _fan(axis, FAN_HALF_ANGLE_DEG, FAN_RAYS)
    intersector = EmbreeIntersector(scene.triangles_mm[keep])
    tri, _ = intersector.intersect(np.repeat(centre[None], len(dirs), axis=0), dirs)
    if (tri < 0).any():
        return None  # some line of sight leaves the scene
    hit_parts = tri_part[keep][tri]
    if any(_clear_or_specular(setup, scene.parts[int(p)]) for p in np.unique(hit_parts)):
        return None
    counts = np.bincount(hit_parts, minlength=len(scene.parts))
    first = [scene.parts[int(p)].name for p in np.argsort(-counts)[:3] if counts[p] > 0]
    return (f"the detector {det.name!r} is closed in: every line of sight from it toward the entrance ends on an "
            f"opaque part ({', '.join(first)}); open the mount or make the cover transparent (a dielectric material)")


def _fan(axis, half_angle_deg: float, n: int) -> np.ndarray:
    """``n`` unit directions spread over the cone of ``half_angle_deg`` around ``axis`` (a Fibonacci spiral)."""
    k = np.arange(n) + 0.5
    cos_t = 1.0 - (k / n) * (1.0 - np.cos(np.radians(half_angle_deg)))
    phi = np.pi * (1 + 5 ** 0.5) * k
    sin_t = np.sqrt(1.0 - cos_t ** 2)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return (cos_t[:, None] * axis + (sin_t * np.cos(phi))[:, None] * u + (sin_t * np.sin(phi))[:, None] * v)


def zero_light_hints(setup) -> list[str]:
    """Every hint of this module for ``setup`` (empty if nothing blocks the light that the scene shows)."""
    hints = opaque_optics(setup)
    closed = closed_detector(setup)
    return hints + ([closed] if closed else [])
