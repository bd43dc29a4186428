"""The designed shields as CadQuery solids in one STEP assembly (CONTRACTS 8.2), for the mechanical CAD.

Each analytic baffle (a zero-thickness sheet in the scene) becomes a solid of ``thickness_mm`` (default:
0.9 of the construction's clearance, 0.2 % of the aperture radius; thicken it in CAD only away from the
beam) grown away from the light: a cylinder grows outward (its inner face is the designed surface, so the beam's
clearance is kept); an annulus grows away from the secondary's mirror (toward the sky). The primary
tube ends in a knife edge at its top: its outer face is chamfered at ``KNIFE_DEG`` to the axis, so the
edge that the direct-path construction grazes is sharp (Breault: a sharp edge scatters the least).
Solid names are the part names (``baffle_primary``...), so a STEP scene can override them one by one.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

KNIFE_DEG = 30.0


def _placement(tel, base_u: float):
    import cadquery as cq

    origin = tel.point(base_u)
    w = tel.axis
    x = tel.e1
    return cq.Location(cq.Plane(origin=_xyz(origin), xDir=_xyz(x), normal=_xyz(w)))


def _xyz(v) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _revolved(profile_rz, loc):
    """A solid of revolution about the local z axis from a closed (r, z) polygon, placed at ``loc``."""
    import cadquery as cq

    wp = cq.Workplane("XZ").polyline([(float(r), float(z)) for r, z in profile_rz]).close()
    solid = wp.revolve(360.0, (0, 0, 0), (0, 1, 0)).val()
    return solid.moved(loc)


def shapes(tel, parts: list[dict], thickness_mm: float | None = None) -> dict:
    """{part name: cadquery Solid} for the design's parts (baffle_parts output)."""
    from straylight.design.shields import margin_mm

    # as thick as the clearance the construction keeps, so the solids vignette nothing the sheets do not
    t = thickness_mm if thickness_mm is not None else 0.9 * margin_mm(tel.aperture_radius_mm)
    out = {}
    for p in parts:
        s = p["surface"]
        base_u = float(tel.u(s["vertex_mm"]))
        loc = _placement(tel, base_u)
        if s["type"] == "cylinder":
            r, L = s["radius_mm"], s["length_mm"]
            if p["type"] == "primary_tube":
                knife = min(t / math.tan(math.radians(KNIFE_DEG)), 0.5 * L)
                prof = [(r, 0.0), (r + t, 0.0), (r + t, L - knife), (r, L)]
            else:
                prof = [(r, 0.0), (r + t, 0.0), (r + t, L), (r, L)]
        else:
            ri, ro = s["inner_radius_mm"], s["outer_radius_mm"]
            if p["type"] == "secondary_cap":  # toward the sky, away from the mirror
                prof = [(ri, 0.0), (ro + t, 0.0), (ro + t, t), (ri, t)]
            elif p["type"] == "field_stop":  # toward the sky, away from the image plane just below it
                prof = [(ri, 0.0), (ro, 0.0), (ro, t), (ri, t)]
            else:  # the collar sits behind the primary: grow it away from the sky
                prof = [(ri, -t), (ro, -t), (ro, 0.0), (ri, 0.0)]
        out[p["name"]] = _revolved(prof, loc)
    return out


def write_step(path, tel, parts: list[dict], thickness_mm: float | None = None) -> Path:
    """One STEP file holding every baffle solid, named by part (atomic write)."""
    from geometry.io import export_assembly_step

    return export_assembly_step(shapes(tel, parts, thickness_mm), Path(path))


def bounding_radii(step_path) -> np.ndarray:  # pragma: no cover - debugging aid
    import cadquery as cq

    shape = cq.importers.importStep(str(step_path)).val()
    assert isinstance(shape, cq.Shape)
    return np.array(shape.BoundingBox().xmax)
