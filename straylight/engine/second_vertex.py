"""Second-vertex sampling: area sampling of the surfaces the detector sees, combined with the walk by MIS.

With ``EstimatorOptions(second_vertex_sampling=True)`` the paths

    ... -> scatter vertex A -> (straight) -> surface point B -> (NEE) -> detector point z

get a second way to pick B. The walk picks B by sampling the BRDF at A and casting the ray; then
NEE joins B to the detector. Off axis in a baffled tube that is a rare event: A (a lit wall or
vane face) scatters into a wide lobe, and only the small part of the tube the detector sees
(the lower vanes' faces and hooks) makes B count -- on the hooked-vane assembly at 30 deg one
such ray carried 84 % of a run's variance. The second strategy draws B directly on the
*critical* surfaces (triangle t with probability q_t, uniform on it: area density
p_C(B) = q_t / A_t), joins A -> B by a shadow ray, and does the same NEE from B.

Both estimates of a path are weighted by the balance heuristic (Veach 1997, ch. 9, eq. 9.10):
with p_W(B) = pdf_A(wo) |cos_B| / d_AB^2 the walk's area density of B (its BRDF-sample, or
target-mixture, pdf at A),

    walk:    NEE at B  x  p_W / (p_W + p_C)
    area:    w_A f_A cos_A |cos_B| / d_AB^2 / (p_W + p_C)  x  f_B cos_B' cos_z A_det / d_Bz^2 x m_nee

(the second factor is the walk's own NEE estimate at B, with the same power-heuristic weight m_nee
against BRDF sampling at B). The random walk's hits on the detector after B keep their weight
1 - m_nee; so for every path the weights add to one and the sum is unbiased for any table q
(triangles with q_t = 0, parts that are not ``brdf_scatter`` surfaces, and B reached after a
specular event are left to the walk alone).

The table q is learnt before the run from probes (own random stream, seed only, so results do
not depend on batch size, threads or workers): q_t is proportional to A_t x (how well the
detector sees t: sqrt of the mean of g^2 over probe points, g = |cos_x| cos_z A_det / d^2 for an
unblocked uniform detector point) x (the mean direct irradiance on t's part, from 256 probes per
part; parts without direct light get q = 0). Stage 1 probes each triangle of the lit parts once;
stage 2 probes the faces (part, normal quantised to 1/8) where stage 1 saw anything, up to 16
times per triangle within a 400k budget, and gives every triangle of such a face half its own
score and half the face's mean (a sliver its probes missed is still drawn). On the hooked-vane
assembly at 30 deg the second vertices that matter are the undersides of the upper vanes just
outside their holes, lit by the vane below and seen by the detector straight down through all
the holes.

Cost: one A -> B shadow ray per ``brdf_scatter`` vertex and, if B is visible, one B -> z per
detector, two BRDF evaluations each. Contributions go to ``detector_nee`` and, negated, to the
part of B's NEE-exchange row, so the power ledger stays exact. Uses 3 + 3 D uniforms of the event
(columns ``EventColumns.second``). A vertex on the walk's last allowed event (``max_events``)
still gets the estimate (the walk itself would have truncated there: the reported truncation is
that much smaller).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from straylight.engine.face_groups import face_groups
from straylight.engine.interactions.registry import Capability, kinds_with, parts_with
from straylight.engine.interactions.stokes import tracks_polarization
from straylight.engine.lobes import lobe_materials
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER
from straylight.engine.targets import target_pdf
from straylight.engine.triangle_sampling import triangle_areas, triangle_points
from straylight.engine.vec3 import power_heuristic_rows
from straylight.engine.walk_shares import keep_walk_share
from straylight.paths import mix_key
from straylight.rng import check_seed
from straylight.sources import orthonormal_basis

TABLE_STREAM = 0x53454356  # entropy word of the table's probe stream
PART_PROBES = 256
PROBES_PER_TRIANGLE = 16
PROBE_BUDGET = 400_000


@dataclass(frozen=True, eq=False)
class CriticalTable:
    """``tri`` (m,) critical triangle ids, ``cdf`` (m,) cumulative q, ``p_area`` (n_triangles,) the
    area density q_t / A_t of every triangle (0 off the table), ``from_part`` (n_parts,) bool: parts
    whose vertices draw a second vertex (``brdf_scatter`` surfaces)."""

    tri: np.ndarray
    cdf: np.ndarray
    p_area: np.ndarray
    from_part: np.ndarray


def scatter_parts(spec) -> np.ndarray:
    """Bool per part: its interaction kind allows second-vertex sampling (Capability.SECOND_VERTEX)."""
    return parts_with(spec, Capability.SECOND_VERTEX)


def unsupported(spec) -> str | None:
    """Why the strategy cannot run on ``spec`` (None when it can). Its vertices are evaluated for
    unpolarized light (or the trace-wide s/p option), so it stays out of traces whose rays carry
    a polarization state (:func:`straylight.engine.interactions.stokes.tracks_polarization`, or a
    part whose material polarizes, Capability.POLARIZES: a ``surface_response`` with Fresnel
    interfaces): there the walk alone is used."""
    if tracks_polarization(spec):
        return "second_vertex_sampling does not follow polarized light (a linear source or scatter_polarization = 'on')"
    for polarizing in kinds_with(spec, Capability.POLARIZES):  # per material (its POLARIZING components)
        return f"second_vertex_sampling does not follow the polarization of {polarizing.name} parts"
    return None


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _detector_link(detector, u3, x, both: bool):
    """A point z on ``detector`` per row of ``x`` (from the uniforms ``u3``) and the link x -> z:
    unit direction w, squared and plain length, and the detector's cosine -w . n_z (its absolute
    value when both sides count)."""
    z, n_z = detector.sample(u3)
    v = z - x
    dsq = _dot(v, v)
    d = np.sqrt(dsq)
    w = v / np.where(d > 0, d, 1.0)[:, None]
    cos_z = -_dot(w, n_z)
    if both:
        cos_z = np.abs(cos_z)
    return z, w, dsq, d, cos_z


def _blocked(isect, origin, z, eps):
    """Bool per row: something lies between ``origin`` (already offset off its surface) and ``z``."""
    to_z = z - origin
    lz = np.sqrt(_dot(to_z, to_z))
    return np.asarray(isect.occluded(np.ascontiguousarray(origin), np.ascontiguousarray(to_z / lz[:, None]),
                                     lz - eps), dtype=bool)


def _local(v, tb, bb, nf):
    return np.stack([_dot(v, tb), _dot(v, bb), _dot(v, nf)], axis=1)


def part_illumination(spec, comp, parts, rng) -> np.ndarray:
    """Mean direct irradiance E (lit side, unblocked) over ``PART_PROBES`` area-uniform probes on each
    of ``parts`` (straylight.engine.first_vertex.source_connection); ones when the sources are not a
    single collimated or point source (then every part counts alike)."""
    # first_vertex imports the interaction kinds, whose NEE imports this module: imported here
    from straylight.engine.first_vertex import source_connection
    from straylight.engine.first_vertex import unsupported as first_vertex_unsupported

    out = np.ones(len(parts))
    if first_vertex_unsupported(spec.sources) is not None:
        return out
    src = spec.sources[0]
    tri_mm, area = spec.triangles_mm, triangle_areas(spec.triangles_mm)
    for k, p in enumerate(parts):
        tris = np.flatnonzero(spec.triangle_part == p)
        cdf = np.cumsum(area[tris])
        u = rng.random((PART_PROBES, 3))
        u[:, 0] = (np.arange(PART_PROBES) + u[:, 0]) / PART_PROBES  # stratified over the part's area
        t = tris[np.minimum(np.searchsorted(cdf, u[:, 0] * cdf[-1], side="right"), len(tris) - 1)]
        x = triangle_points(tri_mm, t, u[:, 1], u[:, 2])
        wi, nf, e, tmax = source_connection(src, x, comp.normals[t])
        lit = np.flatnonzero(e > 0)
        if len(lit):
            o = np.ascontiguousarray(x[lit] + spec.eps * nf[lit])
            blocked = np.asarray(comp.isect.occluded(o, np.ascontiguousarray(wi[lit]), tmax[lit]), dtype=bool)
            e[lit[blocked]] = 0.0
        out[k] = e.mean()
    return out


def _seen_scores(spec, comp, tris, m, rng) -> np.ndarray:
    """sqrt(mean g^2) over ``m`` probes per triangle (stratified along the first barycentric
    coordinate), g = |cos_x| cos_z A_det / d^2 for an unblocked uniform detector point z, summed over
    the detectors: how well the detector sees the triangle (either side)."""
    t = np.repeat(tris, m)
    u = rng.random((len(t), 5))
    u[:, 0] = (np.tile(np.arange(m), len(tris)) + u[:, 0]) / m
    x = triangle_points(spec.triangles_mm, t, u[:, 0], u[:, 1])
    n = comp.normals[t]
    g2 = np.zeros(len(t))
    both = spec.options.output.detector_sides == "both"
    for j in range(len(comp.det_parts)):
        z, w, d2, d, cz = _detector_link(comp.detectors[j], u[:, 2:5], x, both)
        cx = _dot(w, n)
        ok = np.flatnonzero((np.abs(cx) > 0) & (cz > 0) & (d > 2 * spec.eps))
        if len(ok) == 0:
            continue
        side = np.sign(cx[ok])[:, None] * n[ok]
        ok = ok[~_blocked(comp.isect, x[ok] + spec.eps * side, z[ok], spec.eps)]
        g = np.abs(cx[ok]) * cz[ok] * comp.detectors[j].area_mm2 / d2[ok]
        g2[ok] += g * g
    return np.sqrt(g2.reshape(len(tris), m).mean(axis=1))


def build_table(spec, comp) -> CriticalTable:
    """q_t proportional to A_t x (how well the detector sees t) x (direct irradiance on t's part):
    the second vertices that matter are surfaces the detector sees *near* lit ones (on the hooked-vane
    assembly at 30 deg: the undersides of the upper vanes just outside their holes, lit by the vane
    below, seen by the detector through a sliver). Stage 1: one probe per triangle of the lit
    scatter parts; stage 2: up to ``PROBES_PER_TRIANGLE`` probes per triangle on the faces (part,
    quantised normal) where stage 1 saw anything, within ``PROBE_BUDGET``. Own random stream (seed
    only): the table is the same for any batch size, thread or worker count."""
    from_part = scatter_parts(spec)
    n_tri = len(spec.triangles_mm)
    area = triangle_areas(spec.triangles_mm)
    rng = np.random.default_rng([check_seed(spec.seed), TABLE_STREAM])
    parts = np.flatnonzero(from_part)
    light = np.zeros(len(spec.part_roles))
    light[parts] = part_illumination(spec, comp, parts, rng)
    tris = np.flatnonzero((light[spec.triangle_part] > 0) & (area > 0))
    p_area = np.zeros(n_tri)
    empty = CriticalTable(np.zeros(0, np.int64), np.zeros(0), p_area, from_part)
    if len(tris) == 0:
        return empty
    seen = _seen_scores(spec, comp, tris, 1, rng)
    group = face_groups(spec, comp, tris)
    hit_groups = np.unique(group[seen > 0])
    tris = tris[np.isin(group, hit_groups)]
    if len(tris) == 0:
        return empty
    group = group[np.isin(group, hit_groups)]
    m = int(min(PROBES_PER_TRIANGLE, max(1, PROBE_BUDGET // len(tris))))
    seen = _seen_scores(spec, comp, tris, m, rng)
    # defensive half: every triangle of a face the detector sees gets the face's mean density, so a
    # sliver its probes missed is still drawn (q_t = 0 would leave it to the rare walk hits)
    a_t = area[tris]
    group = np.unique(group, return_inverse=True)[1].ravel()
    face_mean = np.bincount(group, weights=a_t * seen) / np.bincount(group, weights=a_t)
    score = a_t * (0.5 * seen + 0.5 * face_mean[group]) * light[spec.triangle_part[tris]]
    keep = score > 0
    if not keep.any():
        return empty
    q = score[keep] / score[keep].sum()
    p_area[tris[keep]] = q / area[tris[keep]]
    return CriticalTable(tris[keep].astype(np.int64), np.cumsum(q), p_area, from_part)


def walk_weights(event, verts, w_vertex):
    """The walk's balance-heuristic share p_W / (p_W + p_C) of the scatter vertices ``verts`` (rows
    of the event) reached straight from a ``brdf_scatter`` vertex, times ``w_vertex`` (first-vertex
    weights or None). Returns the weights for :func:`straylight.engine.nee.estimate` (or None: all 1)."""
    table = event.spec.critical_table
    rays, hit = event.rays, event.hits
    p_c = table.p_area[event.tri[verts]]
    last = rays.last_part[verts]
    prev = (rays.last_event[verts] == EVENT_SCATTER) & (last >= 0)
    prev[prev] = table.from_part[last[prev]]
    s = np.flatnonzero(prev & (p_c > 0))
    if len(s) == 0:
        return w_vertex
    i = verts[s]
    dist = hit.distance_mm[i]
    p_w = rays.last_pdf_per_sr[i] * np.abs(hit.cos_in[i]) / (dist * dist)
    share = p_w / (p_w + p_c[s])
    shares = event.states.get("second_vertex")  # SecondVertexShares with second_vertex_lobe_sampling
    if shares is not None:  # the area strategy draws B's lobe on glossy materials only
        glossy = lobe_materials(event.spec)[event.spec.part_material[hit.part[i]]]
        shares.keep(event, i, np.where(glossy, share, 1.0))
    w = np.ones(len(verts)) if w_vertex is None else w_vertex.copy()
    w[s] *= share
    return w


class SecondVertexShares:
    """With ``second_vertex_lobe_sampling`` the area strategy also leaves its critical point B along the
    lobe's own draw (:func:`_lobe_terms`), so the walk's BRDF-sampled hit on a detector straight
    after such a B keeps only its balance-heuristic share p_W / (p_W + p_C) of B; kept per ray of
    the batch (with the depth at which that hit would come), the rest goes to the NEE exchange."""

    def __init__(self, n_rays_in_batch):
        self.share = np.ones(n_rays_in_batch)
        self.at_depth = np.full(n_rays_in_batch, -1, dtype=np.int64)

    def keep(self, event, rows, share):
        r = event.rays.ray[rows]
        self.share[r] = share
        self.at_depth[r] = event.rays.depth[rows] + 1

    def share_after_vertex(self, event, rec, rec_w):
        """Walk hits on a detector straight after a shared B keep ``share`` (ledger exact)."""
        rays = event.rays
        r_all = rays.ray[rec]
        after = np.flatnonzero((rays.last_event[rec] == EVENT_SCATTER) & (self.at_depth[r_all] == rays.depth[rec])
                               & (self.share[r_all] < 1.0))
        if len(after) == 0:
            return rec, rec_w
        return keep_walk_share(event, rec, rec_w, after, self.share[r_all[after]])


def _brdf_pdf(spec, mat, wi, wo, with_pdf=True):
    f = np.empty(len(wi))
    pdf = np.empty(len(wi))
    pol = spec.options.physics.polarization
    for rows, (fv, pv) in by_material(spec.materials, mat, lambda model, rows: (
            model.brdf(wi[rows], wo[rows], pol), model.pdf(wi[rows], wo[rows], pol) if with_pdf else 0.0)):
        f[rows] = fv
        pdf[rows] = pv
    return f, pdf


def _mixture_pdf(event, pdf, p, nf, dirs, part):
    """The walk's direction density at vertices on parts ``part``: with target parts on and a kind
    that mixes them in (Capability.TARGET_MIS), (1 - q) pdf_brdf + q pdf_target."""
    target = event.scene.target
    if target is None:
        return pdf
    q = float(event.spec.options.estimator.target_fraction)
    mixed = event.capabilities.at(Capability.TARGET_MIS, part)
    if mixed.all():
        return (1 - q) * pdf + q * target_pdf(target, p, nf, dirs, event.spec.eps)
    out = pdf.copy()
    m = np.flatnonzero(mixed)
    out[m] = (1 - q) * pdf[m] + q * target_pdf(target, p[m], nf[m], dirs[m], event.spec.eps)
    return out


def estimate(event, verts, frame):
    """The area strategy from the scatter vertices ``verts`` (rows of the event; local frames
    ``frame``, straylight.engine.interactions.brdf_scatter.LocalFrames): one critical point B per
    vertex, NEE from B to each detector; tallies, records, counts shadow rays (module doc)."""
    spec, hit, scene = event.spec, event.hits, event.scene
    table = spec.critical_table
    if len(table.tri) == 0:
        return
    s = np.flatnonzero(table.from_part[hit.part[verts]])
    if len(s) == 0:
        return
    eps = spec.eps
    i = verts[s]
    col = event.columns.second
    u = event.uniforms[i, col:col + 3]
    k = np.minimum(np.searchsorted(table.cdf, u[:, 0] * table.cdf[-1], side="right"), len(table.tri) - 1)
    t = table.tri[k]
    y = triangle_points(spec.triangles_mm, t, u[:, 1], u[:, 2])
    p_a, n_a = hit.point_mm[i], hit.facing_normal[i]
    v = y - p_a
    d1sq = _dot(v, v)
    d1 = np.sqrt(d1sq)
    w = v / np.where(d1 > 0, d1, 1.0)[:, None]
    cos_a = _dot(w, n_a)
    n_y = scene.normals[t]
    c_y = _dot(w, n_y)
    ok = np.flatnonzero((cos_a > 0) & (np.abs(c_y) > 1e-12) & (d1 > 2 * eps))
    if len(ok) == 0:
        return
    s, i, t, y, w, d1sq, cos_a, c_y = (a[ok] for a in (s, i, t, y, w, d1sq, cos_a, c_y))
    origin = p_a[ok] + eps * n_a[ok]
    to_y = y - origin
    ly = np.sqrt(_dot(to_y, to_y))
    blocked = np.asarray(scene.isect.occluded(np.ascontiguousarray(origin), np.ascontiguousarray(to_y / ly[:, None]),
                                              ly - eps), dtype=bool)
    event.shadow_rays += len(ok)
    ok = np.flatnonzero(~blocked)
    if len(ok) == 0:
        return
    s, i, t, y, w, d1sq, cos_a, c_y = (a[ok] for a in (s, i, t, y, w, d1sq, cos_a, c_y))
    # the walk's side at A: f_A and its direction density toward B
    wo_a = np.stack([_dot(w, frame.tangent[s]), _dot(w, frame.bitangent[s]), cos_a], axis=1)
    f_a, pdf_a = _brdf_pdf(spec, frame.material[s], frame.wi_local[s], wo_a)
    pdf_a = _mixture_pdf(event, pdf_a, hit.point_mm[i], hit.facing_normal[i], w, hit.part[i])
    cos_b = np.abs(c_y)
    p_w = pdf_a * cos_b / d1sq
    p_c = table.p_area[t]
    base = event.rays.weight_w[i] * f_a * cos_a * cos_b / d1sq / (p_w + p_c)
    ok = np.flatnonzero(base > 0)
    if len(ok) == 0:
        return
    s, i, t, y, w, base = (a[ok] for a in (s, i, t, y, w, base))
    nf_y = np.where((_dot(w, scene.normals[t]) < 0)[:, None], scene.normals[t], -scene.normals[t])
    tb_y, bb_y = orthonormal_basis(nf_y)
    wi_y = _local(-w, tb_y, bb_y, nf_y)
    mat_y = spec.part_material[spec.triangle_part[t]]
    part_y = spec.triangle_part[t].astype(np.int64)
    k_nee = event.settings.nee_samples
    both = event.settings.both_sides
    for j in range(len(scene.det_parts)):
        c0 = col + 3 + 3 * j
        z, w2, d2sq, d2, cos_z = _detector_link(scene.detectors[j], event.uniforms[i, c0:c0 + 3], y, both)
        cos_o = _dot(w2, nf_y)
        g = np.flatnonzero((cos_o > 0) & (cos_z > 0) & (d2 > 2 * eps))
        if len(g) == 0:
            continue
        blocked = _blocked(scene.isect, y[g] + eps * nf_y[g], z[g], eps)
        event.shadow_rays += len(g)
        g = g[~blocked]
        if len(g) == 0:
            continue
        wo_y = _local(w2[g], tb_y[g], bb_y[g], nf_y[g])
        f_y, pdf_y = _brdf_pdf(spec, mat_y[g], wi_y[g], wo_y)
        pdf_y = _mixture_pdf(event, pdf_y, y[g], nf_y[g], w2[g], part_y[g])
        area = float(scene.arrays.detector_area_mm2[j])
        p_nee = k_nee * d2sq[g] / (area * cos_z[g])
        c = base[g] * f_y * cos_o[g] * cos_z[g] * area / d2sq[g] * power_heuristic_rows(p_nee, pdf_y)
        good = c > 0
        if not good.any():
            continue
        g, c = g[good], c[good]
        r = event.rays.ray[i[g]]
        tallies, rows = event.tallies, event.rows
        tallies.add(rows.detector_nee + j, r, c)
        tallies.subtract(rows.nee_exchange + part_y[g], r, c)
        _record(event, j, i[g], part_y[g], z[g], c)
    if event.states.get("second_vertex") is not None:
        _lobe_terms(event, i, y, nf_y, tb_y, bb_y, wi_y, mat_y, part_y, base)


def _lobe_terms(event, i, y, nf_y, tb_y, bb_y, wi_y, mat_y, part_y, base):
    """The area strategy's second way out of B: the direction drawn from B's own lobe (uniforms
    ``columns.second_lobe``), kept when its ray reaches a detector first; weighted by the power
    heuristic against the uniform detector point exactly as the walk weights its own hits after B
    (power_heuristic(pdf, p_nee)), so the area strategy's weights at B add to one, and the walk's
    hits after B keep p_W / (p_W + p_C) (:class:`SecondVertexShares`)."""
    spec, scene = event.spec, event.scene
    glossy = np.flatnonzero(lobe_materials(spec)[mat_y])
    if len(glossy) < len(mat_y):
        i, y, nf_y, tb_y, bb_y, wi_y, mat_y, part_y, base = (
            a[glossy] for a in (i, y, nf_y, tb_y, bb_y, wi_y, mat_y, part_y, base))
    eps = spec.eps
    col = event.columns.second_lobe
    u = event.uniforms[i, col:col + 3]
    wo = np.empty((len(i), 3))
    weight = np.empty(len(i))
    pol = spec.options.physics.polarization
    for rows, smp in by_material(spec.materials, mat_y, lambda model, rows: model.sample(wi_y[rows], u[rows], pol)):
        wo[rows], weight[rows] = smp.wo, smp.weight
    ok = np.flatnonzero((wo[:, 2] > 0) & (weight > 0))
    if len(ok) == 0:
        return
    d = wo[ok, :1] * tb_y[ok] + wo[ok, 1:2] * bb_y[ok] + wo[ok, 2:3] * nf_y[ok]
    d = np.ascontiguousarray(d / np.linalg.norm(d, axis=1)[:, None])
    origin = np.ascontiguousarray(y[ok] + eps * nf_y[ok])
    tri, dist = scene.isect.intersect(origin, d)
    event.shadow_rays += len(ok)
    tri, dist = np.asarray(tri), np.asarray(dist, dtype=np.float64)
    hit = tri >= 0
    det_of_part = scene.arrays.detector_of_part
    j_all = np.full(len(ok), -1, dtype=np.int64)
    j_all[hit] = det_of_part[spec.triangle_part[tri[hit]]]
    cos_in = np.zeros(len(ok))
    cos_in[hit] = _dot(d[hit], scene.normals[tri[hit]])
    good = (j_all >= 0) & (np.abs(cos_in) > 0) & (event.settings.both_sides | (cos_in < 0))
    g = np.flatnonzero(good)
    if len(g) == 0:
        return
    k = ok[g]
    j = j_all[g]
    _, pdf_mix = _brdf_pdf(spec, mat_y[k], wi_y[k], wo[k])
    pdf_mix = _mixture_pdf(event, pdf_mix, y[k], nf_y[k], d[g], part_y[k])
    area = scene.arrays.detector_area_mm2[j]
    p_nee = event.settings.nee_samples * dist[g] ** 2 / (area * np.abs(cos_in[g]))
    c = base[k] * weight[k] * power_heuristic_rows(pdf_mix, p_nee)
    for jj in np.unique(j):
        m = np.flatnonzero((j == jj) & (c > 0))
        if len(m) == 0:
            continue
        r = event.rays.ray[i[k[m]]]
        event.tallies.add(event.rows.detector_nee + int(jj), r, c[m])
        event.tallies.subtract(event.rows.nee_exchange + part_y[k[m]], r, c[m])
        _record(event, int(jj), i[k[m]], part_y[k[m]], origin[g[m]] + dist[g[m], None] * d[g[m]], c[m])


def _record(event, j, i, part_b, z, c):
    """Map (and path) records of the area strategy's contributions to detector j (rows ``i``)."""
    rays = event.rays
    keys = events = None
    depth = rays.depth[i]
    if event.settings.record_paths:
        code_a = event.hits.part[i] * 4 + EVENT_SCATTER
        code_b = part_b * 4 + EVENT_SCATTER
        keys = mix_key(mix_key(mix_key(rays.path_key[i], code_a), code_b), event.scene.det_parts[j] * 4 + EVENT_DETECTOR)
        events = rays.history[i]
        K = events.shape[1]
        for off, code in ((0, code_a), (1, code_b)):
            inside = np.flatnonzero(depth + off < K)
            events[inside, depth[inside] + off] = code[inside]
    event.records.add(j, rays.ray[i], z, c, keys, events, depth + 2)
