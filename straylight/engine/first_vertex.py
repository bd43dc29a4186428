"""Area sampling of single-scatter vertices, combined with the forward walk by MIS.

With ``EstimatorOptions(first_vertex_sampling=True)`` the single-scatter paths

    source -> (straight) -> surface point x (one BRDF scatter) -> (straight) -> detector

get a second sampling strategy next to the forward walk's: a point x drawn directly on the
scene's surfaces (triangle t with probability q_t, uniform on it: area density
p_A(x) = q_t / A_t), joined to the source by a deterministic shadow ray and to a uniform
detector point z by another. The forward walk draws the same vertex with area density p_F(x)
(collimated disk: |cos theta_x| / (A_disk |n_disk . d|); point source: |cos theta_x| / (Omega r^2)).
Both estimates of a vertex's contribution are weighted by the balance heuristic,
w_s = p_s / (p_F + p_A) (one sample of each per ray id; Veach 1997, ch. 9), so the sum is
unbiased for any table q, and any vertex with q_t = 0 is left to the forward walk alone.

Why: a collimated beam that lights small faces the detector sees well (the inner edges of
baffle vanes, 1 mm tall, struck by ~0.2 % of the rays at 20 deg off axis) makes the forward
estimate a rare-event count, and from the detector those faces are small too; drawn on their
own area they are found every time.

The table q is learnt before the run from 8 probe points per surface triangle (fewer on scenes
with more than 50k surface triangles; its own random stream): q_t proportional to
A_t sqrt(mean of g^2), with g the probe's single-scatter contribution E(x) f cos_x cos_z / |x - z|^2 (unblocked). It depends only on the
scene, the source and the seed, so results stay independent of batch size and worker count.
Contributions go to the detector and, negated, to the part's NEE-exchange row, so the power
ledger stays exact (docs/engine.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from straylight.engine.face_groups import face_groups
from straylight.engine.interactions.registry import Capability, parts_with
from straylight.engine.lobes import lobe_materials
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER, EVENT_SOURCE
from straylight.engine.triangle_sampling import triangle_points
from straylight.engine.vec3 import power_heuristic_rows
from straylight.engine.walk_shares import keep_walk_share
from straylight.paths import mix_key
from straylight.rng import CHUNK_RAYS, check_seed, chunk_bounds
from straylight.sources import CollimatedDisk, PointSource, orthonormal_basis

VERTEX_STREAM = 0x56455254  # third entropy word: this strategy's streams differ from the forward's
PROBE_STREAM = 0x50524F42
SCREEN_STREAM = 0x5343524E  # the one-probe screen of build_table ("SCRN"), apart from the probes' own stream
LOBE_STREAM = 0x4C4F4245  # the lobe draws of vertex_lobe_sampling (so the other columns keep their bits)
PROBES_PER_TRIANGLE = 8
PROBE_BUDGET = 400_000
FACE_SHARE = 0.25  # large scenes: share of each face's mean density every triangle of the face keeps


def probes_per_triangle(n_triangles: int, budget: int = PROBE_BUDGET, most: int = PROBES_PER_TRIANGLE) -> int:
    """Probes per triangle for a table over ``n_triangles``: ``most``, fewer when that would pass ``budget`` probes
    in all, at least one (a million-triangle scene gets one per triangle)."""
    return int(min(most, max(1, budget // max(int(n_triangles), 1))))


@dataclass(frozen=True, eq=False)
class VertexTable:
    """Triangle sampling table: ``tri`` (m,) triangle ids, ``cdf`` (m,) cumulative q, and
    ``p_area`` (n_triangles,) the area density q_t / A_t of every triangle (0 if not in the table)."""

    tri: np.ndarray
    cdf: np.ndarray
    p_area: np.ndarray


def unsupported(sources) -> str | None:
    """Why the strategy cannot run with these sources (None when it can)."""
    if len(sources) != 1:
        return f"first_vertex_sampling needs exactly one source, got {len(sources)}"
    if getattr(getattr(sources[0], "polarization", None), "is_linear", False):
        return "first_vertex_sampling does not follow polarized sources (its first vertex is evaluated unpolarized)"
    if not isinstance(sources[0], (CollimatedDisk, PointSource)):
        return f"first_vertex_sampling connects to collimated and point sources only, not {type(sources[0]).__name__}"
    return None


def vertex_rng(seed: int, chunk: int) -> np.random.Generator:
    return np.random.default_rng([check_seed(seed), int(chunk), VERTEX_STREAM])


def _local(v, tb, bb, nf):
    return np.stack([np.einsum("ij,ij->i", v, tb), np.einsum("ij,ij->i", v, bb), np.einsum("ij,ij->i", v, nf)],
                    axis=1)


def source_connection(src, x, n_geo):
    """Direction x -> source (unit), lit-side normal, irradiance on that side E(x), shadow length.

    E = 0 where the source cannot light x (outside the beam or cone)."""
    n = len(x)
    if isinstance(src, CollimatedDisk):
        wi = np.ascontiguousarray(np.broadcast_to(-src.direction, (n, 3)))
        denom = float(np.dot(-src.direction, src.normal))
        if abs(denom) < 1e-12:
            return wi, n_geo, np.zeros(n), np.zeros(n)
        t = ((src.center_mm - x) @ src.normal) / denom
        y = x + t[:, None] * wi
        dy = y - src.center_mm
        inside = np.einsum("ij,ij->i", dy, dy) < src.radius_mm ** 2
        cos_g = np.einsum("ij,ij->i", wi, n_geo)
        nf = np.where((cos_g >= 0)[:, None], n_geo, -n_geo)
        e_perp = src.power_w / (math.pi * src.radius_mm ** 2 * abs(denom))
        ok = inside & (t > 0)
        return wi, nf, np.where(ok, e_perp * np.abs(cos_g), 0.0), np.where(ok, t, 0.0)
    v = src.position_mm - x
    r2 = np.einsum("ij,ij->i", v, v)
    r = np.sqrt(r2)
    wi = v / np.where(r > 0, r, 1.0)[:, None]
    cos_g = np.einsum("ij,ij->i", wi, n_geo)
    nf = np.where((cos_g >= 0)[:, None], n_geo, -n_geo)
    cos_max = math.cos(math.radians(src.half_angle_deg))
    ok = ((-wi @ src.axis) >= cos_max) & (r > 0)
    intensity = src.power_w / (2.0 * math.pi * (1.0 - cos_max))
    return wi, nf, np.where(ok, intensity * np.abs(cos_g) / np.where(ok, r2, 1.0), 0.0), np.where(ok, r, 0.0)


def forward_density(src, x, normals):
    """Area density at x (triangle normals ``normals``) of the forward walk's first hit, per ray."""
    if isinstance(src, CollimatedDisk):
        cos_x = normals @ src.direction
        return np.abs(cos_x) / (math.pi * src.radius_mm ** 2 * abs(float(np.dot(src.direction, src.normal))))
    cos_max = math.cos(math.radians(src.half_angle_deg))
    v = x - src.position_mm
    r2 = np.einsum("ij,ij->i", v, v)
    cos_x = np.einsum("ij,ij->i", normals, v) / np.sqrt(r2)
    return np.abs(cos_x) / (2.0 * math.pi * (1.0 - cos_max) * r2)


def _single_scatter(spec, comp, src, t, x, u_det, j, lobe_mis=False):
    """Unblocked single-scatter contribution E f cos_x cos_z / d^2 (W/mm^4 units: per area of x and z)
    of points x on triangles t toward detector j; returns (value, detector point z, shadow rays cast).
    ``lobe_mis``: times the power-heuristic weight of the uniform detector point against the
    material's own draw (:func:`lobe_connection`, the other strategy for the same direction)."""
    eps = spec.eps
    n_geo = comp.normals[t]
    wi, nf, e_x, tmax = source_connection(src, x, n_geo)
    value = np.zeros(len(x))
    z, n_det = comp.detectors[j].sample(u_det)
    lit = np.flatnonzero(e_x > 0)
    shadows = 0
    if len(lit) == 0:
        return value, z, shadows
    v = z[lit] - x[lit]
    d2 = np.einsum("ij,ij->i", v, v)
    dist = np.sqrt(d2)
    wo = v / np.where(dist > 0, dist, 1.0)[:, None]
    cos_o = np.einsum("ij,ij->i", wo, nf[lit])
    cos_z = -np.einsum("ij,ij->i", wo, n_det[lit])
    if spec.options.output.detector_sides == "both":
        cos_z = np.abs(cos_z)
    good = (cos_o > 0) & (cos_z > 0) & (dist > 2 * eps)
    lit, v, d2, dist, wo, cos_o, cos_z = (a[good] for a in (lit, v, d2, dist, wo, cos_o, cos_z))
    if len(lit) == 0:
        return value, z, shadows
    shadow_origin = np.ascontiguousarray(x[lit] + eps * nf[lit])
    blocked = np.asarray(comp.isect.occluded(shadow_origin, np.ascontiguousarray(wi[lit]), tmax[lit]), dtype=bool)
    to_det = np.ascontiguousarray(z[lit] - shadow_origin)
    ld = np.sqrt(np.einsum("ij,ij->i", to_det, to_det))
    blocked |= np.asarray(comp.isect.occluded(shadow_origin, np.ascontiguousarray(to_det / ld[:, None]), ld - eps), dtype=bool)
    shadows = 2 * len(lit)
    keep = ~blocked
    lit, wo, d2, cos_o, cos_z = lit[keep], wo[keep], d2[keep], cos_o[keep], cos_z[keep]
    if len(lit) == 0:
        return value, z, shadows
    tb, bb = orthonormal_basis(nf[lit])
    wi_loc = _local(wi[lit], tb, bb, nf[lit])
    wo_loc = _local(wo, tb, bb, nf[lit])
    mat = spec.part_material[spec.triangle_part[t[lit]]]
    f = np.empty(len(lit))
    pol = spec.options.physics.polarization
    for rows, fv in by_material(spec.materials, mat, lambda model, rows: model.brdf(wi_loc[rows], wo_loc[rows], pol)):
        f[rows] = fv
    value[lit] = e_x[lit] * f * cos_o * cos_z / d2
    if lobe_mis:
        glossy = lobe_materials(spec)[mat]
        lit, mat, wi_loc, wo_loc, d2, cos_z = (a[glossy] for a in (lit, mat, wi_loc, wo_loc, d2, cos_z))
        pdf = np.empty(len(lit))
        for rows, pv in by_material(spec.materials, mat,
                                    lambda model, rows: model.pdf(wi_loc[rows], wo_loc[rows], pol)):
            pdf[rows] = pv
        p_nee = d2 / (comp.detectors[j].area_mm2 * cos_z)  # uniform point on the detector, per sr
        value[lit] *= power_heuristic_rows(p_nee, pdf)
    return value, z, shadows


def lobe_connection(spec, comp, src, t, x, u3, j):
    """The second way to join a sampled vertex x (triangles t) to detector j: the direction drawn
    from the material's own lobe (``model.sample``), kept when its ray reaches detector j first.

    Returns (value, hit point, rows, shadow rays): value = E(x) f cos_x / pdf_lobe x the
    power-heuristic weight against a uniform detector point (density d^2 / (A |cos_z|) per sr),
    so with :func:`_single_scatter`'s ``lobe_mis`` the two weights of a direction add to one
    (Veach 1997, eq. 9.13). A narrow glossy lobe is found by this draw, not by a uniform point."""
    eps = spec.eps
    n_geo = comp.normals[t]
    wi, nf, e_x, tmax = source_connection(src, x, n_geo)
    glossy = lobe_materials(spec)[spec.part_material[spec.triangle_part[t]]]
    lit = np.flatnonzero((e_x > 0) & glossy)
    empty = (np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64), 0)
    if len(lit) == 0:
        return empty
    origin = np.ascontiguousarray(x[lit] + eps * nf[lit])
    blocked = np.asarray(comp.isect.occluded(origin, np.ascontiguousarray(wi[lit]), tmax[lit]), dtype=bool)
    shadows = len(lit)
    lit, origin = lit[~blocked], origin[~blocked]
    if len(lit) == 0:
        return (*empty[:3], shadows)
    nfl = nf[lit]
    tb, bb = orthonormal_basis(nfl)
    wi_loc = _local(wi[lit], tb, bb, nfl)
    mat = spec.part_material[spec.triangle_part[t[lit]]]
    wo = np.empty((len(lit), 3))
    weight = np.empty(len(lit))
    pdf = np.empty(len(lit))
    pol = spec.options.physics.polarization
    for rows, smp in by_material(spec.materials, mat, lambda model, rows: model.sample(wi_loc[rows], u3[lit][rows], pol)):
        wo[rows], weight[rows], pdf[rows] = smp.wo, smp.weight, smp.pdf_per_sr
    ok = (wo[:, 2] > 0) & (weight > 0) & (pdf > 0)
    lit, origin, wo, weight, pdf, tb, bb, nfl = (a[ok] for a in (lit, origin, wo, weight, pdf, tb, bb, nfl))
    if len(lit) == 0:
        return (*empty[:3], shadows)
    d = wo[:, :1] * tb + wo[:, 1:2] * bb + wo[:, 2:3] * nfl
    d /= np.linalg.norm(d, axis=1)[:, None]
    d = np.ascontiguousarray(d)
    tri, dist = comp.isect.intersect(origin, d)
    shadows += len(lit)
    tri = np.asarray(tri)
    on = tri >= 0
    on[on] = spec.triangle_part[tri[on]] == comp.det_parts[j]
    lit, origin, d, weight, pdf, tri, dist = (np.asarray(a)[on] for a in (lit, origin, d, weight, pdf, tri, dist))
    if len(lit) == 0:
        return (*empty[:3], shadows)
    cos_in = np.einsum("ij,ij->i", d, comp.normals[tri])
    front = np.ones(len(lit), dtype=bool) if spec.options.output.detector_sides == "both" else cos_in < 0
    ac = np.abs(cos_in)
    front &= ac > 0
    lit, origin, d, weight, pdf, dist, ac = (a[front] for a in (lit, origin, d, weight, pdf, dist, ac))
    p_nee = dist * dist / (comp.detectors[j].area_mm2 * ac)
    value = e_x[lit] * weight * power_heuristic_rows(pdf, p_nee)
    return value, origin + dist[:, None] * d, lit, shadows


def _may_see_detector(spec, comp, src, surf):
    """Bool per triangle of ``surf``: can a point of it be lit by ``src`` and see a detector on its
    lit side? False only when it cannot (a conservative test, no rays): the detectors' bounding box
    lies wholly behind the triangle's plane on every side the source can light."""
    tri_mm = spec.triangles_mm
    n = comp.normals[surf]
    det = np.concatenate([d.triangles_mm.reshape(-1, 3) for d in comp.detectors])
    lo, hi = det.min(axis=0), det.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    height = n @ corners.T - np.einsum("ij,ij->i", n, tri_mm[surf, 0])[:, None]  # (m, 8) above the plane
    if isinstance(src, CollimatedDisk):
        sides = np.sign(n @ -src.direction)[:, None]
    else:  # the side facing the point source, at each vertex (it may change across a triangle)
        sides = np.sign(np.stack([np.einsum("ij,ij->i", n, src.position_mm - tri_mm[surf, k]) for k in range(3)],
                                 axis=1))
    ok = np.zeros(len(surf), dtype=bool)
    for k in range(sides.shape[1]):
        s = sides[:, k]
        ok |= (s != 0) & ((s[:, None] * height) > 0).any(axis=1)
    return ok


def probe_scores(spec, comp, tris, m, rng, contribution):
    """sqrt(mean g^2) over ``m`` probes per triangle of ``tris`` (stratified along the first
    barycentric coordinate), summed over the detectors; ``contribution(t, x, u_det, j)`` is g at points x
    of triangles t toward a uniform point of detector j (3 uniforms ``u_det`` per point)."""
    t = np.repeat(tris, m)
    u = rng.random((len(t), 5))
    u[:, 0] = (np.tile(np.arange(m), len(tris)) + u[:, 0]) / m
    x = triangle_points(spec.triangles_mm, t, u[:, 0], u[:, 1])
    g2 = np.zeros(len(t))
    for j in range(len(comp.det_parts)):
        g = contribution(t, x, u[:, 2:5], j)
        g2 += g * g
    return np.sqrt(g2.reshape(len(tris), m).mean(axis=1))


def _probe_scores(spec, comp, src, tris, m, rng):
    """:func:`probe_scores` of the single-scatter contribution lit straight by ``src``."""
    return probe_scores(spec, comp, tris, m, rng, lambda t, x, u, j: _single_scatter(spec, comp, src, t, x, u, j)[0])


def build_table(spec, comp, screen: bool = True) -> VertexTable:
    """Learn q_t from PROBES_PER_TRIANGLE probe points per surface triangle (module doc).

    ``screen``: on a scene probed in one stage, one probe per triangle on an own stream first; where
    none of them sees single scatter (behind a lens: the beam lights no surface the detector sees
    straight) the table is empty without the full probes (an eighth of their cost), and otherwise the
    full probes run on their own stream as without the screen (the same table).

    A scene with more surface triangles than PROBE_BUDGET / PROBES_PER_TRIANGLE is probed in two
    stages: one probe per triangle that may be lit and see a detector (:func:`_may_see_detector`)
    finds the parts that contribute at all; the budget then goes to those parts' triangles
    (PROBES_PER_TRIANGLE each when it allows). On the 0.6M-triangle hooked-vane assembly at 30 deg
    one probe per triangle found 943 contributing triangles, eight per triangle 2041 (relative
    error at 1e5 rays 5.3 % -> 0.94 %); the two stages find the eight-probe set at ~1/10 the cost."""
    src = spec.sources[0]
    tri_mm = spec.triangles_mm
    n_tri = len(tri_mm)
    # only parts whose interaction kind allows it are area-sampled (Capability.FIRST_VERTEX); the
    # others (mirrors, optical surfaces: exact normals, Fresnel branching) are left to the walk (q_t = 0)
    surf = np.flatnonzero(parts_with(spec, Capability.FIRST_VERTEX)[spec.triangle_part])
    area = 0.5 * np.linalg.norm(np.cross(tri_mm[:, 1] - tri_mm[:, 0], tri_mm[:, 2] - tri_mm[:, 0]), axis=1)
    surf = surf[area[surf] > 0]
    rng = np.random.default_rng([check_seed(spec.seed), PROBE_STREAM])
    face = None
    if screen and 0 < len(surf) * PROBES_PER_TRIANGLE <= PROBE_BUDGET:
        seen = _probe_scores(spec, comp, src, surf, 1, np.random.default_rng([check_seed(spec.seed), SCREEN_STREAM]))
        if not np.any(seen > 0):
            return VertexTable(np.zeros(0, np.int64), np.zeros(0), np.zeros(n_tri))
    if len(surf) * PROBES_PER_TRIANGLE > PROBE_BUDGET:
        surf = surf[_may_see_detector(spec, comp, src, surf)]
        first = _probe_scores(spec, comp, src, surf, 1, rng)
        parts = np.unique(spec.triangle_part[surf[first > 0]])
        surf = surf[np.isin(spec.triangle_part[surf], parts)]
        face = face_groups(spec, comp, surf)
    # at most PROBE_BUDGET probes in all (a million-triangle scene gets one per triangle)
    m = probes_per_triangle(len(surf))
    score = area[surf] * _probe_scores(spec, comp, src, surf, m, rng)
    if face is not None and len(surf):
        # defensive share: every triangle of a face where a probe saw single scatter keeps a part of
        # the face's mean density, so a lit and seen sliver its probes missed is still drawn
        face_mean = np.bincount(face, weights=score) / np.bincount(face, weights=area[surf])
        score = (1.0 - FACE_SHARE) * score + FACE_SHARE * area[surf] * face_mean[face]
    keep = score > 0
    p_area = np.zeros(n_tri)
    if not keep.any():
        return VertexTable(np.zeros(0, np.int64), np.zeros(0), p_area)
    q = score[keep] / score[keep].sum()
    p_area[surf[keep]] = q / area[surf[keep]]
    return VertexTable(surf[keep].astype(np.int64), np.cumsum(q), p_area)


def run_vertex_pass(spec, comp, table, first_chunk, stop_chunk, tallies, rows, records, record_paths, path_depth):
    """Add this strategy's MIS-weighted estimates for chunks ``first_chunk .. stop_chunk-1`` to ``tallies``
    (one sample per ray id and detector). Returns the number of shadow rays cast."""
    if len(table.tri) == 0:
        return 0
    C = CHUNK_RAYS
    n_total = spec.n_rays
    src = spec.sources[0]
    sizes = [chunk_bounds(k, n_total)[1] - k * C for k in range(first_chunk, stop_chunk)]
    D = len(comp.det_parts)
    u_all = np.concatenate([vertex_rng(spec.seed, spec.chunk_offset + first_chunk + c).random((sizes[c], 6 * D))
                            for c in range(len(sizes))])
    lobe = bool(spec.options.estimator.vertex_lobe_sampling)
    if lobe:
        u_lobe = np.concatenate([np.random.default_rng([check_seed(spec.seed), spec.chunk_offset + first_chunk + c,
                                                        LOBE_STREAM]).random((sizes[c], 3 * D))
                                 for c in range(len(sizes))])
    shadows = 0
    for j in range(D):
        u = u_all[:, 6 * j:6 * j + 6]
        k = np.minimum(np.searchsorted(table.cdf, u[:, 0] * table.cdf[-1], side="right"), len(table.tri) - 1)
        t = table.tri[k]
        x = triangle_points(spec.triangles_mm, t, u[:, 1], u[:, 2])
        g, z, s = _single_scatter(spec, comp, src, t, x, u[:, 3:6], j, lobe_mis=lobe)
        shadows += s
        good = np.flatnonzero(g > 0)
        terms = [(good, g[good] * comp.detectors[j].area_mm2, z[good])]
        if lobe:
            value, z_hit, at, s = lobe_connection(spec, comp, src, t, x, u_lobe[:, 3 * j:3 * j + 3], j)
            shadows += s
            terms.append((at, value, z_hit))
        for r, value, zz in terms:
            if len(r) == 0:
                continue
            tg = t[r]
            p_a = table.p_area[tg]
            p_f = forward_density(src, x[r], comp.normals[tg])
            c = value / (p_a + p_f) / n_total
            _add_vertex_terms(spec, comp, j, tallies, rows, records, record_paths, path_depth, r, tg, zz, c)
    return shadows


def _add_vertex_terms(spec, comp, j, tallies, rows, records, record_paths, path_depth, r, tg, z, c):
    """Contributions ``c`` of rays ``r`` (vertices on triangles ``tg``) to detector j, and their
    path records; the same amount leaves the vertex part's NEE-exchange row (exact ledger)."""
    pt = spec.triangle_part[tg].astype(np.int64)
    tallies.add(rows.detector_nee + j, r, c)
    tallies.subtract(rows.nee_exchange + pt, r, c)
    keys = events = None
    if record_paths:
        code = pt * 4 + EVENT_SCATTER
        keys = mix_key(mix_key(np.zeros(len(r), dtype=np.uint64), code), comp.det_parts[j] * 4 + EVENT_DETECTOR)
        events = np.full((len(r), path_depth), -1, dtype=np.int16)
        if path_depth > 0:
            events[:, 0] = code
    records.add(j, r, z, c, keys, events, np.ones(len(r), dtype=np.int64))


def forward_weight(spec, table, normals, tri, p):
    """Balance-heuristic weight p_F / (p_F + p_A) of the forward walk's first vertices
    (triangles ``tri``, points ``p``)."""
    p_a = table.p_area[tri]
    p_f = forward_density(spec.sources[0], p, normals[tri])
    return np.where(p_a > 0, p_f / (p_f + p_a), 1.0)


class FirstVertexWeights:
    """The forward walk's side of the MIS: the weight of each ray's first (scatter) vertex, kept
    per ray of the batch, applied to its NEE contributions (:meth:`vertex_weights`) and to its walk
    hit on a detector right after that vertex (:meth:`share_single_scatter`)."""

    def __init__(self, spec, table, n_rays_in_batch):
        self.spec = spec
        self.table = table
        self.w_first = np.ones(n_rays_in_batch)

    def vertex_weights(self, event, verts):
        """Forward MIS weights of the scatter vertices ``verts`` (1 unless it is the ray's first event)."""
        first = np.flatnonzero(event.rays.last_event[verts] == EVENT_SOURCE)
        if len(first) == 0:
            return None
        w_vertex = np.ones(len(verts))
        at = verts[first]
        w_vertex[first] = forward_weight(self.spec, self.table, event.scene.normals, event.tri[at],
                                         event.hits.point_mm[at])
        self.w_first[event.rays.ray[at]] = w_vertex[first]
        return w_vertex

    def share_single_scatter(self, event, rec, rec_w):
        """Walk hits on a detector straight after a ray's first (scatter) event keep only their forward
        MIS share ``w_first`` (the rest is the vertex-sampling strategy's); the remainder goes to the
        NEE exchange, so the ledger stays exact. Returns the hits still counted and their weights."""
        rays = event.rays
        single = np.flatnonzero((rays.last_event[rec] == EVENT_SCATTER) & (rays.depth[rec] == 1))
        if len(single) == 0:
            return rec, rec_w
        return keep_walk_share(event, rec, rec_w, single, self.w_first[rays.ray[rec[single]]])
