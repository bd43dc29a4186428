"""Reading and writing parts and scenes.

- STEP export per CadQuery part (``cadquery.exporters``); STL / PLY / OBJ export per
  tessellated part (trimesh; PLY is written with float64 vertices, so it is lossless).
- :func:`load_part` reads STL, OBJ, PLY (trimesh, ``process=False``: face order is kept;
  exactly coincident vertices, as in STL triangle soup, are merged; a triangle-only binary PLY
  through plyfile, the same numbers without importing trimesh) and STEP / IGES from any
  CAD tool (:mod:`geometry.cad`: names and units kept; tessellated at ``tolerance_mm`` and
  cached, :mod:`geometry.cad_cache`); :func:`load_cad_parts` gives one part per solid
  (``split = "solids"``, CONTRACTS §6.2).
- :func:`save_scene` writes one mesh file per part and a scene TOML (CONTRACTS §6) whose
  ``[[part]]`` entries point at them; :func:`load_scene` reads the parts back.

Every error names the file.
"""
from __future__ import annotations

import re
import tempfile
import tomllib
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import plyfile

import atomicio

from geometry.mesh import ROLES, GeometryError, Part, Scene
from geometry.tessellate import DEFAULT_ANGULAR_TOLERANCE_DEG, DEFAULT_TOLERANCE_MM, tessellate

MESH_SUFFIXES = (".stl", ".obj", ".ply")
STEP_SUFFIXES = (".step", ".stp")
CAD_SUFFIXES = STEP_SUFFIXES + (".iges", ".igs")
PART_KEYS = ("name", "mesh", "tolerance_mm", "material", "role", "surface", "back_material", "split", "solids",
             "rotate_deg", "translate_mm", "temperature_k",
             "diffraction")  # diffraction: read by straylight.scene (CONTRACTS §6.5)
SPLIT_MODES = ("none", "solids")
SOLID_KEYS = ("material", "role", "temperature_k")

# files already read while one scene file loads: {(resolved path, what, tolerances): result}. A file used
# by many parts (15 baffles from one STEP, CONTRACTS §6.4) is read and meshed once per tolerance.
_READ_ONCE: ContextVar[dict | None] = ContextVar("geometry_io_read_once", default=None)


@contextmanager
def read_each_file_once():
    """Within the block, each mesh or CAD file (per tolerance) is read and meshed once."""
    token = _READ_ONCE.set({}) if _READ_ONCE.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            _READ_ONCE.reset(token)


def _once(key, read):
    """``read()``, or what it returned for ``key`` earlier in the same :func:`read_each_file_once` block."""
    memo = _READ_ONCE.get()
    if memo is None:
        return read()
    if key not in memo:
        memo[key] = read()
    return memo[key]


def _write_through_scratch(path: Path, write) -> Path:
    """``write(scratch)`` (a library writer that wants a file name: CadQuery's STEP exporter) into a
    scratch folder beside ``path``, then its bytes to ``path`` atomically (:mod:`atomicio`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".export-") as scratch:
        tmp = Path(scratch) / path.name
        write(tmp)
        return atomicio.write_bytes(path, tmp.read_bytes())


def export_step(shape, path) -> Path:
    """Write a CadQuery shape (or a :class:`geometry.parts.ShapePart`) to a STEP file, atomically."""
    import cadquery as cq

    shape = getattr(shape, "shape", shape)
    return _write_through_scratch(Path(path), lambda tmp: cq.exporters.export(shape, str(tmp), exportType="STEP"))


def export_assembly_step(shape_parts: dict, path) -> Path:
    """Write all CadQuery parts into one STEP file as a named assembly (for CAD tools), atomically."""
    import cadquery as cq

    path = Path(path)
    assembly = cq.Assembly(name=path.stem)
    for name, part in shape_parts.items():
        assembly.add(getattr(part, "shape", part), name=name)
    return _write_through_scratch(path, lambda tmp: assembly.export(str(tmp), exportType="STEP"))


def _write_ply64(part: Part, path: Path):
    """Binary little-endian PLY with float64 vertices and int32 triangles (read back exactly by trimesh)."""
    header = ("ply\nformat binary_little_endian 1.0\ncomment straylight geometry part {name}\n"
              "element vertex {nv}\nproperty double x\nproperty double y\nproperty double z\n"
              "element face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
              ).format(name=part.name, nv=len(part.vertices_mm), nf=part.n_triangles)
    faces = np.empty(part.n_triangles, dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"] = 3
    faces["v"] = part.faces
    with atomicio.atomic_open(path, "wb") as out:
        out.write(header.encode("ascii"))
        out.write(np.ascontiguousarray(part.vertices_mm, dtype="<f8").tobytes())
        out.write(faces.tobytes())


def export_mesh(part: Part, path) -> Path:
    """Write a part's triangles to STL (binary, float32), PLY (float64, lossless) or OBJ, atomically."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        _write_ply64(part, path)
    elif suffix in (".stl", ".obj"):
        data = part.to_trimesh().export(file_type=suffix[1:])  # bytes (STL) or text (OBJ), as trimesh writes them
        atomicio.write_bytes(path, data if isinstance(data, bytes) else data.encode("utf-8"))
    else:
        raise GeometryError(f"{path}: unsupported mesh format {suffix!r}; use one of .stl, .ply, .obj")
    return path


def _merge_exact(vertices, faces):
    """Merge exactly equal vertices (STL stores each triangle's corners separately); face order kept."""
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    _, first = np.unique(inverse, return_index=True)
    order = np.argsort(first)  # number vertices in order of first use: deterministic, close to the file
    renumber = np.empty_like(order)
    renumber[order] = np.arange(len(order))
    return unique[order], renumber[inverse.reshape(-1)][faces]


def check_mesh_file(path, what: str) -> None:
    """A mesh or CAD file must be a regular file (not ``/dev/zero``, a FIFO, a folder) no larger than
    a quarter of this machine's memory (its triangles take several times the file's size once read):
    else a GeometryError naming it (atomicio.inputs)."""
    from atomicio.inputs import InputFileError, check_input_file, physical_memory_bytes

    memory = physical_memory_bytes()
    try:
        check_input_file(path, what, max_bytes=memory // 4 if memory else None)
    except FileNotFoundError:
        raise GeometryError(f"{path}: {what} not found") from None
    except InputFileError as exc:
        raise GeometryError(str(exc)) from None


def load_part(path, *, name: str | None = None, material: str | None = None, role: str = "surface",
              tolerance_mm: float = DEFAULT_TOLERANCE_MM,
              angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG) -> Part:
    """Read one part from an STL, OBJ, PLY or STEP file (mm).

    Parameters
    ----------
    path : file; STEP files are tessellated with chord tolerance ``tolerance_mm``
    name : part name (default: the file's stem)
    material, role : tags (role one of ``geometry.mesh.ROLES``)
    """
    path = Path(path)
    name = path.stem if name is None else str(name)
    if role not in ROLES:
        raise GeometryError(f"{path}: part {name!r}: unknown role {role!r}; expected one of {', '.join(ROLES)}")
    check_mesh_file(path, f"mesh file (part {name!r})")
    suffix = path.suffix.lower()
    if suffix in CAD_SUFFIXES:
        (_, _, _, part), = tessellate_cad(path, tolerance_mm=tolerance_mm,
                                          angular_tolerance_deg=angular_tolerance_deg, split=False)
        return Part(name, part.vertices_mm, part.faces, material, role, dict(part.meta))
    if suffix not in MESH_SUFFIXES:
        raise GeometryError(f"{path}: unsupported mesh format {suffix!r}; expected one of "
                            f"{', '.join(MESH_SUFFIXES + CAD_SUFFIXES)}")
    vertices, faces = _once((str(path.resolve()), "mesh"), lambda: _read_mesh(path, suffix))
    try:
        return Part(name, vertices, faces, material, role, {"source": str(path)})
    except GeometryError as exc:
        raise GeometryError(f"{path}: {exc}") from exc


def _read_mesh(path: Path, suffix: str):
    """(vertices (v, 3) float64, faces (m, 3) int64) of an STL/OBJ/PLY file, exact duplicates merged."""
    triangles = _read_triangle_ply(path) if suffix == ".ply" else None
    if triangles is not None:
        return _merge_exact(*triangles)
    import trimesh

    try:
        kwargs: dict[str, Any] = {"maintain_order": True} if suffix == ".obj" else {}
        mesh: Any = trimesh.load(str(path), file_type=suffix[1:], force="mesh", process=False, **kwargs)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # noqa: BLE001 - parsers raise many types; name the file
        raise GeometryError(f"{path}: cannot read mesh: {exc}") from exc
    if faces.ndim != 2 or len(faces) == 0:
        raise GeometryError(f"{path}: the file holds no triangles")
    return _merge_exact(vertices, faces)


def _read_triangle_ply(path: Path):
    """(vertices, faces) of a PLY file holding only vertices (x, y, z) and triangles (``vertex_indices``),
    as :func:`save_scene` writes them, read by plyfile without trimesh (whose import costs ~2 s of every
    command's start-up); None for any other PLY (ASCII, polygons, more elements or properties: trimesh
    reads those). The same numbers as trimesh's reader: the file's doubles and indices as stored."""
    try:
        ply = plyfile.PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
    except Exception:  # noqa: BLE001 - not a fixed-size triangle PLY (or not readable): trimesh decides
        return None
    names = [e.name for e in ply.elements]
    if ply.text or names != ["vertex", "face"] or [p.name for p in ply["face"].properties] != ["vertex_indices"]:
        return None
    vertex = ply["vertex"].data
    if not {"x", "y", "z"} <= set(vertex.dtype.names or ()):
        return None
    vertices = np.stack([np.asarray(vertex[k], dtype=np.float64) for k in ("x", "y", "z")], axis=1)
    faces = np.asarray(ply["face"].data["vertex_indices"], dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0 or (faces.size and (faces.min() < 0 or faces.max() >= len(vertices))):
        return None
    return vertices, faces


class _Instances:
    """Tessellate each distinct solid once: an assembly that places one product many times (36 identical
    vanes) shares one B-rep (``IsPartner``); each placement is the shared mesh moved rigidly (a rigid
    motion keeps every chord error)."""

    def __init__(self):
        self.done = []  # [(un-located shape, Part)]

    def tessellate(self, shape, *, name, kind, **tolerances) -> Part:
        from OCP.TopLoc import TopLoc_Location

        trsf = shape.Location().Transformation()
        if abs(trsf.ScaleFactor() - 1.0) > 1e-12:  # not rigid: tessellate this placement itself
            return tessellate(shape, name=name, kind=kind, **tolerances)
        base = shape.Located(TopLoc_Location())
        for other, mesh in self.done:
            if base.IsPartner(other) and base.Orientation() == other.Orientation():
                break
        else:
            mesh = tessellate(base, name=name, kind=kind, **tolerances)
            self.done.append((base, mesh))
        rot = np.array([[trsf.Value(i, j) for j in (1, 2, 3)] for i in (1, 2, 3)])
        shift = np.array([trsf.Value(i, 4) for i in (1, 2, 3)])
        meta = dict(mesh.meta, tessellation=replace(mesh.meta["tessellation"], name=name))
        return Part(name, mesh.vertices_mm @ rot.T + shift, mesh.faces, None, "surface", meta)


def tessellate_cad(path, *, tolerance_mm: float = DEFAULT_TOLERANCE_MM,
                   angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG, split: bool = True):
    """Tessellate a STEP/IGES file: [(solid name, kind, label in the file, Part)] (one entry for the whole
    file when ``split`` is False). Parts carry no material and role "surface"; results are cached on disk
    (:mod:`geometry.cad_cache`) by file content, tolerances and code version."""
    path = Path(path)
    check_mesh_file(path, "CAD file")
    mode = "solids" if split else "whole"
    return _once((str(path.resolve()), mode, float(tolerance_mm), float(angular_tolerance_deg)),
                 lambda: _tessellate_cad(path, tolerance_mm, angular_tolerance_deg, split, mode))


def _tessellate_cad(path: Path, tolerance_mm: float, angular_tolerance_deg: float, split: bool, mode: str):
    from geometry import cad_cache

    entry = cad_cache.entry_path(path, tolerance_mm=tolerance_mm, angular_tolerance_deg=angular_tolerance_deg,
                                 mode=mode) if cad_cache.enabled() else None
    cached = cad_cache.load(entry) if entry is not None else None
    fresh = cached is None
    if cached is None:
        from geometry import cad_child

        if cad_child.isolated():  # a crash in OpenCascade ends a child process, not this one
            cached = cad_child.tessellate_isolated(tessellate_cad_here, path, entry, tolerance_mm=tolerance_mm,
                                                   angular_tolerance_deg=angular_tolerance_deg, split=split)
        else:
            cached = tessellate_cad_here(path, tolerance_mm=tolerance_mm,
                                         angular_tolerance_deg=angular_tolerance_deg, split=split)
            if entry is not None:
                cad_cache.store(entry, cached)
    from geometry.tessellate import warn_reports

    warn_reports(path, cached, fresh=fresh)
    return cached


def tessellate_cad_here(path: Path, *, tolerance_mm: float, angular_tolerance_deg: float, split: bool):
    """:func:`tessellate_cad` in this process, without the cache (what the child of :mod:`geometry.cad_child` runs)."""
    from geometry.cad import read_cad

    solids = read_cad(path)
    from geometry.limits import ToleranceError, check_mesh_budget

    try:  # before meshing (native code that cannot be stopped): a tolerance that would mesh without bound
        check_mesh_budget([s.shape for s in solids], tolerance_mm, f"{path}")
    except ToleranceError as exc:
        raise GeometryError(str(exc)) from None
    if split:
        items = [(s.name, s.kind, s.label, s.shape) for s in solids]
        aliases = {s.name: list(s.aliases) for s in solids}
    else:
        from geometry.cad import compound_of

        kinds = {s.kind for s in solids}
        items = [(path.stem, "solid" if "solid" in kinds else "sheet", None, compound_of(s.shape for s in solids))]
        aliases = {}
    out = []
    from tqdm.auto import tqdm

    instances = _Instances()
    for k, (name, kind, label, shape) in enumerate(tqdm(items, desc=f"tessellating {path.name}", unit="solid",
                                                        leave=False, disable=None if len(items) > 20 else True), 1):
        try:
            part = instances.tessellate(shape, name=name, tolerance_mm=tolerance_mm,
                                        angular_tolerance_deg=angular_tolerance_deg, kind=kind, warn=False,
                                        context=f"tessellating {path.name}: solid {name!r} ({k} of {len(items)})")
        except GeometryError as exc:
            raise GeometryError(f"{path}: solid {name!r}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - OCC raises bare Standard_Failure; name the file and solid
            raise GeometryError(f"{path}: solid {name!r} cannot be tessellated: {exc}") from None
        part.meta["source"] = str(path)
        part.meta["aliases"] = aliases.get(name, [])  # other names the file gives the solid (its product's)
        part.meta["watertight"] = part.is_watertight  # checked once, kept in the cache entry
        out.append((name, kind, label, part))
    return out


def load_cad_parts(path, *, name: str | None = None, material: str | None = None, role: str = "surface",
                   tolerance_mm: float = DEFAULT_TOLERANCE_MM,
                   angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG,
                   solids: dict | None = None) -> list[Part]:
    """One part per solid of a STEP/IGES assembly, named ``<name>/<solid name>`` (CONTRACTS §6.2).

    solids : {solid name: {"material": ..., "role": ...}} overrides for single solids; an unknown
        solid name is an error that lists the file's solid names.
    """
    path = Path(path)
    name = path.stem if name is None else str(name)
    if role not in ROLES:
        raise GeometryError(f"{path}: part {name!r}: unknown role {role!r}; expected one of {', '.join(ROLES)}")
    items = tessellate_cad(path, tolerance_mm=tolerance_mm, angular_tolerance_deg=angular_tolerance_deg, split=True)
    overrides = dict(solids or {})
    tags_of = _solid_overrides(path, items, overrides)
    parts = []
    for solid, kind, label, part in items:
        tags = tags_of.get(solid, {})
        if not isinstance(tags, dict) or set(tags) - set(SOLID_KEYS):
            bad = sorted(set(tags) - set(SOLID_KEYS)) if isinstance(tags, dict) else tags
            raise GeometryError(f"{path}: solid {solid!r}: overrides must be a table of {', '.join(SOLID_KEYS)}, "
                                f"got {bad!r}")
        solid_role = tags.get("role", role)
        if solid_role not in ROLES:
            raise GeometryError(f"{path}: solid {solid!r}: unknown role {solid_role!r}; expected one of "
                                f"{', '.join(ROLES)}")
        meta = dict(part.meta, solid=solid, label=label,
                    part_aliases=[f"{name}/{a}" for a in part.meta.get("aliases", [])])
        if "temperature_k" in tags:
            meta["temperature_k"] = check_temperature(tags["temperature_k"], f"{path}: solid {solid!r}")
        parts.append(Part(f"{name}/{solid}", part.vertices_mm, part.faces, tags.get("material", material),
                          solid_role, meta))
    return parts


def _solid_overrides(path: Path, items, overrides: dict) -> dict:
    """{solid name: override table}. A key names every solid that answers to it (CONTRACTS 6.2): its own
    name, an alias (the instance name, ``lens:1``) or its product's name before the ``_2`` of a repeat
    (``BOLT`` sets ``BOLT``, ``BOLT_2``...); a solid's own name wins over the other keys."""
    names = [solid for solid, _, _, _ in items]
    aliases = {solid: list(part.meta.get("aliases", [])) for solid, _, _, part in items}
    labels = {solid: label for solid, _, label, _ in items}
    out, unknown, exact = {}, [], set()
    for key in overrides:
        if key in names:
            out[key] = overrides[key]
            exact.add(key)
    for key in overrides:
        matched = [solid for solid in names if key == solid or key in aliases[solid] or key == labels[solid]]
        if not matched:
            unknown.append(key)
        for solid in matched:
            if solid not in exact:
                out.setdefault(solid, overrides[key])
    if unknown:
        listed = ", ".join(f"{n} ({', '.join(aliases[n])})" if aliases[n] else n for n in names)
        raise GeometryError(f"{path}: no solid named {', '.join(map(repr, sorted(unknown)))} in the file; its "
                            f"solids (other names in brackets): {listed}")
    return out


def save_scene(scene: Scene, directory, *, mesh_format: str = "ply", scene_file: str = "scene.toml",
               materials: dict | None = None, sources=None) -> Path:
    """Write every part as ``<name>.<mesh_format>`` and a scene TOML (CONTRACTS §6) listing them.

    materials : optional {key: material dict} written as ``[material.<key>]`` tables
    sources : optional list of source dicts written as ``[[source]]`` entries
    Returns the path of the scene TOML. PLY (default) keeps float64 vertices: no loss.
    """
    import tomli_w

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    mesh_format = mesh_format.lower().lstrip(".")
    if f".{mesh_format}" not in MESH_SUFFIXES:
        raise GeometryError(f"mesh_format must be one of stl, ply, obj, got {mesh_format!r}")
    doc: dict = {}
    if materials:
        doc["material"] = dict(materials)
    entries = []
    for part in scene.parts:
        if not re.fullmatch(r"[A-Za-z0-9_.\-]+", part.name) or part.name.startswith("."):
            raise GeometryError(f"part {part.name!r}: name cannot be used as a file name (letters, digits, _ . - only)")
        mesh_name = f"{part.name}.{mesh_format}"
        export_mesh(part, directory / mesh_name)
        entry = {"name": part.name, "mesh": mesh_name}
        report = part.meta.get("tessellation")
        if report is not None:
            entry["tolerance_mm"] = report.tolerance_mm
        if part.material is not None:
            entry["material"] = part.material
        entry["role"] = part.role
        entries.append(entry)
    doc["part"] = entries
    if sources:
        doc["source"] = [dict(s) for s in sources]
    path = directory / scene_file
    atomicio.write_text(path, tomli_w.dumps(doc))
    return path


def read_scene_toml(path) -> dict:
    """Parse a scene TOML; errors name the file (and TOML line/column)."""
    from atomicio.inputs import InputFileError, read_input_text

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in CAD_SUFFIXES + MESH_SUFFIXES:
        kind = "STEP" if suffix in STEP_SUFFIXES else "IGES" if suffix in CAD_SUFFIXES else suffix[1:].upper()
        raise GeometryError(f"{path}: a {kind} file, not a scene TOML: `straylight geometry check` and `view` take it "
                            f"as it is; the analyses need a scene file: straylight geometry scene {path} -o scene.toml")
    try:
        return tomllib.loads(read_input_text(path, "scene file"))
    except FileNotFoundError:
        raise GeometryError(f"{path}: scene file not found") from None
    except UnicodeDecodeError as exc:
        raise GeometryError(f"{path}: not a scene TOML file (reading it as TOML: not UTF-8 text: {exc})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise GeometryError(f"{path}: not a valid scene TOML file (reading it as TOML: {exc})") from exc
    except InputFileError as exc:
        raise GeometryError(str(exc)) from exc


def load_scene_or_file(path, *, tolerance_mm: float = DEFAULT_TOLERANCE_MM) -> Scene:
    """A scene TOML's parts (:func:`load_scene`), or a STEP/IGES/STL/OBJ/PLY file as a one-file scene: a CAD
    file one part per solid, named ``<file stem>/<solid name>`` (CONTRACTS 6.2), a mesh file one part."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in CAD_SUFFIXES:
        return Scene(tuple(load_cad_parts(path, name=path.stem, tolerance_mm=tolerance_mm)))
    if suffix in MESH_SUFFIXES:
        return Scene((load_part(path, name=path.stem),))
    return load_scene(path)


def load_scene(path) -> Scene:
    """The parts of a scene TOML (CONTRACTS §6), meshes resolved relative to the file.

    Materials and sources are not interpreted here (geometry knows materials by name only);
    a part's ``material`` string is kept as written.
    """
    path = Path(path)
    doc = read_scene_toml(path)
    entries = doc.get("part", [])
    if not isinstance(entries, list) or not entries:
        raise GeometryError(f"{path}: no [[part]] entries")
    with read_each_file_once():
        parts = _load_entries(entries, path)
    try:
        return Scene(tuple(parts))
    except GeometryError as exc:
        raise GeometryError(f"{path}: {exc}") from exc


def _load_entries(entries: list, path: Path) -> list[Part]:
    """The parts of the ``[[part]]`` entries, each placed by its ``rotate_deg`` / ``translate_mm``."""
    from geometry.placement import placement_of

    parts: list[Part] = []
    starts = []  # (first part of the entry, entry): temperatures are set after the loop
    for i, entry in enumerate(entries, start=1):
        where = f"{path}: [[part]] {i}"
        starts.append((len(parts), entry, where))
        unknown = set(entry) - set(PART_KEYS)
        if unknown:
            raise GeometryError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; "
                                f"expected {', '.join(PART_KEYS)}")
        keys = ("name", "mesh") if "surface" not in entry or "mesh" in entry else ("name",)
        for key in keys:
            if not isinstance(entry.get(key), str):
                raise GeometryError(f"{where}: missing or non-string {key!r}")
        tolerance_mm = entry.get("tolerance_mm", DEFAULT_TOLERANCE_MM)
        if not isinstance(tolerance_mm, (int, float)) or isinstance(tolerance_mm, bool):
            raise GeometryError(f"{where}: tolerance_mm must be a number")
        from geometry.limits import ToleranceError, check_tolerance_mm

        try:
            check_tolerance_mm(tolerance_mm, f"{where}: tolerance_mm")
        except ToleranceError as exc:
            raise GeometryError(str(exc)) from None
        placement = placement_of(entry, where)
        if "surface" in entry:
            parts.append(_analytic_entry(entry, path, where, float(tolerance_mm), placement))
            continue
        if "back_material" in entry:
            raise GeometryError(f"{where}: 'back_material' needs an analytic 'surface' (docs/reference/scene.md)")
        if "split" in entry or "solids" in entry:
            placed = _split_entry(entry, path, where, float(tolerance_mm))
        else:
            try:
                placed = [load_part(path.parent / entry["mesh"], name=entry["name"], material=entry.get("material"),
                                    role=entry.get("role", "surface"), tolerance_mm=float(tolerance_mm))]
            except GeometryError as exc:  # name the scene file and entry, not only the mesh file
                raise GeometryError(f"{where}: {exc}") from exc
        parts.extend(placed if placement is None else [placement.part(p) for p in placed])
    _set_temperatures(parts, starts)
    return parts


def check_temperature(value, where: str) -> float:
    """A ``temperature_k`` value (CONTRACTS §7): a finite number >= 0, else a one-line error."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 <= value < float("inf")):
        raise GeometryError(f"{where}: temperature_k must be a number >= 0 (kelvin), got {value!r}")
    from geometry.limits import temperature_limit_message

    message = temperature_limit_message(float(value))
    if message:
        raise GeometryError(f"{where}: {message}")
    return float(value)


def _set_temperatures(parts: list, starts: list) -> None:
    """Each entry's ``temperature_k`` into its parts' ``meta`` (a solid override set earlier wins)."""
    ends = [s for s, _, _ in starts[1:]] + [len(parts)]
    for (first, entry, where), stop in zip(starts, ends):
        if "temperature_k" in entry:
            t = check_temperature(entry["temperature_k"], where)
            for k in range(first, stop):
                if "temperature_k" not in parts[k].meta:  # a new meta dict: meshes may be shared (cached)
                    parts[k] = replace(parts[k], meta=dict(parts[k].meta, temperature_k=t))


def _split_entry(entry: dict, path: Path, where: str, tolerance_mm: float) -> list[Part]:
    """A CAD part with ``split = "solids"`` (and optional ``[part.solids."name"]`` overrides), CONTRACTS §6.2."""
    split = entry.get("split", "none")
    if split not in SPLIT_MODES:
        raise GeometryError(f"{where}: split must be one of {', '.join(map(repr, SPLIT_MODES))}, got {split!r}")
    mesh = path.parent / entry["mesh"]
    if mesh.suffix.lower() not in CAD_SUFFIXES:
        raise GeometryError(f"{where}: split/solids need a STEP or IGES file, got {entry['mesh']!r}")
    solids = entry.get("solids", {})
    if not isinstance(solids, dict):
        raise GeometryError(f"{where}: 'solids' must be tables [part.solids.\"NAME\"]")
    if split == "none":
        if solids:
            raise GeometryError(f"{where}: per-solid overrides ('solids') need split = \"solids\"")
        return [load_part(mesh, name=entry["name"], material=entry.get("material"),
                          role=entry.get("role", "surface"), tolerance_mm=tolerance_mm)]
    try:
        return load_cad_parts(mesh, name=entry["name"], material=entry.get("material"),
                              role=entry.get("role", "surface"), tolerance_mm=tolerance_mm, solids=solids)
    except GeometryError as exc:
        raise GeometryError(f"{where}: {exc}") from exc


def _analytic_entry(entry: dict, path: Path, where: str, tolerance_mm: float, placement=None) -> Part:
    """A part with ``surface = {...}`` (CONTRACTS §6.1): meshed by the project, or its own ``mesh``
    (CAD geometry with its optical prescription) used for the hit search. A placement (§6.4) moves the
    surface (and its own mesh) before the project meshes it."""
    from geometry.analytic import analytic_part, surface_from_dict

    surface = surface_from_dict(entry["surface"], where)
    if placement is not None:
        surface = placement.surface(surface)
    back = entry.get("back_material")
    if back is not None and not isinstance(back, str):
        raise GeometryError(f"{where}: 'back_material' must be a material name (string)")
    mesh = None
    try:
        if "mesh" in entry:
            cad = load_part(path.parent / entry["mesh"], name=entry["name"], tolerance_mm=tolerance_mm)
            mesh = (cad.vertices_mm if placement is None else placement.points(cad.vertices_mm), cad.faces)
        return analytic_part(entry["name"], surface, entry.get("material"), entry.get("role", "surface"), back,
                             tolerance_mm=tolerance_mm, mesh=mesh)
    except GeometryError as exc:
        raise GeometryError(f"{where}: {exc}") from exc


def export_build(shape_parts: dict, scene: Scene, directory, *, mesh_format: str = "stl", step: bool = True,
                 scene_file: str = "scene.toml") -> Path:
    """Write ``<name>.step`` per CadQuery part and ``assembly.step`` (all parts, named), if ``step``;
    ``<name>.<mesh_format>`` for every part of ``scene``; and the scene TOML pointing at the meshes.
    Returns the TOML path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    if step:
        for name, shape_part in shape_parts.items():
            export_step(shape_part, directory / f"{name}.step")
        export_assembly_step(shape_parts, directory / "assembly.step")
    return save_scene(scene, directory, mesh_format=mesh_format, scene_file=scene_file)
