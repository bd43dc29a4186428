"""CadQuery shape -> :class:`geometry.mesh.Part` with a stated chord tolerance.

OpenCascade's ``BRepMesh_IncrementalMesh`` meshes every B-rep face with an absolute
linear deflection ``tolerance_mm`` (the largest allowed distance between a triangle and
the true surface, the chord error) and an angular deflection ``angular_tolerance_deg``
(the largest angle between the normals of neighbouring facets). Adjacent faces share the
nodes of their common edge, so after merging coincident nodes a closed solid gives a
closed (watertight) triangle mesh. Triangles of faces whose orientation is REVERSED are
flipped so that every triangle is counter-clockwise seen from outside (outward normals).

The chord error is then *measured* the same way for every surface and curve type (planes,
cylinders, cones, spheres, tori, B-splines, offsets, surfaces of revolution...), from the
B-rep's own parametric geometry:

- faces: for each sampled triangle the true surface (``BRepAdaptor_Surface``) is evaluated at
  the triangle's centroid and edge midpoints in the (u, v) plane of the mesh nodes, and its
  distance from the triangle's plane is taken (where a flat facet is farthest from a curved
  face: the sagitta of its chords);
- edges: each boundary segment's B-rep curve (``BRepAdaptor_Curve``) is evaluated at the
  segment's mid-parameter and its distance from the segment's line is taken, so that the
  polygon of a flat disk (the detector) counts too.

At most ``_MAX_SAMPLED`` triangles (segments) per face are measured: the largest half and an
even stride through the rest. The result is a lower bound on the true maximum (within a few %
of dense analytic checks in the tests, and exact at the sagitta of circles).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.mesh import GeometryError, Part, Scene

DEFAULT_TOLERANCE_MM = 0.05
DEFAULT_ANGULAR_TOLERANCE_DEG = 10.0
_MERGE_MM = 1e-7  # nodes closer than this are the same node (OCC shares edge nodes exactly)
_MAX_REFINE = 5
_MAX_SAMPLED = 256  # triangles (and boundary segments) per face whose chord error is measured
# centroid and edge midpoints (barycentric weights): where a flat facet is farthest from a curved face
_SAMPLE_WEIGHTS = np.array([[1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])


@dataclass(frozen=True)
class TessellationReport:
    """What :func:`tessellate` did to one part.

    tolerance_mm, angular_tolerance_deg : requested chord and angular deflection
    n_triangles, n_vertices : size of the mesh (after merging shared nodes)
    n_brep_faces : number of B-rep faces meshed
    max_chord_error_mm : largest measured distance between the triangles and the true surface
    method : how it was measured ("sampled": surface and curves evaluated at the sampled facets' midpoints)
    deflection_mm : the linear deflection finally asked of OpenCascade (below ``tolerance_mm`` when the
        first mesh overshot the tolerance and was refined)
    """

    name: str
    tolerance_mm: float
    angular_tolerance_deg: float
    n_triangles: int
    n_vertices: int
    n_brep_faces: int
    max_chord_error_mm: float
    method: str
    deflection_mm: float = float("nan")

    @property
    def within_tolerance(self) -> bool:
        return self.max_chord_error_mm <= self.tolerance_mm * (1 + 1e-9)

    def as_dict(self) -> dict:
        return {"name": self.name, "tolerance_mm": self.tolerance_mm,
                "angular_tolerance_deg": self.angular_tolerance_deg, "n_triangles": self.n_triangles,
                "n_vertices": self.n_vertices, "n_brep_faces": self.n_brep_faces,
                "max_chord_error_mm": self.max_chord_error_mm, "method": self.method,
                "deflection_mm": self.deflection_mm,
                "within_tolerance": self.within_tolerance}


def _wrapped(shape):
    """The OCP TopoDS_Shape of a cadquery Shape / Workplane (or an OCP shape itself)."""
    if hasattr(shape, "vals"):  # a Workplane
        import cadquery as cq

        vals = [v for v in shape.vals() if hasattr(v, "wrapped")]
        if not vals:
            raise GeometryError("the workplane holds no shape to tessellate")
        shape = vals[0] if len(vals) == 1 else cq.Compound.makeCompound(vals)
    return getattr(shape, "wrapped", shape)


def _mesh_faces(topo, tolerance_mm, angular_tolerance_deg):
    """Mesh ``topo``; return [(face, vertices (n,3), triangles (m,3) outward, chord error, edge error)]."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.BRepTools import BRepTools
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    # An existing finer triangulation would be kept by BRepMesh: clear it so the tolerance is the one asked for.
    BRepTools.Clean_s(topo)
    BRepMesh_IncrementalMesh(topo, float(tolerance_mm), False, float(np.deg2rad(angular_tolerance_deg)), True)
    out = []
    explorer = TopExp_Explorer(topo, TopAbs_FACE)
    while explorer.More():
        face = TopoDS.Face_s(explorer.Current())
        explorer.Next()
        location = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(face, location)
        if tri is None or tri.NbTriangles() == 0:
            continue
        node, triangle = tri.Node, tri.Triangle
        nodes = np.array([node(i).Coord() for i in range(1, tri.NbNodes() + 1)])
        if not location.IsIdentity():
            trsf = location.Transformation()
            rot = np.array([[trsf.Value(i, j) for j in (1, 2, 3)] for i in (1, 2, 3)])
            shift = np.array([trsf.Value(i, 4) for i in (1, 2, 3)])
            nodes = nodes @ rot.T + shift
        triangles = np.array([triangle(i).Get() for i in range(1, tri.NbTriangles() + 1)], dtype=np.int64) - 1
        if face.Orientation() == TopAbs_REVERSED:
            triangles = triangles[:, ::-1]
        out.append((face, nodes, triangles, _face_chord_error(face, tri, nodes, triangles),
                    _edge_error(face, tri, location, nodes)))
    return out


def _largest_and_strided(size, n_max):
    """Indices of at most ``n_max`` items: the n_max/2 largest by ``size`` and an even stride through the rest."""
    m = len(size)
    if m <= n_max:
        return np.arange(m)
    largest = np.argpartition(size, m - n_max // 2)[m - n_max // 2:]
    strided = np.arange(0, m, max(1, -(-m // (n_max - n_max // 2))))
    return np.unique(np.concatenate([largest, strided]))


def _face_chord_error(face, tri, nodes, triangles):
    """Largest distance from the face's true surface to its triangles, sampled generically.

    For each sampled triangle the surface is evaluated (``BRepAdaptor_Surface.Value``, any surface
    type) at the triangle's centroid and edge midpoints *in the (u, v) parameter plane* of the mesh
    nodes, and the distance of those surface points from the triangle's plane is taken. Where the
    point projects into the triangle this is its exact distance from the mesh, so the result is a
    lower bound on the true maximum that meets it at the sagitta of circles (the largest deviation of
    a curved face from a flat facet lies at a chord's midpoint). Faces without (u, v) nodes are
    measured by projecting the triangle points onto the surface instead.
    """
    from OCP.BRepAdaptor import BRepAdaptor_Surface

    tri_xyz = nodes[triangles]
    normal = np.cross(tri_xyz[:, 1] - tri_xyz[:, 0], tri_xyz[:, 2] - tri_xyz[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    edge_len = np.linalg.norm(tri_xyz - np.roll(tri_xyz, -1, axis=1), axis=2).max(axis=1)
    pick = _largest_and_strided(np.where(area2 > 0, edge_len, 0.0), _MAX_SAMPLED)
    pick = pick[area2[pick] > 0]
    if len(pick) == 0:
        return 0.0
    unit = normal[pick] / area2[pick, None]
    points = np.einsum("kj,mjc->mkc", _SAMPLE_WEIGHTS, tri_xyz[pick])  # (m, 4, 3)
    if not tri.HasUVNodes():
        return _projected_error(face, points.reshape(-1, 3))
    uv_node = tri.UVNode
    used = np.unique(triangles[pick])
    uv = np.zeros((len(nodes), 2))
    uv[used] = [uv_node(int(i) + 1).Coord() for i in used]
    uv_points = np.einsum("kj,mjc->mkc", _SAMPLE_WEIGHTS, uv[triangles[pick]]).reshape(-1, 2)
    value = BRepAdaptor_Surface(face).Value
    surface = np.array([value(u, v).Coord() for u, v in uv_points]).reshape(points.shape)
    return float(np.abs(np.einsum("mkc,mc->mk", surface - points, unit)).max())


def _projected_error(face, points):
    """Largest distance of ``points`` from the face's surface (``GeomAPI_ProjectPointOnSurf``)."""
    from OCP.BRep import BRep_Tool
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    geom = BRep_Tool.Surface_s(face)
    worst = 0.0
    for x, y, z in points:
        projector = GeomAPI_ProjectPointOnSurf(gp_Pnt(x, y, z), geom)
        if projector.NbPoints() > 0:
            worst = max(worst, projector.LowerDistance())
    return worst


def _edge_error(face, tri, location, nodes):
    """Largest distance between the boundary segments of one meshed face and its B-rep edges.

    Every curve type is treated alike: the edge's 3-D curve (``BRepAdaptor_Curve``) is evaluated at
    the mid-parameter of each mesh segment (OpenCascade stores each boundary node's curve parameter)
    and its distance from the segment's line is taken: the sagitta of the chord, the chord error seen
    from the boundary (e.g. the polygon of a flat disk). Segments are sampled as for faces.
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Curve
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    worst = 0.0
    explorer = TopExp_Explorer(face, TopAbs_EDGE)
    while explorer.More():
        edge = TopoDS.Edge_s(explorer.Current())
        explorer.Next()
        if BRep_Tool.Degenerated_s(edge):
            continue
        polygon = BRep_Tool.PolygonOnTriangulation_s(edge, tri, location)
        if polygon is None or not polygon.HasParameters() or polygon.NbNodes() < 2:
            continue
        index = np.array([polygon.Node(i) for i in range(1, polygon.NbNodes() + 1)]) - 1
        param = polygon.Parameters()
        t = np.array([param.Value(i) for i in range(1, polygon.NbNodes() + 1)])
        a, b = nodes[index[:-1]], nodes[index[1:]]
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        pick = _largest_and_strided(length, _MAX_SAMPLED)
        pick = pick[length[pick] > 0]
        if len(pick) == 0:
            continue
        value = BRepAdaptor_Curve(edge).Value
        mid = np.array([value(s).Coord() for s in (t[pick] + t[pick + 1]) / 2])
        d = mid - a[pick]
        e = seg[pick] / length[pick, None]
        off = d - np.einsum("mc,mc->m", d, e)[:, None] * e
        worst = max(worst, float(np.linalg.norm(off, axis=1).max()))
    return worst


def merge_vertices(vertices: np.ndarray, faces: np.ndarray, distance_mm: float = _MERGE_MM):
    """Merge vertices closer than ``distance_mm``; face order is kept, faces that collapse are dropped.

    Returns (vertices (v, 3), faces (m, 3), kept (m0,) bool mask of the input faces kept).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(vertices)
    pairs = cKDTree(vertices).query_pairs(distance_mm, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else \
        coo_matrix((n, n))
    _, label = connected_components(graph, directed=False)
    # Number the groups in order of first appearance so the output is deterministic.
    _, first = np.unique(label, return_index=True)
    order = np.argsort(first)
    renumber = np.empty_like(order)
    renumber[order] = np.arange(len(order))
    new_index = renumber[label]
    merged = vertices[np.sort(first)]
    f = new_index[faces]
    kept = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    return merged, f[kept], kept


def tessellate(shape, *, name: str = "part", tolerance_mm: float = DEFAULT_TOLERANCE_MM,
               angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG, material: str | None = None,
               role: str = "surface", kind: str | None = None, refine: bool = True) -> Part:
    """Tessellate a CadQuery shape into a :class:`Part`.

    Parameters
    ----------
    shape : cadquery Shape or Workplane (or an OCP TopoDS_Shape)
    tolerance_mm : chord tolerance (absolute linear deflection), mm
    angular_tolerance_deg : angular deflection between neighbouring facets, degrees
    material, role : tags for the part (material by name only)
    kind : "solid" or "sheet"; None: "solid" if the shape holds a solid, else "sheet"
    refine : if the measured chord error exceeds ``tolerance_mm`` (OpenCascade overshoots on
        spheres), re-mesh with a proportionally smaller deflection, up to 5 times

    Returns
    -------
    Part, with ``meta["tessellation"]`` a :class:`TessellationReport` and ``meta["kind"]``.
    """
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer

    if not (np.isfinite(tolerance_mm) and tolerance_mm > 0):
        raise GeometryError(f"part {name!r}: tolerance_mm must be a finite number > 0, got {tolerance_mm!r}")
    if not (np.isfinite(angular_tolerance_deg) and 0 < angular_tolerance_deg < 180):
        raise GeometryError(f"part {name!r}: angular_tolerance_deg must be in (0, 180), got {angular_tolerance_deg!r}")
    topo = _wrapped(shape)
    if kind is None:
        kind = "solid" if TopExp_Explorer(topo, TopAbs_SOLID).More() else "sheet"
    deflection_mm = float(tolerance_mm)
    for _ in range(_MAX_REFINE + 1):
        meshed = _mesh_faces(topo, deflection_mm, angular_tolerance_deg)
        if not meshed:
            raise GeometryError(f"part {name!r}: the shape has no faces to tessellate")
        worst = max(max(face_err, edge_err) for _, _, _, face_err, edge_err in meshed)
        method = "sampled"
        if worst <= tolerance_mm or not refine:
            break
        # OpenCascade overshot (it does on spheres): ask for a proportionally smaller deflection.
        deflection_mm *= 0.8 * tolerance_mm / worst
    offsets = np.cumsum([0] + [len(v) for _, v, _, _, _ in meshed])
    vertices = np.concatenate([v for _, v, _, _, _ in meshed])
    faces = np.concatenate([t + o for (_, _, t, _, _), o in zip(meshed, offsets)])
    brep_face = np.concatenate([np.full(len(t), i) for i, (_, _, t, _, _) in enumerate(meshed)])

    vertices, faces, kept = merge_vertices(vertices, faces)
    report = TessellationReport(name, float(tolerance_mm), float(angular_tolerance_deg), len(faces), len(vertices),
                                len(meshed), float(worst), method, deflection_mm)
    meta = {"tessellation": report, "kind": kind, "brep_face": brep_face[kept]}
    return Part(name, vertices, faces, material, role, meta)


def tessellate_parts(parts, *, tolerance_mm: float = DEFAULT_TOLERANCE_MM,
                     angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG, material: str | None = None,
                     materials: dict | None = None) -> Scene:
    """Tessellate named :class:`geometry.parts.ShapePart` objects (a dict or an iterable) into a Scene.

    material : material name given to every part that is not a detector
    materials : {part name: material name} overriding ``material`` for those parts
    """
    items = list(parts.values()) if isinstance(parts, dict) else list(parts)
    materials = dict(materials or {})
    unknown = set(materials) - {p.name for p in items}
    if unknown:
        raise GeometryError(f"materials given for unknown part(s): {', '.join(sorted(unknown))}")
    from geometry.limits import check_mesh_budget

    check_mesh_budget([p.shape for p in items], tolerance_mm, "tolerance_mm")  # before meshing: native, unstoppable
    out = []
    for p in items:
        tag = materials.get(p.name, None if p.role == "detector" else material)
        out.append(tessellate(p.shape, name=p.name, tolerance_mm=tolerance_mm,
                              angular_tolerance_deg=angular_tolerance_deg, material=tag, role=p.role, kind=p.kind))
    return Scene(tuple(out))


def scene_report(scene: Scene) -> list[TessellationReport]:
    """The tessellation reports of the parts of ``scene`` that have one."""
    return [p.meta["tessellation"] for p in scene.parts if "tessellation" in p.meta]


def format_reports(reports) -> str:
    """Plain-text table of tessellation reports, one line per part, and the totals."""
    reports = list(reports)
    lines = [f"{'part':<16} {'triangles':>9} {'tolerance_mm':>12} {'max_chord_error_mm':>18} method"]
    for r in reports:
        flag = "" if r.within_tolerance else "  ABOVE TOLERANCE"
        lines.append(f"{r.name:<16} {r.n_triangles:>9d} {r.tolerance_mm:>12.4g} {r.max_chord_error_mm:>18.4g} "
                     f"{r.method}{flag}")
    if reports:
        lines.append(f"{'total':<16} {sum(r.n_triangles for r in reports):>9d} {'':>12} "
                     f"{max(r.max_chord_error_mm for r in reports):>18.4g}")
    return "\n".join(lines)
