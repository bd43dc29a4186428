"""Stage: next-event estimation (NEE) toward the detector parts, at the BRDF scatter vertices.

At a vertex x, for each detector j and each of its k samples, a point y uniform over j's area
(triangle by Walker alias, then Turk 1990 barycentrics) and, if unoccluded, the contribution
``w f(wi, wo) cos_x cos_y A / |y - x|^2 * m_nee / k`` (area form of the rendering equation, pdf
1/A) with the power-heuristic MIS weight m_nee against BRDF sampling (Veach 1997, eq. 9.13; MIS
density of NEE k d^2 / (A cos_y)). Contributions go to ``detector_nee`` and, negated, to the
part's ``nee_exchange`` row (the walk's hits on the detector give back the rest), so the ledger
stays exact. Kernels: :func:`nee_pairs` (points), :func:`nee_shadow` (contributions and shadow
rays), :func:`nee_tally`; each with its numpy twin (same bits)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from materials.jit_cache import njit

from straylight.disk_sampling import annulus_point, annulus_points
from straylight.engine.material_groups import brdf_and_pdf, by_material
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER
from straylight.engine.tally_store import tally_add
from straylight.engine.vec3 import dot3, dot_rows, power_heuristic, power_heuristic_rows, take_rows
from straylight.paths import mix_key


class NeePairs(NamedTuple):
    """Vertex-detector sample pairs that face each other, vertex-major."""

    vertex: np.ndarray  # position of the vertex among the event's scatter vertices
    sample: np.ndarray  # j * k + sample number (j: detector)
    point_mm: np.ndarray  # (m, 3) point on the detector
    wo_local: np.ndarray  # (m, 3) direction to it in the vertex's local frame
    dist2_mm2: np.ndarray
    cos_vertex: np.ndarray
    cos_detector: np.ndarray
    direction: np.ndarray  # (m, 3) world direction to it


class ShadowRays(NamedTuple):
    pair: np.ndarray  # positions into the pairs of the contributions > 0
    contribution_w: np.ndarray
    origin_mm: np.ndarray
    direction: np.ndarray
    tmax_mm: np.ndarray


@njit(cache=True, nogil=True)
def nee_pairs(verts, frame, hit, U, u_col0, scene, settings):
    """Detector points for the vertices ``verts`` (rows of the event), kept when they face the
    vertex and the detector (cos_x > 0, cos_y > 0, d > 2 eps); fields of :class:`NeePairs`."""
    n_det = len(scene.detector_area_mm2)
    k_nee = settings.nee_samples
    ns = len(verts)
    m = ns * n_det * k_nee
    pair_vertex = np.empty(m, np.int64)
    pair_sample = np.empty(m, np.int64)
    y = np.empty((m, 3))
    wo_loc = np.empty((m, 3))
    wdir = np.empty((m, 3))
    dist2 = np.empty(m)
    cos_s = np.empty(m)
    cos_d = np.empty(m)
    q = 0
    two_eps = 2 * settings.eps_mm
    p, nf = hit.point_mm, hit.facing_normal
    tb, bb = frame.tangent, frame.bitangent
    det_off, prob, alias = scene.det_offset, scene.det_alias_prob, scene.det_alias
    v0, e1, e2, det_normals = scene.det_v0, scene.det_e1, scene.det_e2, scene.det_normals
    disk_r2 = scene.det_disk_r2
    for s in range(ns):
        i = verts[s]
        p0, p1, p2 = p[i, 0], p[i, 1], p[i, 2]
        f0, f1, f2 = nf[i, 0], nf[i, 1], nf[i, 2]
        for jk in range(n_det * k_nee):
            j = jk // k_nee
            c0 = u_col0 + 3 * jk
            ua, ub, uc = U[i, c0], U[i, c0 + 1], U[i, c0 + 2]
            lo, hi = det_off[j], det_off[j + 1]
            mt = hi - lo
            x = ua * mt
            kk = min(np.int64(x), mt - 1)
            k = kk if x - kk < prob[lo + kk] else alias[lo + kk]
            g = lo + k
            if disk_r2[j, 1] > 0.0:  # an analytic plane detector: its exact disk
                y0, y1, y2 = annulus_point(scene.det_disk_centre[j], scene.det_disk_u[j], scene.det_disk_v[j],
                                           disk_r2[j, 0], disk_r2[j, 1], ub, uc)
                m0, m1, m2 = scene.det_disk_normal[j, 0], scene.det_disk_normal[j, 1], scene.det_disk_normal[j, 2]
            else:
                su = np.sqrt(ub)
                bw1 = su * (1.0 - uc)
                bw2 = su * uc
                y0 = v0[g, 0] + bw1 * e1[g, 0] + bw2 * e2[g, 0]
                y1 = v0[g, 1] + bw1 * e1[g, 1] + bw2 * e2[g, 1]
                y2 = v0[g, 2] + bw1 * e1[g, 2] + bw2 * e2[g, 2]
                m0, m1, m2 = det_normals[g, 0], det_normals[g, 1], det_normals[g, 2]
            v0_, v1_, v2_ = y0 - p0, y1 - p1, y2 - p2
            dd2 = dot3(v0_, v1_, v2_, v0_, v1_, v2_)
            dist = np.sqrt(dd2)
            inv = dist if dist > 0 else 1.0
            a0, a1, a2 = v0_ / inv, v1_ / inv, v2_ / inv
            cs = dot3(a0, a1, a2, f0, f1, f2)
            cd = -dot3(a0, a1, a2, m0, m1, m2)
            if settings.both_sides:
                cd = abs(cd)
            if cs > 0 and cd > 0 and dist > two_eps:
                pair_vertex[q] = s
                pair_sample[q] = jk
                y[q, 0], y[q, 1], y[q, 2] = y0, y1, y2
                wo_loc[q, 0] = dot3(a0, a1, a2, tb[s, 0], tb[s, 1], tb[s, 2])
                wo_loc[q, 1] = dot3(a0, a1, a2, bb[s, 0], bb[s, 1], bb[s, 2])
                wo_loc[q, 2] = cs
                wdir[q, 0], wdir[q, 1], wdir[q, 2] = a0, a1, a2
                dist2[q] = dd2
                cos_s[q] = cs
                cos_d[q] = cd
                q += 1
    return pair_vertex[:q], pair_sample[:q], y[:q], wo_loc[:q], dist2[:q], cos_s[:q], cos_d[:q], wdir[:q]


def nee_pairs_numpy(verts, frame, hit, U, u_col0, scene, settings):
    """:func:`nee_pairs` in vectorised numpy (the reference)."""
    n_jk = len(scene.detector_area_mm2) * settings.nee_samples
    s = np.repeat(np.arange(len(verts)), n_jk)
    jk = np.tile(np.arange(n_jk), len(verts))
    j = jk // settings.nee_samples
    i = verts[s]
    c0 = u_col0 + 3 * jk
    ua, ub, uc = U[i, c0], U[i, c0 + 1], U[i, c0 + 2]
    lo = scene.det_offset[j]
    mt = scene.det_offset[j + 1] - lo
    x = ua * mt
    kk = np.minimum(x.astype(np.int64), mt - 1)
    g = lo + np.where(x - kk < scene.det_alias_prob[lo + kk], kk, scene.det_alias[lo + kk])
    su = np.sqrt(ub)
    bw1 = (su * (1.0 - uc))[:, None]
    bw2 = (su * uc)[:, None]
    y = scene.det_v0[g] + bw1 * scene.det_e1[g] + bw2 * scene.det_e2[g]
    normal_y = scene.det_normals[g]
    for jd in np.flatnonzero(scene.det_disk_r2[:, 1] > 0):  # analytic plane detectors: their exact disks
        rows = np.flatnonzero(j == jd)
        r2 = scene.det_disk_r2[jd]
        y[rows] = annulus_points(scene.det_disk_centre[jd], scene.det_disk_u[jd], scene.det_disk_v[jd], r2[0], r2[1],
                                 np.ascontiguousarray(ub[rows]), np.ascontiguousarray(uc[rows]), np.empty((len(rows), 3)))
        normal_y[rows] = scene.det_disk_normal[jd]
    v = y - take_rows(hit.point_mm, i)
    dd2 = dot_rows(v, v)
    dist = np.sqrt(dd2)
    a = v / np.where(dist > 0, dist, 1.0)[:, None]
    cs = dot_rows(a, take_rows(hit.facing_normal, i))
    cd = -dot_rows(a, normal_y)
    if settings.both_sides:
        cd = np.abs(cd)
    ok = np.flatnonzero((cs > 0) & (cd > 0) & (dist > 2 * settings.eps_mm))
    a, s_ok = a[ok], s[ok]
    wo_loc = np.stack([dot_rows(a, take_rows(frame.tangent, s_ok)), dot_rows(a, take_rows(frame.bitangent, s_ok)),
                       cs[ok]], axis=-1)
    return s_ok, jk[ok], y[ok], wo_loc, dd2[ok], cs[ok], cd[ok], a


@njit(cache=True, nogil=True)
def nee_shadow(pairs, f, pdf_brdf, verts, rays, hit, scene, settings):
    """Contributions c = w f cos_x cos_y A / d^2 * m_nee / k, and the shadow rays of those with
    c > 0 (from the vertex lifted eps, stopping eps short of y); fields of :class:`ShadowRays`."""
    m = len(pairs.vertex)
    k_nee = settings.nee_samples
    eps = settings.eps_mm
    keep = np.empty(m, np.int64)
    contribution = np.empty(m)
    shadow_origin = np.empty((m, 3))
    shadow_dir = np.empty((m, 3))
    tmax = np.empty(m)
    p, nf, w = hit.point_mm, hit.facing_normal, rays.weight_w
    q = 0
    for a in range(m):
        i = verts[pairs.vertex[a]]
        area = scene.detector_area_mm2[pairs.sample[a] // k_nee]
        dist2, cos_d = pairs.dist2_mm2[a], pairs.cos_detector[a]
        p_nee = k_nee * dist2 / (area * cos_d)
        c = w[i] * f[a] * pairs.cos_vertex[a] * cos_d * area / dist2 * power_heuristic(p_nee, pdf_brdf[a]) / k_nee
        if c > 0:
            oo0 = p[i, 0] + eps * nf[i, 0]
            oo1 = p[i, 1] + eps * nf[i, 1]
            oo2 = p[i, 2] + eps * nf[i, 2]
            y = pairs.point_mm
            v0_, v1_, v2_ = y[a, 0] - oo0, y[a, 1] - oo1, y[a, 2] - oo2
            lo = np.sqrt(dot3(v0_, v1_, v2_, v0_, v1_, v2_))
            keep[q] = a
            contribution[q] = c
            shadow_origin[q, 0], shadow_origin[q, 1], shadow_origin[q, 2] = oo0, oo1, oo2
            shadow_dir[q, 0], shadow_dir[q, 1], shadow_dir[q, 2] = v0_ / lo, v1_ / lo, v2_ / lo
            tmax[q] = lo - eps
            q += 1
    return keep[:q], contribution[:q], shadow_origin[:q], shadow_dir[:q], tmax[:q]


def nee_shadow_numpy(pairs, f, pdf_brdf, verts, rays, hit, scene, settings):
    """:func:`nee_shadow` in vectorised numpy (the reference)."""
    k_nee = settings.nee_samples
    eps = settings.eps_mm
    i = verts[pairs.vertex]
    area = scene.detector_area_mm2[pairs.sample // k_nee]
    p_nee = k_nee * pairs.dist2_mm2 / (area * pairs.cos_detector)
    c = (rays.weight_w[i] * f * pairs.cos_vertex * pairs.cos_detector * area / pairs.dist2_mm2
         * power_heuristic_rows(p_nee, pdf_brdf) / k_nee)
    keep = np.flatnonzero(c > 0)
    i = i[keep]
    shadow_origin = take_rows(hit.point_mm, i) + eps * take_rows(hit.facing_normal, i)
    v = pairs.point_mm[keep] - shadow_origin
    lo = np.sqrt(dot_rows(v, v))
    return keep, c[keep], shadow_origin, v / lo[:, None], lo - eps


NEE_WRITES_PER_SHADOW_RAY = 2  # tally writes per unblocked shadow ray in :func:`nee_tally`


@njit(cache=True, nogil=True)
def nee_tally(shadow, blocked, pairs, verts, rays, hit, k_nee, log, rows):
    """Add the unblocked contributions to the detector and (negated) to the part's NEE exchange, into
    ``log`` (straylight.engine.tally_store); returns the positions (into the shadow rays) of the
    unblocked ones."""
    m = len(shadow.pair)
    ok = np.empty(m, np.int64)
    q = 0
    for b in range(m):
        if blocked[b]:
            continue
        a = shadow.pair[b]
        i = verts[pairs.vertex[a]]
        r = rays.ray[i]
        tally_add(log, rows.detector_nee + pairs.sample[a] // k_nee, r, shadow.contribution_w[b])
        tally_add(log, rows.nee_exchange + hit.part[i], r, -shadow.contribution_w[b])
        ok[q] = b
        q += 1
    return ok[:q]


def nee_tally_numpy(shadow, blocked, pairs, verts, rays, hit, k_nee, M, rows):
    """:func:`nee_tally` in numpy (np.add.at: repeated (row, ray) cells added in order)."""
    ok = np.flatnonzero(~np.asarray(blocked, dtype=bool))
    a = shadow.pair[ok]
    i = verts[pairs.vertex[a]]
    r = rays.ray[i]
    c = shadow.contribution_w[ok]
    np.add.at(M, (rows.detector_nee + pairs.sample[a] // k_nee, r), c)
    np.subtract.at(M, (rows.nee_exchange + hit.part[i], r), c)
    return ok


def estimate(event, verts, frame, w_vertex, evaluate=None):
    """NEE from the scatter vertices ``verts`` (rows of the event) with local frames ``frame``
    (straylight.engine.interactions.brdf_scatter.LocalFrames); ``w_vertex``: first-vertex MIS
    weights per vertex or None. Tallies, records and counts the shadow rays. ``evaluate(wi, wo,
    vertex)``, if given, returns ``(f, pdf)`` for local directions of the vertices ``vertex``
    (positions in ``verts``) instead of the materials' ``brdf``/``pdf`` (e.g. per-ray polarization).

    The strategies that work with NEE come in through the walk's ``event.nee_hooks``
    (straylight.engine.strategies.base.Strategy: ``nee_weights``, ``nee_density``, ``after_nee``): e.g.
    second-vertex sampling gives the vertices reached straight from a scatter vertex their walk share and
    draws, after NEE, each vertex's critical second vertex; target sampling mixes its density into the
    walk's. Shadow rays are tested by ``event.shadow_test`` (the walk's: occlusion and diffracting edges).

    With ``nee_split`` (straylight.engine.nee_split) the heavy glossy vertices take K > ``nee_samples``
    samples per detector, all weighed as one K-sample MIS."""
    hooks = event.nee_hooks
    mix = None
    for strategy, state in hooks:
        w_vertex = strategy.nee_weights(state, event, verts, w_vertex)
        mix = strategy.nee_density(state, event, verts) or mix
    split = event.states.get(SPLIT_KEY)
    k_vertex = None
    if split is not None:
        k_vertex = split.counts(event, verts, frame, w_vertex, _probe_pairs(event))
    k0 = event.settings.nee_samples
    # K NEE samples and K lobe draws (the walk's own and K - 1 more) at a split vertex: MIS weights
    # ph(K p_nee, K pdf) per sample / K; these k0 samples carry f k0 / K against pdf k0 (K / K)
    _estimate(event, verts, frame, w_vertex, evaluate, mix,
              None if k_vertex is None else (k0 / k_vertex, np.where(k_vertex > k0, float(k0), 1.0)))
    if k_vertex is not None:
        split_rows = np.flatnonzero(k_vertex > k0)
        block = split.uniforms(event, verts[split_rows])
        for k in np.unique(k_vertex[split_rows]):
            at = np.flatnonzero(k_vertex[split_rows] == k)
            sub = split_rows[at]
            more = int(k) - k0
            fr = type(frame)(*(a[sub] for a in frame))
            wv = None if w_vertex is None else w_vertex[sub]
            ev = None if evaluate is None else (lambda wi, wo, v, sub=sub: evaluate(wi, wo, sub[v]))
            if more > 0:
                _estimate(event, np.ascontiguousarray(verts[sub]), fr, wv, ev,
                          None if mix is None else (lambda pdf, v, d, sub=sub: mix(pdf, sub[v], d)),
                          (np.full(len(sub), more / float(k)), np.full(len(sub), float(more))),
                          U=split.nee_uniforms(event, verts[sub], block[at], more), u_col0=0,
                          settings=event.settings._replace(nee_samples=more))
            split.lobe_draws(event, verts[sub], fr, wv, ev, int(k), block[at])
    for strategy, state in hooks:
        strategy.after_nee(state, event, verts, frame)


SPLIT_KEY = "nee_split"  # the NeeSplit state's key on Event.states (straylight.engine.strategies.nee)


def _probe_pairs(event):
    """``pairs_of(verts, frame, U, k)`` for NeeSplit.counts: k fixed detector points per vertex."""
    def pairs_of(verts, frame, U, k):
        p = NeePairs(*event.kernels.nee_pairs(verts, frame, event.hits, U, 0, event.scene.arrays,
                                               event.settings._replace(nee_samples=k)))
        return p.vertex, p.sample, p.point_mm, p.wo_local, p.dist2_mm2, p.cos_vertex, p.cos_detector
    return pairs_of


def _estimate(event, verts, frame, w_vertex, evaluate, mix, scale=None, U=None, u_col0=None, settings=None):
    """NEE from ``verts``; ``scale`` (or None): per vertex, the factors of f and of the walk's density of
    the vertices split into K NEE samples and K lobe draws (k / K and k for the k samples of this call:
    each then weighs in as one of K, power heuristic of K p_nee against K pdf); ``U``, ``u_col0``,
    ``settings``: the uniforms and the sample count (default: the event's)."""
    spec, kern, hit = event.spec, event.kernels, event.hits
    settings = event.settings if settings is None else settings
    U = event.uniforms if U is None else U
    u_col0 = event.columns.nee if u_col0 is None else u_col0
    pol = spec.options.physics.polarization
    n_jk = len(event.scene.det_parts) * settings.nee_samples
    pairs = NeePairs(*kern.nee_pairs(verts, frame, hit, U, u_col0, event.scene.arrays, settings))
    if len(pairs.vertex) == 0:
        return
    pairs = _unblocked(event, pairs, verts, w_vertex)  # shadow rays first: the materials only where they count
    if len(pairs.vertex) == 0:
        return
    f = np.empty(len(pairs.vertex))
    pdf_brdf = np.empty(len(pairs.vertex))
    wi_local, mat = frame.wi_local, frame.material
    # materials see the same arrays in both walks: one call per (detector, sample) and material,
    # vertices in order (vectorised transcendental functions may round differently in a block's tail)
    for jk in range(n_jk):
        sel = np.flatnonzero(pairs.sample == jk) if n_jk > 1 else slice(None)
        wi_p = wi_local[pairs.vertex[sel]]
        wo_p = pairs.wo_local[sel]
        f_jk = np.empty(len(wi_p))
        pdf_jk = np.empty(len(wi_p))
        if evaluate is not None:
            f_jk[:], pdf_jk[:] = evaluate(wi_p, wo_p, pairs.vertex[sel])
        else:
            for rows, (fv, pv) in by_material(spec.materials, mat[pairs.vertex[sel]], lambda model, rows:
                    brdf_and_pdf(model, wi_p[rows], wo_p[rows], pol)):
                f_jk[rows] = fv
                pdf_jk[rows] = pv
        if mix is not None:  # the walk's density there mixes in another strategy's (target sampling)
            pdf_jk = mix(pdf_jk, pairs.vertex[sel], pairs.direction[sel])
        if scale is not None:  # k of K samples: ph(k p_nee, k pdf) = ph(K p_nee, K pdf), f k / K over k: / K
            f_jk = f_jk * scale[0][pairs.vertex[sel]]
            pdf_jk = pdf_jk * scale[1][pairs.vertex[sel]]
        f[sel] = f_jk if w_vertex is None else f_jk * w_vertex[pairs.vertex[sel]]
        pdf_brdf[sel] = pdf_jk
    shadow = ShadowRays(*kern.nee_shadow(pairs, f, pdf_brdf, verts, event.rays, hit, event.scene.arrays, settings))
    if len(shadow.pair) == 0:
        return
    blocked = np.zeros(len(shadow.pair), dtype=bool)  # every pair left is unblocked (_unblocked)
    event.tallies.reserve(NEE_WRITES_PER_SHADOW_RAY * len(shadow.pair))
    ok = kern.nee_tally(shadow, blocked, pairs, verts, event.rays, hit, settings.nee_samples,
                        event.tallies.kernel_arg, event.rows)
    if len(ok):
        _record(event, verts, pairs, shadow, ok, settings.nee_samples)


def _unblocked(event, pairs, verts, w_vertex) -> NeePairs:
    """The pairs whose shadow ray is not blocked (``event.shadow_test``), of those that can contribute
    (the ray's weight and the vertex's MIS weight > 0). The shadow rays are those of
    :func:`nee_shadow_numpy` (the kernel's bits): testing them before the materials are evaluated
    leaves every contribution as it was and spares the BRDF (and polarization) of the blocked pairs,
    nearly all of them behind a lens. Counts the casts in ``event.shadow_rays``."""
    eps = event.settings.eps_mm
    hit = event.hits
    i = verts[pairs.vertex]
    can = event.rays.weight_w[i] > 0
    if w_vertex is not None:
        can &= w_vertex[pairs.vertex] > 0
    cand = np.flatnonzero(can)
    i = i[cand]
    origin = take_rows(hit.point_mm, i) + eps * take_rows(hit.facing_normal, i)
    v = pairs.point_mm[cand] - origin
    lo = np.sqrt(dot_rows(v, v))
    blocked = event.shadow_test(origin, v / lo[:, None], lo - eps)
    event.shadow_rays += len(cand)
    keep = cand[~np.asarray(blocked, dtype=bool)]
    return NeePairs(*(a[keep] for a in pairs))


def _record(event, verts, pairs, shadow, ok, k_nee):
    """Map (and path) records of the unblocked NEE contributions, per detector. One record call per
    (detector, sample), as both walks make them: the map binning (a BLAS product) then sees the same
    arrays, so the bins are the same to the last bit."""
    a = shadow.pair[ok]
    c = shadow.contribution_w[ok]
    live = verts[pairs.vertex[a]]
    jk_a = pairs.sample[a]
    rays, part = event.rays, event.hits.part
    K = rays.history.shape[1]
    det_parts = event.scene.det_parts
    for jk in range(len(det_parts) * k_nee):
        j = jk // k_nee
        sel = np.flatnonzero(jk_a == jk)
        if len(sel) == 0:
            continue
        i = live[sel]
        keys = events = None
        if event.settings.record_paths:
            code = part[i] * 4 + EVENT_SCATTER
            keys = mix_key(mix_key(rays.path_key[i], code), det_parts[j] * 4 + EVENT_DETECTOR)
            events = rays.history[i]
            depth = rays.depth[i]
            inside = np.flatnonzero(depth < K)
            events[inside, depth[inside]] = code[inside]
        event.records.add(j, rays.ray[i], pairs.point_mm[a[sel]], c[sel], keys, events, rays.depth[i] + 1)
