"""A scene file (CONTRACTS §6) for a user's own STEP/IGES assembly: ``straylight geometry scene``.

The scene loads the file with ``split = "solids"`` (one part per solid, named from the file's
labels), marks the detector solid with a per-solid override, gives every other solid one
material, and adds a ``collimated_disk`` source: light travels along ``-axis`` (the instrument
looks toward +axis), the disk sits ``standoff_mm`` beyond the assembly's +axis end and covers
the assembly's whole cross-section (its radius is the largest distance of any vertex from the
axis through the assembly's centre), so every analysis (CONTRACTS §4.5) runs on it at once.
Tessellating here also fills the tessellation cache, so the next commands start fast.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from geometry.mesh import GeometryError


def cad_scene_doc(cad_path, scene_path, *, detector: str | None = None, material: str = "z302_sample_b",
                  tolerance_mm: float = 0.05, axis=(0.0, 0.0, 1.0), name: str | None = None,
                  standoff_mm: float = 10.0) -> tuple[dict, list]:
    """(scene TOML document, tessellated parts) for ``cad_path``, with paths relative to ``scene_path``.

    detector : the solid to use as detector (default: a solid named "detector", else the only solid whose
        name contains "detector"); an unknown name is an error listing the file's solids.
    """
    import os

    from geometry.io import load_cad_parts

    cad_path, scene_path = Path(cad_path), Path(scene_path)
    name = name or cad_path.stem
    a = np.asarray(axis, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) == 0:
        raise GeometryError(f"axis must be three finite numbers, not all zero, got {axis!r}")
    a = a / np.linalg.norm(a)
    parts = load_cad_parts(cad_path, name=name, material=material, tolerance_mm=tolerance_mm)
    solids = [p.meta["solid"] for p in parts]
    if detector is None:
        guesses = [s for s in solids if s == "detector"] or [s for s in solids if "detector" in s.lower()]
        if len(guesses) != 1:
            raise GeometryError(f"{cad_path}: say which solid is the detector (--detector NAME); its solids: "
                                f"{', '.join(solids)}")
        detector = guesses[0]
    if detector not in solids:
        raise GeometryError(f"{cad_path}: no solid named {detector!r}; its solids: {', '.join(solids)}")
    vertices = np.concatenate([p.vertices_mm for p in parts])
    along = vertices @ a
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2  # bounding-box centre
    centre = centre - (centre @ a) * a
    radial = vertices - centre - np.outer(along, a)
    radius = float(np.linalg.norm(radial, axis=1).max()) * 1.01
    top = centre + (along.max() + standoff_mm) * a
    mesh = os.path.relpath(cad_path.resolve(), scene_path.resolve().parent)
    doc = {
        "part": [{"name": name, "mesh": mesh, "split": "solids", "tolerance_mm": float(tolerance_mm),
                  "material": material, "role": "surface", "solids": {detector: {"role": "detector"}}}],
        "source": [{"type": "collimated_disk", "center_mm": _clean(top), "normal": _clean(-a),
                    "direction": _clean(-a), "radius_mm": round(radius, 6), "power_w": 1.0}],
    }
    return doc, parts


def _clean(v) -> list[float]:
    return [float(round(x, 9)) + 0.0 for x in v]  # + 0.0: no "-0.0" in the file


def write_cad_scene(cad_path, scene_path, **kwargs) -> tuple[Path, list]:
    """Write :func:`cad_scene_doc` to ``scene_path`` (atomically); returns (path, parts)."""
    import atomicio
    import tomli_w

    doc, parts = cad_scene_doc(cad_path, scene_path, **kwargs)
    scene_path = Path(scene_path)
    header = (f"# scene for {Path(cad_path).name}: written by `straylight geometry scene`; edit freely\n"
              f"# (CONTRACTS §6.2: [part.solids.\"NAME\"] sets material/role per solid)\n")
    atomicio.write_text(scene_path, header + tomli_w.dumps(doc))
    return scene_path, parts
