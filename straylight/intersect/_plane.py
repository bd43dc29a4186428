"""Shared float64 plane distance used by both intersectors."""
from __future__ import annotations

import numpy as np


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

    Edge-on hits (|d.n| tiny) fall back to the projection of the centroid on the ray.
    """
    n = normal[tri]
    dn = np.einsum("ij,ij->i", dirs, n)
    num = np.einsum("ij,ij->i", v0[tri] - origins, n)
    edge_on = np.abs(dn) < 1e-12
    t = np.where(edge_on, np.einsum("ij,ij->i", centroid[tri] - origins, dirs), num / np.where(edge_on, 1.0, dn))
    return np.maximum(t, 0.0)
