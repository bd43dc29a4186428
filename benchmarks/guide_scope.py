"""A benchmark instrument with a lens (the optics path): a 50 mm f/4 guide scope, built in CadQuery.

    .venv/bin/python benchmarks/guide_scope.py [--dir DIR] [--tolerance-mm T]

writes (once; a rerun with the same parameters only prints the path) the meshes and ``scene.toml``
to DIR (default ``~/.cache/straylight/benchmarks/guide_scope-<hash>``), so every command of
CONTRACTS §4.5 runs on it; ``benchmarks/newtonian_pst.py --instrument guide_scope`` times
``straylight pst`` on it.

What it holds (z is the optical axis; light enters at the top and travels toward -z; lengths mm):

- ``lens_front``, ``lens_back``: a plano-convex BK7 singlet (n = 1.5195 at 532 nm, the Cassegrain
  filter's glass), clear radius 25, centre thickness 5, convex side to the sky with radius
  R = f (n - 1) = 104 mm (f = 200 mm): exact analytic surfaces (CONTRACTS §6.1: a sphere and a
  plane, ``axis`` out of the glass); ``lens_edge``: its ground edge, blackened (z302_sample_b);
- ``detector``: the guide camera's sensor, the exact disk r < 3 mm at the back focus
  (z = 0, BFD = f - t / n), facing the sky (an analytic plane, CONTRACTS §6.4);
- ``tube``: the wall, inner radius 30, from the camera flange to the top of the dew shield
  (z = -2 .. 290); ``camera``: the flange plate around the sensor (r = 3 .. 31.5, z = -2 .. 0);
- ``vane_1`` .. ``vane_4``: vanes between the lens and the sensor, their holes on the converging
  beam's envelope (+ 1.5 mm); ``shield_vane_1``, ``shield_vane_2``: two vanes in the dew shield
  in front of the lens (hole radius 26);
- ``lens_cell``: the ring holding the lens, with a lip over each face of the lens's edge.

Every mechanical surface is coated ``z302_sample_b``. The on-axis beam is focused onto the sensor
(PST ~ 1e2); past ~1 deg only stray light reaches it: scatter off the tube, vanes and cell
behind the lens (next-event estimation reaches the sensor from there) and scatter in front of it
that the lens then focuses (only the walk reaches the sensor through the glass).
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import scene_cache
from scene_cache import build_once, cache_dir

MATERIAL = "z302_sample_b"
GLASS = {"name": "n_bk7", "wavelength_nm": 532.0, "components": [{"type": "dielectric", "n": 1.5195}]}
FOCAL_MM = 200.0
LENS_RADIUS_MM = 25.0
LENS_THICKNESS_MM = 5.0
DETECTOR_RADIUS_MM = 3.0
TUBE_INNER_MM = 30.0
TUBE_OUTER_MM = 31.5
TOP_Z_MM = 290.0
CAMERA_Z_MM = (-2.0, 0.0)
VANE_Z_MM = (40.0, 80.0, 120.0, 160.0)
SHIELD_VANE_Z_MM = (235.0, 265.0)
SHIELD_HOLE_MM = 26.0
VANE_THICKNESS_MM = 1.0
VANE_CLEARANCE_MM = 1.5
TOLERANCE_MM = 0.01


def glass_index() -> float:
    return float(GLASS["components"][0]["n"])


def front_radius_mm() -> float:
    """Radius of curvature of the convex face: thin-lens f = R / (n - 1) for a plano-convex lens."""
    return FOCAL_MM * (glass_index() - 1.0)


def back_z_mm() -> float:
    """The lens's flat (back) face: the back focal distance above the sensor, BFD = f - t / n."""
    return FOCAL_MM - LENS_THICKNESS_MM / glass_index()


def front_vertex_z_mm() -> float:
    return back_z_mm() + LENS_THICKNESS_MM


def front_sag_mm(rho_mm: float) -> float:
    r = front_radius_mm()
    return r - math.sqrt(r * r - rho_mm * rho_mm)


def vane_hole_mm(z_mm: float) -> float:
    """The converging beam's envelope at height z (lens rim to sensor rim), plus the clearance."""
    return DETECTOR_RADIUS_MM + (LENS_RADIUS_MM - DETECTOR_RADIUS_MM) * z_mm / back_z_mm() + VANE_CLEARANCE_MM


def mechanical_parts() -> dict:
    """Named CadQuery parts (tube, camera plate, vanes, lens cell)."""
    from geometry.parts.assembly import _annulus

    b = back_z_mm()
    edge_top = front_vertex_z_mm() - front_sag_mm(LENS_RADIUS_MM)
    lip_r = LENS_RADIUS_MM - 1.0
    cell_in = LENS_RADIUS_MM + 0.2
    parts = [_annulus(TUBE_INNER_MM, TUBE_OUTER_MM, CAMERA_Z_MM[0], TOP_Z_MM, "tube"),
             _annulus(DETECTOR_RADIUS_MM, TUBE_INNER_MM, CAMERA_Z_MM[0], CAMERA_Z_MM[1], "camera")]
    half = VANE_THICKNESS_MM / 2
    parts += [_annulus(vane_hole_mm(z), TUBE_INNER_MM, z - half, z + half, f"vane_{k}")
              for k, z in enumerate(VANE_Z_MM, start=1)]
    parts += [_annulus(SHIELD_HOLE_MM, TUBE_INNER_MM, z - half, z + half, f"shield_vane_{k}")
              for k, z in enumerate(SHIELD_VANE_Z_MM, start=1)]
    # the cell: a ring around the lens's edge (0.2 mm gap) from 1 mm below the flat face to 0.4 mm
    # above the edge of the convex one, with a 1 mm lip under the flat face and one over the convex face
    lip_top_gap = front_vertex_z_mm() - front_sag_mm(lip_r) + 0.1 - edge_top
    ring = _annulus(cell_in, TUBE_INNER_MM, b - 1.0, edge_top + lip_top_gap + 0.7, "lens_cell").shape
    lower = _annulus(lip_r, cell_in + 0.5, b - 1.0, b - 0.1, "lower").shape
    upper = _annulus(lip_r, cell_in + 0.5, edge_top + lip_top_gap, edge_top + lip_top_gap + 0.7, "upper").shape
    from geometry.parts import ShapePart

    parts.append(ShapePart("lens_cell", ring.fuse(lower, upper).clean(), "surface", "solid"))
    return {p.name: p for p in parts}


def optical_entries() -> list[dict]:
    """The lens's exact surfaces, its blackened edge and the sensor (scene-file part entries)."""
    b, top = back_z_mm(), front_vertex_z_mm()
    edge = top - front_sag_mm(LENS_RADIUS_MM) - b
    return [
        {"name": "lens_front", "material": GLASS["name"], "role": "surface", "tolerance_mm": TOLERANCE_MM,
         "surface": {"type": "conic", "vertex_mm": [0.0, 0.0, top], "axis": [0.0, 0.0, 1.0],
                     "radius_mm": -front_radius_mm(), "conic": 0.0, "outer_radius_mm": LENS_RADIUS_MM}},
        {"name": "lens_back", "material": GLASS["name"], "role": "surface", "tolerance_mm": TOLERANCE_MM,
         "surface": {"type": "plane", "vertex_mm": [0.0, 0.0, b], "axis": [0.0, 0.0, -1.0],
                     "outer_radius_mm": LENS_RADIUS_MM}},
        {"name": "lens_edge", "material": MATERIAL, "role": "surface", "tolerance_mm": TOLERANCE_MM,
         "surface": {"type": "cylinder", "vertex_mm": [0.0, 0.0, b], "axis": [0.0, 0.0, 1.0],
                     "radius_mm": LENS_RADIUS_MM, "length_mm": edge}},
        {"name": "detector", "role": "detector", "tolerance_mm": TOLERANCE_MM,
         "surface": {"type": "plane", "vertex_mm": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0],
                     "outer_radius_mm": DETECTOR_RADIUS_MM}},
    ]


def source() -> dict:
    """The on-axis beam: a disk 10 mm above the dew shield covering the tube."""
    return {"type": "collimated_disk", "center_mm": [0.0, 0.0, TOP_Z_MM + 10.0], "normal": [0.0, 0.0, -1.0],
            "direction": [0.0, 0.0, -1.0], "radius_mm": TUBE_OUTER_MM + 1.0, "power_w": 1.0}


def default_dir(tolerance_mm: float = TOLERANCE_MM) -> Path:
    """Cache folder keyed on the parameters, the tolerance and this file's geometry code."""
    return cache_dir("guide_scope", {
        "f": FOCAL_MM, "lens": [LENS_RADIUS_MM, LENS_THICKNESS_MM], "glass": GLASS, "det": DETECTOR_RADIUS_MM,
        "tube": [TUBE_INNER_MM, TUBE_OUTER_MM, TOP_Z_MM, CAMERA_Z_MM],
        "vanes": [VANE_Z_MM, SHIELD_VANE_Z_MM, SHIELD_HOLE_MM, VANE_THICKNESS_MM, VANE_CLEARANCE_MM],
        "tolerance_mm": tolerance_mm, "v": 1})


def build(directory=None, tolerance_mm: float = TOLERANCE_MM, quiet: bool = False) -> Path:
    """Write the scene once (meshes + scene.toml) and return the scene.toml path; reuse it after."""
    import tomllib

    import tomli_w

    import atomicio
    from geometry.io import save_scene
    from geometry.tessellate import tessellate_parts

    def write(tmp):
        scene = tessellate_parts(mechanical_parts(), tolerance_mm=tolerance_mm, material=MATERIAL)
        path = save_scene(scene, tmp, sources=[source()])
        doc = tomllib.loads(path.read_text())
        doc["material"] = {GLASS["name"]: {k: v for k, v in GLASS.items() if k != "name"}}
        doc["part"] += optical_entries()
        doc["analysis"] = {"detector": "detector",
                           "entrance": {"center_mm": [0.0, 0.0, TOP_Z_MM], "normal": [0.0, 0.0, 1.0],
                                        "radius_mm": TUBE_INNER_MM}}
        atomicio.write_text(path, tomli_w.dumps(doc))
        return (f"the guide scope ({len(doc['part'])} parts, {sum(p.n_triangles for p in scene.parts)} mechanical "
                f"triangles)")

    return build_once(Path(directory) if directory is not None else default_dir(tolerance_mm), write, quiet)


if __name__ == "__main__":
    sys.exit(scene_cache.main(build, __doc__.splitlines()[0], TOLERANCE_MM))
