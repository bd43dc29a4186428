"""Hits on analytic plane parts counted against their exact boundary (CONTRACTS §6.4).

A ``plane`` part (geometry.analytic.Plane: a disk or annulus) is meshed only to find hits, with a
mesh that covers the exact region (outer polygon circumscribed, inner one inscribed). This wrapper
around an intersector (embree or the numpy reference: same interface) refuses the hits that land on
the mesh but outside the exact disk or annulus, and casts those rays on from just past the plane, so
every stage (the walk, next-event shadow rays, first- and second-vertex sampling) sees the exact disk.

A plane is flat, so the hit point on its mesh is on the exact plane: the test ``inner^2 <= rho^2 <=
outer^2`` is exact. Scenes without plane parts do not use the wrapper (same bits as before).
"""
from __future__ import annotations

import numpy as np

from straylight.intersect._plane import plane_distance

MAX_PASSES = 8  # a ray crosses at most this many refused slivers before its hit is taken as found


class ExactBoundaryIntersector:
    """``inner`` (an intersector over ``triangle_part``'s triangles) with the hits on the plane parts
    ``planes`` ({part index: geometry.analytic.Plane}) outside their exact boundary removed.

    eps_mm : how far past a refused hit the ray starts again (the scene's offset)."""

    def __init__(self, inner, triangle_part, planes: dict, eps_mm: float):
        self.inner = inner
        self.planes = inner.planes  # the engine reuses the triangle planes
        self.n_triangles = inner.n_triangles
        self._v0, self._normal, self._centroid = inner.planes
        parts = np.asarray(triangle_part)
        self._disk_of_triangle = np.full(len(parts), -1, dtype=np.int64)
        self._disks = []
        for k, (p, plane) in enumerate(sorted(planes.items())):
            self._disk_of_triangle[parts == p] = k
            self._disks.append(plane)
        # the disk of each triangle, then -1 for a miss (tri = -1 reads the last entry)
        self._disk_or_miss = np.append(self._disk_of_triangle, -1)
        self._centre = np.array([d.vertex_mm for d in self._disks]).reshape(-1, 3)
        self._axis = np.array([d.axis for d in self._disks]).reshape(-1, 3)
        self._r2 = np.array([[d.inner_radius_mm ** 2, d.outer_radius_mm ** 2] for d in self._disks]).reshape(-1, 2)
        self._eps = float(eps_mm)

    def __getattr__(self, name):
        """Anything else is the inner intersector's (e.g. embree's ``_scene``, whose first use waits for the
        BVH build: straylight.engine.backends.dask warms workers up with it)."""
        if name == "inner":  # not yet set (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)

    def _refused(self, tri, origins, dirs):
        """(bool per ray: its hit is on a plane part outside the exact boundary, hit distances)."""
        tri = np.asarray(tri, dtype=np.int64)
        disk = self._disk_or_miss[tri]
        on = np.flatnonzero(disk >= 0)
        refused = np.zeros(len(tri), dtype=bool)
        t = np.full(len(tri), np.inf)
        if len(on) == 0:
            return refused, t
        t_on = plane_distance(self._v0, self._normal, self._centroid, tri[on], origins[on], dirs[on])
        k = disk[on]
        rel = origins[on] + t_on[:, None] * dirs[on] - self._centre[k]
        along = np.einsum("ij,ij->i", rel, self._axis[k])
        rho2 = np.einsum("ij,ij->i", rel, rel) - along * along
        refused[on] = (rho2 > self._r2[k, 1]) | (rho2 < self._r2[k, 0])
        t[on] = t_on
        return refused, t

    def _first(self, origins, dirs, cast):
        """First triangle per ray whose hit is a real one (``cast``: the inner first-triangle query)."""
        tri = np.asarray(cast(origins, dirs))
        out = tri.copy()
        refused, t = self._refused(tri, origins, dirs)
        rows = np.flatnonzero(refused)
        start = np.zeros(len(tri))  # distance from the ray's own origin to where the current cast starts
        for _ in range(MAX_PASSES):
            if len(rows) == 0:
                break
            start[rows] += np.maximum(t[rows], 0.0) + self._eps
            o = origins[rows] + start[rows, None] * dirs[rows]
            again = np.asarray(cast(o, dirs[rows]))
            out[rows] = again
            refused_again, t_again = self._refused(again, o, dirs[rows])
            t[rows] = t_again
            rows = rows[refused_again]
        return out

    def first_triangle(self, origins, dirs) -> np.ndarray:
        origins = np.asarray(origins, dtype=np.float64)
        dirs = np.asarray(dirs, dtype=np.float64)
        return self._first(origins, dirs, self.inner.first_triangle)

    def intersect(self, origins, dirs):
        """(tri int64, t float64) of the first real hit, t from the given origins."""
        origins = np.asarray(origins, dtype=np.float64)
        dirs = np.asarray(dirs, dtype=np.float64)
        tri = self._first(origins, dirs, self.inner.first_triangle).astype(np.int64)
        t = np.full(len(tri), np.inf)
        hit = tri >= 0
        if hit.any():
            t[hit] = plane_distance(self._v0, self._normal, self._centroid, tri[hit], origins[hit], dirs[hit])
        return tri, t

    def intersect_triangles(self, origins, dirs) -> np.ndarray:
        """The triangles of :meth:`intersect` (int64, -1 = miss), without their distances."""
        origins = np.asarray(origins, dtype=np.float64)
        dirs = np.asarray(dirs, dtype=np.float64)
        return self._first(origins, dirs, self.inner.first_triangle).astype(np.int64)

    def occluded(self, origins, dirs, tmax):
        """True where a real hit lies on the ray at 0 < t < tmax: the rays the inner query finds occluded
        are cast again, and a refused sliver does not block."""
        blocked = np.asarray(self.inner.occluded(origins, dirs, tmax), dtype=bool)
        rows = np.flatnonzero(blocked)
        if len(rows) == 0:
            return blocked
        o = np.asarray(origins, dtype=np.float64)[rows]
        d = np.asarray(dirs, dtype=np.float64)[rows]
        tri, t = self.intersect(o, d)
        out = blocked.copy()
        out[rows] = (tri >= 0) & (t < np.asarray(tmax, dtype=np.float64)[rows])
        return out


def plane_parts(part_surfaces) -> dict:
    """{part index: Plane} of the parts whose analytic surface is a plane."""
    from geometry.analytic import Plane

    return {p: s for p, s in enumerate(part_surfaces or ()) if isinstance(s, Plane)}
