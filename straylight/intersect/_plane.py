"""Shared float64 plane distance used by both intersectors."""
from __future__ import annotations

import numpy as np


def triangle_planes(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(v0 (m, 3), unit normal (m, 3), centroid (m, 3)) of (m, 3, 3) triangles."""
    tri = np.asarray(triangles, dtype=np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = n / np.where(length > 0, length, 1.0)
    centroid = (tri[:, 0] + tri[:, 1] + tri[:, 2]) / 3.0  # = tri.mean(axis=1) bit for bit (same sum order), 3x faster
    return tri[:, 0].copy(), n, centroid


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
