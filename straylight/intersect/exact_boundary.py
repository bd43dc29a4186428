"""Hits on analytic plane parts counted against their exact boundary (CONTRACTS §6.4), and on curved
parts inside their clear aperture.

A ``plane`` part (geometry.analytic.Plane: a disk or annulus) is meshed only to find hits, with a
mesh that covers the exact region (outer polygon circumscribed, inner one inscribed). This wrapper
around an intersector (embree or the numpy reference: same interface) refuses the hits that land on
the mesh but outside the exact disk or annulus, and casts those rays on from just past the plane, so
every stage (the walk, next-event shadow rays, first- and second-vertex sampling) sees the exact disk.

A plane is flat, so the hit point on its mesh is on the exact plane: the test ``inner^2 <= rho^2 <=
outer^2`` is exact.

A curved lens or mirror surface (``conic``, ``asphere``) is meshed likewise to cover its clear aperture
(geometry.analytic.covering_rim_radii_mm: its rim ring lies outside the aperture circle). Hits on the
triangles of that rim band (a vertex outside the clear aperture) are refined onto the analytic surface
(``refine_hits``, as the walk refines them, straylight.engine.surface_geometry) and refused where the
refined point is outside the clear aperture, so shadow rays pass where the walk passes (a pass-through).

A refused hit's ray is cast again from ``eps_mm`` past it; a real hit in that gap (a lens facet crossing
an edge ring's plane right behind the ring's refused sliver) is found by casting back over the gap.

Scenes without plane or curved parts do not use the wrapper (same bits as before).
"""
from __future__ import annotations

import numpy as np

from materials.sampling import lazy_njit
from straylight.intersect._plane import plane_distance, plane_distance_numpy

MAX_PASSES = 8  # a ray crosses at most this many refused slivers before its hit is taken as found


class ExactBoundaryIntersector:
    """``inner`` (an intersector over ``triangle_part``'s triangles) with the hits on the plane parts
    ``planes`` ({part index: geometry.analytic.Plane}) outside their exact boundary removed, and those on
    the curved parts' rim bands ``rims`` (:func:`rim_parts`) that refine outside their clear aperture.

    eps_mm : how far past a refused hit the ray starts again (the scene's offset)."""

    def __init__(self, inner, triangle_part, planes: dict, eps_mm: float, rims: dict | None = None):
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
        self._part = np.append(parts.astype(np.int64), -1)  # the part of each triangle, then -1 for a miss
        # the rim band of each curved part (rims: {part index: (surface, triangle indices)}), then -1 for a miss
        self._rim_surfaces = []
        self._rim_or_miss = np.full(len(parts) + 1, -1, dtype=np.int64)
        for k, (p, (surface, triangles)) in enumerate(sorted((rims or {}).items())):
            self._rim_or_miss[np.asarray(triangles, dtype=np.int64)] = k
            self._rim_surfaces.append(surface)

    def __getattr__(self, name):
        """Anything else is the inner intersector's (e.g. embree's ``_scene``, whose first use waits for the
        BVH build: straylight.engine.backends.dask warms workers up with it)."""
        if name == "inner":  # not yet set (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)

    def _refused(self, tri, origins, dirs):
        """(bool per ray: its hit is on a plane part outside the exact boundary, hit distances: the
        plane distance on plane parts, inf elsewhere). One compiled pass, :meth:`_refused_numpy`'s
        operations in its order (the same bits)."""
        tri = np.ascontiguousarray(tri, dtype=np.int64)
        refused = np.zeros(len(tri), dtype=bool)
        t = np.full(len(tri), np.inf)
        if len(tri) == 0:
            return refused, t
        origins = np.ascontiguousarray(origins, np.float64)
        dirs = np.ascontiguousarray(dirs, np.float64)
        # the rim bands' rows (none without curved parts) and facet distances found in the same pass
        # (_refuse_outside_apertures' first steps)
        rim_rows = np.empty(len(tri), np.int64)
        rim_t = np.empty(len(tri))
        n_rim = lazy_njit(_refused_rims_loop, "numpy")(tri, origins, dirs, self._disk_or_miss, self._rim_or_miss,
                                                       self._v0, self._normal, self._centroid, self._centre,
                                                       self._axis, self._r2, refused, t, rim_rows, rim_t)
        if n_rim:
            self._refine_rims(tri, origins, dirs, rim_rows[:n_rim], rim_t[:n_rim], refused, t)
        return refused, t

    def _refused_numpy(self, tri, origins, dirs):
        """:meth:`_refused` in vectorised numpy (the reference it is tested against)."""
        tri = np.asarray(tri, dtype=np.int64)
        disk = self._disk_or_miss[tri]
        on = np.flatnonzero(disk >= 0)
        refused = np.zeros(len(tri), dtype=bool)
        t = np.full(len(tri), np.inf)
        if len(on):
            t_on = plane_distance_numpy(self._v0, self._normal, self._centroid, tri[on], origins[on], dirs[on])
            k = disk[on]
            rel = origins[on] + t_on[:, None] * dirs[on] - self._centre[k]
            along = np.einsum("ij,ij->i", rel, self._axis[k])
            rho2 = np.einsum("ij,ij->i", rel, rel) - along * along
            refused[on] = (rho2 > self._r2[k, 1]) | (rho2 < self._r2[k, 0])
            t[on] = t_on
        self._refuse_outside_apertures(tri, origins, dirs, refused, t)
        return refused, t

    def _refuse_outside_apertures(self, tri, origins, dirs, refused, t):
        """Hits on the rim band of a curved part: refined onto its analytic surface from the facet's plane
        distance (``refine_hits``) and refused where that fails or lands outside the clear aperture (the walk's
        pass-through, straylight.engine.surface_geometry.refine_on_surfaces); ``t`` the facet distance."""
        if not self._rim_surfaces:
            return
        k = self._rim_or_miss[tri]
        on = np.flatnonzero(k >= 0)
        if len(on) == 0:
            return
        o = np.ascontiguousarray(origins[on], dtype=np.float64)
        d = np.ascontiguousarray(dirs[on], dtype=np.float64)
        t_on = plane_distance(self._v0, self._normal, self._centroid, tri[on], o, d)
        t_on = np.where(t_on > 0.0, t_on, 0.0)
        k = k[on]
        for j in np.unique(k):
            g = np.flatnonzero(k == j)
            _t, _n, ok = self._rim_surfaces[j].refine_hits(o[g], d[g], t_on[g])
            refused[on[g]] = ~ok
        t[on] = t_on

    def _refine_rims(self, tri, origins, dirs, on, t_on, refused, t):
        """:meth:`_refuse_outside_apertures` from its rim rows ``on`` and their facet distances ``t_on``
        (:func:`_refused_rims_loop`): each rim band's rows refined and refused as there (the same bits)."""
        o = origins.take(on, axis=0)
        d = dirs.take(on, axis=0)
        k = self._rim_or_miss[tri.take(on)]
        if len(self._rim_surfaces) == 1:
            _t, _n, ok = self._rim_surfaces[0].refine_hits(o, d, t_on)
            refused[on] = ~ok
        else:
            for j in np.unique(k):
                g = np.flatnonzero(k == j)
                _t, _n, ok = self._rim_surfaces[j].refine_hits(o[g], d[g], t_on[g])
                refused[on[g]] = ~ok
        t[on] = t_on

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
            start[rows] += np.maximum(t[rows], 0.0)  # the refused hit
            at = origins[rows] + start[rows, None] * dirs[rows]
            start[rows] += self._eps
            o = origins[rows] + start[rows, None] * dirs[rows]
            again = np.asarray(cast(o, dirs[rows]))
            refused_again, t_again = self._refused(again, o, dirs[rows])
            found = self._in_gap(out[rows], at, o, dirs[rows], cast)
            out[rows] = np.where(found >= 0, found, again)
            refused_again &= found < 0
            t[rows] = t_again
            rows = rows[refused_again]
        return out

    def _in_gap(self, refused_tri, at, o, dirs, cast):
        """Per ray, a real hit between a refused one (at ``at``, on ``refused_tri``) and the cast's restart
        ``o`` (``eps_mm`` on), -1 where none: the restart steps over it (a lens facet crossing a ring's plane
        right behind the ring's refused sliver). Cast back from ``o`` over the gap; the refused part's own
        triangles there are not hits."""
        back = np.asarray(cast(o, -dirs)).astype(np.int64)
        found = np.full(len(o), -1, dtype=np.int64)
        rows = np.flatnonzero((back >= 0) & (self._part[back] != self._part[refused_tri]))
        if len(rows) == 0:
            return found
        tb = plane_distance(self._v0, self._normal, self._centroid, back[rows],
                            np.ascontiguousarray(o[rows]), np.ascontiguousarray(-dirs[rows]))
        rows = rows[(tb >= 0.0) & (tb < self._eps)]
        if len(rows) == 0:
            return found
        refused, _t = self._refused(back[rows], np.ascontiguousarray(at[rows]), np.ascontiguousarray(dirs[rows]))
        found[rows[~refused]] = back[rows[~refused]]
        return found

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


def _refused_rims_loop(tri, origins, dirs, disk_or_miss, rim_or_miss, v0, normal, centroid, centre, axis, r2,
                       refused, t, rim_rows, rim_t):
    """:meth:`ExactBoundaryIntersector._refused_numpy` row by row (``tri`` -1: a miss, the last entry of
    ``disk_or_miss``; the plane distance of straylight.intersect._plane's loop, einsum's dot order), and the
    rows whose triangle is on a curved part's rim band (``rim_or_miss``) listed in ``rim_rows`` in order with
    their facet distances in ``rim_t`` (``np.where(t > 0, t, 0)``); returns how many."""
    n_rim = 0
    for r in range(len(tri)):
        j = tri[r]
        k = disk_or_miss[j]
        rim = rim_or_miss[j]
        if k < 0 and rim < 0:
            continue
        n0, n1, n2 = normal[j, 0], normal[j, 1], normal[j, 2]
        o0, o1, o2 = origins[r, 0], origins[r, 1], origins[r, 2]
        d0, d1, d2 = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        dn = (d0 * n0 + d2 * n2) + d1 * n1
        if abs(dn) < 1e-12:
            c0, c1, c2 = centroid[j, 0] - o0, centroid[j, 1] - o1, centroid[j, 2] - o2
            tp = (c0 * d0 + c2 * d2) + c1 * d1
        else:
            a0, a1, a2 = v0[j, 0] - o0, v0[j, 1] - o1, v0[j, 2] - o2
            tp = ((a0 * n0 + a2 * n2) + a1 * n1) / dn
        tp = tp if (tp > 0.0 or tp != tp) else 0.0
        if rim >= 0:
            rim_rows[n_rim] = r
            rim_t[n_rim] = tp if tp > 0.0 else 0.0
            n_rim += 1
        if k < 0:
            continue
        x0 = (o0 + tp * d0) - centre[k, 0]
        x1 = (o1 + tp * d1) - centre[k, 1]
        x2 = (o2 + tp * d2) - centre[k, 2]
        along = (x0 * axis[k, 0] + x2 * axis[k, 2]) + x1 * axis[k, 1]
        rho2 = ((x0 * x0 + x2 * x2) + x1 * x1) - along * along
        refused[r] = rho2 > r2[k, 1] or rho2 < r2[k, 0]
        t[r] = tp
    return n_rim


def rim_parts(part_surfaces, triangles_mm, triangle_part) -> dict:
    """{part index: (surface, indices of its rim triangles)} of the parts whose analytic surface is curved
    (a ``conic`` or ``asphere`` with a clear aperture, not a plane): the triangles with a vertex outside the
    clear aperture (geometry.analytic.covering_rim_radii_mm puts the mesh's rim ring there)."""
    from geometry.analytic import Plane

    out = {}
    parts = np.asarray(triangle_part)
    for p, surface in enumerate(part_surfaces or ()):
        if surface is None or isinstance(surface, Plane) or not hasattr(surface, "in_aperture"):
            continue
        rows = np.flatnonzero(parts == p)
        if len(rows) == 0:
            continue
        local = surface.to_local(np.asarray(triangles_mm, dtype=np.float64)[rows].reshape(-1, 3))
        outside = ~surface.in_aperture(local).reshape(-1, 3).all(axis=1)
        if outside.any():
            out[p] = (surface, rows[outside])
    return out


def plane_parts(part_surfaces) -> dict:
    """{part index: Plane} of the parts whose analytic surface is a plane."""
    from geometry.analytic import Plane

    return {p: s for p, s in enumerate(part_surfaces or ()) if isinstance(s, Plane)}
