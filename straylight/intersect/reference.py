"""Exact numpy ray-triangle intersection (Moller-Trumbore, float64), slow.

For tests and small scenes: every ray is tested against every triangle (in blocks).
Same interface as :class:`straylight.intersect.embree.EmbreeIntersector`.
"""
from __future__ import annotations

import numpy as np

from straylight.intersect._plane import plane_distance, triangle_planes


class ReferenceIntersector:
    """Brute-force intersection. triangles_mm : (m, 3, 3) float."""

    def __init__(self, triangles_mm, block: int = 2_000_000):
        tri = np.ascontiguousarray(triangles_mm, dtype=np.float64)
        if tri.ndim != 3 or tri.shape[1:] != (3, 3) or len(tri) == 0:
            raise ValueError(f"triangles_mm must be a non-empty (m, 3, 3) array, got {tri.shape}")
        self.n_triangles = len(tri)
        self._a = tri[:, 0]
        self._e1 = tri[:, 1] - tri[:, 0]
        self._e2 = tri[:, 2] - tri[:, 0]
        self._block = block
        self.planes = triangle_planes(tri)  # (v0, unit normal, centroid) per triangle; the engine reuses them
        self._v0, self._normal, self._centroid = self.planes

    def _all_t(self, o, d):
        """(n, m) hit distance, inf where the ray misses the triangle (Moller & Trumbore 1997)."""
        p = np.cross(d[:, None, :], self._e2[None])
        det = np.einsum("nmk,mk->nm", p, self._e1)
        ok = np.abs(det) > 1e-300
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o[:, None, :] - self._a[None]
        u = np.einsum("nmk,nmk->nm", s, p) * inv
        q = np.cross(s, self._e1[None])
        v = np.einsum("nk,nmk->nm", d, q) * inv
        t = np.einsum("mk,nmk->nm", self._e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        return np.where(hit, t, np.inf)

    def _rows(self, n):
        step = max(1, self._block // self.n_triangles)
        return [(i, min(i + step, n)) for i in range(0, n, step)]

    def intersect(self, origins, dirs):
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(dirs, dtype=np.float64)
        tri = np.full(len(o), -1, dtype=np.int64)
        for a, b in self._rows(len(o)):
            t = self._all_t(o[a:b], d[a:b])
            best = np.argmin(t, axis=1)
            hit = np.isfinite(t[np.arange(b - a), best])
            tri[a:b] = np.where(hit, best, -1)
        t = np.full(len(o), np.inf)
        hit = tri >= 0
        if hit.any():
            t[hit] = plane_distance(self._v0, self._normal, self._centroid, tri[hit], o[hit], d[hit])
        return tri, t

    def first_triangle(self, origins, dirs) -> np.ndarray:
        return self.intersect(origins, dirs)[0].astype(np.int32)

    def occluded(self, origins, dirs, tmax):
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(dirs, dtype=np.float64)
        out = np.zeros(len(o), dtype=bool)
        for a, b in self._rows(len(o)):
            t = self._all_t(o[a:b], d[a:b])
            out[a:b] = (t < np.asarray(tmax, dtype=np.float64)[a:b, None]).any(axis=1)
        return out
