"""Scene files (CONTRACTS §6) -> a resolved scene: parts, material models, sources.

Material names are resolved once, here: a ``[material.NAME]`` table of the scene file, a material
file path (relative to the scene file), or a preset of ``materials/library``. An unknown name is an
error that lists the known ones. Meshes are read by ``geometry.io`` (STL, OBJ, PLY; STEP is
tessellated at ``tolerance_mm``).

Warnings (tracing can still be right): a non-watertight part that is not a detector, and a source
none of whose probe rays reaches the scene's bounding box.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from straylight.polarization import PolarizationError, attach, check_polarization_for_source, split_polarization
from straylight.sources import SourceError, source_from_dict

TOP_KEYS = ("material", "part", "source", "analysis")  # [analysis]: straylight.analyses.scene_setup


class SceneFileError(ValueError):
    """A scene file that cannot be traced; the message names the file and the entry."""


class SceneWarning(UserWarning):
    """Something suspicious in a scene file that does not stop the trace."""


@dataclass(frozen=True, eq=False)
class ResolvedScene:
    """A scene ready to trace: ``trace(rs.scene, rs.sources, n, seed, materials=rs.materials)``."""

    path: Path | None
    scene: object
    materials: dict
    sources: tuple
    warnings: tuple

    def trace(self, n_rays, seed=0, options=None, **kwargs):
        from straylight.trace import trace

        return trace(self.scene, self.sources, n_rays, seed, materials=self.materials, options=options, **kwargs)


def _known_materials(inline) -> str:
    try:
        from materials import list_presets

        presets = list(list_presets())
    except ImportError:
        presets = []
    names = sorted(inline) + [p for p in presets if p not in inline]
    return ", ".join(names) if names else "none"


def resolve_material(name: str, inline: dict, base_dir: Path, where: str):
    """One material name -> model (inline table, then file relative to base_dir, then preset)."""
    from materials import load_material
    from materials.base import MaterialError

    try:
        if name in inline:
            table = inline[name]
            if not isinstance(table, dict):
                raise SceneFileError(f"{where}: [material.{name}] must be a table")
            return load_material(dict(table), name=name)
        candidate = base_dir / name
        if candidate.exists() or name.endswith(".json"):  # a file (load_material refuses what is not a regular one)
            if not candidate.exists():
                raise SceneFileError(f"{where}: material file {str(candidate)!r} not found")
            return load_material(candidate)
        return load_material(name)
    except MaterialError as exc:
        if "unknown material" in str(exc):
            raise SceneFileError(
                f"{where}: unknown material {name!r}; known: {_known_materials(inline)}") from None
        raise SceneFileError(f"{where}: {exc}") from None


def _resolve_back_material(part, materials: dict, inline: dict, base_dir: Path, where: str) -> None:
    """An analytic part's ``back_material`` (CONTRACTS §6.1) is resolved like its ``material``."""
    back = getattr(part, "back_material", None)
    if back is None or back in materials:
        return
    if part.role != "surface":
        raise SceneFileError(f"{where}: 'back_material' is for role = \"surface\" parts")
    materials[back] = resolve_material(back, inline, base_dir, where)


def _watertight(part) -> bool:
    """``part.is_watertight``, or the answer recorded when its mesh was made (``meta["watertight"]``:
    CAD solids, checked once and kept in the tessellation cache, geometry.cad_cache)."""
    known = part.meta.get("watertight")
    return bool(known) if known is not None else part.is_watertight


def _probe_reaches_box(source, lo, hi, n=256) -> bool:
    """Do any of n deterministic probe rays of the source cross the box [lo, hi]?"""
    g = np.random.default_rng(0)
    u = np.empty((n, 5))
    u[:, 1:] = g.random((n, 4))
    o, d = source.emit(u[:, 1:])  # a strided view, as the engine passes them
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (lo - o) * inv
        t2 = (hi - o) * inv
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return bool(np.any(tmax >= np.maximum(tmin, 0.0)))


DIFFRACTION_KINDS = ("edges",)


def _mark_diffraction(doc: dict, scene, path: Path) -> None:
    """``diffraction = "edges"`` on a [[part]] (CONTRACTS §6.5) -> ``meta["diffraction"]`` of the parts
    it made (with ``split = "solids"``, every solid ``NAME/...``)."""
    for i, entry in enumerate(doc.get("part", []), start=1):
        if not isinstance(entry, dict) or "diffraction" not in entry:
            continue
        kind = entry["diffraction"]
        where = f"{path}: [[part]] {i} ({entry.get('name')!r})"
        if kind not in DIFFRACTION_KINDS:
            raise SceneFileError(f"{where}: diffraction must be \"edges\", got {kind!r}")
        if entry.get("role", "surface") == "detector":
            raise SceneFileError(f"{where}: a detector part cannot diffract; put diffraction = \"edges\" on the stop")
        name = entry.get("name")
        for part in scene.parts:
            if part.name == name or part.name.startswith(f"{name}/"):
                part.meta["diffraction"] = kind


def _check_analysis_detector(doc, scene, path) -> None:
    """``[analysis] detector`` names a detector part of the scene (a CAD solid by its product or instance
    name, CONTRACTS 6.2): every command refuses a name that does not, not only those that tilt a beam."""
    from geometry.mesh import GeometryError

    table = doc.get("analysis")
    name = table.get("detector") if isinstance(table, dict) else None
    if not isinstance(name, str):
        return  # absent, or wrongly typed: the analyses' own check (scene_setup.parse_analysis_table) says so
    detectors = [p.name for p in scene.parts if p.role == "detector"]
    try:
        resolved = scene.resolve(name) if hasattr(scene, "resolve") else name
    except GeometryError:
        resolved = None
    if resolved not in detectors:
        raise SceneFileError(f"{path}: [analysis] detector {name!r} is not a detector part of the scene; "
                             f"detectors: {', '.join(detectors) or 'none'}")


def load_scene(path, check_watertight: bool = True, sources: bool = True) -> ResolvedScene:
    """Read and resolve a scene TOML (CONTRACTS §6).

    ``sources=False`` (the thermal commands, CONTRACTS §7): ``[[source]]`` entries are ignored
    and may be absent.

    Raises SceneFileError (a ValueError) naming the file and entry for: unknown top-level keys,
    a missing mesh, an unknown material, a surface part without material, a bad or missing source.
    Emits SceneWarning for non-watertight parts and sources that cannot reach the scene.
    """
    from geometry.io import load_scene as load_geometry
    from geometry.io import read_scene_toml
    from geometry.mesh import GeometryError

    path = Path(path)
    try:
        doc = read_scene_toml(path)
    except GeometryError as exc:
        raise SceneFileError(str(exc)) from None
    unknown = sorted(set(doc) - set(TOP_KEYS))
    if unknown:
        raise SceneFileError(f"{path}: unknown top-level key(s) {', '.join(unknown)}; expected {', '.join(TOP_KEYS)}")
    inline = doc.get("material", {})
    if not isinstance(inline, dict):
        raise SceneFileError(f"{path}: 'material' must be tables [material.NAME]")
    try:
        scene = load_geometry(path)
    except GeometryError as exc:
        raise SceneFileError(str(exc)) from None
    _mark_diffraction(doc, scene, path)
    _check_analysis_detector(doc, scene, path)
    notes = []
    materials = {}
    for i, part in enumerate(scene.parts, start=1):
        where = f"{path}: [[part]] {i} ({part.name!r})"
        if part.role == "surface":
            if part.material is None:
                raise SceneFileError(f"{where}: a surface part needs a material")
            if part.material not in materials:
                materials[part.material] = resolve_material(part.material, inline, path.parent, where)
        _resolve_back_material(part, materials, inline, path.parent, where)
        if check_watertight and part.role != "detector" and part.meta.get("kind") != "sheet" \
                and not _watertight(part):
            notes.append(f"{where}: mesh is not watertight (light may enter the solid through gaps)")
    from straylight.engine.runtime import runtime

    runtime()  # started: the sources' probe below is the first compiled code (numba without scipy.linalg)
    entries = doc.get("source", []) if sources else []
    if sources and (not isinstance(entries, list) or not entries):
        raise SceneFileError(f"{path}: no [[source]] entries")
    resolved = []
    lo, hi = scene.bounds_mm
    for i, entry in enumerate(entries, start=1):
        where = f"{path}: [[source]] {i}"
        try:
            entry, pol = split_polarization(entry, where)
            src = attach(source_from_dict(entry, where=where), pol)
            check_polarization_for_source(pol, src, where)
        except (SourceError, PolarizationError) as exc:
            raise SceneFileError(str(exc)) from None
        if not _probe_reaches_box(src, lo, hi):
            notes.append(f"{where}: no ray of this source reaches the scene's bounding box")
        resolved.append(src)
    for note in notes:
        warnings.warn(note, SceneWarning, stacklevel=2)
    return ResolvedScene(path, scene, materials, tuple(resolved), tuple(notes))
