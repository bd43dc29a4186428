"""NEE splitting at the heavy glossy vertices (``EstimatorOptions.nee_split``; docs/engine.md, "NEE
splitting at glints").

At a scatter vertex x whose NEE is predicted to carry much power, the walk takes K > k shadow-ray
samples per detector instead of the ``nee_samples`` = k, and weighs them and the walk's own BRDF-sampled
hit on a detector right after x as a K-sample multi-sample MIS (Veach 1997, eq. 9.13: power
heuristic with the NEE density K d^2 / (A cos_y), each sample / K). For every vertex the weights
of NEE and of the walk's hit still add to one, so the sum is unbiased whatever K is, as long as K
depends on the vertex only (never on a sample).

K comes from a prediction of the vertex's NEE contribution made with fixed detector points
(:data:`PROBE_UNIFORMS`, no shadow rays): e = w f cos_x cos_y A / d^2, the largest over the probe
points, times the vertex's first-vertex share; K = k 2^ceil(log2(e / (tau w0))) when e > tau w0
(w0: the start weight, tau = :data:`SPLIT_TAU`), at most ``nee_split``. Only materials with a
peaked lobe (``ComponentFlags.GLOSSY``) are split: there a glint (the lobe's peak on the
detector) makes a few vertices carry most of the power, and one uniform detector point or the one
lobe draw sees it by chance.

The K - k further samples draw their uniforms from an own stream per chunk (:data:`SPLIT_STREAM`),
consumed in ray order, so the event columns keep their bits and results do not depend on batch
size or threads. The walk's hit after a split vertex keeps ``ph(pdf, K p1) / ph(pdf, k p1)`` of
the weight the hit stage gave it (:meth:`NeeSplit.share_walk_hits`; the rest to the NEE exchange,
ledger exact)."""
from __future__ import annotations

import numpy as np

from straylight.engine.lobes import lobe_materials
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER
from straylight.engine.vec3 import power_heuristic_rows
from straylight.engine.walk_shares import keep_walk_share
from straylight.paths import mix_key
from straylight.rng import check_seed, chunk_stream_uniforms

SPLIT_STREAM = 0x4E53504C  # third entropy word of the further samples' streams ("NSPL")
#: the predicted contribution (in start weights) above which a vertex's NEE is split
SPLIT_TAU = 3e-7
#: fixed detector points of the prediction: the (alias, radial, angular) uniforms of the NEE sampler
#: (a disk detector: its centre; a mesh: a corner of its middle triangle in the alias table). Four more
#: at 0.7 of the radius found the same glints on the guide scope at 15 deg for 5x the BRDF calls
PROBE_UNIFORMS = ((0.5, 0.0, 0.0),)


class NeeSplit:
    """Per batch: the uniforms of the probe points, the further samples' streams, and per ray the K of
    its last split vertex with the depth at which the walk's hit after it would come."""

    def __init__(self, ctx):
        spec = ctx.spec
        self.k_max = int(spec.options.estimator.nee_split)
        self.k0 = int(spec.options.estimator.nee_samples)
        self.glossy = lobe_materials(spec)
        self.threshold_w = SPLIT_TAU * float(ctx.start_weight_w)
        self.seed = check_seed(spec.seed)
        self.first_chunk = int(spec.chunk_offset) + int(ctx.first_chunk)
        self.n_det = len(ctx.scene.det_parts)
        self.eps = float(spec.eps)
        self.width = 3 * self.n_det * (self.k_max - self.k0) + 3 * (self.k_max - 1)
        self.k_of_ray = np.ones(ctx.n_rays, dtype=np.int64)
        self.at_depth = np.full(ctx.n_rays, -1, dtype=np.int64)
        self._gens: dict = {}
        self._probe_u = np.empty((0, 0))
        self.log: list | None = None  # a list: each call appends (vertices, predicted e / threshold) (diagnostics)

    # ------------------------------------------------------------------ the split factor

    def counts(self, event, verts, frame, w_vertex, pairs_of):
        """K per vertex of ``verts`` (rows of the event), or None when none is split; remembers the
        split vertices' K for the walk's hit after them. ``pairs_of(verts, frame, U, k)`` gives the
        (vertex, sample, point, wo_local, dist2, cos_x, cos_y) of k detector points per vertex from uniforms U."""
        cand = np.flatnonzero(self.glossy[frame.material])
        if len(cand) == 0:
            return None
        P = len(PROBE_UNIFORMS)
        n_rows = event.uniforms.shape[0]
        if self._probe_u.shape[0] < n_rows:
            row = np.tile(np.asarray(PROBE_UNIFORMS, dtype=np.float64).ravel(), self.n_det)
            self._probe_u = np.ascontiguousarray(np.broadcast_to(row, (max(n_rows, 1024), len(row))))
        sub = np.ascontiguousarray(verts[cand])
        fr = type(frame)(*(a[cand] for a in frame))
        vertex, sample, points, wo, dist2, cos_x, cos_y = pairs_of(sub, fr, self._probe_u, P)
        if len(vertex) == 0:
            return None
        wi = fr.wi_local[vertex]
        f = np.empty(len(vertex))  # unpolarized: a prediction only (any function of the vertex keeps it unbiased)
        for rows, fv in by_material(event.spec.materials, fr.material[vertex],
                                    lambda model, rows: model.brdf(wi[rows], wo[rows])):
            f[rows] = fv
        area = event.scene.arrays.detector_area_mm2[sample // P]
        scale = event.rays.weight_w[sub[vertex]]
        if w_vertex is not None:
            scale = scale * w_vertex[cand[vertex]]
        g = scale * f * cos_x * cos_y * area / dist2
        # the probes that could make a vertex heavy: kept only if they see the detector point
        look = np.flatnonzero(g > self.threshold_w)
        if len(look) == 0:
            return None
        p = event.hits.point_mm[sub[vertex[look]]] + event.settings.eps_mm * event.hits.facing_normal[sub[vertex[look]]]
        v = points[look] - p
        d = np.sqrt(np.einsum("ij,ij->i", v, v))
        blocked = np.asarray(event.shadow_test(p, v / d[:, None], d - event.settings.eps_mm), dtype=bool)
        event.shadow_rays += len(look)
        e = np.zeros(len(cand))
        np.maximum.at(e, vertex[look[~blocked]], g[look[~blocked]])
        if self.log is not None:
            self.log.append((event.hits.part[sub], event.rays.depth[sub], e / self.threshold_w))
        heavy = np.flatnonzero(e > self.threshold_w)
        if len(heavy) == 0:
            return None
        steps = np.ceil(np.log2(e[heavy] / self.threshold_w))
        k_heavy = np.minimum(self.k0 * np.exp2(np.maximum(steps, 1.0)), self.k_max).astype(np.int64)
        k = np.full(len(verts), self.k0, dtype=np.int64)
        k[cand[heavy]] = k_heavy
        split = np.flatnonzero(k > self.k0)
        if len(split) == 0:
            return None
        r = event.rays.ray[verts[split]]
        self.k_of_ray[r] = k[split]
        self.at_depth[r] = event.rays.depth[verts[split]] + 1
        return k

    def uniforms(self, event, rows):
        """The further draws' uniforms of the split vertices ``rows`` (rows of the event), one row each
        (in the order of ``rows``): 3 per detector and further NEE sample, then 3 per further lobe draw,
        for the largest K; each from its chunk's own stream in ray order (what a chunk draws depends on
        its rays only, not on the batch)."""
        return chunk_stream_uniforms(self._gens, self.seed, self.first_chunk, SPLIT_STREAM, event.rays.ray[rows],
                                     self.width)

    def nee_uniforms(self, event, rows, block, more):
        """An event-row-indexed array of the further NEE samples' uniforms (``more`` per detector) of the
        vertices ``rows`` (``block``: their rows of :meth:`uniforms`); other rows unset."""
        width = 3 * self.n_det * more
        U = np.empty((event.uniforms.shape[0], max(width, 1)))
        U[rows, :width] = block[:, :width]
        return U

    def lobe_draws(self, event, verts, frame, w_vertex, evaluate, k, block):
        """The K - 1 further lobe draws (the material's own ``sample``) of the split vertices ``verts``
        (rows of the event, all split into ``k``; ``block``: their rows of :meth:`uniforms`), each cast
        and, when it reaches a detector first on its sensitive side, counted like the walk's hit there:
        w f cos / pdf x ph(K pdf, K p1) / K (p1 = d^2 / (A |cos_y|)), into ``detector_nee`` and,
        negated, the part's NEE exchange (ledger exact). ``evaluate`` as NEE's (positions in ``verts``)."""
        n_more = int(k) - 1
        if n_more <= 0 or len(verts) == 0:
            return
        spec, scene, hit, rays = event.spec, event.scene, event.hits, event.rays
        pol = spec.options.physics.polarization
        m = len(verts)
        pos = np.repeat(np.arange(m), n_more)
        c0 = 3 * self.n_det * (self.k_max - self.k0)
        u = block[:, c0:c0 + 3 * n_more].reshape(m * n_more, 3)
        wi = frame.wi_local[pos]
        mat = frame.material[pos]
        wo = np.empty((len(pos), 3))
        pdf = np.empty(len(pos))
        for rows, smp in by_material(spec.materials, mat, lambda model, rows: model.sample(wi[rows], u[rows], pol)):
            wo[rows] = smp.wo
            pdf[rows] = smp.pdf_per_sr
        ok = np.flatnonzero((wo[:, 2] > 0) & (pdf > 0))
        if len(ok) == 0:
            return
        pos, wi, wo, pdf = pos[ok], wi[ok], wo[ok], pdf[ok]
        i = verts[pos]
        nf = hit.facing_normal[i]
        d = wo[:, :1] * frame.tangent[pos] + wo[:, 1:2] * frame.bitangent[pos] + wo[:, 2:3] * nf
        d /= np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
        o = hit.point_mm[i] + self.eps * nf
        tri = np.asarray(scene.isect.first_triangle(o, d), dtype=np.int64)
        event.shadow_rays += len(tri)
        arr = scene.arrays
        part = np.where(tri >= 0, arr.triangle_part[np.maximum(tri, 0)], -1)
        j = np.where(part >= 0, arr.detector_of_part[np.maximum(part, 0)], -1)
        n_t = arr.normals[np.maximum(tri, 0)]
        cos_in = np.einsum("ij,ij->i", d, n_t)
        sens = (j >= 0) & (np.abs(cos_in) > 1e-12) & (event.settings.both_sides | (cos_in < 0))
        got = np.flatnonzero(sens)
        if len(got) == 0:
            return
        pos, i, wi, wo, pdf, d, o, tri, j, cos_in = (x[got] for x in (pos, i, wi, wo, pdf, d, o, tri, j, cos_in))
        t = (arr.plane_d[tri] - np.einsum("ij,ij->i", n_t[got], o)) / cos_in
        if evaluate is not None:
            f, _ = evaluate(wi, wo, pos)
        else:
            f = np.empty(len(pos))
            for rows, fv in by_material(spec.materials, frame.material[pos],
                                        lambda model, rows: model.brdf(wi[rows], wo[rows], pol)):
                f[rows] = fv
        p1 = t * t / (arr.detector_area_mm2[j] * np.abs(cos_in))
        c = rays.weight_w[i] * f * wo[:, 2] / pdf * power_heuristic_rows(k * pdf, k * p1) / k
        if w_vertex is not None:
            c = c * w_vertex[pos]
        keep = np.flatnonzero(c > 0)
        if len(keep) == 0:
            return
        i, j, c, y = i[keep], j[keep], c[keep], o[keep] + t[keep, None] * d[keep]
        r = rays.ray[i]
        tallies, trow = event.tallies, event.rows
        tallies.add(trow.detector_nee + j, r, c)
        tallies.subtract(trow.nee_exchange + hit.part[i], r, c)
        for jj in np.unique(j):
            sel = np.flatnonzero(j == jj)
            self._record(event, int(jj), i[sel], y[sel], c[sel])

    @staticmethod
    def _record(event, j, i, points, c):
        """Map (and path) records of further lobe draws from the vertices ``i`` (rows of the event)
        that reached detector ``j``, keyed like NEE's (straylight.engine.nee._record)."""
        rays, part = event.rays, event.hits.part
        keys = events = None
        if event.settings.record_paths:
            K = rays.history.shape[1]
            code = part[i] * 4 + EVENT_SCATTER
            keys = mix_key(mix_key(rays.path_key[i], code), event.scene.det_parts[j] * 4 + EVENT_DETECTOR)
            events = rays.history[i]
            depth = rays.depth[i]
            inside = np.flatnonzero(depth < K)
            events[inside, depth[inside]] = code[inside]
        event.records.add(j, rays.ray[i], points, c, keys, events, rays.depth[i] + 1)

    # ------------------------------------------------------------------ the walk's hit after a split vertex

    def share_walk_hits(self, event, rec, rec_w):
        """Walk hits on a detector straight after a split vertex keep ph(K pdf, K p1) / K over the
        ph(pdf, k p1) the hit stage gave them (it is one of the vertex's K lobe draws)."""
        rays, hit = event.rays, event.hits
        r = rays.ray[rec]
        last = rays.last_part[rec]
        after = np.flatnonzero((rays.last_event[rec] == EVENT_SCATTER) & (self.at_depth[r] == rays.depth[rec])
                               & (self.k_of_ray[r] > self.k0) & event.settings.nee_part[np.maximum(last, 0)])
        if len(after) == 0:
            return rec, rec_w
        i = rec[after]
        j = event.scene.arrays.detector_of_part[hit.part[i]]
        t = hit.distance_mm[i]
        p1 = t * t / (event.scene.arrays.detector_area_mm2[j] * np.abs(hit.cos_in[i]))
        pdf = rays.last_pdf_per_sr[i]
        before = power_heuristic_rows(pdf, self.k0 * p1)
        k = self.k_of_ray[r[after]]
        now = power_heuristic_rows(k * pdf, k * p1) / k
        share = np.where(before > 0, now / np.where(before > 0, before, 1.0), 1.0)
        return keep_walk_share(event, rec, rec_w, after, share)
