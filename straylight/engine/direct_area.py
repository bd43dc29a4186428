"""The unscattered light, exactly: where a collimated beam reaches the detector straight, by 2-D clipping.

Near a baffle's geometric cut-off the beam reaches the detector only through a thin sliver: on the built-in
tube at 14 deg, 8e-6 of the source's rays (1.4e-5 of the detector's area) reach it without touching
anything, and that light is 17 % of the detector's power. The walk meets the sliver once in ~1e5 rays, each
such ray carrying ~1e4 times the mean: a run of 6e4 rays (seed 1) stopped at 6.32e-5 +- 1.1 % where the
point is 7.6e-5, and the study's sweep spent 2e6 rays there without reaching 2 % (VOV 0.5). No random
sampling of the source or of the detector finds such a region (it is as thin on both).

**What is computed.** For one ``collimated_disk`` source (direction d, radius r, power Phi) and one flat
detector made of mesh triangles, everything is projected along d onto a plane normal to it. The light that
reaches the detector straight lands on

    A = proj(detector) ∩ proj(source disk) \\ ∪ proj(triangles between the detector's plane and the source's)

(each triangle clipped to the slab between the two planes first: a triangle behind the detector or beyond
the source blocks nothing), and its power is P = Phi / (pi r^2 |d . n_src|) x area(A): the irradiance normal
to the beam times the projected area. The polygons are united, intersected and measured by Clipper2
(manifold3d's ``CrossSection``, exact to its 1e-8 precision), on the same triangles embree intersects, so A is
exactly the set of points whose ray's first triangle is the detector's: P is the expectation of the walk's
hits on the detector at its first event.

**How it enters the estimate.** Each ray of the trace adds P / N (N the trace's rays) to the detector's
tally (``detector_nee``, taken from the ``escaped`` row: the ledger stays exact), and the walk's own hits on
the detector at the first event are dropped (their weight moved to that same row; the escaped power stays an
unbiased estimate, as entrance sampling keeps it). Both sides' expectations are P, so the estimate stays unbiased; a constant added to every ray changes
no per-ray variance, so the rare heavy direct hits are gone from the error and nothing is added to it. Each
ray's share is recorded at a point drawn uniformly in A (the irradiance is uniform there), on a stream of
its own keyed by seed and chunk, so the irradiance map and the path records ("source -> detector") keep
their meaning and no other strategy's random numbers move.

**When it runs** (:func:`unsupported`, :func:`build`): one ``collimated_disk`` source, one detector part
whose triangles lie in one plane, analytic surfaces that are planes or cylinders only (an exact plane, detector
or aperture, counts with its exact disk or annulus, as the walk does; a cylinder, a tube's wall, with a prism of
4096 sides of the circle's area; a lens or mirror surface is not its triangles), no diffraction (the plan's rule for a strategy that does not see the edges); and only where A is not empty
(:class:`Declined` otherwise: every number as without it). A side the trace does not count
(``detector_sides = "front"`` with the beam on the back) is not lit.
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from straylight.engine.ray_batch import EVENT_DETECTOR
from straylight.engine.roles import ROLE_DETECTOR
from straylight.paths import mix_key
from straylight.rng import CHUNK_RAYS
from straylight.sources import CollimatedDisk

#: entropy word of the streams that place each ray's share in the lit region ("DRCT")
STREAM = 0x44524354
#: sides of the polygons that stand for circles (the source's disk, an exact plane's disk or annulus, an exact
#: cylinder's cross-section), each of the circle's own area (:func:`_ring`)
DISK_SIDES = 4096
#: cells per side of the raster of the lit region that culls the occluding triangles
RASTER_CELLS = 256
#: the analytic surfaces it follows: a plane by its exact disk or annulus, a cylinder (a tube's wall) by a prism of
#: DISK_SIDES sides whose cross-section has the circle's area (its silhouette within ~1e-7 of the radius)
EXACT_KINDS = ("plane", "cylinder")
#: occluding triangles united and cut from the lit region at a time (nearest the detector first: build)
OCCLUDER_BATCH = 2_000
#: coplanarity of the detector's triangles: normals parallel to within this (1 - |cos|), vertices within
#: FLAT_OFFSET of the detector's size off its plane
FLAT_TOLERANCE = 1e-9
FLAT_OFFSET = 1e-6


@dataclass(frozen=True, eq=False)
class DirectArea:
    """The lit region A of the detector (module doc): its power ``power_w`` (W), the detector's index
    ``detector`` (among the scene's detectors) and part ``part``, and A as triangles on the detector's plane
    (``triangles_mm``, (m, 3, 3)) with their cumulative area fractions ``cdf`` for placing the records."""

    power_w: float
    detector: int
    part: int
    triangles_mm: np.ndarray
    cdf: np.ndarray


@dataclass(frozen=True)
class Declined:
    """No part of the detector sees the beam straight (or its side is not counted): the plan turns the
    strategy off with :attr:`reason`."""

    reason: str


def unsupported(spec) -> str | None:
    """Why the strategy cannot run on ``spec`` (None when it can), in one line."""
    if len(spec.sources) != 1 or not isinstance(spec.sources[0], CollimatedDisk):
        return "it computes the light of exactly one collimated_disk source"
    if int(np.count_nonzero(np.asarray(spec.part_roles) == ROLE_DETECTOR)) != 1:
        return "it needs exactly one detector part"
    curved = [name for name, srf in zip(spec.part_names, spec.part_surfaces or ()) if srf is not None
              and getattr(srf, "kind", "") not in EXACT_KINDS]
    if curved:
        return (f"the scene has curved analytic surfaces ({', '.join(curved[:3])}{', ...' if len(curved) > 3 else ''}), "
                "which the 2-D clip of the parts' outlines does not follow")
    return None


def _basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors normal to ``d`` and to each other (the projection plane's axes)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def _ring(center, axis, radius_mm: float) -> np.ndarray:
    """(:data:`DISK_SIDES`, 3) points of the circle of ``radius_mm`` about ``center`` in the plane normal to
    ``axis``: a polygon of the circle's own area (radius scaled by sqrt(theta / sin theta), theta = 2 pi / n)."""
    t, b = _basis(np.asarray(axis, dtype=np.float64))
    phi = np.linspace(0.0, 2.0 * math.pi, DISK_SIDES, endpoint=False)
    theta = 2.0 * math.pi / DISK_SIDES
    r = float(radius_mm) * math.sqrt(theta / math.sin(theta))
    return np.asarray(center, dtype=np.float64) + r * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b)


def _plane_rings(srf) -> list[np.ndarray]:
    """The exact disk or annulus of an analytic plane (geometry.analytic.Plane: the walk counts hits inside it
    only) as rings (:func:`_ring`), outer first."""
    return [_ring(srf.vertex_mm, srf.axis, r) for r in (srf.outer_radius_mm, srf.inner_radius_mm) if r > 0.0]


def _cylinder_triangles(srf) -> np.ndarray:
    """(2 n, 3, 3) world triangles of an analytic cylinder's side (geometry.analytic.Cylinder, 0 <= z <= length
    along its axis) as a prism on two rings (:func:`_ring`): the walk meets the exact cylinder, which its own
    coarser mesh only finds."""
    axis = np.asarray(srf.axis, dtype=np.float64)
    lo = _ring(srf.vertex_mm, axis, srf.radius_mm)
    hi = lo + float(srf.length_mm) * axis
    lo_next, hi_next = np.roll(lo, -1, axis=0), np.roll(hi, -1, axis=0)
    return np.concatenate([np.stack([lo, lo_next, hi_next], axis=1), np.stack([lo, hi_next, hi], axis=1)])


def _signed_areas(tri2: np.ndarray) -> np.ndarray:
    """Twice the signed areas of 2-D triangles (m, 3, 2): > 0 counter-clockwise."""
    a, b = tri2[:, 1] - tri2[:, 0], tri2[:, 2] - tri2[:, 0]
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _raster(contours, lo, hi, g: int) -> np.ndarray:
    """(g, g) bool: the cells (x index first) of the box ``lo``..``hi`` whose centre lies inside the polygons
    ``contours`` (even-odd: a centre is inside when an odd number of edges cross its row to its left) or that an
    edge crosses, grown by one cell all round: every cell the polygons reach is marked (a box that covers none
    cannot overlap them)."""
    a = np.concatenate([np.asarray(c, dtype=np.float64) for c in contours])
    b = np.concatenate([np.roll(np.asarray(c, dtype=np.float64), -1, axis=0) for c in contours])
    step = (hi - lo) / g
    ys = lo[1] + (np.arange(g) + 0.5) * step[1]
    e, r = np.nonzero((a[:, 1, None] > ys[None, :]) != (b[:, 1, None] > ys[None, :]))
    x = a[e, 0] + (ys[r] - a[e, 1]) * (b[e, 0] - a[e, 0]) / (b[e, 1] - a[e, 1])
    first = np.clip(np.ceil((x - lo[0]) / step[0] - 0.5), 0, g).astype(np.int64)  # first centre right of x
    counts = np.zeros((g + 1, g), dtype=np.int64)
    np.add.at(counts, (first, r), 1)
    mask = (np.cumsum(counts, axis=0)[:g] % 2) == 1
    # and every cell an edge passes through: a part of the polygons thinner than a cell (the tip of a lens-shaped
    # region) holds no cell's centre, and a triangle over it alone must not be culled (points along each edge
    # every quarter cell, their cells marked, then grown by one)
    length = np.linalg.norm(b - a, axis=1)
    k = np.ceil(length / (0.25 * float(step.min()))).astype(np.int64) + 1
    t = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    pts = np.repeat(a, k, axis=0) + (np.repeat(b - a, k, axis=0) * (t / np.repeat(np.maximum(k - 1, 1), k))[:, None])
    cell = np.clip(np.floor((pts - lo) / step).astype(np.int64), 0, g - 1)
    mask[cell[:, 0], cell[:, 1]] = True
    grown = mask.copy()
    grown[1:] |= mask[:-1]
    grown[:-1] |= mask[1:]
    grown2 = grown.copy()
    grown2[:, 1:] |= grown[:, :-1]
    grown2[:, :-1] |= grown[:, 1:]
    return grown2


class _Cells:
    """A raster of a region (:func:`_raster` over the box ``lo``..``hi``) with its summed-area table: which
    boxes cover one of its cells (:meth:`touching`)."""

    def __init__(self, contours, lo, hi, g: int):
        self.lo, self.hi, self.g = lo, hi, g
        mask = _raster(contours, lo, hi, g)
        self.cells = int(np.count_nonzero(mask))
        self.table = np.zeros((g + 1, g + 1), dtype=np.int64)
        self.table[1:, 1:] = np.cumsum(np.cumsum(mask, axis=0), axis=1)

    def touching(self, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
        """Bool per box (rows of ``box_lo``, ``box_hi``): whether it covers a cell of the raster."""
        g, lo, hi = self.g, self.lo, self.hi
        step = (hi - lo) / g
        i0 = np.clip(np.floor((box_lo - lo) / step).astype(np.int64), 0, g - 1)
        i1 = np.clip(np.floor((box_hi - lo) / step).astype(np.int64), 0, g - 1)
        outside = (box_hi[:, 0] < lo[0]) | (box_lo[:, 0] > hi[0]) | (box_hi[:, 1] < lo[1]) | (box_lo[:, 1] > hi[1])
        t = self.table
        count = t[i1[:, 0] + 1, i1[:, 1] + 1] - t[i0[:, 0], i1[:, 1] + 1] - t[i1[:, 0] + 1, i0[:, 1]] + t[i0[:, 0], i0[:, 1]]
        return (count > 0) & ~outside


def _clip(poly: np.ndarray, n: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The part of the convex polygon ``poly`` (k, 3) where (x - c) . n >= 0 (Sutherland-Hodgman, one plane)."""
    out = []
    k = len(poly)
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        da, db = float((a - c) @ n), float((b - c) @ n)
        if da >= 0.0:
            out.append(a)
        if (da >= 0.0) != (db >= 0.0):
            out.append(a + (b - a) * (da / (da - db)))
    return np.array(out) if out else np.zeros((0, 3))


def build(spec) -> DirectArea | Declined:
    """The lit region and its power for ``spec`` (module doc)."""
    from manifold3d import CrossSection, FillRule, triangulate

    src = spec.sources[0]
    d = np.asarray(src.direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    roles = np.asarray(spec.part_roles)
    det_part = int(np.flatnonzero(roles == ROLE_DETECTOR)[0])
    tri = np.asarray(spec.triangles_mm, dtype=np.float64)
    part = np.asarray(spec.triangle_part)
    surfaces = tuple(spec.part_surfaces or ()) + (None,) * (len(spec.part_names) - len(spec.part_surfaces or ()))
    planes = [i for i, srf in enumerate(surfaces) if getattr(srf, "kind", "") == "plane"]
    cylinders = [i for i, srf in enumerate(surfaces) if getattr(srf, "kind", "") == "cylinder"]
    det_plane = surfaces[det_part]
    dt = tri[part == det_part]
    normal = np.cross(dt[:, 1] - dt[:, 0], dt[:, 2] - dt[:, 0])
    size = np.linalg.norm(normal, axis=1)
    dt, normal = dt[size > 0], normal[size > 0] / size[size > 0, None]
    if len(dt) == 0:
        return Declined("the detector part has no triangle of non-zero area")
    n0, c0 = normal[0], dt[0, 0]
    extent = float(np.ptp(dt.reshape(-1, 3), axis=0).max()) or 1.0
    if np.min(np.abs(normal @ n0)) < 1.0 - FLAT_TOLERANCE or \
            np.max(np.abs((dt.reshape(-1, 3) - c0) @ n0)) > FLAT_OFFSET * extent:
        return Declined("the detector is not one flat face")
    cos_det = float(n0 @ d)
    if abs(cos_det) < 1e-12:
        return Declined("the beam runs along the detector's plane")
    if cos_det > 0 and spec.options.output.detector_sides == "front":
        return Declined("the beam reaches the detector's back, which this trace does not count")
    toward_source = -n0 if cos_det > 0 else n0  # the detector's side the beam comes from
    src_normal = np.asarray(src.normal, dtype=np.float64)
    beam_side = src_normal if float(src_normal @ d) > 0 else -src_normal  # from the source's plane, the beam's way
    center = np.asarray(src.center_mm, dtype=np.float64)
    e1, e2 = _basis(d)

    def project(x):
        return np.stack([x @ e1, x @ e2], axis=-1)

    def ccw(polygons):
        """The polygons wound counter-clockwise (their union is then the Positive fill of them all; a
        non-zero fill would cancel a clockwise triangle against a counter-clockwise one)."""
        out = []
        for q in polygons:
            a = float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
            if a > 0.0:
                out.append(q)
            elif a < 0.0:
                out.append(q[::-1])
        return out

    # only the detector's part on the beam's side of the source's plane can be lit (the source is a disk
    # the rays leave; behind it nothing arrives)
    if det_plane is not None:  # an exact plane: its disk or annulus, not the mesh that finds its hits
        rings = _plane_rings(det_plane)
        if not all((((r - center) @ beam_side) > 0).all() for r in rings):
            return Declined("the detector's exact plane reaches behind the source's plane")
        outer = CrossSection(ccw([project(rings[0])]), FillRule.Positive)
        region = outer - CrossSection(ccw([project(rings[1])]), FillRule.Positive) if len(rings) > 1 else outer
    else:
        ahead = [c if (((c - center) @ beam_side) > 0).all() else _clip(c, beam_side, center) for c in dt]
        region = CrossSection(ccw(project(c) for c in ahead if len(c) >= 3), FillRule.Positive)
    region = region ^ CrossSection(ccw([project(_ring(center, src_normal, src.radius_mm))]), FillRule.Positive)
    if region.is_empty():
        return Declined("the detector lies outside the beam")
    # an exact plane blocks with its disk or annulus (its mesh covers more: the walk passes the rest), so its
    # triangles are left out and its outline cut first
    exact_occluders = []
    for i in planes:
        if i == det_part:
            continue
        rings = _plane_rings(surfaces[i])
        sd = [(r - c0) @ toward_source for r in rings]
        ss = [(r - center) @ beam_side for r in rings]
        if all((a > 0).all() for a in sd) and all((a > 0).all() for a in ss):
            ring_cs = CrossSection(ccw([project(rings[0])]), FillRule.Positive)
            if len(rings) > 1:
                ring_cs = ring_cs - CrossSection(ccw([project(rings[1])]), FillRule.Positive)
            exact_occluders.append(ring_cs)
        elif any((a > 0).any() for a in sd) and any((a > 0).any() for a in ss):
            return Declined(f"the exact plane {spec.part_names[i]!r} crosses the detector's or the source's plane")
    for ring_cs in exact_occluders:
        region = region - ring_cs
    others = tri[(part != det_part) & ~np.isin(part, planes + cylinders)]
    if cylinders:  # an exact cylinder by its fine prism, not by the mesh that finds its hits
        others = np.concatenate([others, *(_cylinder_triangles(surfaces[i]) for i in cylinders)])
    # the slab between the detector's plane and the source's: a triangle behind the one or beyond the other
    # blocks nothing; one across a plane blocks with the part inside
    s_det = (others - c0) @ toward_source  # (m, 3): > 0 on the source's side of the detector
    s_src = (others - center) @ beam_side  # > 0 on the beam's side of the source's plane
    inside = (s_det > 0).all(1) & (s_src > 0).all(1)
    across = ~inside & (s_det > 0).any(1) & (s_src > 0).any(1)
    keep = np.flatnonzero(inside | across)
    flat = project(others[keep].reshape(-1, 3)).reshape(-1, 3, 2)
    lo, hi = flat.min(axis=1), flat.max(axis=1)
    # nearest the detector first, in batches: what a batch takes from the lit region, the triangles behind it
    # cannot take again, so each batch is culled to the current lit region (a raster of it grown by a cell:
    # a triangle whose box covers none of its cells cannot overlap it). Beyond a cut-off the first batches leave
    # nothing; on axis the vane rings around the detector's disk are culled before any union.
    depth = s_det[keep].min(axis=1)
    order = np.argsort(depth, kind="stable")
    lit = region
    cells = None  # a raster of the lit region (it only shrinks: an older raster still covers it, so it is made
    raster_area = math.inf  # again only once the region has lost a fifth of the area it had then)
    for first in range(0, len(order), OCCLUDER_BATCH):
        if lit.is_empty():
            break
        if cells is None or lit.area() < 0.8 * raster_area:
            raster_area = lit.area()
            l_lo, l_hi = np.array(lit.bounds()[:2]), np.array(lit.bounds()[2:])
            pad = 1e-6 * max(float(np.max(l_hi - l_lo)), 1.0)
            cells = _Cells(lit.to_polygons(), l_lo - pad, l_hi + pad, RASTER_CELLS)
        b = order[first:first + OCCLUDER_BATCH]
        b = b[(hi[b, 0] >= cells.lo[0]) & (lo[b, 0] <= cells.hi[0]) & (hi[b, 1] >= cells.lo[1]) & (lo[b, 1] <= cells.hi[1])]
        if len(b) and cells.cells >= 64:  # (a region thinner than a cell: every box in its box is kept)
            b = b[cells.touching(lo[b], hi[b])]
        if len(b) == 0:
            continue
        whole = inside[keep[b]]
        flat_in = flat[b[whole]].copy()
        signed = _signed_areas(flat_in)
        flat_in[signed < 0] = flat_in[signed < 0][:, ::-1]  # every triangle counter-clockwise
        polys = list(flat_in[signed != 0])
        for t in others[keep[b[~whole]]]:
            p = _clip(_clip(t, toward_source, c0), beam_side, center)
            if len(p) >= 3:
                polys += ccw([project(p)])
        if polys:
            lit = lit - CrossSection(polys, FillRule.Positive)
    area = float(lit.area())
    if not area > 0.0:
        return Declined("no point of the detector sees the beam straight (0 mm^2 lit)")
    footprint = math.pi * float(src.radius_mm) ** 2 * abs(float(src_normal @ d))
    power = float(src.power_w) / footprint * area
    contours = [np.asarray(c, dtype=np.float64) for c in lit.to_polygons()]
    flat2 = np.concatenate(contours)
    faces = np.asarray(triangulate(contours), dtype=np.int64).reshape(-1, 3)
    corners = flat2[faces]  # (m, 3, 2)
    # back onto the detector's plane along d: x = a e1 + b e2 + t d with n0 . (x - c0) = 0
    ab = corners[..., 0:1] * e1 + corners[..., 1:2] * e2
    t = ((c0 - ab) @ n0) / cos_det
    on_plane = ab + t[..., None] * d
    e_a, e_b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    areas = 0.5 * np.abs(e_a[:, 0] * e_b[:, 1] - e_a[:, 1] * e_b[:, 0])
    cdf = np.cumsum(areas)
    cdf /= cdf[-1]
    detector = int(np.flatnonzero(np.asarray(spec.detector_parts) == det_part)[0])
    return DirectArea(power_w=power, detector=detector, part=det_part,
                      triangles_mm=np.ascontiguousarray(on_plane), cdf=cdf)


def points_in(table: DirectArea, u: np.ndarray) -> np.ndarray:
    """Points uniform in the lit region (area measure) from uniforms ``u`` (n, 3)."""
    k = np.minimum(np.searchsorted(table.cdf, u[:, 0], side="right"), len(table.cdf) - 1)
    s = np.sqrt(u[:, 1])
    b = u[:, 2]
    t = table.triangles_mm[k]
    return t[:, 0] * (1.0 - s)[:, None] + t[:, 1] * (s * (1.0 - b))[:, None] + t[:, 2] * (s * b)[:, None]


def ray_uniforms(spec, first_chunk: int, stop_chunk: int, n: int) -> np.ndarray:
    """The (n, 3) uniforms placing the records of the batch's rays (a stream per chunk, keyed by seed,
    ``spec.chunk_offset`` + chunk and :data:`STREAM`: the same for any batch split)."""
    u = np.empty((n, 3))
    for c in range(first_chunk, stop_chunk):
        lo = (c - first_chunk) * CHUNK_RAYS
        hi = min(lo + CHUNK_RAYS, n)
        if hi <= lo:
            break
        np.random.default_rng([int(spec.seed), int(spec.chunk_offset + c), STREAM]).random(out=u[lo:hi])
    return u


class DirectShares:
    """Per batch: every ray's share P / N of the direct light, and the walk's direct hits dropped."""

    def __init__(self, ctx, table: DirectArea):
        spec, rows = ctx.spec, ctx.rows
        self.table = table
        self.events = 0
        n = ctx.n_rays
        ray = np.arange(n, dtype=np.int64)
        value = np.full(n, table.power_w / float(spec.n_rays))
        ctx.tallies.add(rows.detector_nee + table.detector, ray, value)
        ctx.tallies.subtract(rows.escaped, ray, value)
        z = points_in(table, ray_uniforms(spec, ctx.first_chunk, ctx.stop_chunk, n))
        keys = events = None
        records = ctx.records
        if records.record_paths:
            keys = np.full(n, mix_key(np.zeros(1, np.uint64), table.part * 4 + EVENT_DETECTOR)[0], dtype=np.uint64)
            events = np.full((n, int(spec.options.output.path_depth)), -1, dtype=np.int16)
        records.add(table.detector, ray, z, value, keys, events, np.zeros(n, dtype=np.int64))

    def share_walk_hits(self, event, rec, rec_w):
        """At the first event every counted walk hit on the detector is direct: its weight moves to the
        ``escaped`` row (the light is counted above, and taken from that row there)."""
        if self.events > 0:
            return rec, rec_w
        r = event.rays.ray[rec]  # (the scene's one detector: unsupported() asks for exactly one)
        event.tallies.subtract(event.rows.detector_direct + self.table.detector, r, rec_w)
        event.tallies.add(event.rows.escaped, r, rec_w)
        return rec[:0], rec_w[:0]

    def after_hits(self, event, continuing) -> None:
        self.events += 1
