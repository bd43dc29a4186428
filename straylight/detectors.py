"""Detector parts: area sampling for next-event estimation, and irradiance-map frames.

A detector part is any set of triangles. Next-event estimation samples a point uniformly
over its area (triangle by area, then uniform barycentrics), so the pdf per unit area is
``1 / area_mm2``. An analytic ``plane`` detector (CONTRACTS §6.4) is its exact disk or annulus
(:class:`Disk`): area pi (outer^2 - inner^2), points drawn on the disk itself. Irradiance maps bin
positions in the plane that best fits the part (area-weighted principal axes).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np


@dataclass(frozen=True, eq=False)
class Disk:
    """An exact disk or annulus: centre, in-plane axes u, v, normal (unit), squared radii."""

    centre_mm: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray
    normal: np.ndarray
    r2_in: float
    r2_out: float

    @classmethod
    def of_plane(cls, plane) -> Disk:
        """The disk of a geometry.analytic.Plane (its local frame: rows u, v, w of ``rotation``)."""
        u, v, w = (np.ascontiguousarray(a, dtype=np.float64) for a in plane.rotation)
        return cls(np.ascontiguousarray(plane.vertex_mm, dtype=np.float64), u, v, w,
                   float(plane.inner_radius_mm) ** 2, float(plane.outer_radius_mm) ** 2)

    @property
    def area_mm2(self) -> float:
        return math.pi * (self.r2_out - self.r2_in)


@dataclass(frozen=True, eq=False)
class DetectorGeometry:
    """Sampling and binning data of one detector part.

    triangles_mm : (m, 3, 3); normals : (m, 3) unit; area_mm2 : total area;
    origin_mm, axis_u, axis_v, normal : plane frame of the map; extent_mm : (umin, umax, vmin, vmax).
    """

    triangles_mm: np.ndarray
    normals: np.ndarray
    cdf: np.ndarray
    area_mm2: float
    origin_mm: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray
    extent_mm: tuple
    disk: Disk | None = None  # an analytic plane detector: sampled and measured exactly

    @classmethod
    def from_plane(cls, triangles_mm, plane):
        """The geometry of an analytic plane part (its mesh ``triangles_mm`` finds the hits and frames
        the maps; the exact disk gives the area and the samples)."""
        disk = Disk.of_plane(plane)
        return replace(cls.from_triangles(triangles_mm), area_mm2=disk.area_mm2, disk=disk)

    @classmethod
    def from_triangles(cls, triangles_mm):
        tri = np.asarray(triangles_mm, dtype=np.float64)
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        twice = np.linalg.norm(cross, axis=1)
        areas = 0.5 * twice
        total = float(areas.sum())
        if total <= 0:
            raise ValueError("detector part has zero area")
        normals = cross / np.where(twice > 0, twice, 1.0)[:, None]
        cdf = np.cumsum(areas) / total
        cdf[-1] = 1.0
        centroids = tri.mean(axis=1)
        origin = (centroids * areas[:, None]).sum(axis=0) / total
        mean_normal = (normals * areas[:, None]).sum(axis=0)
        if np.linalg.norm(mean_normal) > 0.5 * total:
            normal = mean_normal / np.linalg.norm(mean_normal)
        else:  # closed or folded detector: the plane of least spread
            pts = tri.reshape(-1, 3) - origin
            normal = np.linalg.eigh(pts.T @ pts)[1][:, 0]
        ref = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis_u = ref - normal * (ref @ normal)
        axis_u /= np.linalg.norm(axis_u)
        axis_v = np.cross(normal, axis_u)
        pts = tri.reshape(-1, 3) - origin
        pu, pv = pts @ axis_u, pts @ axis_v
        pad = 1e-9 * max(1.0, float(np.ptp(pu)), float(np.ptp(pv)))
        extent = (float(pu.min()) - pad, float(pu.max()) + pad, float(pv.min()) - pad, float(pv.max()) + pad)
        return cls(tri, normals, cdf, total, origin, axis_u, axis_v, normal, extent)

    def sample(self, u):
        """Uniform points over the area. u : (n, 3) -> (points (n, 3), triangle normals (n, 3))."""
        if self.disk is not None:
            from straylight.disk_sampling import sample_annulus

            return sample_annulus(self.disk, u[:, 1], u[:, 2]), np.tile(self.disk.normal, (len(u), 1))
        k = self._pick_triangle(u[:, 0])
        su = np.sqrt(u[:, 1])
        b1 = (su * (1.0 - u[:, 2]))[:, None]
        b2 = (su * u[:, 2])[:, None]
        # P = A + b1 (B - A) + b2 (C - A), uniform over the triangle (Turk 1990)
        v0, e1, e2 = self.vertex_and_edges_mm
        pts = v0[k] + b1 * e1[k] + b2 * e2[k]
        return pts, self.normals[k]

    def _pick_triangle(self, u0):
        """Triangle index with probability area / total (Walker's alias method, Vose's table)."""
        prob, alias = self.alias_table
        m = len(prob)
        x = u0 * m
        k = np.minimum(x.astype(np.int64), m - 1)
        return np.where(x - k < prob[k], k, alias[k])

    @cached_property
    def alias_table(self):
        """(probability, alias) of Walker's alias table over the triangles (by area; Vose)."""
        p = np.diff(np.concatenate([[0.0], self.cdf])) * len(self.cdf)
        prob = np.ones(len(p))
        alias = np.arange(len(p))
        small = [i for i in range(len(p)) if p[i] < 1.0]
        large = [i for i in range(len(p)) if p[i] >= 1.0]
        p = p.copy()
        while small and large:
            s, g = small.pop(), large.pop()
            prob[s], alias[s] = p[s], g
            p[g] -= 1.0 - p[s]
            (small if p[g] < 1.0 else large).append(g)
        return prob, alias

    @cached_property
    def vertex_and_edges_mm(self):
        """(v0, v1 - v0, v2 - v0) of every triangle, each (m, 3) contiguous."""
        tri = self.triangles_mm
        return (np.ascontiguousarray(tri[:, 0]), np.ascontiguousarray(tri[:, 1] - tri[:, 0]),
                np.ascontiguousarray(tri[:, 2] - tri[:, 0]))

    def bin_index(self, points, bins):
        """Flat bin index (u-major) of points in the map grid of shape ``bins``."""
        rel = points - self.origin_mm
        umin, umax, vmin, vmax = self.extent_mm
        iu = np.floor((rel @ self.axis_u - umin) / (umax - umin) * bins[0]).astype(np.int64)
        iv = np.floor((rel @ self.axis_v - vmin) / (vmax - vmin) * bins[1]).astype(np.int64)
        # np.minimum/np.maximum: the same integers as np.clip without its Python-level overhead
        return (np.minimum(np.maximum(iu, 0), bins[0] - 1) * bins[1]
                + np.minimum(np.maximum(iv, 0), bins[1] - 1))

    def edges_mm(self, bins):
        umin, umax, vmin, vmax = self.extent_mm
        return np.linspace(umin, umax, bins[0] + 1), np.linspace(vmin, vmax, bins[1] + 1)


@dataclass(frozen=True, eq=False)
class IrradianceMap:
    """Power per bin on a detector plane with per-bin Monte Carlo standard error.

    power_w, stderr_w : (nu, nv); edges_u_mm (nu+1,), edges_v_mm (nv+1,);
    irradiance_w_per_mm2 = power_w / bin area (bin area in the plane of the map).
    """

    edges_u_mm: np.ndarray
    edges_v_mm: np.ndarray
    power_w: np.ndarray
    stderr_w: np.ndarray
    origin_mm: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray

    @property
    def bin_area_mm2(self) -> float:
        return float(np.diff(self.edges_u_mm)[0] * np.diff(self.edges_v_mm)[0])

    @property
    def irradiance_w_per_mm2(self) -> np.ndarray:
        return self.power_w / self.bin_area_mm2

    @property
    def irradiance_stderr_w_per_mm2(self) -> np.ndarray:
        return self.stderr_w / self.bin_area_mm2


# ------------------------------------------------------------------ the area a user means

FRONT_FACE_COS = 0.5  # a closed detector's face counts if its outward normal is within 60 deg of the front


@dataclass(frozen=True)
class SensitiveArea:
    """The detector area a PST divides by, and how it was chosen (written to pst.json)."""

    area_mm2: float
    total_area_mm2: float
    closed: bool
    rule: str


MERGE_DIGITS = 8  # trimesh's tol.merge = 1e-8: vertices equal to 8 decimals are one vertex


def is_watertight_merged(vertices_mm, faces) -> bool:
    """``trimesh.Trimesh(vertices_mm, faces, process=True).is_watertight`` without importing trimesh (~2 s
    of start-up): vertices merged as trimesh's ``merge_vertices`` does (coordinates x 10^8 rounded to
    integers), then every edge shared by exactly two triangles (trimesh's ``graph.is_watertight``)."""
    key = (np.asarray(vertices_mm, dtype=np.float64) * 10**MERGE_DIGITS).round().astype(np.int64)
    merged = np.unique(key, axis=0, return_inverse=True)[1].ravel()[np.asarray(faces, dtype=np.int64)]
    edges = np.sort(merged[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    counts = np.unique(edges, axis=0, return_counts=True)[1]
    return bool(np.all(counts == 2))


def sensitive_area(vertices_mm, faces, toward_mm=None) -> SensitiveArea:
    """Area of a detector part that light can reach from the instrument's side.

    - An open part (a sheet: the detector disk of a tessellated scene, a one-sided STL) counts
      all its triangles: each point of it is one point of the sensitive surface.
    - A closed part (a thin solid from CAD: front, back and rim) counts its *front* faces: the
      triangles whose outward normal is within 60 deg of the front normal N. N is the normal of the
      part's plane of least spread (the area-weighted principal axis of its vertices), turned to
      face ``toward_mm`` (the entrance centre; it says on which side the instrument is). The back
      faces point away from the light and the rim of a thin disk is at 90 deg, so a 0.5 mm
      thick disk counts exactly its front disk, as the one-sided disk of its front face would.
    """
    v = np.asarray(vertices_mm, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    twice = np.linalg.norm(cross, axis=1)
    total = float(0.5 * twice.sum())
    if total <= 0:
        raise ValueError("detector part has zero area")
    closed = is_watertight_merged(v, f)
    if not closed:
        return SensitiveArea(total, total, False, "open part: the area of all its triangles")
    geo = DetectorGeometry.from_triangles(tri)
    normal = geo.normal
    if toward_mm is not None and float(np.dot(np.asarray(toward_mm, dtype=np.float64) - geo.origin_mm, normal)) < 0:
        normal = -normal
    unit = cross / np.where(twice > 0, twice, 1.0)[:, None]
    front = unit @ normal > FRONT_FACE_COS
    area = float(0.5 * twice[front].sum())
    if area <= 0:
        raise ValueError("closed detector part: no face points to the instrument's side; "
                         "give [analysis] detector_area_mm2")
    return SensitiveArea(area, total, True,
                         "closed part: its front faces (outward normal within 60 deg of the face toward the entrance)")
