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
from straylight.engine.ray_batch import EVENT_SCATTER
from straylight.engine.vec3 import power_heuristic_rows
from straylight.engine.walk_shares import keep_walk_share
from straylight.rng import CHUNK_RAYS, check_seed

SPLIT_STREAM = 0x4E53504C  # third entropy word of the further samples' streams ("NSPL")
#: the predicted contribution (in start weights) above which a vertex's NEE is split
SPLIT_TAU = 3e-7
#: fixed detector points of the prediction: the (alias, radial, angular) uniforms of the NEE sampler
#: (a disk detector: its centre and four points at 0.7 of the radius)
PROBE_UNIFORMS = ((0.5, 0.0, 0.0), (0.5, 0.49, 0.0), (0.5, 0.49, 0.25), (0.5, 0.49, 0.5), (0.5, 0.49, 0.75))


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

    def uniforms(self, event, rows, width):
        """Uniforms (n_rows of the event, ``width``) of the further samples; only ``rows`` filled, each from
        its chunk's own stream in ray order (``self.k_max - k0`` samples per detector are drawn for
        every split vertex, so what a chunk draws depends on its rays only)."""
        full = 3 * self.n_det * (self.k_max - self.k0)
        U = np.empty((event.uniforms.shape[0], max(width, 1)))
        r = event.rays.ray[rows]
        chunk = r // CHUNK_RAYS
        order = np.argsort(r, kind="stable")
        for c in np.unique(chunk):
            at = order[chunk[order] == c]
            gen = self._gens.get(int(c))
            if gen is None:
                gen = self._gens[int(c)] = np.random.default_rng([self.seed, self.first_chunk + int(c), SPLIT_STREAM])
            U[rows[at], :width] = gen.random((len(at), full))[:, :width]
        return U

    # ------------------------------------------------------------------ the walk's hit after a split vertex

    def share_walk_hits(self, event, rec, rec_w):
        """Walk hits on a detector straight after a split vertex keep ph(pdf, K p1) / ph(pdf, k p1)."""
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
        now = power_heuristic_rows(pdf, self.k_of_ray[r[after]] * p1)
        share = np.where(before > 0, now / np.where(before > 0, before, 1.0), 1.0)
        return keep_walk_share(event, rec, rec_w, after, share)
