"""Edge diffraction in the walk (CONTRACTS §6.5): HURB at the edges of parts marked
``diffraction = "edges"``. docs/diffraction.md describes the method, its limits and its checks.

- :func:`scene_diffraction` builds, once per trace, what the workers need (:class:`Diffraction`:
  the edge table of straylight.engine.edge_index, the wavelength, the HURB factor).
- :func:`divert` is the walk's hook: after the ray casts, each ray that passes a diffracting edge
  before its hit is taken out of this event, moved to its closest approach to the edge and bent by
  the HURB law (straylight.engine.hurb), with its power unchanged; it goes on at the next event.
  Its path records ``diffracted at <part>``.
- :func:`blocked_by_edges`: next-event estimation treats a shadow ray that passes a diffracting edge
  as blocked, since the walk bends every ray there: both estimate the same light.

Edges of finite thickness: a mesh vane's rim has two sharp edges (top and bottom corners); a ray
through the hole passes them in turn and is diffracted at each it passes in the open (the first
bend may send it into the rim face instead). An analytic ``plane`` aperture has zero thickness:
one edge per rim.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from geometry.analytic import Plane
from geometry.edges import sharp_edges
from straylight.engine.edge_index import EdgeTable, band_prisms, edge_table, passages
from straylight.engine.hurb import GAMMA, METHOD, deflect, tan_sigma
from straylight.engine.options import TraceError
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_DIFFRACTION, RayBatch
from straylight.intersect.embree import EmbreeIntersector
from straylight.paths import mix_key


@dataclass(frozen=True, eq=False)
class Diffraction:
    """What the walk needs to diffract (picklable)."""

    edges: EdgeTable
    wavelength_nm: float
    gamma: float = GAMMA
    past_mm: float = 0.0  # a ray bent at a rim starts this far past the aperture's plane (set by make_spec)

    @property
    def band_mm(self) -> float:
        return self.edges.band_mm


def diffracting_parts(scene) -> list:
    """Indices of the parts marked ``diffraction = "edges"``."""
    return [i for i, p in enumerate(scene.parts) if (p.meta or {}).get("diffraction") == "edges"]


def trace_wavelength_nm(sources, materials, parts=("a part",)) -> float:
    """The sources' ``wavelength_nm`` (all the same), else the materials' common ``wavelength_nm``;
    ``parts``: the diffracting parts' names, for the message when neither gives one."""
    given = {float(w) for w in (getattr(s, "wavelength_nm", None) for s in sources) if w is not None}
    if len(given) > 1:
        raise TraceError(f"diffraction needs one wavelength; the sources give {sorted(given)} nm")
    if given:
        return given.pop()
    known = {float(w) for w in (getattr(m, "wavelength_nm", None) for m in materials) if w is not None}
    if len(known) == 1:
        return known.pop()
    who = ", ".join(parts)
    raise TraceError(f"{who} diffract{'s' if len(parts) == 1 else ''} (diffraction = \"edges\") and neither the "
                     "[[source]] nor the materials give one wavelength: give wavelength_nm on the [[source]]")


def _rims(part):
    """(centre, axis, radius, open inside) of a plane part's rims."""
    s = part.surface
    out = []
    if float(getattr(s, "inner_radius_mm", 0.0) or 0.0) > 0.0:
        out.append((s.vertex_mm, s.axis, float(s.inner_radius_mm), True))
    out.append((s.vertex_mm, s.axis, float(s.outer_radius_mm), False))
    return out


def scene_diffraction(scene, sources, materials, options) -> Diffraction | None:
    """The trace's :class:`Diffraction`, or None when no part diffracts or ``options.physics.diffraction`` is
    ``"off"``."""
    if options.physics.diffraction == "off":
        return None
    marked = diffracting_parts(scene)
    if not marked:
        return None
    for i in marked:
        if scene.parts[i].role == "detector":
            raise TraceError(f"part {scene.parts[i].name!r}: a detector cannot diffract (diffraction = \"edges\")")
    wavelength_nm = trace_wavelength_nm(sources, materials, tuple(repr(scene.parts[i].name) for i in marked))
    band_mm = float(options.physics.diffraction_band_wavelengths) * wavelength_nm * 1e-6
    segments, rims = [], []
    for i in marked:
        part = scene.parts[i]
        if isinstance(part.surface, Plane):
            rims.extend((i, *rim) for rim in _rims(part))
        else:
            segments.append((i, sharp_edges(part.vertices_mm, part.faces)))
    return Diffraction(edges=edge_table(segments, rims, band_mm), wavelength_nm=wavelength_nm,
                       gamma=float(options.physics.hurb_gamma))


def hit_distance(scene, rays, tri) -> np.ndarray:
    """Distance to each ray's hit (inf for a miss), from the hit triangle's plane as the hit stage."""
    tri = np.asarray(tri, dtype=np.int64)
    t = np.full(len(tri), np.inf)
    hit = np.flatnonzero(tri >= 0)
    if len(hit):
        k = tri[hit]
        a = scene.arrays
        n = a.normals[k]
        o, d = rays.origin_mm[hit], rays.direction[hit]
        cos_in = np.einsum("ij,ij->i", n, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            th = (a.plane_d[k] - np.einsum("ij,ij->i", n, o)) / cos_in
        edge_on = ~(np.abs(cos_in) >= 1e-12)
        th[edge_on] = np.einsum("ij,ij->i", a.centroids[k[edge_on]] - o[edge_on], d[edge_on])
        t[hit] = th
    return t


def subset(rays: RayBatch, rows) -> RayBatch:
    """The rays at ``rows``."""
    hist = rays.history[rows] if len(rays.history) else rays.history
    return RayBatch(*(f[rows] for f in rays[:9]), hist)


def merge(a: RayBatch, skip_a, b: RayBatch, skip_b):
    """Two ray batches as one, ascending ray id (the order the random streams are drawn in)."""
    if len(b.ray) == 0:
        return a, skip_a
    order = np.argsort(np.concatenate([a.ray, b.ray]), kind="stable")
    fields = [np.concatenate([fa, fb])[order] for fa, fb in zip(a[:9], b[:9])]
    hist = np.concatenate([a.history, b.history])[order] if len(a.history) + len(b.history) else a.history
    return RayBatch(*fields, hist), np.concatenate([skip_a, skip_b])[order]


def divert(diff: Diffraction, scene, rays: RayBatch, tri, skip, U, sample_col: int, record_paths: bool):
    """Split this event's rays: (rows that go on to their hit, the diffracted rays' next state, their
    skip ids), or None when no ray passes an edge. ``skip``: (n, 3) edge ids each ray must ignore
    (the edge it was just diffracted at), or None."""
    tmax = hit_distance(scene, rays, tri)
    tri = np.asarray(tri, dtype=np.int64)
    hit_part = np.where(tri >= 0, scene.arrays.triangle_part[np.maximum(tri, 0)], -1).astype(np.int64)
    near = segment_candidates(diff, scene, rays.origin_mm, rays.direction, tmax)
    edge, t, db, da, b = passages(diff.edges, rays.origin_mm, rays.direction, tmax, skip, hit_part, near)
    bent = np.flatnonzero(edge >= 0)
    if len(bent) == 0:
        return None
    keep = np.flatnonzero(edge < 0)
    d = rays.direction[bent]
    # a rim's crossing lies on its part's plane: start just past it (scene epsilon along the ray)
    past = np.where(edge[bent] >= len(diff.edges.seg_a), diff.past_mm, 0.0)
    origin = rays.origin_mm[bent] + (t[bent] + past)[:, None] * d
    direction = deflect(d, b[bent], db[bent], da[bent], diff.wavelength_nm, U[bent, sample_col],
                        U[bent, sample_col + 1], diff.gamma)
    part = diff.edges.part_of(edge[bent])
    pdf = direction_pdf(d, b[bent], db[bent], da[bent], direction, diff)
    code = part * 4 + EVENT_DIFFRACTION
    depth = rays.depth[bent]
    hist = rays.history[bent] if len(rays.history) else rays.history
    if record_paths and len(hist):
        inside = np.flatnonzero(depth < hist.shape[1])
        hist[inside, depth[inside]] = code[inside]
    key = mix_key(rays.path_key[bent], code) if record_paths else rays.path_key[bent]
    nxt = RayBatch(ray=rays.ray[bent], origin_mm=origin, direction=direction, weight_w=rays.weight_w[bent],
                   last_event=np.full(len(bent), EVENT_DIFFRACTION, dtype=np.int8), last_pdf_per_sr=pdf,
                   last_part=part, path_key=key, depth=depth + 1, history=hist)
    vertex = BentVertices(incoming=d, b=b[bent], delta_b_mm=db[bent], delta_a_mm=da[bent], uniforms=U[bent])
    return keep, nxt, diff.edges.skip_of(edge[bent]), vertex


def truncate(diff_rays: RayBatch, tallies, rows) -> None:
    """At the last event, diffracted rays stop: their power goes to the part's ``truncated`` row."""
    tallies.reserve(len(diff_rays.ray))
    tallies.add(rows.truncated + diff_rays.last_part, diff_rays.ray, diff_rays.weight_w)


def blocked_by_edges(diff: Diffraction | None, origin, direction, tmax, skip=None, scene=None) -> np.ndarray:
    """Shadow rays that pass a diffracting edge before ``tmax`` (next-event estimation treats them
    as blocked: the walk would have bent them); ``skip``: (n, 3) edge ids each may pass; ``scene``:
    the compiled scene (its thread's band prisms pre-select the rays), or None (every ray searched)."""
    n = len(origin)
    if diff is None or n == 0:
        return np.zeros(n, dtype=bool)
    tmax = np.asarray(tmax, dtype=np.float64)
    near = segment_candidates(diff, scene, origin, direction, tmax) if scene is not None else None
    edge = passages(diff.edges, origin, direction, tmax, skip, near=near)[0]
    return edge >= 0


def shadow_test(diff: Diffraction | None, scene):
    """The walk's shadow test for one batch (handed to next-event estimation on ``Event.shadow_test``):
    ``blocked(origin, direction, tmax)``, True where the segment is occluded by the scene or, when
    parts diffract, passes a diffracting edge (the walk bends every ray that passes one)."""
    isect = scene.isect

    def blocked(origin, direction, tmax) -> np.ndarray:
        out = np.asarray(isect.occluded(origin, direction, tmax), dtype=bool)
        if diff is not None:
            out = out | blocked_by_edges(diff, origin, direction, tmax, scene=scene)
        return out

    return blocked


def segment_candidates(diff: Diffraction, scene, origin, direction, tmax) -> np.ndarray:
    """Rays that may pass a mesh edge before ``tmax``: one embree occlusion query against the edges'
    band prisms (straylight.engine.edge_index.band_prisms), built once per thread and edge set."""
    n = len(origin)
    if len(diff.edges.seg_a) == 0:
        return np.zeros(n, dtype=bool)
    h = hashlib.sha1(diff.edges.seg_a.tobytes())
    h.update(diff.edges.seg_b.tobytes())
    h.update(repr(diff.edges.band_mm).encode())
    prisms = scene.thread_local(f"diffraction_prisms_{h.hexdigest()}",
                                lambda: EmbreeIntersector(band_prisms(diff.edges)))
    return np.asarray(prisms.occluded(origin, direction, np.minimum(tmax, 1e30)), dtype=bool)


class BentVertices(NamedTuple):
    """What next-event estimation needs of this event's diffraction vertices (one row per bent ray)."""

    incoming: np.ndarray  # (n, 3) direction before the bend
    b: np.ndarray  # (n, 3) unit, across the edge toward the ray
    delta_b_mm: np.ndarray
    delta_a_mm: np.ndarray  # inf: the 1-D law (no density in solid angle: no NEE)
    uniforms: np.ndarray  # (n, width) the rays' uniforms of this event (their NEE columns are free)


def direction_pdf(incoming, b, delta_b_mm, delta_a_mm, direction, diff: Diffraction) -> np.ndarray:
    """Density per steradian of the HURB law (straylight.engine.hurb) at ``direction``: Gaussian in
    (tan theta_b, tan theta_a) times the Jacobian of the gnomonic map, 1 / (direction . incoming)^3;
    0 where the law is 1-D (delta_a = inf: a Dirac along the edge) or the direction turns back."""
    s = np.asarray(incoming, dtype=np.float64)
    w = np.asarray(direction, dtype=np.float64)
    a = np.cross(s, b)
    cs = np.einsum("ij,ij->i", w, s)
    sb = tan_sigma(delta_b_mm, diff.wavelength_nm, diff.gamma)
    sa = tan_sigma(delta_a_mm, diff.wavelength_nm, diff.gamma)
    ok = (cs > 0) & (sa > 0) & (sb > 0)
    out = np.zeros(len(w))
    if ok.any():
        c = cs[ok]
        tb = np.einsum("ij,ij->i", w[ok], b[ok]) / c
        ta = np.einsum("ij,ij->i", w[ok], a[ok]) / c
        p_tan = np.exp(-0.5 * ((tb / sb[ok]) ** 2 + (ta / sa[ok]) ** 2)) / (2.0 * np.pi * sb[ok] * sa[ok])
        out[ok] = p_tan / c**3
    return out


def next_event(diff: Diffraction, scene, bent: RayBatch, skip, vertex: BentVertices, columns, settings, tallies,
               rows, records) -> int:
    """Next-event estimation from this event's diffraction vertices (where the law has a density):
    per detector and NEE sample, a point y uniform on the detector, the contribution
    ``w p_hurb(omega) cos_y A / (k d^2)`` times the power-heuristic weight against the bend itself
    (the walk's hit on the detector right after a bend keeps the other share, straylight.engine.hits),
    if the shadow ray is unblocked and passes no other diffracting edge. Returns the shadow rays cast."""
    from straylight.engine.vec3 import power_heuristic_rows

    live = np.flatnonzero(bent.last_pdf_per_sr > 0)
    if len(live) == 0 or len(scene.detectors) == 0:
        return 0
    k = int(settings.nee_samples)
    x = bent.origin_mm[live]
    cast = 0
    for j, det in enumerate(scene.detectors):
        for s in range(k):
            c0 = columns.nee + 3 * (j * k + s)
            y, ny = det.sample(vertex.uniforms[live, c0:c0 + 3])
            v = y - x
            d2 = np.einsum("ij,ij->i", v, v)
            dist = np.sqrt(d2)
            omega = v / np.where(dist > 0, dist, 1.0)[:, None]
            cos_y = -np.einsum("ij,ij->i", omega, ny)
            if settings.both_sides:
                cos_y = np.abs(cos_y)
            p_hurb = direction_pdf(vertex.incoming[live], vertex.b[live], vertex.delta_b_mm[live],
                                   vertex.delta_a_mm[live], omega, diff)
            area = float(det.area_mm2)
            go = np.flatnonzero((cos_y > 0) & (dist > 2 * settings.eps_mm) & (p_hurb > 0))
            if len(go) == 0:
                continue
            p_nee = k * d2[go] / (area * cos_y[go])
            c = bent.weight_w[live[go]] * p_hurb[go] * cos_y[go] * area / (k * d2[go]) \
                * power_heuristic_rows(p_nee, p_hurb[go])
            tmax = dist[go] - settings.eps_mm
            blocked = np.asarray(scene.isect.occluded(x[go], omega[go], tmax), dtype=bool)
            blocked |= blocked_by_edges(diff, x[go], omega[go], tmax, skip[live[go]], scene)
            cast += len(go)
            ok = np.flatnonzero(~blocked & (c > 0))
            if len(ok) == 0:
                continue
            rows_ = live[go[ok]]
            r = bent.ray[rows_]
            tallies.add(rows.detector_nee + j, r, c[ok])
            tallies.subtract(rows.nee_exchange + bent.last_part[rows_], r, c[ok])
            keys = events = None
            if settings.record_paths:
                keys = mix_key(bent.path_key[rows_], scene.det_parts[j] * 4 + EVENT_DETECTOR)
                events = bent.history[rows_]
            records.add(j, r, y[go[ok]], c[ok], keys, events, bent.depth[rows_])
    return cast


def describe_method(gamma: float = GAMMA) -> str:
    return f"{METHOD}, gamma = {gamma:.3f}" if not math.isclose(gamma, GAMMA) else METHOD
