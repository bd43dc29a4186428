"""Mesh checks with trimesh and manifold3d, and mesh booleans with manifold3d.

A solid part must be watertight (every edge shared by exactly two triangles), consistently
wound, enclose a positive volume (outward normals) and be a valid manifold for manifold3d.
An open sheet (a detector, ``meta["kind"] == "sheet"``) must be consistently wound with no
edge shared by more than two triangles; it is not expected to be closed. Solid parts should
not interpenetrate: their pairwise intersection volumes are measured with manifold3d.

A part that fails gives a :class:`GeometryWarning` (or, with ``strict=True``, a
:class:`GeometryError`) whose message names the part.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from geometry.mesh import GeometryError, Part, Scene


class GeometryWarning(UserWarning):
    """A mesh check failed; the message names the part."""


@dataclass(frozen=True)
class PartCheck:
    """Result of :func:`check_part`. Volumes in mm^3 (signed: negative means inward normals)."""

    name: str
    kind: str
    n_triangles: int
    watertight: bool
    winding_consistent: bool
    n_open_edges: int
    n_nonmanifold_edges: int
    n_degenerate: int
    volume_mm3: float
    manifold_status: str
    problems: tuple[str, ...] = ()
    role: str = "surface"
    material: str | None = None
    also: tuple[str, ...] = ()  # other names the CAD file gives the solid (its product's, CONTRACTS 6.2)

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "n_triangles": self.n_triangles, "watertight": self.watertight,
                "winding_consistent": self.winding_consistent, "n_open_edges": self.n_open_edges,
                "n_nonmanifold_edges": self.n_nonmanifold_edges, "n_degenerate": self.n_degenerate,
                "volume_mm3": self.volume_mm3, "manifold_status": self.manifold_status,
                "problems": list(self.problems), "ok": self.ok, "role": self.role, "material": self.material,
                "also": list(self.also)}


@dataclass(frozen=True)
class Overlap:
    """Two solids that interpenetrate (CONTRACTS 6.2): the intersection's volume, its depth (how far a surface
    of one lies inside the other) and the chord tolerance it is compared with. ``changes_trace``: a detector or
    a transparent (``dielectric``) part is involved, or the depth is beyond the tolerance; otherwise it is an
    interference among opaque parts that no ray can tell from touching faces (``why`` says which)."""

    a: str
    b: str
    volume_mm3: float
    depth_mm: float
    tolerance_mm: float
    changes_trace: bool
    why: str

    def as_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "volume_mm3": self.volume_mm3, "depth_mm": self.depth_mm,
                "tolerance_mm": self.tolerance_mm, "changes_trace": self.changes_trace, "why": self.why}

    def line(self) -> str:
        return (f"overlap {self.a} / {self.b}: {self.volume_mm3:.3g} mm^3, depth {self.depth_mm:.3g} mm "
                f"({self.why})")


@dataclass(frozen=True)
class SceneCheck:
    """Result of :func:`check_scene`: one :class:`PartCheck` per part and the overlapping solid pairs."""

    parts: tuple[PartCheck, ...]
    overlaps: tuple[Overlap, ...] = ()
    overlap_tolerance_mm3: float = 0.0
    problems: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def trace_changing_overlaps(self) -> tuple[Overlap, ...]:
        return tuple(o for o in self.overlaps if o.changes_trace)

    def as_dict(self) -> dict:
        return {"ok": self.ok, "parts": [p.as_dict() for p in self.parts],
                "overlaps": [o.as_dict() for o in self.overlaps],
                "overlap_tolerance_mm3": self.overlap_tolerance_mm3, "problems": list(self.problems)}

    def format(self) -> str:
        """A plain-text table, one line per part, then the problems."""
        w = max([16] + [len(p.name) for p in self.parts])
        lines = [f"{'part':<{w}} {'role':<8} {'kind':<6} {'triangles':>9} {'watertight':>10} {'winding':>8} "
                 f"{'volume_mm3':>12} {'manifold':<8} material"]
        for p in self.parts:
            lines.append(f"{p.name:<{w}} {p.role:<8} {p.kind:<6} {p.n_triangles:>9d} {str(p.watertight):>10} "
                         f"{str(p.winding_consistent):>8} {p.volume_mm3:>12.6g} {p.manifold_status:<8} "
                         f"{p.material or '-'}" + (f"  (also: {', '.join(p.also)})" if p.also else ""))
        lines.append(f"{'total':<{w}} {'':<8} {'':<6} {sum(p.n_triangles for p in self.parts):>9d} "
                     f"({len(self.parts)} parts)")
        lines.extend(o.line() for o in self.overlaps)
        lines.extend(f"PROBLEM: {message}" for message in self.problems)
        lines.append("checks: ok" if self.ok else f"checks: {len(self.problems)} problem(s)")
        return "\n".join(lines)


def part_kind(part: Part) -> str:
    """"solid" or "sheet": from ``meta["kind"]`` if the part has one, else "sheet" only for open detectors."""
    kind = part.meta.get("kind")
    if kind in ("solid", "sheet"):
        return kind
    if part.role == "detector" and _edge_counts(part.faces)[1] > 0:
        return "sheet"
    return "solid"


def _edge_counts(faces):
    """(counts of each undirected edge, number of open edges, number of non-manifold edges)."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return counts, int((counts == 1).sum()), int((counts > 2).sum())


def to_manifold(part: Part):
    """manifold3d.Manifold of a part (float64 vertices)."""
    import manifold3d

    mesh = manifold3d.Mesh64(vert_properties=np.array(part.vertices_mm, dtype=np.float64, order="C"),
                             tri_verts=np.array(part.faces, dtype=np.uint64, order="C"))
    return manifold3d.Manifold(mesh)


def from_manifold(manifold, *, name: str, material: str | None = None, role: str = "surface") -> Part:
    """Part from a manifold3d.Manifold."""
    mesh = manifold.to_mesh64()
    vertices = np.ascontiguousarray(np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3])
    return Part(name, vertices, np.asarray(mesh.tri_verts, dtype=np.int64), material, role, {"kind": "solid"})


def check_part(part: Part) -> PartCheck:
    """Check one part with trimesh (``process=False``) and, for solids, manifold3d."""
    mesh = part.to_trimesh()
    kind = part_kind(part)
    _, n_open, n_nonmanifold = _edge_counts(part.faces)
    area = np.linalg.norm(np.cross(*(part.vertices_mm[part.faces[:, 1:]] - part.vertices_mm[part.faces[:, :1]])
                                   .transpose(1, 0, 2)), axis=1) / 2
    scale = max(float(np.ptp(part.vertices_mm, axis=0).max()), 1e-300)
    n_degenerate = int((area <= 1e-12 * scale**2).sum())
    winding = bool(mesh.is_winding_consistent)
    watertight = bool(mesh.is_watertight)
    problems = []
    if not winding:
        problems.append(f"part {part.name!r}: inconsistent triangle winding")
    if n_nonmanifold:
        problems.append(f"part {part.name!r}: {n_nonmanifold} edge(s) shared by more than two triangles")
    if n_degenerate:
        problems.append(f"part {part.name!r}: {n_degenerate} degenerate (zero-area) triangle(s)")
    if kind == "sheet":
        volume, status = 0.0, "not checked (open sheet)"
    else:
        volume = float(mesh.volume) if watertight else float("nan")
        if not watertight:
            problems.append(f"part {part.name!r} is not watertight: {n_open} open edge(s)")
        elif volume <= 0:
            problems.append(f"part {part.name!r}: normals point inward (volume {volume:.6g} mm^3)")
        status = str(to_manifold(part).status()).split(".")[-1]
        if status != "NoError":
            problems.append(f"part {part.name!r}: manifold3d says {status}")
    return PartCheck(part.name, kind, part.n_triangles, watertight, winding, n_open, n_nonmanifold, n_degenerate,
                     volume, status, tuple(problems), part.role, part.material,
                     tuple(str(a) for a in part.meta.get("aliases", ())))


def overlap_volumes(scene: Scene, names=None) -> list[tuple[str, str, float]]:
    """Intersection volume (mm^3) of every pair of valid solid parts whose bounding boxes overlap."""
    return [(a, b, v) for a, b, v, _ in _intersections(scene, names)]


def _intersections(scene: Scene, names=None):
    """[(name a, name b, volume mm^3, intersection Manifold)] of the valid solids whose bounding boxes overlap."""
    solids = []
    for part in scene.parts:
        if names is not None and part.name not in names:
            continue
        manifold = to_manifold(part)
        if str(manifold.status()).endswith("NoError") and not manifold.is_empty():
            solids.append((part.name, manifold, part.vertices_mm.min(axis=0), part.vertices_mm.max(axis=0)))
    out = []
    for i, (name_a, a, lo_a, hi_a) in enumerate(solids):
        for name_b, b, lo_b, hi_b in solids[i + 1:]:
            if np.all(lo_a < hi_b) and np.all(lo_b < hi_a):
                inter = a ^ b
                out.append((name_a, name_b, float(inter.volume()), inter))
    return out


def overlap_depth_mm(a: Part, b: Part, intersection) -> float:
    """How deep the two solids interpenetrate: the largest distance from a point of their intersection's surface
    (a manifold3d.Manifold; its vertices, edge midpoints and triangle centroids) to the surface of ``a`` or of
    ``b`` (each point lies on one of the two surfaces; its distance to the other is how far that surface runs
    inside the other solid). A thin press-fit ring
    gives its radial interference, two tessellations of one cylinder their sagitta. Distances by trimesh's
    closest-point query on the triangles near the intersection."""
    import trimesh

    mesh = intersection.to_mesh64()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    if len(vertices) == 0 or len(faces) == 0:
        return 0.0
    tri = vertices[faces]  # vertices, edge midpoints and centroids: a vertex on an edge of both solids is 0 from both
    points = np.concatenate([vertices, tri.mean(axis=1), (tri + np.roll(tri, 1, axis=1)).reshape(-1, 3) / 2])
    lo, hi = points.min(axis=0), points.max(axis=0)
    reach = float(np.linalg.norm(hi - lo)) + 1e-9
    distances = []
    for part in (a, b):
        tri = part.vertices_mm[part.faces]
        near = np.all((tri.min(axis=1) <= hi + reach) & (tri.max(axis=1) >= lo - reach), axis=1)
        if not near.any():
            return reach
        sub = trimesh.Trimesh(part.vertices_mm, part.faces[near], process=False)
        _, d, _ = trimesh.proximity.closest_point(sub, points)
        distances.append(np.asarray(d, dtype=float))
    depth = np.minimum(np.maximum(distances[0], distances[1]), reach)
    return float(depth.max())


def _chord_tolerance_mm(part: Part, default_mm: float) -> float:
    """The chord tolerance a part's mesh holds: the tolerance asked, or the chord error reached where meshing
    stopped short of it (a stalled B-spline face: touching faces then overlap by up to that error); a mesh
    given as it is (STL...) has ``default_mm``."""
    report = part.meta.get("tessellation")
    asked = getattr(report, "tolerance_mm", None)
    if asked is None:
        return float(default_mm)
    reached = getattr(report, "max_chord_error_mm", None)
    return max(float(asked), float(reached) if reached is not None and reached == reached else 0.0)


def check_scene(scene: Scene, *, overlaps: bool = True, overlap_tolerance_mm3: float | None = None,
                strict: bool = False, transparent=(), chord_tolerance_mm: float | None = None) -> SceneCheck:
    """Check every part; warn (or raise, ``strict=True``) naming each part that fails.

    overlap_tolerance_mm3 : intersection volume above which two solids count as overlapping.
        Default: 1e-3 mm^3, well below the volume of any real interference yet above the
        slivers left where two tessellated cylinders of the same radius touch.
    transparent : names of the parts whose material transmits (``dielectric``): an overlap with one of them
        changes the trace (the glass's surface runs inside another part).
    chord_tolerance_mm : the depth an overlap of two opaque parts may have and not count as a problem
        (CONTRACTS 6.2): default the larger chord tolerance of the two parts' meshes (a CAD part's
        ``tolerance_mm``, or the chord error its mesh reached where meshing stopped short), else 0.05 mm
        (the default chord tolerance).

    An overlap is a problem only where it would change a trace: a detector or a transparent part is in it,
    or it is deeper than the chord tolerance. Other overlaps (press fits, touching faces of a vendor's CAD)
    are listed with their volume and depth, not counted as problems.
    """
    from geometry.tessellate import DEFAULT_TOLERANCE_MM

    tolerance = 1e-3 if overlap_tolerance_mm3 is None else float(overlap_tolerance_mm3)
    parts = tuple(check_part(p) for p in scene.parts)
    problems = [m for p in parts for m in p.problems]
    found = []
    if overlaps:
        valid = {p.name for p in parts if p.kind == "solid" and p.ok}
        glass = set(transparent)
        for name_a, name_b, volume, inter in _intersections(scene, valid):
            if volume <= tolerance:
                continue
            a, b = scene.part(name_a), scene.part(name_b)
            chord = chord_tolerance_mm if chord_tolerance_mm is not None else \
                max(_chord_tolerance_mm(a, DEFAULT_TOLERANCE_MM), _chord_tolerance_mm(b, DEFAULT_TOLERANCE_MM))
            depth = overlap_depth_mm(a, b, inter)
            detector = [p.name for p in (a, b) if p.role == "detector"]
            clear = [p.name for p in (a, b) if p.name in glass]
            if detector:
                why = f"{detector[0]} is a detector: changes the trace"
            elif clear:
                why = f"{clear[0]} is transparent (dielectric): changes the trace"
            elif depth > chord:
                why = f"deeper than the chord tolerance {chord:g} mm: changes the trace"
            else:
                why = f"opaque parts within the chord tolerance {chord:g} mm: no ray can tell, ignored"
            found.append(Overlap(name_a, name_b, volume, depth, chord, bool(detector or clear or depth > chord), why))
        problems += [f"parts {o.a!r} and {o.b!r} overlap by {o.volume_mm3:.3g} mm^3, depth {o.depth_mm:.3g} mm ({o.why})"
                     for o in found if o.changes_trace]
    result = SceneCheck(parts, tuple(found), tolerance, tuple(problems))
    if problems:
        if strict:
            raise GeometryError(problems[0] + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""))
        for message in problems:
            warnings.warn(message, GeometryWarning, stacklevel=2)
    return result


def union_parts(parts, *, name: str, material: str | None = None, role: str = "surface") -> Part:
    """Boolean union (manifold3d) of solid parts into one watertight part."""
    import manifold3d

    manifolds = [to_manifold(p) for p in parts]
    bad = [p.name for p, m in zip(parts, manifolds) if not str(m.status()).endswith("NoError")]
    if bad:
        raise GeometryError(f"union_parts: not a valid manifold: {', '.join(bad)}")
    fused = manifold3d.Manifold.batch_boolean(manifolds, manifold3d.OpType.Add)
    return from_manifold(fused, name=name, material=material, role=role)
