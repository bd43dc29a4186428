"""A scene file (CONTRACTS §6) for a user's own STEP/IGES assembly: ``straylight geometry scene``.

The scene loads the file with ``split = "solids"`` (one part per solid, named from the file's
labels), marks the detector solid with a per-solid override -- or, since mechanical CAD rarely
holds a detector solid, adds a detector (and an entrance) as an exact analytic disk (CONTRACTS
§6.4) -- gives every other solid one material, and adds a ``collimated_disk`` source: light
travels along ``-axis`` (the instrument
looks toward +axis), the disk sits ``standoff_mm`` beyond the assembly's +axis end and covers
the assembly's whole cross-section (its radius is the largest distance of any vertex from the
axis through the assembly's centre), so every analysis (CONTRACTS §4.5) runs on it at once.
Tessellating here also fills the tessellation cache, so the next commands start fast. Without a
detector the scene is written all the same, and the analyses refuse it in one line saying what to add.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from geometry.mesh import GeometryError


def disk_table(values, what: str) -> dict:
    """``(x, y, z, nx, ny, nz, r)`` -> a CONTRACTS §6.1 ``plane`` surface table (a disk facing n)."""
    v = np.asarray(values, dtype=float)
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise GeometryError(f"{what} needs 7 numbers X Y Z NX NY NZ R, got {values!r}")
    if np.linalg.norm(v[3:6]) == 0 or not v[6] > 0:
        raise GeometryError(f"{what}: the normal NX NY NZ must not be zero and the radius R must be > 0")
    return {"type": "plane", "vertex_mm": _clean(v[:3]), "axis": _clean(v[3:6] / np.linalg.norm(v[3:6])),
            "outer_radius_mm": float(v[6])}


def cad_scene_doc(cad_path, scene_path, *, detector: str | None = None, material: str = "z302_sample_b",
                  tolerance_mm: float = 0.05, axis=(0.0, 0.0, 1.0), name: str | None = None,
                  standoff_mm: float = 10.0, detector_disk=None, entrance_disk=None) -> tuple[dict, list]:
    """(scene TOML document, tessellated parts) for ``cad_path``, with paths relative to ``scene_path``.

    detector : the solid to use as detector (default: a solid named "detector", else the only solid whose
        name contains "detector"; none if no solid is named so); an unknown name is an error listing the
        file's solids.
    detector_disk : ``(x, y, z, nx, ny, nz, r)``: a detector part ``detector`` that is this exact disk,
        sensitive on the side n points to (CONTRACTS §6.4), instead of a solid.
    entrance_disk : ``(x, y, z, nx, ny, nz, r)``: the ``[analysis] entrance`` (CONTRACTS §6.3).
    """
    import os

    from geometry.io import load_cad_parts

    cad_path, scene_path = Path(cad_path), Path(scene_path)
    name = name or cad_path.stem
    a = np.asarray(axis, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) == 0:
        raise GeometryError(f"axis must be three finite numbers, not all zero, got {axis!r}")
    a = a / np.linalg.norm(a)
    if detector is not None and detector_disk is not None:
        raise GeometryError("give a detector solid or a detector disk, not both")
    # the disks are checked before the assembly is read and meshed (seconds to minutes of OpenCascade)
    detector_table = None if detector_disk is None else disk_table(detector_disk, "--detector-disk")
    entrance_table = None if entrance_disk is None else disk_table(entrance_disk, "--entrance-disk")
    parts = load_cad_parts(cad_path, name=name, material=material, tolerance_mm=tolerance_mm)
    solids = [p.meta["solid"] for p in parts]
    if detector is None and detector_disk is None:
        guesses = [s for s in solids if s == "detector"] or [s for s in solids if "detector" in s.lower()]
        detector = guesses[0] if len(guesses) == 1 else None
    if detector is not None and detector not in solids:  # an instance name (CONTRACTS 6.2) names its solid
        hits = [p.meta["solid"] for p in parts if detector in p.meta.get("aliases", ())]
        if len(hits) != 1:
            listed = ", ".join(p.meta["solid"] + (f" ({', '.join(p.meta['aliases'])})" if p.meta.get("aliases") else "")
                               for p in parts)
            raise GeometryError(f"{cad_path}: no solid named {detector!r}; its solids (other names in brackets): "
                                f"{listed}")
        detector = hits[0]
    vertices = np.concatenate([p.vertices_mm for p in parts])
    along = vertices @ a
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2  # bounding-box centre
    centre = centre - (centre @ a) * a
    radial = vertices - centre - np.outer(along, a)
    radius = float(np.linalg.norm(radial, axis=1).max()) * 1.01
    top = centre + (along.max() + standoff_mm) * a
    mesh = os.path.relpath(cad_path.resolve(), scene_path.resolve().parent)
    cad = {"name": name, "mesh": mesh, "split": "solids", "tolerance_mm": float(tolerance_mm),
           "material": material, "role": "surface"}
    if detector is not None:
        cad["solids"] = {detector: {"role": "detector"}}
    doc: dict[str, Any] = {"part": [cad],
           "source": [{"type": "collimated_disk", "center_mm": _clean(top), "normal": _clean(-a),
                       "direction": _clean(-a), "radius_mm": round(radius, 6), "power_w": 1.0}]}
    if detector_disk is not None:
        if name == "detector":
            raise GeometryError(f"{cad_path}: the assembly's part is named 'detector': rename it (name=...)")
        doc["part"].append({"name": "detector", "role": "detector", "surface": detector_table})
    if entrance_table is not None:
        e = entrance_table
        doc["analysis"] = {"entrance": {"center_mm": e["vertex_mm"], "normal": e["axis"],
                                        "radius_mm": e["outer_radius_mm"]}}
    return doc, parts


def detector_of(doc: dict) -> str | None:
    """The detector part (or solid) a :func:`cad_scene_doc` names, None if it has none."""
    for part in doc["part"]:
        if part.get("role") == "detector":
            return part["name"]
        for solid, tags in part.get("solids", {}).items():
            if tags.get("role") == "detector":
                return f"{part['name']}/{solid}"
    return None


def _clean(v) -> list[float]:
    return [float(round(x, 9)) + 0.0 for x in v]  # + 0.0: no "-0.0" in the file


def write_cad_scene(cad_path, scene_path, **kwargs) -> tuple[Path, list]:
    """Write :func:`cad_scene_doc` to ``scene_path`` (atomically); returns (path, parts)."""
    import atomicio
    import tomli_w

    doc, parts = cad_scene_doc(cad_path, scene_path, **kwargs)
    scene_path = Path(scene_path)
    header = (f"# scene for {Path(cad_path).name}: written by `straylight geometry scene`; edit freely\n"
              f"# (docs/reference/scene.md: [part.solids.\"NAME\"] sets material/role per solid; a product or instance name)\n")
    if detector_of(doc) is None:
        header += ("# NO DETECTOR YET: the analyses need one. Add a detector disk (docs/reference/scene.md), e.g.\n"
                   "# [[part]]\n# name = \"detector\"\n# role = \"detector\"\n"
                   "# surface = {type = \"plane\", vertex_mm = [X, Y, Z], axis = [NX, NY, NZ], outer_radius_mm = R}\n"
                   "# or mark a solid: [part.solids.\"NAME\"] role = \"detector\"\n")
    atomicio.write_text(scene_path, header + tomli_w.dumps(doc))
    return scene_path, parts
