"""CadQuery shape -> :class:`geometry.mesh.Part` with a stated chord tolerance.

OpenCascade's ``BRepMesh_IncrementalMesh`` meshes every B-rep face with an absolute
linear deflection ``tolerance_mm`` (the largest allowed distance between a triangle and
the true surface, the chord error) and an angular deflection ``angular_tolerance_deg``
(the largest angle between the normals of neighbouring facets). Adjacent faces share the
nodes of their common edge, so after merging coincident nodes a closed solid gives a
closed (watertight) triangle mesh. Triangles of faces whose orientation is REVERSED are
flipped so that every triangle is counter-clockwise seen from outside (outward normals).

The chord error is then *measured*, face by face, against the analytic surface:

- plane: distance of the vertices from the plane (triangles are flat);
- cylinder: exact, ``R - min |r_perp|`` over each triangle (the distance from the axis is
  convex, so its minimum over the triangle is the 2-D distance from the axis to the
  triangle projected along the axis);
- cone, sphere: analytic distance at 28 points per triangle (a regular barycentric grid);
- any other surface (B-splines from STEP files, tori): ``GeomAPI_ProjectPointOnSurf`` at the
  centroid and edge midpoints of each triangle (of at most 5000 evenly strided triangles per face);
- and the other way round, the boundary: the distance from the midpoint of every boundary
  segment of a face's mesh to its B-rep edge (circles analytically), so that the polygon
  of a flat disk (the detector) counts too.

The sampled methods give a lower bound on the true maximum; the report says which
method each part needed (the worst one used).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.mesh import GeometryError, Part, Scene

DEFAULT_TOLERANCE_MM = 0.05
DEFAULT_ANGULAR_TOLERANCE_DEG = 10.0
_MERGE_MM = 1e-7  # nodes closer than this are the same node (OCC shares edge nodes exactly)
_MAX_REFINE = 5
_MAX_PROJECTED = 5000  # triangles per face measured by point projection (slow path for B-spline faces)
_METHOD_RANK = {"none": 0, "exact": 1, "sampled": 2, "projected": 3}


@dataclass(frozen=True)
class TessellationReport:
    """What :func:`tessellate` did to one part.

    tolerance_mm, angular_tolerance_deg : requested chord and angular deflection
    n_triangles, n_vertices : size of the mesh (after merging shared nodes)
    n_brep_faces : number of B-rep faces meshed
    max_chord_error_mm : largest measured distance between the triangles and the true surface
    method : how it was measured ("exact" for planes and cylinders only, else "sampled" or "projected")
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
    """Mesh ``topo``; return [(face, vertices (n,3), triangles (m,3) outward)] for every meshed face."""
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
        trsf = location.Transformation()
        nodes = np.array([tri.Node(i).Transformed(trsf).Coord() for i in range(1, tri.NbNodes() + 1)])
        triangles = np.array([tri.Triangle(i).Get() for i in range(1, tri.NbTriangles() + 1)], dtype=np.int64) - 1
        if face.Orientation() == TopAbs_REVERSED:
            triangles = triangles[:, ::-1]
        out.append((face, nodes, triangles, _edge_error(face, tri, location, nodes)))
    return out


def _edge_error(face, tri, location, nodes):
    """Largest distance from the midpoints of the boundary segments of one meshed face to its B-rep edges.

    This is the chord error seen from the other side: how far the mesh boundary (e.g. the
    polygon of a disk) lies from the true edge. Circles and lines are measured analytically,
    other curves with ``GeomAPI_ProjectPointOnCurve``.
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Curve
    from OCP.GeomAbs import GeomAbs_Circle, GeomAbs_Line
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    worst = 0.0
    explorer = TopExp_Explorer(face, TopAbs_EDGE)
    while explorer.More():
        edge = TopoDS.Edge_s(explorer.Current())
        explorer.Next()
        polygon = BRep_Tool.PolygonOnTriangulation_s(edge, tri, location)
        if polygon is None or BRep_Tool.Degenerated_s(edge):
            continue
        index = np.array([polygon.Node(i) for i in range(1, polygon.NbNodes() + 1)]) - 1
        p = nodes[index]
        mid = (p[1:] + p[:-1]) / 2
        curve = BRepAdaptor_Curve(edge)
        kind = curve.GetType()
        if kind == GeomAbs_Line:
            continue
        if kind == GeomAbs_Circle:
            circle = curve.Circle()
            c = np.array(circle.Location().Coord())
            n = np.array(circle.Axis().Direction().Coord())
            q = mid - c
            h = q @ n
            rho = np.linalg.norm(q - h[:, None] * n, axis=1)
            worst = max(worst, float(np.sqrt((rho - circle.Radius()) ** 2 + h ** 2).max()))
            continue
        from OCP.GeomAPI import GeomAPI_ProjectPointOnCurve
        from OCP.gp import gp_Pnt

        geom, first, last = BRep_Tool.Curve_s(edge, 0.0, 0.0)
        if geom is None:
            continue
        for x, y, z in mid:
            projector = GeomAPI_ProjectPointOnCurve(gp_Pnt(x, y, z), geom)
            if projector.NbPoints() > 0:
                worst = max(worst, projector.LowerDistance())
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


def _barycentric(levels: int = 3) -> np.ndarray:
    """(k, 3) barycentric weights on a regular grid with ``levels`` steps per edge."""
    w = [(i, j, levels - i - j) for i in range(levels + 1) for j in range(levels + 1 - i)]
    return np.array(w, dtype=float) / levels


def _cylinder_error(tri, axis_point, axis_dir, radius):
    """Exact max distance of each triangle (m, 3, 3) from a cylinder."""
    d = axis_dir / np.linalg.norm(axis_dir)
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    q = tri - axis_point
    p = np.stack([q @ e1, q @ e2], axis=-1)  # (m, 3, 2)
    a, b, c = p[:, 0], p[:, 1], p[:, 2]

    def cross(u, v):
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

    s1, s2, s3 = cross(b - a, -a), cross(c - b, -b), cross(a - c, -c)
    inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))

    def seg(u, v):
        e = v - u
        ee = np.einsum("ij,ij->i", e, e)
        t = np.clip(-np.einsum("ij,ij->i", u, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
        return np.linalg.norm(u + t[:, None] * e, axis=1)

    dmin = np.where(inside, 0.0, np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a)))
    r_vertex = np.linalg.norm(p, axis=2).max(axis=1)
    return np.maximum(radius - dmin, r_vertex - radius)


def _face_chord_error(face, tri):
    """(max chord error of the triangles tri (m, 3, 3) of one face, method)."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.GeomAbs import GeomAbs_Cone, GeomAbs_Cylinder, GeomAbs_Plane, GeomAbs_Sphere

    surface = BRepAdaptor_Surface(face)
    kind = surface.GetType()

    def xyz(p):
        return np.array(p.Coord())

    if kind == GeomAbs_Plane:
        pos = surface.Plane().Position()
        dist = np.abs((tri - xyz(pos.Location())) @ xyz(pos.Direction()))
        return float(dist.max()), "exact"
    if kind == GeomAbs_Cylinder:
        cyl = surface.Cylinder()
        err = _cylinder_error(tri, xyz(cyl.Axis().Location()), xyz(cyl.Axis().Direction()), cyl.Radius())
        return float(err.max()), "exact"
    points = np.einsum("kj,mjc->mkc", _barycentric(6), tri).reshape(-1, 3)
    if kind == GeomAbs_Cone:
        cone = surface.Cone()
        pos = cone.Position()
        c, d = xyz(pos.Location()), xyz(pos.Direction())
        q = points - c
        h = q @ d
        rho = np.linalg.norm(q - h[:, None] * d, axis=1)
        alpha = cone.SemiAngle()
        dist = np.abs(rho - cone.RefRadius() - h * np.tan(alpha)) * np.cos(alpha)
        return float(dist.max()), "sampled"
    if kind == GeomAbs_Sphere:
        sphere = surface.Sphere()
        dist = np.abs(np.linalg.norm(points - xyz(sphere.Location()), axis=1) - sphere.Radius())
        return float(dist.max()), "sampled"
    from OCP.BRep import BRep_Tool
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    geom = BRep_Tool.Surface_s(face)
    # One Python call per point: sample at most _MAX_PROJECTED triangles per face, evenly strided.
    tri = tri[:: max(1, -(-len(tri) // _MAX_PROJECTED))]
    mids = np.concatenate([tri.mean(axis=1), (tri + np.roll(tri, -1, axis=1)).reshape(-1, 3) / 2])
    worst = 0.0
    for x, y, z in mids:
        projector = GeomAPI_ProjectPointOnSurf(gp_Pnt(x, y, z), geom)
        if projector.NbPoints() > 0:
            worst = max(worst, projector.LowerDistance())
    return worst, "projected"


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
        worst, method = 0.0, "none"
        for face, v, t, edge_err in meshed:
            err, how = _face_chord_error(face, v[t])
            worst = max(worst, err, edge_err)
            method = how if _METHOD_RANK[how] > _METHOD_RANK[method] else method
        if worst <= tolerance_mm or not refine:
            break
        # OpenCascade overshot (it does on spheres): ask for a proportionally smaller deflection.
        deflection_mm *= 0.8 * tolerance_mm / worst
    offsets = np.cumsum([0] + [len(v) for _, v, _, _ in meshed])
    vertices = np.concatenate([v for _, v, _, _ in meshed])
    faces = np.concatenate([t + o for (_, _, t, _), o in zip(meshed, offsets)])
    brep_face = np.concatenate([np.full(len(t), i) for i, (_, _, t, _) in enumerate(meshed)])

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
