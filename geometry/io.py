"""Reading and writing parts and scenes.

- STEP export per CadQuery part (``cadquery.exporters``); STL / PLY / OBJ export per
  tessellated part (trimesh; PLY is written with float64 vertices, so it is lossless).
- :func:`load_part` reads STL, OBJ, PLY (trimesh, ``process=False``: face order is kept;
  exactly coincident vertices, as in STL triangle soup, are merged) and STEP (CadQuery
  importer, then :func:`geometry.tessellate.tessellate` at ``tolerance_mm``).
- :func:`save_scene` writes one mesh file per part and a scene TOML (CONTRACTS §6) whose
  ``[[part]]`` entries point at them; :func:`load_scene` reads the parts back.

Every error names the file.
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np

import atomicio

from geometry.mesh import ROLES, GeometryError, Part, Scene
from geometry.tessellate import DEFAULT_ANGULAR_TOLERANCE_DEG, DEFAULT_TOLERANCE_MM, tessellate

MESH_SUFFIXES = (".stl", ".obj", ".ply")
STEP_SUFFIXES = (".step", ".stp")
PART_KEYS = ("name", "mesh", "tolerance_mm", "material", "role", "surface", "back_material")


def export_step(shape, path) -> Path:
    """Write a CadQuery shape (or a :class:`geometry.parts.ShapePart`) to a STEP file."""
    import cadquery as cq

    path = Path(path)
    shape = getattr(shape, "shape", shape)
    cq.exporters.export(shape, str(path), exportType="STEP")
    return path


def export_assembly_step(shape_parts: dict, path) -> Path:
    """Write all CadQuery parts into one STEP file as a named assembly (for CAD tools)."""
    import cadquery as cq

    path = Path(path)
    assembly = cq.Assembly(name=path.stem)
    for name, part in shape_parts.items():
        assembly.add(getattr(part, "shape", part), name=name)
    assembly.export(str(path), exportType="STEP")
    return path


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
    """Write a part's triangles to STL (binary, float32), PLY (float64, lossless) or OBJ."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        _write_ply64(part, path)
    elif suffix in (".stl", ".obj"):
        part.to_trimesh().export(str(path), file_type=suffix[1:])
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
    if not path.is_file():
        raise GeometryError(f"{path}: mesh file not found (part {name!r})")
    suffix = path.suffix.lower()
    if suffix in STEP_SUFFIXES:
        import cadquery as cq

        try:
            shapes = cq.importers.importStep(str(path)).vals()
        except Exception as exc:  # noqa: BLE001 - OCC raises bare exceptions; name the file
            raise GeometryError(f"{path}: cannot read STEP file: {exc}") from exc
        if not shapes:
            raise GeometryError(f"{path}: the STEP file holds no shape")
        shape = shapes[0] if len(shapes) == 1 else cq.Compound.makeCompound(shapes)
        try:
            part = tessellate(shape, name=name, tolerance_mm=tolerance_mm, angular_tolerance_deg=angular_tolerance_deg,
                              material=material, role=role)
        except GeometryError as exc:
            raise GeometryError(f"{path}: {exc}") from exc
        part.meta["source"] = str(path)
        return part
    if suffix not in MESH_SUFFIXES:
        raise GeometryError(f"{path}: unsupported mesh format {suffix!r}; expected one of "
                            f"{', '.join(MESH_SUFFIXES + STEP_SUFFIXES)}")
    import trimesh

    try:
        kwargs = {"maintain_order": True} if suffix == ".obj" else {}
        mesh = trimesh.load(str(path), file_type=suffix[1:], force="mesh", process=False, **kwargs)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # noqa: BLE001 - parsers raise many types; name the file
        raise GeometryError(f"{path}: cannot read mesh: {exc}") from exc
    if faces.ndim != 2 or len(faces) == 0:
        raise GeometryError(f"{path}: the file holds no triangles")
    vertices, faces = _merge_exact(vertices, faces)
    try:
        return Part(name, vertices, faces, material, role, {"source": str(path)})
    except GeometryError as exc:
        raise GeometryError(f"{path}: {exc}") from exc


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
    path = Path(path)
    if not path.is_file():
        raise GeometryError(f"{path}: scene file not found")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GeometryError(f"{path}: {exc}") from exc


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
    parts = []
    for i, entry in enumerate(entries, start=1):
        where = f"{path}: [[part]] {i}"
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
        if "surface" in entry:
            parts.append(_analytic_entry(entry, path, where, float(tolerance_mm)))
            continue
        if "back_material" in entry:
            raise GeometryError(f"{where}: 'back_material' needs an analytic 'surface' (CONTRACTS §6.1)")
        try:
            parts.append(load_part(path.parent / entry["mesh"], name=entry["name"], material=entry.get("material"),
                                   role=entry.get("role", "surface"), tolerance_mm=float(tolerance_mm)))
        except GeometryError as exc:  # name the scene file and entry, not only the mesh file
            raise GeometryError(f"{where}: {exc}") from exc
    try:
        return Scene(tuple(parts))
    except GeometryError as exc:
        raise GeometryError(f"{path}: {exc}") from exc


def _analytic_entry(entry: dict, path: Path, where: str, tolerance_mm: float) -> Part:
    """A part with ``surface = {...}`` (CONTRACTS §6.1): meshed by the project, or its own ``mesh``
    (CAD geometry with its optical prescription) used for the hit search."""
    from geometry.analytic import analytic_part, surface_from_dict

    surface = surface_from_dict(entry["surface"], where)
    back = entry.get("back_material")
    if back is not None and not isinstance(back, str):
        raise GeometryError(f"{where}: 'back_material' must be a material name (string)")
    mesh = None
    try:
        if "mesh" in entry:
            cad = load_part(path.parent / entry["mesh"], name=entry["name"], tolerance_mm=tolerance_mm)
            mesh = (cad.vertices_mm, cad.faces)
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
