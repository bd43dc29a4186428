"""Uniform points on mesh triangles (Turk 1990, "Generating random points in triangles", Graphics Gems):
``x = v0 + sqrt(u1) (1 - u2) (v1 - v0) + sqrt(u1) u2 (v2 - v0)``, density 1 / area on each triangle; and the
triangles' areas, to choose among them. Shared by first- and second-vertex sampling, the lens table and the
field cone."""
from __future__ import annotations

import numpy as np


def triangle_points(tri_mm, t, u1, u2) -> np.ndarray:
    """(n, 3) uniform points on triangles ``t`` of ``tri_mm`` (T, 3, 3) from uniforms ``u1``, ``u2`` (n,)."""
    su = np.sqrt(u1)
    b1, b2 = su * (1.0 - u2), su * u2
    v0 = tri_mm[t, 0]
    return v0 + b1[:, None] * (tri_mm[t, 1] - v0) + b2[:, None] * (tri_mm[t, 2] - v0)


def triangle_areas(tri_mm) -> np.ndarray:
    """(T,) areas of the triangles ``tri_mm`` (T, 3, 3), mm^2."""
    return 0.5 * np.linalg.norm(np.cross(tri_mm[:, 1] - tri_mm[:, 0], tri_mm[:, 2] - tri_mm[:, 0]), axis=1)
