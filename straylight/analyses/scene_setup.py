"""A scene file (CONTRACTS §6) set up for the analyses: the beam, the entrance and the detector.

The beam is the scene's ``collimated_disk`` source (the only one, or the first with a warning-free
rule: several collimated sources are an error). At 0 deg off axis it is that source exactly; an
off-axis angle tilts its rays away from the source's own ``direction`` (azimuth 0 toward the world
axis least aligned with it: :attr:`straylight.analyses.types.Beam.basis`).

The optional ``[analysis]`` table (CONTRACTS §6.3)::

    [analysis]
    detector = "focal_plane"       # default: the only detector part
    entrance = {center_mm = [0, 0, 300], normal = [0, 0, 1], radius_mm = 50}
    detector_area_mm2 = 1134.1     # optional override of the sensitive area (see docs/study.md)

With an entrance, the source disk slides in its own plane so that its central ray passes through
the entrance centre at every tilt (the beam keeps covering the entrance) and ``entrance_ratio`` is
detector power / beam power crossing the entrance disk. Without one, the entrance is the source
disk itself (centre, radius; normal against the rays): the disk stays put at every tilt, as in
shared/BENCHMARK.md, and ``entrance_ratio`` is detector power / beam power.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

ANALYSIS_KEYS = ("detector", "entrance", "detector_area_mm2")
ENTRANCE_KEYS = ("center_mm", "normal", "radius_mm")


def _vector(value, where: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{where} must be 3 numbers, got {value!r}")
    return v


def parse_analysis_table(doc: dict, path) -> dict:
    """The checked ``[analysis]`` table of a scene document: {detector, entrance, detector_area_mm2}."""
    from straylight.analyses.types import Entrance

    table = doc.get("analysis", {})
    where = f"{path}: [analysis]"
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table")
    unknown = sorted(set(table) - set(ANALYSIS_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; expected {', '.join(ANALYSIS_KEYS)}")
    out: dict[str, Any] = {"detector": None, "entrance": None, "detector_area_mm2": None}
    if "detector" in table:
        if not isinstance(table["detector"], str):
            raise ValueError(f"{where}: detector must be a part name (a string)")
        out["detector"] = table["detector"]
    if "entrance" in table:
        ent = table["entrance"]
        if not isinstance(ent, dict):
            raise ValueError(f"{where}: entrance must be a table {{center_mm, normal, radius_mm}}")
        missing = [k for k in ENTRANCE_KEYS if k not in ent]
        extra = sorted(set(ent) - set(ENTRANCE_KEYS))
        if missing or extra:
            raise ValueError(f"{where}: entrance needs exactly {', '.join(ENTRANCE_KEYS)}"
                             + (f"; missing {', '.join(missing)}" if missing else "")
                             + (f"; unknown {', '.join(extra)}" if extra else ""))
        r = ent["radius_mm"]
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not r > 0:
            raise ValueError(f"{where}: entrance radius_mm must be a number > 0, got {r!r}")
        normal = _vector(ent["normal"], f"{where}: entrance normal")
        if np.linalg.norm(normal) == 0:
            raise ValueError(f"{where}: entrance normal must not be zero")
        out["entrance"] = Entrance(center_mm=_vector(ent["center_mm"], f"{where}: entrance center_mm"),
                                   radius_mm=float(r), normal=normal)
    if "detector_area_mm2" in table:
        a = table["detector_area_mm2"]
        if isinstance(a, bool) or not isinstance(a, (int, float)) or not a > 0:
            raise ValueError(f"{where}: detector_area_mm2 must be a number > 0, got {a!r}")
        out["detector_area_mm2"] = float(a)
    return out


def beam_of_scene(sources, path):
    """The scene's collimated_disk source as a :class:`Beam` (no pivot yet)."""
    from straylight.analyses.types import Beam
    from straylight.sources import CollimatedDisk

    beams = [s for s in sources if isinstance(s, CollimatedDisk)]
    if not beams:
        kinds = ", ".join(sorted({type(s).__name__ for s in sources})) or "none"
        raise ValueError(f"{path}: no collimated_disk [[source]] to tilt for the analyses (sources: {kinds})")
    if len(beams) > 1:
        raise ValueError(f"{path}: {len(beams)} collimated_disk sources; the analyses tilt one beam: keep one")
    src = beams[0]
    return Beam(center_mm=src.center_mm, axis=src.direction, radius_mm=float(src.radius_mm),
                power_w=float(src.power_w), disk_normal=src.normal, wavelength_nm=src.wavelength_nm)


def setup_from_resolved(rs, analysis: dict, path, detector: str | None = None, entrance=None):
    """A :class:`Setup` from a resolved scene and its ``[analysis]`` settings.

    ``detector`` / ``entrance`` given here (command-line options) override the file's table.
    """
    from dataclasses import replace

    from straylight.analyses.types import Entrance, Setup
    from straylight.analyses.pst import detector_name

    beam = beam_of_scene(rs.sources, path)
    det = detector or analysis.get("detector")
    try:
        det = detector_name(rs.scene, det)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    ent = entrance if entrance is not None else analysis.get("entrance")
    if ent is not None:
        beam = replace(beam, pivot_mm=ent.center_mm)
    else:
        ent = Entrance(center_mm=beam.center_mm, radius_mm=beam.radius_mm, normal=-beam.axis)
    return Setup(rs.scene, rs.materials, beam, ent, det, f"scene {path}", None,
                 analysis.get("detector_area_mm2"))


def scene_setup(path, detector: str | None = None, entrance=None):
    """Load SCENE.toml and set it up for the analyses (see the module docstring)."""
    from geometry.io import read_scene_toml
    from straylight.scene import load_scene

    path = Path(path)
    rs = load_scene(path)
    analysis = parse_analysis_table(read_scene_toml(path), path)
    return setup_from_resolved(rs, analysis, path, detector=detector, entrance=entrance)


def scene_tables(beam, entrance, detector: str, detector_area_mm2=None) -> tuple[dict, dict]:
    """The ``[[source]]`` (the beam at 0 deg) and ``[analysis]`` tables that make :func:`scene_setup`
    read a scene back with this beam, entrance and detector."""
    b = beam
    source = {"type": "collimated_disk", "center_mm": [float(x) for x in b.center_mm],
              "normal": [float(x) for x in b.disk_normal], "direction": [float(x) for x in b.axis],
              "radius_mm": float(b.radius_mm), "power_w": float(b.power_w)}
    analysis: dict[str, Any] = {"detector": detector}
    e = entrance
    if e is not None:
        if b.pivot_mm is not None and not np.allclose(b.pivot_mm, e.center_mm):
            raise ValueError("the beam pivots about a point other than the entrance centre: not expressible "
                             "in a scene file")
        normal = -b.axis if e.normal is None else e.normal
        analysis["entrance"] = {"center_mm": [float(x) for x in e.center_mm],
                                "normal": [float(x) for x in normal], "radius_mm": float(e.radius_mm)}
    if detector_area_mm2 is not None:
        analysis["detector_area_mm2"] = float(detector_area_mm2)
    return source, analysis


def add_scene_tables(path, tables: dict) -> Path:
    """Rewrite the scene TOML at ``path`` (atomically) with top-level ``tables`` added or replaced."""
    import tomllib

    import tomli_w

    import atomicio

    doc = tomllib.loads(Path(path).read_text())
    doc.update(tables)
    atomicio.write_text(path, tomli_w.dumps(doc))
    return Path(path)


def write_setup_scene(setup, directory, scene_file: str = "scene.toml") -> Path:
    """Write a Setup as a scene file (meshes, source, ``[analysis]``) that :func:`scene_setup` reads
    back to the same analyses: the beam at 0 deg as the ``[[source]]``, its entrance and detector.

    Materials are written by name (presets and material files resolve by name again).
    """
    from geometry.io import save_scene

    source, analysis = scene_tables(setup.beam, setup.entrance, setup.detector, setup.detector_area_mm2)
    path = save_scene(setup.scene, directory, scene_file=scene_file, sources=[source])
    return add_scene_tables(path, {"analysis": analysis})
