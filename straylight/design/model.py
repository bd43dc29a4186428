"""A designed tube as CadQuery parts, a tessellated scene, a scene file and a STEP model.

Parts (CONTRACTS 4.6): ``wall`` (r = R .. R + wall, z = 0 .. L), ``vane_1`` (lowest) ..
``vane_N`` (built by :func:`geometry.parts.tube.vane`, bevel included), ``end_plate``
(r = S .. R + wall, z = -1 .. 0) and ``detector`` (the disk r < S at z = 0 facing +z). The beam
is a ``collimated_disk`` just above the entrance, along -z, wide enough to cover the entrance and
the wall's rim at any tilt up to ``MAX_TILT_DEG`` (its disk stays put when ``straylight pst``
tilts it, so it must be wider than the entrance by standoff x tan(tilt)).
"""
from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

WALL_THICKNESS_MM = 1.0
END_PLATE_THICKNESS_MM = 1.0
BEAM_STANDOFF_MM = 0.2
MAX_TILT_DEG = 85.0
TOLERANCE_MM = 0.05
COATING_KEY = "coating"


def beam_radius_mm(tube_radius_mm: float) -> float:
    """Radius of the beam disk: wall's outer radius + standoff tan(MAX_TILT_DEG)."""
    return tube_radius_mm + WALL_THICKNESS_MM + BEAM_STANDOFF_MM * math.tan(math.radians(MAX_TILT_DEG))


def beam_source_dict(spec) -> dict:
    """The scene file's ``[[source]]`` (CONTRACTS 6): a collimated disk along -z above the entrance."""
    return {"type": "collimated_disk", "center_mm": [0.0, 0.0, spec.tube_length_mm + BEAM_STANDOFF_MM],
            "normal": [0.0, 0.0, -1.0], "direction": [0.0, 0.0, -1.0],
            "radius_mm": beam_radius_mm(spec.tube_radius_mm), "power_w": 1.0}


def beam(spec):
    """The :class:`straylight.analyses.types.Beam` that ``straylight pst`` builds from that source."""
    from straylight.analyses.types import Beam

    src = beam_source_dict(spec)
    return Beam(center_mm=src["center_mm"], axis=src["normal"], radius_mm=src["radius_mm"], power_w=src["power_w"])


def shape_parts(spec, vanes) -> dict:
    """Named CadQuery parts of the tube with these vanes (sorted by z, named vane_1.. from the bottom)."""
    from geometry.parts.detector import disk_detector
    from geometry.parts.stops import annular_plate
    from geometry.parts.tube import vane

    R, L, S = spec.tube_radius_mm, spec.tube_length_mm, spec.stop_radius_mm
    parts = [annular_plate(R, R + WALL_THICKNESS_MM, L, L, name="wall")]
    for k, v in enumerate(sorted(vanes, key=lambda v: v.z_mm), start=1):
        parts.append(vane(v.inner_radius_mm, R, v.thickness_mm, v.z_mm, spec.bevel_deg, spec.bevel_side,
                          name=f"vane_{k}"))
    parts.append(annular_plate(S, R + WALL_THICKNESS_MM, END_PLATE_THICKNESS_MM, 0.0, name="end_plate"))
    parts.append(disk_detector(S, name="detector"))
    return {p.name: p for p in parts}


@lru_cache(maxsize=4096)
def _tessellated(kind: str, args: tuple, name: str):
    """One tessellated part, cached: the optimiser rebuilds the same wall, plate and detector often."""
    from geometry.parts.detector import disk_detector
    from geometry.parts.stops import annular_plate
    from geometry.parts.tube import vane
    from geometry.tessellate import tessellate

    if kind == "plate":
        part = annular_plate(*args, name=name)
    elif kind == "vane":
        part = vane(*args, name=name)
    else:
        part = disk_detector(*args, name=name)
    mesh = tessellate(part.shape, name=name, tolerance_mm=TOLERANCE_MM, material=None if kind == "detector"
                      else COATING_KEY, role=part.role, kind=part.kind)
    mesh.vertices_mm.flags.writeable = False
    mesh.faces.flags.writeable = False
    return mesh


def scene(spec, vanes):
    """Tessellated :class:`geometry.mesh.Scene` of :func:`shape_parts` (material tag ``coating``)."""
    from geometry.mesh import Scene

    R, L, S = spec.tube_radius_mm, spec.tube_length_mm, spec.stop_radius_mm
    parts = [_tessellated("plate", (R, R + WALL_THICKNESS_MM, L, L), "wall")]
    for k, v in enumerate(sorted(vanes, key=lambda v: v.z_mm), start=1):
        parts.append(_tessellated("vane", (v.inner_radius_mm, R, v.thickness_mm, v.z_mm, spec.bevel_deg,
                                           spec.bevel_side), f"vane_{k}"))
    parts.append(_tessellated("plate", (S, R + WALL_THICKNESS_MM, END_PLATE_THICKNESS_MM, 0.0), "end_plate"))
    parts.append(_tessellated("detector", (S,), "detector"))
    return Scene(tuple(parts))


def coating(material):
    """(scene-file material table or None, preset name or None, {COATING_KEY: model}) for a preset name,
    a material file path or a model. A file is copied into the scene file as ``[material.coating]``."""
    from materials import load_material

    if not isinstance(material, (str, Path)):  # a model object: written out with its own to_dict()
        return material.to_dict(), None, {COATING_KEY: material}
    model = load_material(material)
    path = Path(material)
    if path.is_file():
        return json.loads(path.read_text()), None, {COATING_KEY: model}
    return None, str(material), {COATING_KEY: model}


def write_scene(spec, vanes, material, directory) -> Path:
    """Write ``scene.toml`` with one PLY mesh per part (float64: lossless) into ``directory``."""
    from dataclasses import replace

    from geometry.io import save_scene
    from geometry.mesh import Scene

    table, preset, _ = coating(material)
    sc = scene(spec, vanes)
    if preset is not None:  # name the preset directly; a file or model goes inline as [material.coating]
        sc = Scene(tuple(replace(p, material=preset) if p.material == COATING_KEY else p for p in sc.parts))
    materials = {COATING_KEY: table} if table is not None else None
    return save_scene(sc, directory, materials=materials, sources=[beam_source_dict(spec)])


def write_step(spec, vanes, path) -> Path:
    """The CadQuery assembly (wall, vanes, end plate, detector; named) as one STEP file, written
    atomically (:func:`geometry.io.export_assembly_step`)."""
    from geometry.io import export_assembly_step

    return export_assembly_step(shape_parts(spec, vanes), Path(path))
