"""Shared float64 plane distance used by both intersectors."""
from __future__ import annotations

import numpy as np

from materials.sampling import lazy_njit


PLANE_BLOCK = 16384  # triangles per block of triangle_planes: its temporaries stay in the CPU cache


def triangle_planes(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(v0 (m, 3), unit normal (m, 3), centroid (m, 3)) of (m, 3, 3) triangles.

    The same numbers as ``n = np.cross(e1, e2); n / np.linalg.norm(n, axis=1, keepdims=True)`` and
    ``tri.mean(axis=1)`` bit for bit (tests/straylight/test_plane.py): the same products and sums
    in the same order (np.cross's ``a1 b2 - a2 b1``, ...; the norm's ``(x0^2 + x1^2) + x2^2``;
    ``(p0 + p1) + p2``), written out on blocks of :data:`PLANE_BLOCK` triangles, ~2x faster
    (0.36M triangles: 0.10-0.24 -> 0.05 s, part of every worker's start-up)."""
    tri = np.asarray(triangles, dtype=np.float64)
    m = len(tri)
    v0 = tri[:, 0].copy()
    normal = np.empty((m, 3))
    centroid = np.empty((m, 3))
    for a in range(0, m, PLANE_BLOCK):
        t = tri[a:a + PLANE_BLOCK]
        e1 = t[:, 1] - t[:, 0]
        e2 = t[:, 2] - t[:, 0]
        n = normal[a:a + PLANE_BLOCK]
        n[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        n[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        n[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        length = np.sqrt(n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2])
        n /= np.where(length > 0, length, 1.0)[:, None]
        np.divide(t[:, 0] + t[:, 1] + t[:, 2], 3.0, out=centroid[a:a + PLANE_BLOCK])
    return v0, normal, centroid


def plane_distance(v0, normal, centroid, tri, origins, dirs) -> np.ndarray:
    """Distance along ``dirs`` from ``origins`` to the plane of triangle ``tri`` (float64).

    Edge-on hits (|d.n| tiny) fall back to the projection of the centroid on the ray. One compiled
    pass, :func:`plane_distance_numpy`'s operations in its order (the same bits)."""
    tri = np.ascontiguousarray(tri, dtype=np.int64)
    out = np.empty(len(tri))
    if len(tri):
        lazy_njit(_plane_distance_loop, "numpy")(v0, normal, centroid, tri, np.ascontiguousarray(origins, np.float64),
                                                 np.ascontiguousarray(dirs, np.float64), out)
    return out


def _plane_distance_loop(v0, normal, centroid, tri, origins, dirs, out):
    """:func:`plane_distance_numpy` row by row: einsum's dot order ``(a0 b0 + a2 b2) + a1 b1``,
    ``np.maximum(t, 0)`` (NaN kept, -0 to +0)."""
    for r in range(len(tri)):
        k = tri[r]
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        o0, o1, o2 = origins[r, 0], origins[r, 1], origins[r, 2]
        d0, d1, d2 = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        dn = (d0 * n0 + d2 * n2) + d1 * n1
        if abs(dn) < 1e-12:
            c0, c1, c2 = centroid[k, 0] - o0, centroid[k, 1] - o1, centroid[k, 2] - o2
            t = (c0 * d0 + c2 * d2) + c1 * d1
        else:
            a0, a1, a2 = v0[k, 0] - o0, v0[k, 1] - o1, v0[k, 2] - o2
            t = ((a0 * n0 + a2 * n2) + a1 * n1) / dn
        out[r] = t if (t > 0.0 or t != t) else 0.0  # np.maximum(t, 0.0): +0 for -0


def plane_distance_numpy(v0, normal, centroid, tri, origins, dirs) -> np.ndarray:
    """:func:`plane_distance` in vectorised numpy (the reference it is tested against)."""
    n = normal[tri]
    dn = np.einsum("ij,ij->i", dirs, n)
    num = np.einsum("ij,ij->i", v0[tri] - origins, n)
    edge_on = np.abs(dn) < 1e-12
    t = np.where(edge_on, np.einsum("ij,ij->i", centroid[tri] - origins, dirs), num / np.where(edge_on, 1.0, dn))
    return np.maximum(t, 0.0)
