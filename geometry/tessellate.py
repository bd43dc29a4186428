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

Parameters written by CAD tools cannot always be trusted (a B-spline face whose parametrization is
far from uniform, an edge whose polygon parameters do not match its curve): a point at a mid-parameter
then lands far along the surface, not above the facet, and the parametric estimate stays high however
fine the mesh. Every sample whose parametric estimate exceeds half the tolerance is therefore checked by
projection (``ShapeAnalysis_Surface`` / ``ShapeAnalysis_Curve``): the distance of the facet's point
(segment's midpoint) from the true surface (curve), which is the chord error's definition.

Refinement (:func:`tessellate`): while the measured error exceeds the tolerance the deflection asked of
OpenCascade is cut; it stops, with a :class:`TessellationWarning` naming the part and the B-rep faces,
when the error stops falling (less than 10 % better than the round before: the mesh with the smallest
error is kept) or when the next mesh would exceed the part's triangle budget (``triangle_budget``,
default :data:`DEFAULT_TRIANGLE_BUDGET`, env ``STRAYLIGHT_TRIANGLE_BUDGET``): the count is predicted
before meshing (triangles scale as 1/deflection on curved faces), so a tiny tolerance never makes
gigabytes. Open edges of a solid's mesh (faces of the B-rep that do not share their edges) are healed by
sewing the solid's faces once; what stays open is counted in the report, with the B-rep faces along it.
"""
from __future__ import annotations

import os
import sys
import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from geometry.mesh import GeometryError, Part, Scene

DEFAULT_TOLERANCE_MM = 0.05
DEFAULT_ANGULAR_TOLERANCE_DEG = 10.0
_MERGE_MM = 1e-7  # nodes closer than this are the same node (OCC shares edge nodes exactly)
_MAX_REFINE = 5
DEFAULT_TRIANGLE_BUDGET = 2_000_000  # per part: ~100 MB of mesh and acceleration structure
ENV_BUDGET = "STRAYLIGHT_TRIANGLE_BUDGET"
_STALL = 0.9  # a round must cut the error below 90 % of the previous round's, else refinement stops
_VERIFY_FRACTION = 0.5  # parametric samples above this fraction of the tolerance are checked by projection
_PROGRESS_S = 5.0  # seconds between progress lines inside one part
MESH_IN_PARALLEL = True  # OpenCascade's thread pool; off in a forked reader child (geometry.cad_child), where the
# parent's pool threads do not exist and a parallel mesh would wait for them forever
POOL_STARTED = False  # this process has meshed in parallel (its thread pool exists): readers start by spawn
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
    n_open_edges : mesh edges used by one triangle only (after healing); 0 for a closed mesh
    stopped : why refinement stopped short of the tolerance ("" if it did not): "stalled" (the error
        stopped falling), "budget" (the triangle budget), "no-refine"
    note : one line for the user (which faces stay above tolerance, where the mesh is open)
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
    n_open_edges: int = 0
    stopped: str = ""
    note: str = ""

    @property
    def within_tolerance(self) -> bool:
        return self.max_chord_error_mm <= self.tolerance_mm * (1 + 1e-9)

    def as_dict(self) -> dict:
        return {"name": self.name, "tolerance_mm": self.tolerance_mm,
                "angular_tolerance_deg": self.angular_tolerance_deg, "n_triangles": self.n_triangles,
                "n_vertices": self.n_vertices, "n_brep_faces": self.n_brep_faces,
                "max_chord_error_mm": self.max_chord_error_mm, "method": self.method,
                "deflection_mm": self.deflection_mm, "n_open_edges": self.n_open_edges,
                "stopped": self.stopped, "note": self.note,
                "within_tolerance": self.within_tolerance}


class TessellationWarning(UserWarning):
    """A part whose mesh could not reach its tolerance (refinement stalled or hit the triangle budget),
    or whose mesh stays open."""


def triangle_budget() -> int:
    """Triangles allowed per part: ``$STRAYLIGHT_TRIANGLE_BUDGET`` if set, else :data:`DEFAULT_TRIANGLE_BUDGET`."""
    raw = os.environ.get(ENV_BUDGET, "").strip()
    if not raw:
        return DEFAULT_TRIANGLE_BUDGET
    try:
        value = int(float(raw))
    except ValueError:
        raise GeometryError(f"{ENV_BUDGET}={raw!r}: expected a whole number of triangles") from None
    if value < 100:
        raise GeometryError(f"{ENV_BUDGET}={raw!r}: expected at least 100 triangles")
    return value


class Progress:
    """A line on stderr every few seconds while one part is meshed and measured ("face k of n"), so a
    large solid never looks hung; silent for parts that take less than ``_PROGRESS_S`` seconds."""

    def __init__(self, context: str, stream=None, every_s: float = _PROGRESS_S):
        self.context, self.stream, self.every_s = context, stream, every_s
        self.start = self.last = time.monotonic()

    def __call__(self, what: str, k: int, n: int) -> None:
        now = time.monotonic()
        if now - self.last >= self.every_s:
            self.last = now
            stream = self.stream or sys.stderr
            print(f"{self.context}: {what} face {k} of {n} ({now - self.start:.0f} s)", file=stream, flush=True)


def _wrapped(shape):
    """The OCP TopoDS_Shape of a cadquery Shape / Workplane (or an OCP shape itself)."""
    if hasattr(shape, "vals"):  # a Workplane
        import cadquery as cq

        vals = [v for v in shape.vals() if hasattr(v, "wrapped")]
        if not vals:
            raise GeometryError("the workplane holds no shape to tessellate")
        shape = vals[0] if len(vals) == 1 else cq.Compound.makeCompound(vals)
    return getattr(shape, "wrapped", shape)


def _mesh_faces(topo, tolerance_mm, angular_tolerance_deg, verify_above_mm=None, progress=None):
    """Mesh ``topo``; return [(face, vertices (n,3), triangles (m,3) outward, chord error, edge error, projected)].

    verify_above_mm : samples whose parametric error exceeds this are measured by projection instead
        (default: half of ``tolerance_mm``); ``projected`` tells whether any sample of the face was.
    progress : optional callable(what, k, n) called per face.
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.BRepTools import BRepTools
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    verify = _VERIFY_FRACTION * tolerance_mm if verify_above_mm is None else verify_above_mm
    # An existing finer triangulation would be kept by BRepMesh: clear it so the tolerance is the one asked for.
    BRepTools.Clean_s(topo)
    global POOL_STARTED
    POOL_STARTED = POOL_STARTED or MESH_IN_PARALLEL
    BRepMesh_IncrementalMesh(topo, float(tolerance_mm), False, float(np.deg2rad(angular_tolerance_deg)),
                             MESH_IN_PARALLEL)
    faces = []
    explorer = TopExp_Explorer(topo, TopAbs_FACE)
    while explorer.More():
        faces.append(TopoDS.Face_s(explorer.Current()))
        explorer.Next()
    out = []
    for k, face in enumerate(faces, start=1):
        if progress is not None:
            progress("measuring", k, len(faces))
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
        face_err, face_proj = _face_chord_error(face, tri, nodes, triangles, verify)
        edge_err, edge_proj = _edge_error(face, tri, location, nodes, verify)
        out.append((face, nodes, triangles, face_err, edge_err, face_proj or edge_proj))
    return out


def _largest_and_strided(size, n_max):
    """Indices of at most ``n_max`` items: the n_max/2 largest by ``size`` and an even stride through the rest."""
    m = len(size)
    if m <= n_max:
        return np.arange(m)
    largest = np.argpartition(size, m - n_max // 2)[m - n_max // 2:]
    strided = np.arange(0, m, max(1, -(-m // (n_max - n_max // 2))))
    return np.unique(np.concatenate([largest, strided]))


def _face_chord_error(face, tri, nodes, triangles, verify_above_mm=np.inf):
    """(largest distance between the face's true surface and its triangles, whether projection was used).

    For each sampled triangle the surface is evaluated (``BRepAdaptor_Surface.Value``, any surface
    type) at the triangle's centroid and edge midpoints *in the (u, v) parameter plane* of the mesh
    nodes, and the distance of those surface points from the triangle's plane is taken. Where the
    point projects into the triangle this is its exact distance from the mesh, so the result is a
    lower bound on the true maximum that meets it at the sagitta of circles (the largest deviation of
    a curved face from a flat facet lies at a chord's midpoint).

    That estimate trusts the parametrization; on a B-spline face written with a far-from-uniform one the
    mid-parameter point lies far along the surface and its distance from the facet's plane is not a chord
    error. Triangles whose estimate exceeds ``verify_above_mm`` (and faces without (u, v) nodes) are
    measured by projecting the facet's own centroid and edge midpoints onto the surface instead
    (``ShapeAnalysis_Surface``, started from the (u, v) guess): the distance from mesh to surface.
    """
    from OCP.BRepAdaptor import BRepAdaptor_Surface

    tri_xyz = nodes[triangles]
    normal = np.cross(tri_xyz[:, 1] - tri_xyz[:, 0], tri_xyz[:, 2] - tri_xyz[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    edge_len = np.linalg.norm(tri_xyz - np.roll(tri_xyz, -1, axis=1), axis=2).max(axis=1)
    pick = _largest_and_strided(np.where(area2 > 0, edge_len, 0.0), _MAX_SAMPLED)
    pick = pick[area2[pick] > 0]
    if len(pick) == 0:
        return 0.0, False
    unit = normal[pick] / area2[pick, None]
    points = np.einsum("kj,mjc->mkc", _SAMPLE_WEIGHTS, tri_xyz[pick])  # (m, 4, 3)
    if not tri.HasUVNodes():
        return float(_projected_distances(face, points.reshape(-1, 3)).max()), True
    uv_node = tri.UVNode
    used = np.unique(triangles[pick])
    uv = np.zeros((len(nodes), 2))
    uv[used] = [uv_node(int(i) + 1).Coord() for i in used]
    uv_points = np.einsum("kj,mjc->mkc", _SAMPLE_WEIGHTS, uv[triangles[pick]])  # (m, 4, 2)
    value = BRepAdaptor_Surface(face).Value
    surface = np.array([value(u, v).Coord() for u, v in uv_points.reshape(-1, 2)]).reshape(points.shape)
    err = np.abs(np.einsum("mkc,mc->mk", surface - points, unit)).max(axis=1)  # (m,)
    suspect = err > verify_above_mm
    if not suspect.any():
        return float(err.max()), False
    err[suspect] = _projected_distances(face, points[suspect].reshape(-1, 3),
                                        uv_points[suspect].reshape(-1, 2)).reshape(-1, 4).max(axis=1)
    return float(err.max()), True


def _projected_distances(face, points, uv_guess=None):
    """Distance of each of ``points`` (n, 3) from the face's surface (``ShapeAnalysis_Surface``: the smaller of
    Newton from the (u, v) guess, when given, and its global search)."""
    from OCP.BRep import BRep_Tool
    from OCP.gp import gp_Pnt, gp_Pnt2d
    from OCP.ShapeAnalysis import ShapeAnalysis_Surface

    analysis = ShapeAnalysis_Surface(BRep_Tool.Surface_s(face))
    out = np.empty(len(points))
    for i, (x, y, z) in enumerate(points):
        p = gp_Pnt(float(x), float(y), float(z))
        gap = np.inf
        if uv_guess is not None:  # Newton from the guess; it may stop at a local minimum, so also search
            analysis.NextValueOfUV(gp_Pnt2d(float(uv_guess[i, 0]), float(uv_guess[i, 1])), p, 1e-9, -1.0)
            gap = analysis.Gap()
        analysis.ValueOfUV(p, 1e-9)
        out[i] = min(gap, analysis.Gap())
    return out


def _edge_error(face, tri, location, nodes, verify_above_mm=np.inf):
    """(largest distance between the boundary segments of one meshed face and its B-rep edges, projected).

    Every curve type is treated alike: the edge's 3-D curve (``BRepAdaptor_Curve``) is evaluated at
    the mid-parameter of each mesh segment (OpenCascade stores each boundary node's curve parameter)
    and its distance from the segment's line is taken: the sagitta of the chord, the chord error seen
    from the boundary (e.g. the polygon of a flat disk). Segments are sampled as for faces. A segment
    whose estimate exceeds ``verify_above_mm`` (polygon parameters that do not match the curve's) is
    measured by projecting its midpoint onto the curve (``ShapeAnalysis_Curve.Project``) instead.
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Curve
    from OCP.gp import gp_Pnt
    from OCP.ShapeAnalysis import ShapeAnalysis_Curve
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    worst, projected = 0.0, False
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
        curve = BRepAdaptor_Curve(edge)
        value = curve.Value
        mid = np.array([value(s).Coord() for s in (t[pick] + t[pick + 1]) / 2])
        d = mid - a[pick]
        e = seg[pick] / length[pick, None]
        off = np.linalg.norm(d - np.einsum("mc,mc->m", d, e)[:, None] * e, axis=1)
        suspect = off > verify_above_mm
        if suspect.any():
            projected = True
            analysis, proj = ShapeAnalysis_Curve(), gp_Pnt()
            chord_mid = (a[pick] + b[pick])[suspect] / 2
            off[suspect] = [analysis.Project(curve, gp_Pnt(*map(float, p)), 1e-9, proj, 0.0, False)
                            for p in chord_mid]
        worst = max(worst, float(off.max()))
    return worst, projected


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


def _surface_type(face) -> str:
    from OCP.BRepAdaptor import BRepAdaptor_Surface

    return BRepAdaptor_Surface(face).GetType().name.replace("GeomAbs_", "")


def _diagonal_mm(topo) -> float:
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib

    box = Bnd_Box()
    BRepBndLib.Add_s(topo, box, False)
    if box.IsVoid():
        return 0.0
    x0, y0, z0, x1, y1, z1 = box.Get()
    return float(np.linalg.norm([x1 - x0, y1 - y0, z1 - z0]))


def _n_triangles(meshed) -> int:
    return sum(len(m[2]) for m in meshed)


def _worst(meshed) -> float:
    return max(max(m[3], m[4]) for m in meshed)


def _faces_above(meshed, tolerance_mm, limit=5) -> str:
    """'face 78 (BSplineSurface) 0.094 mm, ...' for the faces whose error exceeds the tolerance, worst first."""
    above = sorted(((max(m[3], m[4]), k) for k, m in enumerate(meshed) if max(m[3], m[4]) > tolerance_mm),
                   reverse=True)
    text = ", ".join(f"face {k + 1} ({_surface_type(meshed[k][0])}) {err:.3g} mm" for err, k in above[:limit])
    return text + (f" and {len(above) - limit} more" if len(above) > limit else "")


def _open_edges(faces: np.ndarray):
    """(number of undirected edges used by exactly one triangle, mask of the triangles along them)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    return int((counts == 1).sum()), once.reshape(3, -1).any(axis=0)


def _sewn(topo):
    """The shape's faces sewn (``BRepBuilderAPI_Sewing``): faces that touch but do not share their edges
    (an open B-rep) come to share them, so the mesh closes there. None if sewing fails."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    try:
        sewing = BRepBuilderAPI_Sewing(1e-3)
        explorer = TopExp_Explorer(topo, TopAbs_FACE)
        while explorer.More():
            sewing.Add(explorer.Current())
            explorer.Next()
        sewing.Perform()
        sewn = sewing.SewedShape()
        return None if sewn.IsNull() else sewn
    except Exception:  # noqa: BLE001 - healing is best effort; the unhealed mesh is reported
        return None


def _assemble(meshed):
    """(vertices, faces, brep_face) of the merged mesh of meshed faces."""
    offsets = np.cumsum([0] + [len(m[1]) for m in meshed])
    vertices = np.concatenate([m[1] for m in meshed])
    faces = np.concatenate([m[2] + o for m, o in zip(meshed, offsets)])
    brep_face = np.concatenate([np.full(len(m[2]), i) for i, m in enumerate(meshed)])
    vertices, faces, kept = merge_vertices(vertices, faces)
    return vertices, faces, brep_face[kept]


def tessellate(shape, *, name: str = "part", tolerance_mm: float = DEFAULT_TOLERANCE_MM,
               angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG, material: str | None = None,
               role: str = "surface", kind: str | None = None, refine: bool = True,
               budget: int | None = None, context: str | None = None, progress=None, heal: bool = True,
               warn: bool = True) -> Part:
    """Tessellate a CadQuery shape into a :class:`Part`.

    Parameters
    ----------
    shape : cadquery Shape or Workplane (or an OCP TopoDS_Shape)
    tolerance_mm : chord tolerance (absolute linear deflection), mm
    angular_tolerance_deg : angular deflection between neighbouring facets, degrees
    material, role : tags for the part (material by name only)
    kind : "solid" or "sheet"; None: "solid" if the shape holds a solid, else "sheet"
    refine : if the measured chord error exceeds ``tolerance_mm`` (OpenCascade overshoots on
        spheres), re-mesh with a proportionally smaller deflection, up to 5 times, while the error falls
        and the mesh stays within ``budget``
    budget : triangles allowed for this part (default :func:`triangle_budget`)
    context : how warnings name the part (default ``part 'NAME'``)
    progress : callable(what, k, n) called per B-rep face (default: a :class:`Progress` line every few s)
    heal : sew a solid whose mesh is open and keep the healed mesh if it has fewer open edges
    warn : give a :class:`TessellationWarning` when the tolerance is not reached or the mesh is open (CAD
        files read through :func:`geometry.io.tessellate_cad` warn from their reports instead)

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
    budget = triangle_budget() if budget is None else int(budget)
    context = context or f"part {name!r}"
    progress = Progress(context) if progress is None else progress
    topo = _wrapped(shape)
    if kind is None:
        kind = "solid" if TopExp_Explorer(topo, TopAbs_SOLID).More() else "sheet"
    tol = float(tolerance_mm)
    notes, stopped = [], ""

    # Triangles grow as 1/deflection on curved faces: predict the count from a coarse probe mesh so that a
    # tiny tolerance is refused up front (meshed at the finest deflection the budget allows), not after
    # OpenCascade has filled the memory.
    deflection_mm = tol
    probe_mm = _diagonal_mm(topo) / 2000.0
    if probe_mm > 4 * tol:
        probe = _mesh_faces(topo, probe_mm, angular_tolerance_deg, np.inf)
        predicted = _n_triangles(probe) * probe_mm / tol
        if predicted > budget:
            deflection_mm = min(probe_mm, tol * predicted / budget)
            stopped = "budget"
            notes.append(f"tolerance {tol:g} mm would need about {predicted:.3g} triangles (budget {budget}): "
                         f"meshed at {deflection_mm:.3g} mm instead")
    best: tuple[float, float, Any] | None = None  # (worst, deflection, meshed)
    previous = np.inf
    for _ in range(_MAX_REFINE + 1):
        meshed = _mesh_faces(topo, deflection_mm, angular_tolerance_deg, _VERIFY_FRACTION * tol, progress)
        if not meshed:
            raise GeometryError(f"{context}: the shape has no faces to tessellate")
        worst, n_tri = _worst(meshed), _n_triangles(meshed)
        for _ in range(4):  # the budget is a hard cap: a first mesh over it is made coarser
            if best is not None or n_tri <= budget:
                break
            deflection_mm *= 1.25 * n_tri / budget
            stopped = "budget"
            meshed = _mesh_faces(topo, deflection_mm, angular_tolerance_deg, _VERIFY_FRACTION * tol, progress)
            worst, n_tri = _worst(meshed), _n_triangles(meshed)
        if n_tri > budget and best is not None:  # the probe's prediction undershot: keep the previous mesh
            stopped = "budget"
            notes.append(f"refining to {deflection_mm:.3g} mm gave {n_tri} triangles (budget {budget}): kept "
                         f"the mesh at {best[1]:.3g} mm")
            break
        if best is None or worst < best[0]:
            best = (worst, deflection_mm, meshed)
        if worst <= tol or stopped:
            break
        if not refine:
            stopped = "no-refine"
            break
        if worst > _STALL * previous:
            stopped = "stalled"
            notes.append(f"chord error stopped falling ({previous:.3g} -> {worst:.3g} mm at deflection "
                         f"{deflection_mm:.3g} mm): refinement stopped")
            break
        previous = worst
        # OpenCascade overshot (it does on spheres): ask for a proportionally smaller deflection.
        new_mm = deflection_mm * 0.8 * tol / worst
        if n_tri * deflection_mm / new_mm > budget:
            new_mm = deflection_mm * n_tri / budget
            if new_mm >= 0.95 * deflection_mm:
                stopped = "budget"
                notes.append(f"a finer mesh would exceed the triangle budget ({budget})")
                break
        deflection_mm = new_mm
    else:
        stopped = stopped or "stalled"
    assert best is not None  # the first pass always keeps its mesh
    worst, deflection_mm, meshed = best
    if worst > tol:
        notes.append(f"above tolerance: {_faces_above(meshed, tol)}")
        stopped = stopped or "stalled"
    else:
        stopped = "" if stopped != "budget" else stopped
    vertices, faces, brep_face = _assemble(meshed)
    n_open, along = _open_edges(faces)
    if n_open and kind == "solid" and heal:
        sewn = _sewn(topo)
        if sewn is not None:
            healed = _mesh_faces(sewn, deflection_mm, angular_tolerance_deg, _VERIFY_FRACTION * tol, progress)
            if healed:
                h_vertices, h_faces, h_brep = _assemble(healed)
                h_open, h_along = _open_edges(h_faces)
                if h_open < n_open:
                    notes.append(f"healed by sewing: open edges {n_open} -> {h_open}")
                    vertices, faces, brep_face, n_open, along = h_vertices, h_faces, h_brep, h_open, h_along
                    meshed, worst = healed, max(worst, _worst(healed))
    if n_open and kind == "solid":
        where = np.unique(brep_face[along]) + 1
        shown = ", ".join(map(str, where[:8])) + (f" and {len(where) - 8} more" if len(where) > 8 else "")
        notes.append(f"mesh open: {n_open} open edges along B-rep faces {shown}; the tracer treats the solid's "
                     f"triangles as surfaces, so light through a gap meets their inner side (same material, or "
                     f"back_material) and the power ledger still closes")
    note = "; ".join(notes)
    if notes and (stopped or n_open) and warn:
        warnings.warn(f"{context}: {note}", TessellationWarning, stacklevel=2)
    report = TessellationReport(name, tol, float(angular_tolerance_deg), len(faces), len(vertices),
                                len(meshed), float(worst), "sampled+projected" if any(m[5] for m in meshed)
                                else "sampled", deflection_mm, n_open, stopped, note)
    meta = {"tessellation": report, "kind": kind, "brep_face": brep_face}
    return Part(name, vertices, faces, material, role, meta)


def warn_reports(path, items, *, fresh: bool = True) -> None:
    """One :class:`TessellationWarning` for a CAD file some of whose solids stopped short of their tolerance or
    are open: [(name, kind, label, Part)]. It names each such solid with its chord error and faces (the
    report's note) and says what to do; it is said when the file is tessellated (``fresh``), not again when
    the same meshes come from the cache (the reports are kept with them: ``straylight geometry check``
    lists each solid's chord error)."""
    if not fresh:
        return
    bad = []
    for name, _, _, part in items:
        report = part.meta.get("tessellation")
        if report is not None and (report.stopped or report.n_open_edges) and report.note:
            bad.append((name, report))
    if not bad:
        return
    asked = max(r.tolerance_mm for _, r in bad)
    listed = "; ".join(f"{name!r} {r.max_chord_error_mm:.3g} mm ({r.note})" for name, r in bad)
    warnings.warn(f"{path}: {len(bad)} solid(s) not meshed within {asked:g} mm: {listed}. The trace uses these "
                  f"meshes as they are; to do better ask a coarser tolerance_mm (the error then stays within it), "
                  f"or re-export the named faces from the CAD tool. Said once: the meshes and this report are "
                  f"cached", TessellationWarning, stacklevel=3)


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
