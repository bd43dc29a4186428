"""The built-in baffled tube set up for analyses: scene, materials, beam and entrance.

The default is the reference tube of ``shared/BENCHMARK.md`` (wall r 50..51 mm, 300 mm
long, 7 vanes with r = 35 mm holes, end plate, detector r < 35 mm at z = 0 facing +z),
coated with the ``z302_sample_b`` preset. The beam is a disk 10 mm above the entrance,
perpendicular to the tube axis, of the wall's outer radius (51 mm); tilted, it slides in its
plane so that its central ray still passes through the entrance centre, so it always covers
the entrance and the rim exactly. BENCHMARK.md launches rays over r < 60 mm at z = 310 mm;
the extra rays there meet only the outer wall, whose normal faces away from every other
surface, so they cannot reach the detector: the ratios are the same in expectation, and
no ray is spent on them.
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from straylight.analyses.types import Beam, Entrance, Setup

DEFAULT_MATERIAL = "z302_sample_b"
DEFAULT_TOLERANCE_MM = 0.05
BEAM_STANDOFF_MM = 10.0


def resolve_materials(material) -> tuple[str, dict | None]:
    """A material name (preset or file) or a Brdf object -> (tag, {tag: model})."""
    if isinstance(material, str):
        from materials import load_material

        return material, {material: load_material(material)}
    return "coating", {"coating": material}


@lru_cache(maxsize=16)
def _tube_scene(params, tolerance_mm: float):
    """Tessellated tube, untagged; cached because CadQuery takes seconds and scenes are immutable."""
    from geometry.parts.tube import build_tube
    from geometry.tessellate import tessellate_parts

    return tessellate_parts(build_tube(params), tolerance_mm=tolerance_mm)


def _tagged(scene, tag: str):
    """The same triangles with material ``tag`` on every non-detector part (arrays are shared)."""
    from geometry.mesh import Part, Scene

    return Scene(tuple(Part(p.name, p.vertices_mm, p.faces, None if p.role == "detector" else tag, p.role, p.meta)
                       for p in scene.parts))


def tube_setup(material=DEFAULT_MATERIAL, tolerance_mm: float = DEFAULT_TOLERANCE_MM, **params) -> Setup:
    """The built-in tube (``geometry.parts.tube.TubeParams`` keywords override the reference).

    material : preset name, material file path, or a Brdf model, put on every non-detector part
    """
    from geometry.parts.tube import REFERENCE_TUBE

    p = replace(REFERENCE_TUBE, **params) if params else REFERENCE_TUBE
    tag, mats = resolve_materials(material)
    scene = _tagged(_tube_scene(p, float(tolerance_mm)), tag)
    beam, entrance = tube_beam_and_entrance(p)
    params_dict = {f: getattr(p, f) for f in p.names()}
    desc = (f"baffled tube r={p.inner_radius_mm:g} mm, L={p.length_mm:g} mm, {p.vane_count} vanes "
            f"(hole r={p.vane_inner_radius_mm:g} mm), coating {material if isinstance(material, str) else repr(material)}")
    return Setup(scene, mats, beam, entrance, "detector", desc, params_dict)


def tube_beam_and_entrance(p) -> tuple[Beam, Entrance]:
    """The PST beam and entrance of a tube built from ``TubeParams`` ``p``."""
    top = p.length_mm + (p.aperture_stop_thickness_mm if p.aperture_stop_radius_mm is not None else 0.0)
    r_entrance = p.aperture_stop_radius_mm if p.aperture_stop_radius_mm is not None else p.inner_radius_mm
    # only the entrance and the rim (r < outer radius at the top) can send light inside: rays
    # outside it meet the outer wall, whose normal faces away from every other surface
    beam_radius = p.outer_radius_mm
    # the disk slides with the tilt so that it always covers the entrance and the rim
    beam = Beam(center_mm=np.array([0.0, 0.0, top + BEAM_STANDOFF_MM]), axis=np.array([0.0, 0.0, -1.0]),
                radius_mm=beam_radius,
                pivot_mm=np.array([0.0, 0.0, top]))
    entrance = Entrance(center_mm=np.array([0.0, 0.0, top]), radius_mm=r_entrance, normal=np.array([0.0, 0.0, 1.0]))
    return beam, entrance
