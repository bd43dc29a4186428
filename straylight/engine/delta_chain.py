"""Chains of interfaces into a detector, followed by splitting (the lens's own ghosts).

At a Fresnel interface (``optical_surface`` parts) the walk picks one branch, lobe, reflection or
transmission, with probability proportional to its power (docs/engine.md, "Branch by probability,
not splitting"). A ghost that needs two reflections inside a lens ("vane -> front (T) -> back (R)
-> front (R) -> back (T) -> sensor") is then followed by ~R^2 = 1.6e-3 of the rays that enter the
lens, each with ~600x the weight it carries: on the guide scope (benchmarks/guide_scope.py) at
5-20 deg such paths hold 71-99 % of the power, and runs that draw none of them report a PST 100x
low with a small error bar.

With ``TraceOptions(delta_chain=K)`` (K >= 1) the walk's first interface hit of every run of
interface hits (the ray did not arrive from one) starts a *split tree*: both the reflected and
the transmitted ray are cast, and at every further interface (a part whose kind declares
``Capability.DELTA_CHAIN``) both again, up to K interfaces in all, each branch carrying its expected
weight

    w x prod_i (M_i S_i)_0 x bulk_i

(M_i the Mueller matrix of the interface's reflection or transmission on the branch's Stokes vector
S_i, as ``optical_surface`` applies it; bulk_i the medium's attenuation on the way to it). A branch
that hits a detector (on a counted side) after k <= K interfaces scores there; one that hits
anything else (a scatter surface, an absorber, a mirror of another kind) or escapes stops. Exactly
these paths, "interface^k -> detector" with k <= K starting at the run's first interface, are
dropped from the walk (their weight moved to the NEE-exchange row of the interface's part, so the
ledger stays exact): the tree's score is the expectation of the dropped walk hits over every branch
choice along the run (a conditional expectation), so the sum is unbiased, and the branch noise leaves
the lens's ghosts and its direct image. Walk hits after more than K interfaces are kept. Cost: at
most 2 + 4 + ... + 2^K casts per run start (~2 per interface level in a singlet: one branch leaves
the lens and stops at the tube).

With ``delta_chain_reflections = R`` > 0 a branch is reflected only while it has met fewer than R
reflections (a ghost's order; transmissions are followed up to K interfaces), and the walk keeps its hits
after runs with more than R reflections: a cemented doublet's two-reflection ghosts cross the cement
on every pass (7 interfaces, not a singlet's 4), and with R = 2 a cap of K = 32 costs a shallow lens
nothing while the trees stay polynomial in the number of surfaces.

Roulette, which is unbiased, keeps the walk's side an unbiased estimate of what the tree covers; a
walk truncated by ``max_events`` would not reach the detector where the tree does (the tree follows
the physics there).
"""
from __future__ import annotations

import numpy as np

from materials.mueller import apply_interface_mueller, rotate_stokes, s_vector
from materials.sampling import lazy_njit
from materials.smooth import reflect, refract
from straylight.engine.capabilities import Capability
from straylight.engine.interface_rows import deflected, frame_rotation, unit_s_vector
from straylight.engine.material_groups import distinct
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER, EVENT_SOURCE, EVENT_SPECULAR
from straylight.engine.roles import ROLE_DETECTOR
from straylight.engine.surface_geometry import at_interfaces, branch_coefficients, cast_branches
from straylight.engine.vec3 import take_rows
from straylight.engine.walk_shares import keep_walk_share
from straylight.paths import mix_key


#: columns of interface codes a branch starts with; they grow as a branch meets more (a cap K of 32
#: interfaces must not cost a singlet's trees, whose branches meet at most 4, 32 columns per row)
CODE_COLUMNS = 8


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def widen_codes(codes: np.ndarray, width: int) -> np.ndarray:
    """``codes`` (n, m) with -1 columns appended up to ``width`` (itself when m >= width)."""
    if codes.shape[1] >= width:
        return codes
    return np.concatenate([codes, np.full((len(codes), width - codes.shape[1]), -1, dtype=codes.dtype)], axis=1)


def concat_codes(parts) -> np.ndarray:
    """Code arrays of several branch sets stacked, the narrower ones widened to the widest."""
    width = max(c.shape[1] for c in parts)
    return np.concatenate([widen_codes(c, width) for c in parts])


class Branches:
    """Rays of the split trees in flight: event row of the tree's root, origin, direction, weight,
    Stokes vector (S0 = 1) and its frame e1, interfaces met, last part, path key, event codes,
    reflections met."""

    FIELDS = ("row", "origin", "d", "w", "S", "e1", "k", "last_part", "key", "codes", "refl", "tag")

    def __init__(self, row, origin, d, w, S, e1, k, last_part, key, codes, refl, tag=None):
        self.row, self.origin, self.d, self.w, self.S, self.e1 = row, origin, d, w, S, e1
        self.k, self.last_part, self.key, self.codes, self.refl = k, last_part, key, codes, refl
        self.tag = np.full(len(row), -1, dtype=np.int64) if tag is None else tag  # a further lobe draw's index (-1: the walk's)

    def take(self, sel):
        return Branches(*(take_rows(getattr(self, f), sel) for f in self.FIELDS))


class DeltaChains:
    """Per batch: each ray's count of interface branches (reflection or transmission at a
    ``DELTA_CHAIN`` part) since its run of them started (0: not in a run) and of the reflections among
    them; ``splits``: per part, its kind declares ``DELTA_CHAIN`` (a continuing hit elsewhere ends the
    run). ``max_reflections`` R > 0: the trees follow only branches with at most R reflections (any
    transmissions, up to K interfaces in all), and the walk keeps its hits after more."""

    def __init__(self, n_rays_in_batch, max_interfaces, splits=None, max_reflections=0, lobe_split=None, ends=None):
        self.run = np.zeros(n_rays_in_batch, dtype=np.int64)
        #: straylight.engine.tree_split.LobeSplit (``tree_split`` > 1) or None; per ray, the share the walk's
        #: own tree keeps after a split vertex (1 / K, for branches the split does not leave to it: LobeSplit.walk_keeps;
        #: 0 after a vertex the end draws cover)
        self.lobe_split = lobe_split
        #: straylight.engine.tree_ends.TreeEnds (``tree_ends``) or None; per ray, whether its run started straight
        #: after the source (the end draws' trees are rooted only there)
        self.ends = ends
        self.from_source = np.zeros(n_rays_in_batch, dtype=bool)
        self.walk_scale = np.ones(n_rays_in_batch)
        self.refl = np.zeros(n_rays_in_batch, dtype=np.int64)
        self.k_max = int(max_interfaces)
        self.r_max = int(max_reflections) if int(max_reflections) > 0 else self.k_max
        self.splits = splits

    # ------------------------------------------------------------------ the walk's side

    def at_interfaces(self, event, h):
        """The interface hits ``h`` (straylight.engine.event.Interfaces): those that start a run and carry
        power start split trees (:meth:`split`); then every hit advances its ray's run."""
        root = np.flatnonzero(h.live & (h.E_r + h.E_t > 0) & self.starts(event, h.rows))
        if len(root):
            at = np.where(h.refined[root, None], h.exact[root], event.hits.point_mm[h.rows[root]])
            self.split(event, h.rows[root], at, h.facing[root], h.d[root], h.s[root], h.S[root],
                       tuple(x[root] for x in h.fresnel))
        if self.lobe_split is not None or self.ends is not None:  # the run after a split vertex has started
            self.walk_scale[event.rays.ray[h.rows[~h.passing]]] = 1.0
        self.advance(event, h.rows, h.reflected | h.transmitted, h.passing, h.reflected)

    def starts(self, event, rows):
        """Of the interface hits ``rows``, which start a run (the ray did not come from one)."""
        return self.run[event.rays.ray[rows]] == 0

    def advance(self, event, rows, specular, passing, reflected):
        """After the interface hits ``rows``: a reflection or transmission extends the run (a
        reflection also its reflection count), a lobe (or an absorbed ray) ends it, a pass-through
        leaves it as it is."""
        r = event.rays.ray[rows]
        if self.ends is not None:
            start = (self.run[r] == 0) & ~passing
            self.from_source[r[start]] = event.rays.last_event[rows[start]] == EVENT_SOURCE
        self.run[r] = np.where(passing, self.run[r], np.where(specular, self.run[r] + 1, 0))
        self.refl[r] = np.where(passing, self.refl[r], np.where(specular, self.refl[r] + reflected, 0))

    def leave_run(self, event, rows):
        """Continuing hits ``rows`` on parts whose kind does not split end their run; after a vertex the end
        draws cover (straylight.engine.tree_ends: reached along a run the root's tree follows) the walk's own
        tree keeps only its branches with a reflection (``walk_scale`` 0: only the end draws set it so)."""
        if len(rows):
            r = event.rays.ray[rows]
            scale = 1.0
            if self.ends is not None:
                part = event.hits.part[rows].astype(np.int64)
                covered = self.from_source[r] & self.covers(self.run[r], self.refl[r]) \
                    & self.ends.qualifies(event.spec, part, self.refl[r])
                scale = np.where(covered, 0.0, 1.0)
            self.walk_scale[r] = scale
            self.run[r] = 0
            self.refl[r] = 0

    def covers(self, k, refl) -> np.ndarray:
        """Runs of ``k`` interfaces with ``refl`` reflections that the trees count (1 <= k <= K, refl <= R)."""
        return (k >= 1) & (k <= self.k_max) & (refl <= self.r_max)

    def share_after_chain(self, event, rec, rec_w):
        """The walk's detector hits after 1..K interfaces (at most R reflections) of a run, which the tree
        counted, are dropped (their weight to the NEE exchange: the ledger stays exact)."""
        r = event.rays.ray[rec]
        drop = np.flatnonzero(self.covers(self.run[r], self.refl[r]))
        if len(drop) == 0:
            return rec, rec_w
        return keep_walk_share(event, rec, rec_w, drop, np.zeros(len(drop)))

    # ------------------------------------------------------------------ the trees

    def split(self, event, rows, at, facing, d, s, S, fresnel):
        """Start trees at the interface hits ``rows`` (run starts): ``at`` the (refined) points,
        ``facing`` the normals on the incident side, ``d`` the arriving directions, ``s`` the s
        vectors and ``S`` the arriving Stokes vectors in the s/p basis, ``fresnel = (r_s, r_p, t_s,
        t_p, cos_t, eta, bulk)`` of each hit."""
        rays = event.rays
        part = event.hits.part[rows].astype(np.int64)
        w = rays.weight_w[rows]
        key = rays.path_key[rows] if event.settings.record_paths else np.zeros(len(rows), np.uint64)
        codes = np.full((len(rows), min(self.k_max, CODE_COLUMNS)), -1, dtype=np.int64)
        n = len(rows)
        src = Branches(np.asarray(rows, dtype=np.int64), at, d, w, S, s, np.zeros(n, np.int64), part, key, codes,
                       np.zeros(n, np.int64))
        self.grow(event, self._children(event, src, np.arange(n), at, d, part, facing, s, S, fresnel))
        if self.ends is not None:
            self.ends.draw(event, self)

    def grow(self, event, live):
        """Cast and split the branches ``live`` until every one has scored or ended."""
        for _ in range(event.spec.options.physics.max_events):  # each step splits or passes a hit: the walk's own bound
            if live is None or len(live.w) == 0:
                break
            live = self._step(event, live)

    def _children(self, event, src, sel, at, d, part, facing, s, S, fresnel, carry=None):
        """The reflected and transmitted branches of the interface hits ``at`` on ``part`` of the branches
        ``src`` rows ``sel`` (arriving along ``d``, facing normals ``facing``, s vectors ``s``, Stokes vectors
        ``S`` in the s/p basis, ``fresnel = (r_s, r_p, t_s, t_p, cos_t, eta, bulk)``): all reflections in
        row order, then all transmissions, then the branches ``carry = (rows of src, hit points, parts)``
        that pass their hit unchanged (from just past it). One compiled pass (:func:`_children_loop`) over
        :func:`children_numpy`'s operations in its order (the same bits); ``|a|^2`` and ``a_s a_p*`` are
        numpy's, as in materials.mueller.apply_interface_mueller."""
        n = len(sel)
        if carry is None:
            carry = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64))
        if n == 0 and len(carry[0]) == 0:
            return None
        rs, rp, ts, tp, cos_t, eta, bulk = (_rows(x, n, t) for x, t in zip(fresnel, (complex,) * 4 + (float,) * 3))
        code = part * 4 + EVENT_SPECULAR
        key = take_rows(src.key, sel)
        if event.settings.record_paths:
            key = mix_key(key, code)
        out = lazy_njit(_children_loop, "numpy")(
            np.ascontiguousarray(sel, dtype=np.int64), src.row, src.w, src.k, src.refl, src.tag,
            np.ascontiguousarray(src.codes), key, code, _f64(at), _f64(d), _f64(facing), _f64(S), _f64(s), part,
            np.abs(rs) ** 2, np.abs(rp) ** 2, rs * np.conj(rp), np.abs(ts) ** 2, np.abs(tp) ** 2, ts * np.conj(tp),
            cos_t, eta, bulk, 2.0 * event.settings.eps_mm, self._reflections_followed(),
            np.ascontiguousarray(carry[0], dtype=np.int64), _f64(carry[1]), np.ascontiguousarray(carry[2], np.int64),
            _f64(src.d), _f64(src.S), _f64(src.e1), src.key)
        if len(out[0]) == 0:
            return None
        return Branches(*out)

    def _reflections_followed(self) -> int:
        """R of the branches growing now: the end draws' trees follow transmissions only
        (``TreeEnds.reflections``)."""
        if self.ends is not None and self.ends.table is not None:
            return self.ends.reflections
        return self.r_max

    def _step(self, event, b):
        """Cast the branches ``b``: score those that reach a detector, split those that meet another
        interface (if fewer than K were met), pass those that refine outside a clear aperture.
        ``b``'s fields are gathered once per outcome (the row indices are composed, not the branches)."""
        spec, scene = event.spec, event.scene
        h = cast_branches(spec, scene, b.origin, b.d)
        event.shadow_rays += len(b.w)
        hit, tri, dist, part, cos_in = h.hit, h.tri, h.distance_mm, h.part, h.cos_in
        det = spec.part_roles[part] == ROLE_DETECTOR
        if event.settings.both_sides:
            counted = det
        else:  # a front-only detector counts light against its normals
            counted = det & (cos_in < 0)
        sc = np.flatnonzero(counted)
        if len(sc):
            i = hit[sc]
            taken = b.take(i)
            self._score(event, taken, part[sc], taken.origin + dist[sc, None] * taken.d, take_rows(scene.normals, tri[sc]))
        interface = event.capabilities.at(Capability.DELTA_CHAIN, part)
        if self.ends is not None:
            stop = np.flatnonzero(~det & ~interface)
            if len(stop):
                self.ends.collect(event, b, hit[stop], part[stop], tri[stop], dist[stop])
        go = np.flatnonzero(~det & interface)
        if len(go) == 0:
            return None
        idx, part, dist, cos_in = hit[go], part[go], dist[go], cos_in[go]
        front, facing, at, passing = at_interfaces(spec, scene, part, tri[go], take_rows(b.origin, idx),
                                                   take_rows(b.d, idx), dist, b.last_part[idx], cos_in)
        through = np.flatnonzero(passing)  # the walk passes such a hit unchanged: so does the branch
        carry = (idx[through], take_rows(at, through), part[through])
        live = np.flatnonzero(~passing & (b.k[idx] < self.k_max))  # the walk's hits after K + 1 interfaces stay its own
        sel = idx[live]
        part, at, facing, dist = part[live], take_rows(at, live), take_rows(facing, live), dist[live]
        d = take_rows(b.d, sel)
        fresnel = branch_coefficients(spec, part, front[live], d, facing, dist)
        s, S = incidence_frames(b.S, b.e1, sel, d, facing)
        return self._children(event, b, sel, at, d, part, facing, s, S, fresnel, carry)

    def _score(self, event, b, part, z, nz):
        """Count the branches ``b`` that reached detector parts ``part`` at points ``z`` (triangle normals ``nz``)."""
        rays = event.rays
        j_of = event.scene.arrays.detector_of_part[part]
        start_part = event.hits.part[b.row].astype(np.int64)
        for j in distinct(j_of):
            m = np.flatnonzero(j_of == j)
            i = b.row[m]
            r = rays.ray[i]
            split, ends = self.lobe_split, self.ends
            drawn = split is not None and split.draws is not None  # branches of further lobe draws (tree_split)
            at_end = ends is not None and ends.table is not None  # branches of end draws (tree_ends)
            if at_end:
                w = np.where(ends.walk_keeps(event, b.k[m], b.codes[m], int(j)), 0.0, b.w[m])
            elif drawn:
                w = b.w[m] * split.share(event, b.tag[m], b.k[m], b.codes[m], int(j), b.d[m]) \
                    * split.ghost_share(event, i, b.tag[m], int(j), z[m], nz[m], b.codes[m], b.k[m], b.d[m])
            else:
                keeper = split if split is not None else ends
                scale = np.ones(len(m))
                if keeper is not None:
                    kept = keeper.walk_keeps(event, b.k[m], b.codes[m], int(j))
                    if ends is not None:  # after an end the draws cover, the walk keeps the runs they do not follow
                        kept |= (self.walk_scale[r] == 0.0) & (b.refl[m] > ends.reflections)
                    scale = np.where(kept, 1.0, self.walk_scale[r])
                # a strategy that also counts this run keeps its share (against the walk's draws at a split vertex:
                # 1 / scale of them, straylight.engine.tree_split), or one that makes this very path
                draws = np.where((scale > 0.0) & (scale < 1.0), 1.0 / np.where(scale > 0.0, scale, 1.0), 1.0)
                w = b.w[m] * event.tree_share(i, int(j), b.d[m], draws) * scale
                w = w * event.branch_share(i, int(j), z[m], nz[m], b.codes[m], b.k[m])
                w = w * _own_tree_ghost_share(event, i, int(j), z[m], nz[m], b.codes[m], b.k[m], b.d[m], draws)
            shared = split is not None or ends is not None
            keep = np.flatnonzero(w > 0) if shared else m
            if shared and len(keep) < len(m):
                m, i, r, w = m[keep], i[keep], r[keep], w[keep]
                if len(m) == 0:
                    continue
            event.tallies.add(event.rows.detector_nee + int(j), r, w)
            event.tallies.subtract(event.rows.nee_exchange + start_part[m], r, w)
            keys = events = None
            depth = rays.depth[i] + (1 if drawn else 0)  # a further draw's tree starts at its vertex, not past it
            if at_end:
                ends.record(event, b, m, r, i, z[m], w, j, depth)
                continue
            if event.settings.record_paths:
                keys = mix_key(b.key[m], event.scene.det_parts[int(j)] * 4 + EVENT_DETECTOR)
                events = rays.history[i]
                if drawn:
                    at = np.flatnonzero(rays.depth[i] < events.shape[1])
                    events[at, rays.depth[i][at]] = start_part[m][at] * 4 + EVENT_SCATTER
                for step in range(b.codes.shape[1]):
                    at = np.flatnonzero((b.codes[m, step] >= 0) & (depth + step < events.shape[1]))
                    events[at, depth[at] + step] = b.codes[m[at], step]
            event.records.add(int(j), r, z[m], w, keys, events, depth + b.k[m])


def _own_tree_ghost_share(event, rows, detector: int, z, nz, codes, k, arrival, draws) -> np.ndarray:
    """The factor the walk's own tree (rooted at the interface hits ``rows``, ``draws`` of its direction at P)
    keeps against specular NEE's ghost connections at the eye chains' vertices (1 without them):
    straylight.engine.specular_nee.SpecularNee.ghost_share, with the walk's density of its own draw."""
    nee, rc = event.states.get("specular_nee"), event.states.get("reverse_chain")
    if nee is None or not nee.ghosts_shared(event.states):
        return np.ones(len(rows))
    rays = event.rays
    r = rays.ray[rows]
    owned = rc.owns(event, rows, extra=1) & (rays.depth[rows] == nee.depth[r] + 1)
    p_walk = rc.p_walk[r] * draws
    beam = rc.p_walk[r] / np.where(nee.pdf[r] > 0, nee.pdf[r], np.inf)
    return nee.ghost_share(event, r, owned, detector, z, nz, codes, k, take_rows(rays.direction, rows), arrival,
                           p_walk, beam)


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _rows(a, n, dtype) -> np.ndarray:
    """``a`` as a contiguous (n,) array of ``dtype`` (a scalar broadcast)."""
    a = np.asarray(a, dtype=dtype)
    return np.ascontiguousarray(a if a.shape == (n,) else np.broadcast_to(a, (n,)))


def children_numpy(src, sel, at, d, part, facing, s, S, fresnel, eps, r_max, record_paths, carry=None):
    """:meth:`DeltaChains._children` in numpy (the reference it is tested against): the fields of ``src``
    gathered on ``sel``, each branch's Mueller product, selection, direction and Stokes vector in turn
    (``eps`` twice the scene's offset); then the branches ``carry`` gathered, moved past their hits, and
    the two sets stacked."""
    children = _children_numpy(src, sel, at, d, part, facing, s, S, fresnel, eps, r_max, record_paths)
    carried = None
    if carry is not None and len(carry[0]):
        carried = src.take(carry[0])
        carried.origin = np.ascontiguousarray(carry[1] + eps * carried.d)
        carried.last_part = carry[2]
    parts = [x for x in (children, carried) if x is not None and len(x.w)]
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    return Branches(*(concat_codes([o.codes for o in parts]) if f == "codes"
                      else np.concatenate([getattr(o, f) for o in parts]) for f in Branches.FIELDS))


def _children_numpy(src, sel, at, d, part, facing, s, S, fresnel, eps, r_max, record_paths):
    """The reflected and transmitted branches of :func:`children_numpy`."""
    if len(sel) == 0:
        return None
    b = src.take(np.asarray(sel, dtype=np.int64))
    b.origin, b.d, b.last_part = at, d, part
    rs, rp, ts, tp, cos_t, eta, bulk = fresnel
    code = b.last_part * 4 + EVENT_SPECULAR
    key = mix_key(b.key, code) if record_paths else b.key
    rows, origin, d, weight, stokes, refl = [], [], [], [], [], []
    for a_s, a_p, sign in ((rs, rp, 1.0), (ts, tp, -1.0)):
        So = apply_interface_mueller(a_s, a_p, S)
        w = b.w * So[:, 0] * bulk
        # a reflection past the trees' R is not followed: the walk keeps those paths (share_after_chain)
        g = np.flatnonzero((w > 0) & (b.refl < r_max)) if sign > 0 else np.flatnonzero(w > 0)
        if len(g) == 0:
            continue
        d_g, facing_g, So_g = take_rows(b.d, g), take_rows(facing, g), take_rows(So, g)
        if sign > 0:
            d_out = reflect(d_g, facing_g)
        else:
            d_out = refract(d_g, facing_g, np.broadcast_to(eta, (len(b.w),))[g],
                            np.broadcast_to(cos_t, (len(b.w),))[g])
        rows.append(g)
        origin.append(np.ascontiguousarray(take_rows(b.origin, g) + sign * eps * facing_g))
        d.append(np.ascontiguousarray(d_out))
        weight.append(w[g])
        stokes.append(So_g / So_g[:, :1])
        refl.append(b.refl[g] + (1 if sign > 0 else 0))
    if not rows:
        return None
    g = rows[0] if len(rows) == 1 else np.concatenate(rows)
    codes = widen_codes(b.codes[g], int(b.k[g].max()) + 1)  # the column of this interface exists
    codes[np.arange(len(g)), b.k[g]] = code[g]
    origin, d, weight, stokes, refl = (x[0] if len(x) == 1 else np.concatenate(x)
                                       for x in (origin, d, weight, stokes, refl))
    return Branches(b.row[g], origin, d, weight, stokes, s[g], b.k[g] + 1, b.last_part[g], key[g], codes, refl,
                    b.tag[g])


def _children_loop(sel, row, w, k, refl, tag, codes, key, code, at, d, facing, S, s, part, ss_r, pp_r, c_r, ss_t,
                   pp_t, c_t, cos_t, eta, bulk, eps, r_max, carry, carry_at, carry_part, src_d, src_S, src_e1,
                   src_key):
    """:func:`children_numpy` row by row: materials.mueller's ``_apply_interface_loop`` and materials.smooth's
    ``_reflect_loop`` / ``_refract_loop`` written out in their order; the output fields of
    :class:`Branches`, reflections first, then transmissions, then the carried rows ``carry`` of the
    source branches (``src_*`` their fields), each moved ``eps`` past its hit ``carry_at``."""
    n = len(sel)
    So = np.empty((2, n, 4))
    wo = np.empty((2, n))
    take = np.zeros((2, n), np.bool_)
    m = 0
    k_top = -1
    for b in range(2):
        for r in range(n):
            if b == 0:
                A, B, C, D = 0.5 * (ss_r[r] + pp_r[r]), 0.5 * (ss_r[r] - pp_r[r]), c_r[r].real, c_r[r].imag
            else:
                A, B, C, D = 0.5 * (ss_t[r] + pp_t[r]), 0.5 * (ss_t[r] - pp_t[r]), c_t[r].real, c_t[r].imag
            s0, s1, s2, s3 = S[r, 0], S[r, 1], S[r, 2], S[r, 3]
            So[b, r, 0] = (((0.0 + A * s0) + B * s1) + 0.0 * s2) + 0.0 * s3
            So[b, r, 1] = (((0.0 + B * s0) + A * s1) + 0.0 * s2) + 0.0 * s3
            So[b, r, 2] = (((0.0 + 0.0 * s0) + 0.0 * s1) + C * s2) + D * s3
            So[b, r, 3] = (((0.0 + 0.0 * s0) + 0.0 * s1) + -D * s2) + C * s3
            i = sel[r]
            wo[b, r] = w[i] * So[b, r, 0] * bulk[r]
            if wo[b, r] > 0 and (b == 1 or refl[i] < r_max):
                take[b, r] = True
                m += 1
                k_top = max(k_top, k[i])
    width = max(codes.shape[1], k_top + 1)
    m_children = m
    m += len(carry)
    o_row = np.empty(m, np.int64)
    o_origin = np.empty((m, 3))
    o_d = np.empty((m, 3))
    o_w = np.empty(m)
    o_S = np.empty((m, 4))
    o_e1 = np.empty((m, 3))
    o_k = np.empty(m, np.int64)
    o_part = np.empty(m, np.int64)
    o_key = np.empty(m, np.uint64)
    o_codes = np.full((m, width), -1, np.int64)
    o_refl = np.empty(m, np.int64)
    o_tag = np.empty(m, np.int64)
    j = 0
    for b in range(2):
        sign = 1.0 if b == 0 else -1.0
        step = sign * eps
        for r in range(n):
            if not take[b, r]:
                continue
            i = sel[r]
            o_row[j] = row[i]
            f0, f1, f2 = facing[r, 0], facing[r, 1], facing[r, 2]
            o_origin[j, 0] = at[r, 0] + step * f0
            o_origin[j, 1] = at[r, 1] + step * f1
            o_origin[j, 2] = at[r, 2] + step * f2
            o_d[j, 0], o_d[j, 1], o_d[j, 2] = deflected(d[r, 0], d[r, 1], d[r, 2], f0, f1, f2, b == 0, eta[r], cos_t[r])
            o_w[j] = wo[b, r]
            s0 = So[b, r, 0]
            for c in range(4):
                o_S[j, c] = So[b, r, c] / s0
            o_e1[j, 0], o_e1[j, 1], o_e1[j, 2] = s[r, 0], s[r, 1], s[r, 2]
            o_k[j] = k[i] + 1
            o_part[j] = part[r]
            o_key[j] = key[r]
            for c in range(codes.shape[1]):
                o_codes[j, c] = codes[i, c]
            o_codes[j, k[i]] = code[r]
            o_refl[j] = refl[i] + (1 if b == 0 else 0)
            o_tag[j] = tag[i]
            j += 1
    for r in range(len(carry)):
        i = carry[r]
        j = m_children + r
        o_row[j] = row[i]
        for c in range(3):
            o_origin[j, c] = carry_at[r, c] + eps * src_d[i, c]
            o_d[j, c] = src_d[i, c]
            o_e1[j, c] = src_e1[i, c]
        o_w[j] = w[i]
        for c in range(4):
            o_S[j, c] = src_S[i, c]
        o_k[j] = k[i]
        o_part[j] = carry_part[r]
        o_key[j] = src_key[i]
        for c in range(codes.shape[1]):
            o_codes[j, c] = codes[i, c]
        o_refl[j] = refl[i]
        o_tag[j] = tag[i]
    return o_row, o_origin, o_d, o_w, o_S, o_e1, o_k, o_part, o_key, o_codes, o_refl, o_tag


def incidence_frames(S, e1, sel, d, facing):
    """(s vectors, Stokes vectors in the s/p basis) of the branches ``sel`` (Stokes ``S[sel]`` in the frames
    ``e1[sel]``) arriving along ``d`` at normals ``facing``: materials.mueller's ``s_vector`` and
    ``rotate_stokes`` on the gathered rows, in one compiled pass (:func:`incidence_frames_numpy`'s
    operations in its order: the same bits)."""
    n = len(sel)
    s_out, S_out = np.empty((n, 3)), np.empty((n, 4))
    if n:
        lazy_njit(_incidence_frames_loop, "numpy")(np.ascontiguousarray(sel, np.int64), _f64(S), _f64(e1), _f64(d),
                                                   _f64(facing), s_out, S_out)
    return s_out, S_out


def incidence_frames_numpy(S, e1, sel, d, facing):
    """:func:`incidence_frames` as separate passes (the reference it is tested against)."""
    s = s_vector(d, facing)
    return s, rotate_stokes(take_rows(S, sel), take_rows(e1, sel), s, d)


def _incidence_frames_loop(sel, S, e1, d, facing, s_out, S_out):
    """:func:`incidence_frames_numpy` row by row: materials.mueller's ``_s_vector_loop`` and
    ``_rotate_stokes_loop`` written out."""
    for r in range(len(sel)):
        d0, d1, d2 = d[r, 0], d[r, 1], d[r, 2]
        n0, n1, n2 = facing[r, 0], facing[r, 1], facing[r, 2]
        b0, b1, b2 = unit_s_vector(d0, d1, d2, n0, n1, n2)
        s_out[r, 0], s_out[r, 1], s_out[r, 2] = b0, b1, b2
        i = sel[r]
        cc, ss = frame_rotation(e1[i, 0], e1[i, 1], e1[i, 2], d0, d1, d2, b0, b1, b2)
        S1, S2 = S[i, 1], S[i, 2]
        S_out[r, 0] = S[i, 0]
        S_out[r, 1] = cc * S1 + ss * S2
        S_out[r, 2] = -ss * S1 + cc * S2
        S_out[r, 3] = S[i, 3]
