"""Lobe splitting into the split trees (``EstimatorOptions.tree_split``; docs/engine.md, "Lobe draws into
the split trees").

At a scatter vertex P lit straight by the source (the ray's first hit) on a glossy pure scatterer
(``ComponentFlags.GLOSSY``, an end-point kind of the reverse chains) the walk draws K - 1 further lobe
directions (the material's ``sample``, an own stream per chunk: :data:`TREE_STREAM`) besides its own.
Each starts a branch at P with weight w f cos / pdf / K (the walk's throughput over K) that
straylight.engine.delta_chain follows like a tree rooted at its first interface hit; the walk's own tree
after P keeps 1 / K of its branches (``DeltaChains.walk_scale``). For each path the K draws are K
identically distributed estimates of the same conditional expectation, so their mean is unbiased for any
K that depends on the vertex only. The MIS weights against the eye chains are the multi-sample balance
heuristic (Veach 1997, eq. 9.13): the walk makes K samples of (P, omega), each of density p_walk, so a draw
keeps K p_walk / (K p_walk + p_eye) of its 1 / K and the eye chains' source connection p_eye / (K p_walk +
p_eye) (:meth:`LobeSplit.draws_at_source_points`); the weights still add to one for each path. Branches whose
path specular NEE may also make (:meth:`LobeSplit.walk_keeps`: its sequences' parts, or without its batch
state at most ``k_min`` = ``specular_nee`` interfaces) are left to the walk's own tree (its weight there
unchanged, its density one draw's)."""
from __future__ import annotations

import numpy as np

from straylight.engine.delta_chain import CODE_COLUMNS, Branches
from straylight.engine.interactions.brdf_scatter import local_frame
from straylight.engine.lobes import lobe_materials
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_SCATTER, EVENT_SOURCE
from straylight.engine.reverse_chain import _beam_footprint, _source_linear, beam_density, scatter_ends
from straylight.paths import mix_key
from straylight.rng import check_seed, chunk_stream_uniforms
from straylight.engine.vec3 import take_rows

TREE_STREAM = 0x5453504C  # third entropy word of the further lobe draws' streams ("TSPL")


def walk_keeps(states, k, codes, detector: int, k_min: int) -> np.ndarray:
    """(n,) bool: split-tree branches (``k`` interfaces, ``codes``) reaching ``detector`` that the walk's own tree
    keeps whole, whose drawn copies score nothing: those specular NEE may also make
    (straylight.engine.specular_nee.SpecularNee.covers), or without its state k <= ``k_min`` (its ``specular_nee``).
    ``states``: the batch's strategy states (``Event.states``)."""
    nee = states.get("specular_nee")
    if nee is None:
        return k <= k_min
    return nee.covers(k, codes, detector, states)


class LobeSplit:
    """Per batch: which materials split, K, the further draws' streams, and while their branches grow,
    each draw's (p_walk, cos(omega, n_P), owned by the eye chains) (:attr:`draws`)."""

    def __init__(self, ctx, k: int, splits: np.ndarray):
        spec = ctx.spec
        self.k = int(k)
        self.k_min = int(spec.options.estimator.specular_nee)
        # unpolarized light at P (a linear source's first vertex receives polarized light: the walk's weight
        # there has the polarized BRDF's factor, which the draws would miss)
        self.material = lobe_materials(spec) & scatter_ends(spec) & (not _source_linear(spec))
        self.splits = splits
        self.seed = check_seed(spec.seed)
        self.first_chunk = int(spec.chunk_offset) + int(ctx.first_chunk)
        self.w0 = float(ctx.start_weight_w)
        self.source = spec.sources[0]
        self._gens: dict = {}
        self.draws: tuple | None = None

    def uniforms(self, event, rows):
        """3 uniforms per further draw of the vertices ``rows`` (rows of the event), from each chunk's own
        stream in ray order (what a chunk draws depends on its rays only)."""
        return chunk_stream_uniforms(self._gens, self.seed, self.first_chunk, TREE_STREAM, event.rays.ray[rows],
                                     3 * (self.k - 1))

    def at_vertices(self, event, chains, cont, out):
        """After the interactions: the split vertices among the continuing hits ``cont`` (``out``: what the
        walk did there) send their further draws into ``chains`` (DeltaChains) and keep 1 / K of the walk's tree."""
        rays, hit, spec = event.rays, event.hits, event.spec
        part = hit.part[cont].astype(np.int64)
        mat = spec.part_material[part]
        sel = np.flatnonzero((out.event == EVENT_SCATTER) & (rays.last_event[cont] == EVENT_SOURCE)
                             & self.material[mat] & ~self.splits[part] & (rays.weight_w[cont] > 0))
        if len(sel) == 0:
            return
        rows = cont[sel]
        chains.walk_scale[rays.ray[rows]] = 1.0 / self.k
        n_more = self.k - 1
        m = len(rows)
        pos = np.repeat(np.arange(m), n_more)
        u = self.uniforms(event, rows).reshape(m * n_more, 3)
        nf = take_rows(hit.facing_normal, rows)
        tb, bb, wi_all = local_frame(take_rows(rays.direction, rows), nf)
        wi = wi_all[pos]
        pol = spec.options.physics.polarization
        wo = np.empty((len(pos), 3))
        weight = np.empty(len(pos))
        pdf = np.empty(len(pos))
        for g, smp in by_material(spec.materials, mat[sel][pos], lambda model, g: model.sample(wi[g], u[g], pol)):
            wo[g] = smp.wo
            weight[g] = smp.weight
            pdf[g] = smp.pdf_per_sr
        ok = np.flatnonzero((wo[:, 2] > 0) & (pdf > 0) & (weight > 0))
        if len(ok) == 0:
            return
        pos, wo, weight, pdf = pos[ok], wo[ok], weight[ok], pdf[ok]
        i = rows[pos]
        d = wo[:, :1] * tb[pos] + wo[:, 1:2] * bb[pos] + wo[:, 2:3] * nf[pos]
        d /= np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
        n = len(i)
        # the walk's density of (P, omega) for each draw (reverse_chain.ReverseChains._walk_density, from the source)
        rc = event.states.get("reverse_chain")
        if rc is not None:
            beam = beam_density(self.w0, rays.weight_w[i], take_rows(rays.direction, i), nf[pos],
                                _beam_footprint(self.source))
            owned = rc.end_material[mat[sel][pos]] & rc.pred[rays.ray[i]] & (rc.k_tree > 0)
            self.draws = (beam * pdf * self.k, wo[:, 2], owned, d, beam)  # K draws of this density (module doc)
        else:
            self.draws = (np.zeros(n), wo[:, 2], np.zeros(n, dtype=bool), d, np.zeros(n))
        key = mix_key(rays.path_key[i], part[sel][pos] * 4 + EVENT_SCATTER) if event.settings.record_paths \
            else np.zeros(n, np.uint64)
        S = np.zeros((n, 4))
        S[:, 0] = 1.0  # a pure scatterer's light leaves unpolarized (reverse_chain.scatter_ends)
        b = Branches(i, np.ascontiguousarray(take_rows(hit.point_mm, i) + 2.0 * event.settings.eps_mm * nf[pos]),
                     np.ascontiguousarray(d), rays.weight_w[i] * weight / self.k, S, tb[pos], np.zeros(n, np.int64),
                     part[sel][pos], key, np.full((n, CODE_COLUMNS), -1, dtype=np.int64), np.zeros(n, np.int64),
                     np.arange(n, dtype=np.int64))
        try:
            chains.grow(event, b)
        finally:
            self.draws = None

    def ghost_share(self, event, rows, tag, detector: int, z, nz, codes, k, arrival) -> np.ndarray:
        """The factor the draws ``tag`` (at the vertices ``rows``) keep against specular NEE's ghost connections
        at the eye chains' vertices (straylight.engine.specular_nee.SpecularNee.ghost_share; 1 without them)."""
        nee = event.states.get("specular_nee")
        if nee is None or not nee.ghosts_shared(event.states):
            return np.ones(len(rows))
        assert self.draws is not None
        p_walk, _cos, owned, d, beam = (x[tag] for x in self.draws)
        r = event.rays.ray[rows]
        owned = owned & (nee.depth[r] == event.rays.depth[rows])
        return nee.ghost_share(event, r, owned, detector, z, nz, codes, k, d, arrival, p_walk, beam)

    def draws_at_source_points(self, states, material, part, k, codes, detector: int) -> np.ndarray:
        """(n,) the walk's draws (K or 1) at points P lit straight by the source, of ``material`` on ``part``,
        along runs of ``k`` interfaces ``codes`` into ``detector``: K where P splits (the walk's draw and K - 1
        more) and the drawn copies score the run (not :meth:`walk_keeps`), else 1. The density the eye chains
        weigh their source connection against is this times one draw's (module doc)."""
        split = self.material[material] & ~self.splits[part]
        return np.where(split & ~walk_keeps(states, k, codes, detector, self.k_min), float(self.k), 1.0)

    def walk_keeps(self, event, k, codes, detector: int) -> np.ndarray:
        """(n,) bool: the branches (``k`` interfaces, ``codes``) reaching ``detector`` that the walk's own
        tree keeps whole (the further draws' share 0): :func:`walk_keeps`."""
        return walk_keeps(event.states, k, codes, detector, self.k_min)

    def share(self, event, tag, k, codes, detector: int, arrival) -> np.ndarray:
        """The share further draws ``tag`` keep on ``detector`` after ``k`` interfaces ``codes``: 0 where
        :meth:`walk_keeps` (the walk's own tree keeps those), else their balance weight against the eye
        chains."""
        assert self.draws is not None  # (called by DeltaChains while the draws' branches grow)
        p_walk, cos_out, owned = (x[tag] for x in self.draws[:3])
        out = np.where(self.walk_keeps(event, k, codes, detector), 0.0, 1.0)
        rc = event.states.get("reverse_chain")
        if rc is not None and owned.any():
            out = out * rc.share_of(event, owned, p_walk, cos_out, detector, arrival)
        return out

