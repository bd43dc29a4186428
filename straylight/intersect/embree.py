"""Fast intersection with embreex (Embree 4 through Cython; releases the GIL).

The scene is built once from a (m, 3, 3) triangle array in float32 (what Embree stores);
hit distances are recomputed in float64 from the triangle planes so that hit points lie
on the surface to double precision.
"""
from __future__ import annotations

import threading

import numpy as np

from straylight.intersect._plane import plane_distance, triangle_planes
from straylight.intersect.coherence import CELL_BITS, MIN_RAYS, MIN_TRIANGLES, coherent_float32, scatter_back

_NO_EXTRA = np.zeros(0)


def _float64_rows(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


class EmbreeIntersector:
    """First-hit and occlusion queries against a fixed triangle soup.

    Parameters
    ----------
    triangles_mm : (m, 3, 3) float
        Triangles, vertices in mm.
    """

    def __init__(self, triangles_mm):
        from embreex.rtcore import EmbreeDevice
        from embreex.rtcore_scene import EmbreeScene

        from straylight.intersect import embree_build

        tri = np.ascontiguousarray(triangles_mm, dtype=np.float64)
        if tri.ndim != 3 or tri.shape[1:] != (3, 3) or len(tri) == 0:
            raise ValueError(f"triangles_mm must be a non-empty (m, 3, 3) array, got {tri.shape}")
        self.n_triangles = len(tri)
        from straylight.budget import check_embree_address_space

        check_embree_address_space(self.n_triangles)  # Embree aborts the process when it runs out
        self._device = EmbreeDevice()
        self._embree = EmbreeScene(self._device)
        self._building = None
        # the same Embree geometry as embreex's TriangleMesh, filled by numpy and its BVH built on a thread
        # without the GIL (straylight.intersect.embree_build), else embreex's way
        if embree_build.add_triangles(self._embree, self._device, tri):
            self._building = threading.Thread(target=embree_build.commit, args=(self._embree, self._device),
                                              name="embree-bvh", daemon=True)
            self._building.start()
        else:
            from embreex.mesh_construction import TriangleMesh

            self._mesh = TriangleMesh(self._embree, tri)  # float64 in: the same float32 vertices (C cast)
        self.planes = triangle_planes(tri)  # (v0, unit normal, centroid) per triangle; the engine reuses them
        self._v0, self._normal, self._centroid = self.planes
        self._min_rays = MIN_RAYS if self.n_triangles >= MIN_TRIANGLES else np.inf  # coherent order pays?

    @property
    def _scene(self):
        """The embreex scene, its BVH built (waits for the build thread the first time)."""
        building = self._building
        if building is not None:
            building.join()
            self._building = None
        return self._embree

    def first_triangle(self, origins, dirs) -> np.ndarray:
        """Index of the first triangle hit (int32, -1 = miss), without the distance. Large calls
        are cast in a coherent order (straylight.intersect.coherence; same answers)."""
        if len(origins) < self._min_rays:
            o32 = np.ascontiguousarray(origins, dtype=np.float32)
            d32 = np.ascontiguousarray(dirs, dtype=np.float32)
            return self._scene.run(o32, d32)
        o32, d32, _, perm = coherent_float32(_float64_rows(origins), _float64_rows(dirs), _NO_EXTRA, CELL_BITS)
        return scatter_back(self._scene.run(o32, d32), perm)

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

    def intersect_triangles(self, origins, dirs) -> np.ndarray:
        """The triangles of :meth:`intersect` (int64, -1 = miss), without their distances."""
        o32 = np.ascontiguousarray(origins, dtype=np.float32)
        d32 = np.ascontiguousarray(dirs, dtype=np.float32)
        return self._scene.run(o32, d32).astype(np.int64)

    def occluded(self, origins, dirs, tmax):
        """True where some triangle lies on the ray at 0 < t < tmax."""
        if len(origins) == 0:
            return np.zeros(0, dtype=bool)
        if len(origins) < self._min_rays:
            o32 = np.ascontiguousarray(origins, dtype=np.float32)
            d32 = np.ascontiguousarray(dirs, dtype=np.float32)
            tm = np.ascontiguousarray(tmax, dtype=np.float32)
            return self._scene.run(o32, d32, dists=tm, query="OCCLUDED") != -1
        o32, d32, tm, perm = coherent_float32(_float64_rows(origins), _float64_rows(dirs), _float64_rows(tmax),
                                              CELL_BITS)
        return scatter_back(self._scene.run(o32, d32, dists=tm, query="OCCLUDED"), perm) != -1
