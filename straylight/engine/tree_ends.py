"""Lobe draws at the split trees' branch ends (``EstimatorOptions.tree_ends``; docs/engine.md, "Lobe draws at
the trees' branch ends").

A split tree (straylight.engine.delta_chain) follows both branches of every interface by expected weight, and
a branch that meets a scatter part stops there. The walk goes on from such a point P only where its own
branch choices led it there: a point lit by a reflection inside a lens ("source -> front (T) -> back (R) ->
front (T) -> P") is reached by ~R = 4 % of the rays that enter the lens there, each with 25x the weight. On
the guide scope at 15 deg the lens cell's upper lip, lit so and seen through the lens at a glint ("P -> front
-> back -> sensor"), made single rays carry ~1000x the mean (docs/engine.md, "The guide scope: what holds each
angle").

Here a branch of a tree rooted at the ray's first interface after the source (the beam's own light inside the
lens) that ends on a glossy pure scatterer (``ComponentFlags.GLOSSY``, a scatter end of the reverse chains)
after at least one reflection takes one draw from the material's lobe at P, kept with probability q =
min(1, w_P / (:data:`END_TAU` w_root)) (w_P the branch's expected weight, w_root the walk's at the root:
Russian roulette, unbiased, so that the weak ends of two reflections cost little). The draw's ray, of weight
w_P f cos / pdf / q (the polarized f = M[0] . S for the branch's Stokes vector on a polarizing material, as
the walk scatters), is followed by a split tree of its own that follows transmissions only
(:data:`END_REFLECTIONS`); its branches that reach a detector through one interface or more score there. Those
paths, "root run -> P -> lobe -> k >= 1 transmissions -> detector" with the root run within the trees' limits,
are dropped from the walk: after such a P (reached by its own choices along a run the root's tree covers) the
walk's own tree keeps only its branches with a reflection (``DeltaChains.walk_scale`` 0 for the others, as
``tree_split`` keeps 1 / K). Each end's draw is an unbiased estimate of what the walk's lobe draw at P and its tree
would count, weighted by the expectation over the root run's branch choices: the sum is unbiased, and the
family is found by every ray whose beam lights P, not by 4 % of them.

What stays the walk's: its NEE and detector hits straight after P, its later vertices, and the runs the trees'
further draws leave to it (``walk_keeps``: those specular NEE may also make, or without its state at most
``specular_nee`` interfaces). The eye chains own no path through P (P is not lit straight by the source), so the
draws' trees keep their whole weight. The ends of a further draw's tree (``tree_split``) and of an end's own
tree take no draw (one level). Each draw takes 4 uniforms (the roulette, 3 for the lobe) from an own stream per
chunk (:data:`END_STREAM`, in ray order): results do not depend on batch size or threads. Off with a fixed
polarization (the walk then evaluates every vertex for "s" or "p") and with a linear source (P's light is
polarized by the source too).

**Draws into the field.** Where the delta-chain strategy's table holds the detectors' field through the lens
(straylight.engine.field_cone: a cone of directions, ~atan(r_sensor / f) about the axis), a share
:data:`END_FIELD_SHARE` of the draws takes a direction uniform in that cone instead of the lobe's (3 uniforms
more per end from an own stream, :data:`END_FIELD_STREAM`), and every draw weighs f cos / ((1 - a) pdf_lobe +
a pdf_cone): the one-sample estimate of the mixture, unbiased for any cone. A glint seen through the lens is
reached from P only within the field, which the lobe alone finds ~2e-5 of the time on the guide scope."""
from __future__ import annotations

import numpy as np

from materials.mueller import rotate_stokes, s_vector
from materials.polarized_brdf import is_polarizing, mueller_brdf
from straylight.engine.interactions.brdf_scatter import local_frame
from straylight.engine.interactions.scatter_polarization import scattered_rows
from straylight.engine.lobes import lobe_materials
from straylight.engine.material_groups import brdf_and_pdf, by_material, distinct
from straylight.engine.delta_chain import CODE_COLUMNS, Branches
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER, EVENT_SOURCE
from straylight.engine.reverse_chain import _source_linear, scatter_ends
from straylight.engine.tree_split import walk_keeps
from straylight.engine.vec3 import take_rows
from straylight.paths import mix_key
from straylight.rng import check_seed, chunk_stream_uniforms

END_STREAM = 0x54454E44  # third entropy word of the end draws' streams ("TEND")
#: an end is drawn with probability min(1, w_P / (END_TAU w_root)): a single reflection (R ~ 4 % on glass, 1 %
#: coated) always, a two-reflection end ~R^2 / END_TAU of the time
END_TAU = 0.02
#: reflections an end draw's tree follows: none (a glint seen through a lens is "P -> T ... T -> detector"; a tree
#: of a double Gauss with two reflections has ~50 branches, with none ~1 per surface); the walk's own tree after
#: an end keeps the runs with reflections
END_REFLECTIONS = 0
#: the share of the end draws aimed into the detectors' field through the lens, where it is known (module doc)
END_FIELD_SHARE = 0.2
END_FIELD_STREAM = 0x54464C44  # third entropy word of the draws into the field's streams ("TFLD")


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def unsupported(spec) -> str | None:
    """Why the end draws cannot run in this trace (None when they can)."""
    if spec.options.physics.polarization != "u":
        return "the walk evaluates every vertex for one polarization"
    if len(spec.sources) != 1 or _source_linear(spec):
        return "the end draws take the light at P as the trees carry it from one unpolarized source"
    return None


class TreeEnds:
    """Per batch: which materials take end draws, the draws' streams, the ends collected while a root's trees
    grow (:meth:`collect`), and while an end's tree grows, what its records need of the root run (:attr:`table`)."""

    reflections = END_REFLECTIONS

    def __init__(self, ctx):
        spec = ctx.spec
        self.material = lobe_materials(spec) & scatter_ends(spec)
        self.seed = check_seed(spec.seed)
        self.first_chunk = int(spec.chunk_offset) + int(ctx.first_chunk)
        self.k_min = int(spec.options.estimator.specular_nee)
        self._gens: dict = {}
        self.pending: list = []
        self.table: tuple | None = None  # (root-run codes, their count k, P's part) per end draw, while they grow
        field = spec.end_field  # straylight.engine.field_cone.FieldTable (None: a spec made without the tables)
        self.cone = None if field is None else field.cone
        self._field_gens: dict = {}

    def qualifies(self, spec, part, refl) -> np.ndarray:
        """Ends on ``part`` after ``refl`` reflections that take a draw (given a root after the source)."""
        return self.material[spec.part_material[part]] & (refl >= 1)

    def collect(self, event, b, idx, part, tri, dist):
        """The branches ``b`` rows ``idx`` stopped on the non-interface parts ``part`` (triangles ``tri``, at
        ``dist`` along them): those of a root after the source (not of a further draw or an end's own tree)
        that qualify are kept for :meth:`draw`."""
        if self.table is not None:
            return
        ok = np.flatnonzero((b.tag[idx] < 0) & self.qualifies(event.spec, part, b.refl[idx])
                            & (event.rays.last_event[b.row[idx]] == EVENT_SOURCE))
        if len(ok) == 0:
            return
        i = idx[ok]
        d = take_rows(b.d, i)
        n = take_rows(event.scene.normals, tri[ok])
        facing = np.where((_dot(n, d) > 0)[:, None], -n, n)
        self.pending.append((b.take(i), take_rows(b.origin, i) + dist[ok, None] * d, facing, part[ok]))

    def draw(self, event, chains):
        """Draw at the ends collected since the last call and grow their trees in ``chains`` (DeltaChains)."""
        pending, self.pending = self.pending, []
        for ends, p, nf, part in pending:
            branches, table = self._draws(event, ends, p, nf, part)
            if branches is None:
                continue
            self.table = table
            try:
                chains.grow(event, branches)
            finally:
                self.table = None

    def _draws(self, event, e, p, nf, part):
        rays, spec = event.rays, event.spec
        u = chunk_stream_uniforms(self._gens, self.seed, self.first_chunk, END_STREAM, rays.ray[e.row], 4)
        w_root = rays.weight_w[e.row]
        q = np.minimum(1.0, e.w / (END_TAU * np.where(w_root > 0, w_root, np.inf)))
        u_field = None if self.cone is None else chunk_stream_uniforms(
            self._field_gens, self.seed, self.first_chunk, END_FIELD_STREAM, rays.ray[e.row], 3)
        keep = np.flatnonzero(u[:, 0] < q)
        if len(keep) == 0:
            return None, None
        e = e.take(keep)
        p, nf, part, u, q = p[keep], nf[keep], part[keep], u[keep, 1:], q[keep]
        mat = spec.part_material[part]
        tb, bb, wi = local_frame(e.d, nf)
        m = len(part)
        wo, weight, pdf = np.empty((m, 3)), np.empty(m), np.empty(m)
        for g, smp in by_material(spec.materials, mat, lambda model, g: model.sample(wi[g], u[g], "u")):
            wo[g], weight[g], pdf[g] = smp.wo, smp.weight, smp.pdf_per_sr
        if u_field is not None:
            wo, weight, pdf = self._into_field(spec, mat, wi, tb, bb, nf, wo, weight, pdf, u_field[keep])
        S_out = np.zeros((m, 4))
        S_out[:, 0] = 1.0
        e1_out = tb.copy()
        ratio = self._polarized(spec, e, nf, tb, bb, wi, wo, mat, S_out, e1_out)
        ok = np.flatnonzero((wo[:, 2] > 0) & (pdf > 0) & (weight * ratio > 0))
        if len(ok) == 0:
            return None, None
        d = wo[ok, :1] * tb[ok] + wo[ok, 1:2] * bb[ok] + wo[ok, 2:3] * nf[ok]
        d /= np.sqrt(_dot(d, d))[:, None]
        n = len(ok)
        key = mix_key(e.key[ok], part[ok] * 4 + EVENT_SCATTER) if event.settings.record_paths else e.key[ok]
        branches = Branches(e.row[ok], np.ascontiguousarray(p[ok] + 2.0 * event.settings.eps_mm * nf[ok]),
                            np.ascontiguousarray(d), e.w[ok] * weight[ok] * ratio[ok] / q[ok], S_out[ok], e1_out[ok],
                            np.zeros(n, np.int64), part[ok], key, np.full((n, CODE_COLUMNS), -1, dtype=np.int64),
                            np.zeros(n, np.int64), np.arange(n, dtype=np.int64))
        return branches, (e.codes[ok], e.k[ok], part[ok])

    def _into_field(self, spec, mat, wi, tb, bb, nf, wo, weight, pdf, u):
        """The lobe draws ``wo`` (local frames ``tb``, ``bb``, ``nf``; weights f cos / pdf) as draws of the mixture
        (module doc, "Draws into the field"): those with ``u[:, 0]`` < :data:`END_FIELD_SHARE` take a direction
        uniform in the field cone from ``u[:, 1:]`` instead; every draw's weight is f cos / p_mix and its pdf p_mix."""
        cone, a = self.cone, END_FIELD_SHARE
        wo = wo.copy()
        drawn = pdf > 0
        f_cos = np.where(drawn, weight * np.where(drawn, pdf, 0.0), 0.0)  # a lobe draw's weight is f cos / pdf
        p_lobe = np.where(drawn, pdf, 0.0)
        aim = np.flatnonzero(u[:, 0] < a)
        if len(aim):
            d = cone.sample(u[aim, 1:])
            wo_a = np.stack([_dot(d, tb[aim]), _dot(d, bb[aim]), _dot(d, nf[aim])], axis=1)
            wo[aim] = wo_a
            wi_a = wi[aim]
            for g, (f, p_a) in by_material(spec.materials, mat[aim],
                                           lambda model, g: brdf_and_pdf(model, wi_a[g], wo_a[g], "u")):
                f_cos[aim[g]] = f * np.maximum(wo_a[g, 2], 0.0)
                p_lobe[aim[g]] = p_a
        world = wo[:, :1] * tb + wo[:, 1:2] * bb + wo[:, 2:3] * nf
        p_mix = (1.0 - a) * p_lobe + a * cone.density_per_sr * cone.contains(world)
        good = (wo[:, 2] > 0) & (p_mix > 0)
        return wo, np.where(good, f_cos / np.where(good, p_mix, 1.0), 0.0), p_mix

    @staticmethod
    def _polarized(spec, e, nf, tb, bb, wi, wo, mat, S_out, e1_out) -> np.ndarray:
        """f_pol / f_u of the draws on polarizing materials for the branches' Stokes vectors (``M[0] . S /
        M00``, as straylight.engine.interactions.scatter_polarization scatters), their scattered states ``M S``
        (normalised) into ``S_out`` and frames into ``e1_out``; 1 elsewhere (the light leaves unpolarized)."""
        ratio = np.ones(len(mat))
        polar = [k for k in distinct(mat) if is_polarizing(spec.materials[k])]
        if not polar:
            return ratio
        s = s_vector(e.d, nf)
        S_in = rotate_stokes(e.S, e.e1, s, e.d)
        s_loc = np.stack([_dot(s, tb), _dot(s, bb), _dot(s, nf)], axis=1)
        polarized = np.any(S_in[:, 1:] != 0.0, axis=1)
        for k in polar:
            g = np.flatnonzero((mat == k) & (wo[:, 2] > 0))
            if len(g) == 0:
                continue
            M, e1_loc = mueller_brdf(spec.materials[k], wi[g], wo[g], s_loc[g])
            scattered_rows(M, e1_loc, S_in, polarized, tb, bb, nf, g, g, g, ratio, S_out, e1_out)
            S_out[g] /= S_out[g, :1]  # M S as the walk stores it, normalised (1, 0, 0, 0 where nothing is scattered)
        return ratio

    def walk_keeps(self, event, k, codes, detector: int) -> np.ndarray:
        """(n,) bool: the end draws' branches (``k`` interfaces, ``codes``) the walk's own tree keeps whole (their
        share 0 here): those specular NEE may also make, or without its state at most ``specular_nee`` interfaces
        (straylight.engine.tree_split.walk_keeps, the same rule); and a draw straight onto the detector (k = 0),
        which the walk's NEE and lobe hits at P count."""
        return walk_keeps(event.states, k, codes, detector, self.k_min) | (k == 0)

    def record(self, event, b, m, r, i, z, w, j, depth):
        """Path records of the end draws' branches ``b`` rows ``m`` (rays ``r``, event rows ``i``) scoring ``w`` at
        ``z`` on detector ``j``: the root run's codes, P, then the draw's run."""
        rays = event.rays
        keys = events = None
        c1, k1, pp = (x[b.tag[m]] for x in self.table)
        end = depth + k1 + 1 + b.k[m]
        if event.settings.record_paths:
            events = rays.history[i]
            width = events.shape[1]
            for step in range(c1.shape[1]):
                at = np.flatnonzero((c1[:, step] >= 0) & (depth + step < width))
                events[at, depth[at] + step] = c1[at, step]
            at = np.flatnonzero(depth + k1 < width)
            events[at, (depth + k1)[at]] = pp[at] * 4 + EVENT_SCATTER
            after = depth + k1 + 1
            for step in range(b.codes.shape[1]):
                at = np.flatnonzero((b.codes[m, step] >= 0) & (after + step < width))
                events[at, after[at] + step] = b.codes[m[at], step]
            keys = mix_key(b.key[m], event.scene.det_parts[int(j)] * 4 + EVENT_DETECTOR)
        event.records.add(int(j), r, z, w, keys, events, end)
