"""Fast intersection with embreex (Embree 4 through Cython; releases the GIL).

The scene is built once from a (m, 3, 3) triangle array in float32 (what Embree stores);
hit distances are recomputed in float64 from the triangle planes so that hit points lie
on the surface to double precision.
"""
from __future__ import annotations

import numpy as np

from straylight.intersect._plane import plane_distance, triangle_planes


class EmbreeIntersector:
    """First-hit and occlusion queries against a fixed triangle soup.

    Parameters
    ----------
    triangles_mm : (m, 3, 3) float
        Triangles, vertices in mm.
    """

    def __init__(self, triangles_mm):
        from embreex.mesh_construction import TriangleMesh
        from embreex.rtcore_scene import EmbreeScene

        tri = np.ascontiguousarray(triangles_mm, dtype=np.float64)
        if tri.ndim != 3 or tri.shape[1:] != (3, 3) or len(tri) == 0:
            raise ValueError(f"triangles_mm must be a non-empty (m, 3, 3) array, got {tri.shape}")
        self.n_triangles = len(tri)
        self._scene = EmbreeScene()
        self._mesh = TriangleMesh(self._scene, np.ascontiguousarray(tri, dtype=np.float32))
        self._v0, self._normal, self._centroid = triangle_planes(tri)

    def first_triangle(self, origins, dirs) -> np.ndarray:
        """Index of the first triangle hit (int32, -1 = miss), without the distance."""
        o32 = np.ascontiguousarray(origins, dtype=np.float32)
        d32 = np.ascontiguousarray(dirs, dtype=np.float32)
        return self._scene.run(o32, d32)

    def intersect(self, origins, dirs):
        """First hit. origins, dirs : (n, 3) float64 (dirs unit). Returns (tri int64, t float64)."""
        o32 = np.ascontiguousarray(origins, dtype=np.float32)
        d32 = np.ascontiguousarray(dirs, dtype=np.float32)
        tri = self._scene.run(o32, d32).astype(np.int64)
        t = np.full(len(tri), np.inf)
        hit = tri >= 0
        if hit.any():
            t[hit] = plane_distance(
                self._v0, self._normal, self._centroid, tri[hit], np.asarray(origins)[hit], np.asarray(dirs)[hit]
            )
        return tri, t

    def occluded(self, origins, dirs, tmax):
        """True where some triangle lies on the ray at 0 < t < tmax."""
        if len(origins) == 0:
            return np.zeros(0, dtype=bool)
        o32 = np.ascontiguousarray(origins, dtype=np.float32)
        d32 = np.ascontiguousarray(dirs, dtype=np.float32)
        tm = np.ascontiguousarray(tmax, dtype=np.float32)
        return self._scene.run(o32, d32, dists=tm, query="OCCLUDED") != -1
