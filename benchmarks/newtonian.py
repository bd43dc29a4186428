"""A benchmark instrument that looks like the field: a 120 mm Newtonian reflector, built in CadQuery.

    .venv/bin/python benchmarks/newtonian.py [--dir DIR] [--tolerance-mm T]

writes (once; a rerun with the same parameters only prints the path) the meshes and ``scene.toml``
of the tube to DIR (default ``~/.cache/straylight/benchmarks/newtonian-<hash>``), so every command of
CONTRACTS §4.5 runs on it. ``benchmarks/newtonian_pst.py`` times ``straylight pst`` on it.

What it holds (z is the tube axis; light enters at the top and travels toward -z; lengths mm):

- ``section_1`` .. ``section_11``: wall sections, inner radius 72, 62 mm long, flanged and drilled
  (``geometry.parts.assembly.tube_section``);
- ``vane_1`` .. ``vane_33``: three hooked vanes per section (hole radius 63, a 4 mm lip leaning
  20 deg toward the wall: ``geometry.parts.assembly.hooked_vane``);
- ``spider``: three 1 mm legs at z = 630; ``secondary_holder``: the 44 mm hub they hold, its bottom cut
  at 45 deg (the flat the secondary mirror sits on);
- ``entrance_stop``: the rim annulus r = 70 .. flange at the top;
- ``mirror_cell``: a base plate closing the tube, the cup wall around the primary (r = 60.5 .. 71.95),
  and three clips reaching 3.5 mm over the primary's edge, 0.5 mm above its face;
- ``detector``: the primary's aperture, the disk r < 60 at z = 12 facing the sky (a sheet).

Every surface is coated ``z302_sample_b`` (the glossy black of the issue's printed Newtonian). The
primary and secondary mirrors themselves are not modelled: the stray light that reaches the
primary's aperture is what the PST counts (the issue's "detector = the primary's aperture").
At the default chord tolerance (0.004 mm) the scene has about 0.4M triangles.
"""
from __future__ import annotations

import json
import sys
from dataclasses import asdict, replace
from pathlib import Path

import scene_cache
from scene_cache import build_once, cache_dir

PRIMARY_Z_MM = 12.0
PRIMARY_RADIUS_MM = 60.0
CELL_INNER_RADIUS_MM = 60.5
CLIP_REACH_MM = 3.5
CLIP_WIDTH_MM = 10.0
CLIP_GAP_MM = 0.5
CLIP_THICKNESS_MM = 2.0
BASE_Z_MM = (2.0, 5.0)
TOLERANCE_MM = 0.004
MATERIAL = "z302_sample_b"


def params():
    """The tube's :class:`geometry.parts.assembly.HookedTubeParams` (11 sections of 3 hooked vanes)."""
    from geometry.parts.assembly import DEFAULT

    return replace(DEFAULT, inner_radius_mm=72.0, section_count=11, section_length_mm=62.0, vane_count=33,
                   vane_first_z_mm=50.0, vane_last_z_mm=585.0, vane_inner_radius_mm=63.0, spider_leg_count=3,
                   spider_z_mm=630.0, hub_radius_mm=22.0, hub_length_mm=40.0, hub_fillet_mm=2.0,
                   entrance_radius_mm=70.0, field_stop_radius_mm=PRIMARY_RADIUS_MM, detector_kind="sheet")


def _spider_and_holder(p):
    """Three legs from the holder to the wall, and the holder: a hub with a 45-deg bottom flat."""
    import cadquery as cq

    from geometry.parts import ShapePart

    z, r = p.spider_z_mm, p.inner_radius_mm - p.vane_clearance_mm
    hub = cq.Solid.makeCylinder(p.hub_radius_mm, p.hub_length_mm, cq.Vector(0, 0, z - p.hub_length_mm / 2))
    top = [e for e in hub.Edges() if e.Center().z > z + p.hub_length_mm / 2 - 1e-6]
    hub = hub.fillet(p.hub_fillet_mm, top)
    cutter = cq.Solid.makeBox(8 * p.hub_radius_mm, 8 * p.hub_radius_mm, 4 * p.hub_radius_mm,
                              cq.Vector(-4 * p.hub_radius_mm, -4 * p.hub_radius_mm, -4 * p.hub_radius_mm))
    cutter = cutter.rotate(cq.Vector(0, 0, 0), cq.Vector(1, 0, 0), 45).translate(
        cq.Vector(0, 0, z - p.hub_length_mm / 4))
    holder = hub.cut(cutter).clean()
    legs = []
    reach = r - p.hub_radius_mm
    for k in range(p.spider_leg_count):
        leg = cq.Solid.makeBox(reach, p.spider_leg_thickness_mm, p.spider_leg_height_mm,
                               cq.Vector(p.hub_radius_mm, -p.spider_leg_thickness_mm / 2, z - p.spider_leg_height_mm / 2))
        legs.append(leg.rotate(cq.Vector(0, 0, 0), cq.Vector(0, 0, 1), 90.0 + 360.0 * k / p.spider_leg_count))
    spider = legs[0].fuse(*legs[1:]).clean() if len(legs) > 1 else legs[0]
    return ShapePart("spider", spider, "surface", "solid"), ShapePart("secondary_holder", holder, "surface", "solid")


def _mirror_cell(p):
    """Base plate + cup wall around the primary + three clips over its edge (one solid)."""
    import cadquery as cq

    from geometry.parts import ShapePart
    from geometry.parts.assembly import _revolve

    r_wall = p.inner_radius_mm - p.vane_clearance_mm
    top = PRIMARY_Z_MM + CLIP_GAP_MM + CLIP_THICKNESS_MM
    profile = [(0.0, BASE_Z_MM[0]), (r_wall, BASE_Z_MM[0]), (r_wall, top), (CELL_INNER_RADIUS_MM, top),
               (CELL_INNER_RADIUS_MM, BASE_Z_MM[1]), (0.0, BASE_Z_MM[1])]
    cell = _revolve(profile)
    clips = []
    for k in range(3):
        r0 = PRIMARY_RADIUS_MM - CLIP_REACH_MM
        clip = cq.Solid.makeBox(CELL_INNER_RADIUS_MM + 1.0 - r0, CLIP_WIDTH_MM, CLIP_THICKNESS_MM,
                                cq.Vector(r0, -CLIP_WIDTH_MM / 2, PRIMARY_Z_MM + CLIP_GAP_MM))
        clips.append(clip.rotate(cq.Vector(0, 0, 0), cq.Vector(0, 0, 1), 30.0 + 120.0 * k))
    body = cell.fuse(*clips).clean()
    return ShapePart("mirror_cell", body.Solids()[0], "surface", "solid")


def _detector():
    import cadquery as cq

    from geometry.parts import ShapePart

    face = cq.Face.makeFromWires(cq.Wire.makeCircle(PRIMARY_RADIUS_MM, cq.Vector(0, 0, PRIMARY_Z_MM),
                                                    cq.Vector(0, 0, 1)))
    return ShapePart("detector", face, "detector", "sheet")


def newtonian_parts(p=None) -> dict:
    """Named CadQuery parts of the Newtonian (see the module docstring)."""
    from geometry.parts.assembly import _annulus, hooked_vane, tube_section

    p = p or params()
    parts = [tube_section(p, i, name=f"section_{i + 1}") for i in range(p.section_count)]
    parts += [hooked_vane(p, z, name=f"vane_{k}") for k, z in enumerate(p.vane_centres_mm, start=1)]
    parts += list(_spider_and_holder(p))
    parts.append(_annulus(p.entrance_radius_mm, p.flange_radius_mm, p.length_mm, p.top_z_mm, "entrance_stop"))
    parts.append(_mirror_cell(p))
    parts.append(_detector())
    return {part.name: part for part in parts}


def source(p=None) -> dict:
    """The on-axis beam: a disk 10 mm above the entrance stop covering the flanges."""
    from geometry.parts.assembly import collimated_source

    return collimated_source(p or params())


def default_dir(tolerance_mm: float = TOLERANCE_MM) -> Path:
    """Cache folder keyed on the parameters, the tolerance and this file's geometry code."""
    return cache_dir("newtonian", {"params": asdict(params()), "tolerance_mm": tolerance_mm, "cell": [
        PRIMARY_Z_MM, CLIP_REACH_MM, CLIP_WIDTH_MM, CLIP_GAP_MM, CLIP_THICKNESS_MM, BASE_Z_MM, CELL_INNER_RADIUS_MM],
        "v": 1})


def build(directory=None, tolerance_mm: float = TOLERANCE_MM, quiet: bool = False) -> Path:
    """Write the scene once (meshes + scene.toml) and return the scene.toml path; reuse it after."""
    from geometry.io import save_scene
    from geometry.tessellate import tessellate_parts

    def write(tmp):
        scene = tessellate_parts(newtonian_parts(), tolerance_mm=tolerance_mm, material=MATERIAL)
        save_scene(scene, tmp, sources=[source()])
        (tmp / "params.json").write_text(json.dumps(asdict(params()), indent=2))
        return f"the Newtonian ({len(scene.parts)} parts, {sum(p.n_triangles for p in scene.parts)} triangles)"

    return build_once(Path(directory) if directory is not None else default_dir(tolerance_mm), write, quiet)


if __name__ == "__main__":
    sys.exit(scene_cache.main(build, __doc__.splitlines()[0], TOLERANCE_MM))
