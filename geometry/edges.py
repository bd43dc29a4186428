"""Sharp edges of a triangle mesh: the edges that diffract (CONTRACTS §6.5).

An edge is *sharp* when the normals of its two faces turn by ``min_turn_deg`` (60 deg) or more
across it and the edge is convex (the solid's wedge there is at most 180 - 60 = 120 deg: a vane's
square rim, a knife edge), or when it borders one face only (the rim of an open sheet). Concave
edges (a vane meeting the wall, seen from the air) are not: light cannot pass outside them.

Each edge carries, per face, the unit vector in the face plane perpendicular to the edge pointing
into the face (``into_face``), which is what a diffraction query needs to tell a ray that passes
the edge in the open from one that passes over the solid (straylight.engine.edge_index), and the
edges that share its end points in the sharp-edge chain (``neighbours``), so that a ray diffracted
at one segment of a tessellated rim is not diffracted again at the next segment.
Vertices are welded by position first (STL files repeat them per triangle).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_TURN_DEG = 60.0  # CONTRACTS §6.5: faces meeting at a dihedral angle of 60 deg or more


@dataclass(frozen=True, eq=False)
class SharpEdges:
    """Sharp edges of one mesh.

    start_mm, end_mm : (E, 3) end points
    into_face : (E, 2, 3) unit vectors in each adjacent face, perpendicular to the edge, pointing
        into the face; the second is zero for an edge with one face
    neighbours : (E, 2) int64 index of a sharp edge sharing the start / end point, -1 if none
    turn_deg : (E,) angle between the two face normals (180 for an edge with one face)
    """

    start_mm: np.ndarray
    end_mm: np.ndarray
    into_face: np.ndarray
    neighbours: np.ndarray
    turn_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.start_mm)


def _weld(vertices_mm: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces re-indexed onto vertices merged by position (1e-9 of the mesh size)."""
    v = np.asarray(vertices_mm, dtype=np.float64)
    size = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    q = np.round(v / max(size * 1e-9, 1e-12)).astype(np.int64)
    _, inverse = np.unique(q, axis=0, return_inverse=True)
    return inverse.ravel()[np.asarray(faces, dtype=np.int64)]


def _into(a, b, c):
    """Unit vector from the edge a-b toward c, perpendicular to the edge (rows)."""
    e = b - a
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    w = c - a
    w = w - np.sum(w * e, axis=1, keepdims=True) * e
    n = np.linalg.norm(w, axis=1, keepdims=True)
    return w / np.where(n > 0, n, 1.0)


def sharp_edges(vertices_mm, faces, min_turn_deg: float = MIN_TURN_DEG) -> SharpEdges:
    """The sharp edges of the mesh (module docstring). Non-manifold edges (3+ faces) are skipped."""
    v = np.asarray(vertices_mm, dtype=np.float64)
    f = _weld(v, faces)
    pos = np.zeros((int(f.max()) + 1, 3))
    pos[f.ravel()] = v[np.asarray(faces, dtype=np.int64).ravel()]
    m = len(f)
    # each face's three edges (a, b) and the vertex opposite (c)
    a = f[:, [0, 1, 2]].ravel()
    b = f[:, [1, 2, 0]].ravel()
    c = f[:, [2, 0, 1]].ravel()
    face = np.repeat(np.arange(m), 3)
    key = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tri = pos[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.where(np.linalg.norm(normal, axis=1, keepdims=True) > 0,
                       np.linalg.norm(normal, axis=1, keepdims=True), 1.0)
    one = counts == 1
    two = counts == 2
    h1 = order[first]  # half-edge of the first face of each unique edge
    h2 = order[np.minimum(first + 1, len(order) - 1)]
    ea, eb = pos[uniq[:, 0]], pos[uniq[:, 1]]
    n1, n2 = normal[face[h1]], normal[face[h2]]
    cos_turn = np.clip(np.sum(n1 * n2, axis=1), -1.0, 1.0)
    turn = np.degrees(np.arccos(cos_turn))
    c1, c2 = pos[c[h1]], pos[c[h2]]
    convex = np.sum((c2 - ea) * n1, axis=1) < 0  # face 2 lies behind face 1's plane
    keep = one | (two & (turn >= min_turn_deg) & convex)
    turn = np.where(one, 180.0, turn)
    idx = np.flatnonzero(keep)
    into = np.zeros((len(idx), 2, 3))
    into[:, 0] = _into(ea[idx], eb[idx], c1[idx])
    has2 = two[idx]
    into[has2, 1] = _into(ea[idx][has2], eb[idx][has2], c2[idx][has2])
    ends = uniq[idx]
    neighbours = _neighbours(ends)
    return SharpEdges(start_mm=ea[idx].copy(), end_mm=eb[idx].copy(), into_face=into, neighbours=neighbours,
                      turn_deg=turn[idx])


def _neighbours(ends: np.ndarray) -> np.ndarray:
    """(E, 2): for each edge's start and end vertex, another sharp edge at that vertex (-1: none)."""
    out = np.full((len(ends), 2), -1, dtype=np.int64)
    at: dict[int, list[int]] = {}  # vertex -> the sharp edges that meet there
    for e, (p, q) in enumerate(ends.tolist()):
        at.setdefault(p, []).append(e)
        at.setdefault(q, []).append(e)
    for e, (p, q) in enumerate(ends.tolist()):
        for slot, vtx in ((0, p), (1, q)):
            others = [o for o in at[vtx] if o != e]
            if others:
                out[e, slot] = others[0]
    return out
