"""Where a ray passes a diffracting edge: the nearest-edge query of edge diffraction.

Two kinds of edge (CONTRACTS §6.5), one id space (mesh segments first, then rims):

- mesh segments (geometry.edges.SharpEdges), in a bounding-volume hierarchy of their boxes grown by
  the band; a ray *passes* segment [A, B] when its closest approach to the line AB falls inside the
  segment, ahead of the ray and before its hit, at a miss distance delta < band, and on the open
  side: seen along the ray, neither face of the edge lies on the ray's side of it (``into_face . m
  <= 0``, m the unit vector from the edge to the ray). A ray over a face is blocked, not diffracted
  (HURB bends the light that gets through, Freniere et al. 1999).
- rims of analytic apertures (a ``plane`` part's ``inner_radius_mm`` and ``outer_radius_mm``): the
  ray crosses the plane ahead of its hit, inside the hole (inner rim) or outside the disk (outer
  rim), less than the band from the circle.

:func:`first_passage` returns, per ray, the first passage along it: edge id, distance along the
ray, the miss distance ``delta_b`` across the edge (seen along the ray), the along-edge extent
``delta_a`` of the HURB ellipse (``inf`` for a straight edge or an outer rim: the 1-D law) and the
unit vector ``b`` across the edge toward the ray (perpendicular to the ray).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from materials.jit_cache import njit

LEAF_SIZE = 4


@dataclass(frozen=True, eq=False)
class EdgeTable:
    """Diffracting edges of a scene (picklable; the kernels take its arrays)."""

    seg_a: np.ndarray  # (E, 3)
    seg_b: np.ndarray  # (E, 3)
    seg_into: np.ndarray  # (E, 2, 3) into-face unit vectors (zero row: no second face)
    seg_nbr: np.ndarray  # (E, 2) int64 neighbouring segment ids in the sharp-edge chain, -1 none
    seg_rc: np.ndarray  # (E,) radius of curvature of the chain at the segment (inf: straight)
    seg_part: np.ndarray  # (E,) int64 part index
    node_lo: np.ndarray  # (N, 3) BVH boxes (grown by the band)
    node_hi: np.ndarray
    node_child: np.ndarray  # (N, 2) int64, -1 for a leaf
    node_range: np.ndarray  # (N, 2) int64 start, count into ``order`` (leaves)
    order: np.ndarray  # (E,) int64
    rim_center: np.ndarray  # (R, 3)
    rim_axis: np.ndarray  # (R, 3) unit
    rim_radius: np.ndarray  # (R,)
    rim_inside: np.ndarray  # (R,) bool: the open side is inside the circle (a hole's rim)
    rim_part: np.ndarray  # (R,) int64
    band_mm: float

    @property
    def n_edges(self) -> int:
        return len(self.seg_a) + len(self.rim_radius)

    def part_of(self, edge: np.ndarray) -> np.ndarray:
        """Part index of each edge id."""
        edge = np.asarray(edge, dtype=np.int64)
        ne = len(self.seg_a)
        seg = np.minimum(edge, max(ne - 1, 0))
        rim = np.maximum(edge - ne, 0)
        out = np.empty(len(edge), dtype=np.int64)
        is_seg = edge < ne
        if ne:
            out[is_seg] = self.seg_part[seg[is_seg]]
        if len(self.rim_radius):
            out[~is_seg] = self.rim_part[rim[~is_seg]]
        return out

    def skip_of(self, edge: np.ndarray) -> np.ndarray:
        """(n, 3) ids a ray just diffracted at ``edge`` must not pass again: the edge and its
        neighbours (a tessellated rim is one edge to the ray); -1 pads."""
        edge = np.asarray(edge, dtype=np.int64)
        out = np.full((len(edge), 3), -1, dtype=np.int64)
        out[:, 0] = edge
        seg = (edge >= 0) & (edge < len(self.seg_a))
        out[seg, 1:] = self.seg_nbr[edge[seg]]
        return out


def chain_curvature_radius(edges, max_turn_deg: float = 30.0) -> np.ndarray:
    """Radius of curvature of the sharp-edge chain at each segment, from the turn of direction to
    its neighbours (a regular polygon of side L turning by phi: R = L / (2 sin(phi / 2))); inf for
    a straight run, an end, or a corner (turn above ``max_turn_deg``)."""
    a, b = edges.start_mm, edges.end_mm
    t = b - a
    length = np.linalg.norm(t, axis=1)
    t = t / np.where(length > 0, length, 1.0)[:, None]
    radii = np.full((len(a), 2), np.inf)
    for slot in range(2):
        nb = edges.neighbours[:, slot]
        ok = nb >= 0
        cosphi = np.abs(np.sum(t[ok] * t[nb[ok]], axis=1)).clip(-1.0, 1.0)
        phi = np.arccos(cosphi)
        mean_len = 0.5 * (length[ok] + length[nb[ok]])
        r = np.where((phi > 1e-9) & (phi <= np.radians(max_turn_deg)), mean_len / (2.0 * np.sin(0.5 * phi)), np.inf)
        radii[ok, slot] = r
    both = np.isfinite(radii).all(axis=1)
    out = np.where(both, radii.mean(axis=1), np.inf)
    return out


def _build_bvh(lo, hi):
    """Median-split BVH over boxes (lo, hi): node arrays and the leaf order."""
    n = len(lo)
    node_lo, node_hi, child, rng = [], [], [], []
    order = np.arange(n, dtype=np.int64)
    centre = 0.5 * (lo + hi)
    stack = [(0, n, -1, 0)]
    while stack:
        start, count, parent, slot = stack.pop()
        ids = order[start:start + count]
        k = len(node_lo)
        node_lo.append(lo[ids].min(axis=0) if count else np.zeros(3))
        node_hi.append(hi[ids].max(axis=0) if count else np.zeros(3))
        child.append([-1, -1])
        rng.append([start, count])
        if parent >= 0:
            child[parent][slot] = k
        if count > LEAF_SIZE:
            axis = int(np.argmax(node_hi[k] - node_lo[k]))
            sub = ids[np.argsort(centre[ids, axis], kind="stable")]
            order[start:start + count] = sub
            half = count // 2
            stack.append((start, half, k, 0))
            stack.append((start + half, count - half, k, 1))
    return (np.array(node_lo, dtype=np.float64).reshape(-1, 3), np.array(node_hi, dtype=np.float64).reshape(-1, 3),
            np.array(child, dtype=np.int64).reshape(-1, 2), np.array(rng, dtype=np.int64).reshape(-1, 2), order)


def edge_table(segments, rims, band_mm: float) -> EdgeTable:
    """Build the table. ``segments``: list of (part index, geometry.edges.SharpEdges);
    ``rims``: list of (part index, centre, unit axis, radius_mm, open inside)."""
    a, b, into, nbr, rc, part = [], [], [], [], [], []
    offset = 0
    for p, e in segments:
        if len(e) == 0:
            continue
        a.append(e.start_mm)
        b.append(e.end_mm)
        into.append(e.into_face)
        nbr.append(np.where(e.neighbours >= 0, e.neighbours + offset, -1))
        rc.append(chain_curvature_radius(e))
        part.append(np.full(len(e), p, dtype=np.int64))
        offset += len(e)
    if a:
        a, b, into = np.concatenate(a), np.concatenate(b), np.concatenate(into)
        nbr, rc, part = np.concatenate(nbr), np.concatenate(rc), np.concatenate(part)
        lo = np.minimum(a, b) - band_mm
        hi = np.maximum(a, b) + band_mm
        node_lo, node_hi, child, rng, order = _build_bvh(lo, hi)
    else:
        a = b = np.zeros((0, 3))
        into = np.zeros((0, 2, 3))
        nbr = np.zeros((0, 2), dtype=np.int64)
        rc = np.zeros(0)
        part = np.zeros(0, dtype=np.int64)
        node_lo = node_hi = np.zeros((0, 3))
        child = rng = np.zeros((0, 2), dtype=np.int64)
        order = np.zeros(0, dtype=np.int64)
    r_c = np.array([r[1] for r in rims], dtype=np.float64).reshape(-1, 3)
    r_a = np.array([r[2] for r in rims], dtype=np.float64).reshape(-1, 3)
    return EdgeTable(seg_a=np.ascontiguousarray(a), seg_b=np.ascontiguousarray(b), seg_into=np.ascontiguousarray(into),
                     seg_nbr=nbr, seg_rc=rc, seg_part=part, node_lo=node_lo, node_hi=node_hi, node_child=child,
                     node_range=rng, order=order, rim_center=r_c, rim_axis=r_a,
                     rim_radius=np.array([r[3] for r in rims], dtype=np.float64),
                     rim_inside=np.array([bool(r[4]) for r in rims], dtype=np.bool_),
                     rim_part=np.array([r[0] for r in rims], dtype=np.int64), band_mm=float(band_mm))


@njit(cache=True, nogil=True)
def _box_hit(o, inv, lo, hi, tmax):
    t0 = 0.0
    t1 = tmax
    for k in range(3):
        ta = (lo[k] - o[k]) * inv[k]
        tb = (hi[k] - o[k]) * inv[k]
        if ta > tb:
            ta, tb = tb, ta
        if math.isnan(ta) or math.isnan(tb):  # 0 * inf: the ray lies in the slab's plane
            if o[k] < lo[k] or o[k] > hi[k]:
                return False
            continue
        t0 = max(t0, ta)
        t1 = min(t1, tb)
        if t0 > t1:
            return False
    return True


@njit(cache=True, nogil=True)
def _segment(o, d, tmax, s, a, b, into, band, out_m):
    """(t, delta) of the ray's passage of segment s, or (-1, 0); writes the unit vector from the
    edge to the ray into out_m."""
    ex, ey, ez = b[s, 0] - a[s, 0], b[s, 1] - a[s, 1], b[s, 2] - a[s, 2]
    length = math.sqrt(ex * ex + ey * ey + ez * ez)
    if length == 0.0:
        return -1.0, 0.0
    ex, ey, ez = ex / length, ey / length, ez / length
    wx, wy, wz = o[0] - a[s, 0], o[1] - a[s, 1], o[2] - a[s, 2]
    bb = d[0] * ex + d[1] * ey + d[2] * ez
    den = 1.0 - bb * bb
    if den < 1e-12:
        return -1.0, 0.0
    dw = d[0] * wx + d[1] * wy + d[2] * wz
    ew = ex * wx + ey * wy + ez * wz
    t = (bb * ew - dw) / den
    u = (ew - bb * dw) / den
    if t <= 0.0 or t >= tmax or u < 0.0 or u > length:
        return -1.0, 0.0
    qx = o[0] + t * d[0] - (a[s, 0] + u * ex)
    qy = o[1] + t * d[1] - (a[s, 1] + u * ey)
    qz = o[2] + t * d[2] - (a[s, 2] + u * ez)
    delta = math.sqrt(qx * qx + qy * qy + qz * qz)
    if delta >= band or delta <= 0.0:
        return -1.0, 0.0
    qx, qy, qz = qx / delta, qy / delta, qz / delta
    for f in range(2):
        if into[s, f, 0] * qx + into[s, f, 1] * qy + into[s, f, 2] * qz > 1e-9:
            return -1.0, 0.0  # the ray passes over this face: blocked, not diffracted
    out_m[0], out_m[1], out_m[2] = qx, qy, qz
    return t, delta


@njit(cache=True, nogil=True)
def first_passage(origin, direction, tmax, hit_part, skip, near, band, seg_a, seg_b, seg_into, seg_rc, node_lo, node_hi,
                  node_child, node_range, order, rim_center, rim_axis, rim_radius, rim_inside, rim_part):
    """Per ray: (edge id or -1, distance along the ray, delta_b, delta_a, b (n, 3)); see the module
    docstring. ``tmax``: the ray's hit distance (inf for a miss); ``hit_part``: the part it hits (-1
    none): a rim's own part does not block the rim's crossing (its mesh only approximates the hole);
    ``skip`` (n, 3): ids to ignore; ``near`` (n,): the ray may pass a segment (else only rims are tested)."""
    n = origin.shape[0]
    ne = seg_a.shape[0]
    edge = np.full(n, -1, np.int64)
    t_out = np.zeros(n)
    db = np.zeros(n)
    da = np.zeros(n)
    bvec = np.zeros((n, 3))
    m = np.zeros(3)
    inv = np.zeros(3)
    stack = np.empty(64, np.int64)
    for i in range(n):
        o = origin[i]
        d = direction[i]
        best = tmax[i]
        for k in range(3):
            inv[k] = 1.0 / d[k] if d[k] != 0.0 else np.inf
        if ne > 0 and near[i]:
            stack[0] = 0
            top = 1
            while top > 0:
                top -= 1
                node = stack[top]
                if not _box_hit(o, inv, node_lo[node], node_hi[node], best):
                    continue
                if node_child[node, 0] < 0:
                    start, count = node_range[node, 0], node_range[node, 1]
                    for j in range(start, start + count):
                        s = order[j]
                        if s == skip[i, 0] or s == skip[i, 1] or s == skip[i, 2]:
                            continue
                        t, delta = _segment(o, d, best, s, seg_a, seg_b, seg_into, band, m)
                        if t > 0.0:
                            best = t
                            edge[i] = s
                            t_out[i] = t
                            db[i] = delta
                            da[i] = math.sqrt(delta * seg_rc[s]) if seg_rc[s] < np.inf else np.inf
                            bvec[i, 0], bvec[i, 1], bvec[i, 2] = m[0], m[1], m[2]
                else:
                    stack[top] = node_child[node, 0]
                    stack[top + 1] = node_child[node, 1]
                    top += 2
        for r in range(rim_radius.shape[0]):
            rid = ne + r
            if rid == skip[i, 0]:
                continue
            ax = rim_axis[r]
            cos_d = d[0] * ax[0] + d[1] * ax[1] + d[2] * ax[2]
            if abs(cos_d) < 1e-12:
                continue
            c = rim_center[r]
            t = ((c[0] - o[0]) * ax[0] + (c[1] - o[1]) * ax[1] + (c[2] - o[2]) * ax[2]) / cos_d
            limit = best
            if hit_part[i] == rim_part[r] and best == tmax[i]:
                limit = tmax[i] * (1.0 + 1e-9) + 1e-9  # the crossing is the mesh hit itself
            if t <= 0.0 or t >= limit:
                continue
            px = o[0] + t * d[0] - c[0]
            py = o[1] + t * d[1] - c[1]
            pz = o[2] + t * d[2] - c[2]
            rho = math.sqrt(px * px + py * py + pz * pz)  # in the plane: the point is on it
            radius = rim_radius[r]
            dist = radius - rho if rim_inside[r] else rho - radius
            if dist <= 0.0 or dist >= band or rho == 0.0:
                continue
            sgn = -1.0 if rim_inside[r] else 1.0  # from the rim toward the ray, in the plane
            bx, by, bz = sgn * px / rho, sgn * py / rho, sgn * pz / rho
            bd = bx * d[0] + by * d[1] + bz * d[2]
            cos_b = math.sqrt(max(1.0 - bd * bd, 0.0))
            if cos_b < 1e-9:
                continue
            # b' = b made perpendicular to the ray; the ray sees the miss distance shortened by cos_b
            qx, qy, qz = bx - bd * d[0], by - bd * d[1], bz - bd * d[2]
            best = t
            edge[i] = rid
            t_out[i] = t
            db[i] = dist * cos_b
            if rim_inside[r]:
                # tangent direction of the rim at the point: axis x radial
                tx = ax[1] * pz - ax[2] * py
                ty = ax[2] * px - ax[0] * pz
                tz = ax[0] * py - ax[1] * px
                td = (tx * d[0] + ty * d[1] + tz * d[2]) / rho
                da[i] = math.sqrt(dist * radius) * math.sqrt(max(1.0 - td * td, 0.0))
            else:
                da[i] = np.inf
            bvec[i, 0], bvec[i, 1], bvec[i, 2] = qx / cos_b, qy / cos_b, qz / cos_b
    return edge, t_out, db, da, bvec


def passages(table: EdgeTable, origin, direction, tmax, skip=None, hit_part=None, near=None):
    """:func:`first_passage` on the table's arrays (``near``: see :func:`band_prisms`; None: every ray)."""
    n = len(origin)
    if near is None:
        near = np.ones(n, dtype=np.bool_)
    if skip is None:
        skip = np.full((n, 3), -1, dtype=np.int64)
    if hit_part is None:
        hit_part = np.full(n, -1, dtype=np.int64)
    return first_passage(np.ascontiguousarray(origin, dtype=np.float64), np.ascontiguousarray(direction, dtype=np.float64),
                         np.ascontiguousarray(tmax, dtype=np.float64), np.ascontiguousarray(hit_part, dtype=np.int64),
                         np.ascontiguousarray(skip, dtype=np.int64), np.ascontiguousarray(near, dtype=np.bool_),
                         float(table.band_mm), table.seg_a, table.seg_b, table.seg_into, table.seg_rc, table.node_lo,
                         table.node_hi, table.node_child, table.node_range, table.order, table.rim_center,
                         table.rim_axis, table.rim_radius, table.rim_inside, table.rim_part)


def band_prisms(table: EdgeTable, margin: float = 1.5) -> np.ndarray:
    """(8 E, 3, 3) triangles: around each segment a closed triangular prism whose inscribed radius is
    ``margin`` x the band, extended by the band past both ends. A ray that passes a segment closer
    than the band crosses its prism's surface (or starts inside it), so one embree occlusion query
    against these prisms finds the few rays that need :func:`first_passage`'s segment search."""
    a, b = table.seg_a, table.seg_b
    if len(a) == 0:
        return np.zeros((0, 3, 3))
    r = float(table.band_mm)
    e = b - a
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    helper = np.where(np.abs(e[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    u = np.cross(e, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(e, u)
    circ = 2.0 * margin * r  # circumradius of an equilateral triangle of inradius margin * r
    ang = np.radians([90.0, 210.0, 330.0])
    lo = a - r * e
    hi = b + r * e
    ring = [circ * (np.cos(t) * u + np.sin(t) * v) for t in ang]
    p = [lo + q for q in ring] + [hi + q for q in ring]  # p0..p2 bottom, p3..p5 top
    faces = [(0, 1, 2), (3, 5, 4), (0, 3, 1), (1, 3, 4), (1, 4, 2), (2, 4, 5), (2, 5, 0), (0, 5, 3)]
    return np.stack([np.stack([p[i], p[j], p[k]], axis=1) for i, j, k in faces], axis=1).reshape(-1, 3, 3)
