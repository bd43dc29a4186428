"""Compiled (numba) per-vertex kernels of :func:`straylight.trace.run_batch`.

Each kernel does, ray by ray in one pass, what the numpy version did in ~40 vectorised steps
(fancy-index copies, masks, compaction); the arithmetic is written in the same order as numpy
evaluates it, so the numbers are bit-identical to the numpy formulation:

- ``np.einsum("ij,ij->i", a, b)`` on (n, 3) rows sums ``(a0 b0 + a2 b2) + a1 b1`` (:func:`_dot`);
- ``np.linalg.norm(v, axis=1)`` is ``sqrt((v0^2 + v1^2) + v2^2)``;
- no fused multiply-add (numba does not contract without ``fastmath``).

Materials, sources, random draws and ray casts stay outside: the kernels prepare contiguous
arrays for them and consume their results. Estimators and ledger: see :mod:`straylight.trace`.
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

_SURFACE, _MIRROR, _ABSORBER, _DETECTOR = 0, 1, 2, 3
KIND_SCATTER, KIND_SPECULAR, KIND_DETECTOR = 1, 2, 3

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True, nogil=True, inline="always")
def _dot(a0, a1, a2, b0, b1, b2):
    # numpy's einsum order for three terms
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True, nogil=True, inline="always")
def _mis(p_this, p_other):
    """Power heuristic p^2 / (p^2 + q^2) (Veach 1997, eq. 9.13)."""
    a = p_this * p_this
    b = p_other * p_other
    total = a + b
    return a / total if total > 0 else 0.0


@njit(cache=True, nogil=True, inline="always")
def mix_key1(h, code):
    """splitmix64 fold of one event code (same as straylight.paths.mix_key)."""
    x = (h ^ (np.uint64(code) + np.uint64(1))) * _GOLDEN
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def hits(tri, o, d, w, idx, prev_kind, pdf_prev, prev_part, tri_part, part_roles, normals, plane_d, centroids,
         det_of_part, det_area, both_sides, nee, k_nee, M, r_esc, r_inc, r_first, r_abs, r_walk, r_nex, r_direct):
    """First event of every live ray: escape, detector, absorber tallies; the continuing rays.

    Returns (cont, p, nf, part, t, cos_in, rec, rec_w): ``cont`` positions of the rays that go on
    (surface or mirror hit), hit points ``p`` and incident-side normals ``nf`` (n, 3) of all rays,
    ``rec`` positions of counted detector hits and their weights ``rec_w`` (MIS share of NEE removed).
    """
    n = len(tri)
    p = np.empty((n, 3))
    nf = np.empty((n, 3))
    part = np.empty(n, np.int64)
    t_out = np.empty(n)
    cos_out = np.empty(n)
    cont = np.empty(n, np.int64)
    rec = np.empty(n, np.int64)
    rec_w = np.empty(n)
    nc = 0
    nr = 0
    for i in range(n):
        k = tri[i]
        r = idx[i]
        if k < 0:
            M[r_esc, r] += w[i]
            part[i] = -1
            continue
        pt = np.int64(tri_part[k])
        part[i] = pt
        role = part_roles[pt]
        n0, n1, n2 = normals[k, 0], normals[k, 1], normals[k, 2]
        d0, d1, d2 = d[i, 0], d[i, 1], d[i, 2]
        o0, o1, o2 = o[i, 0], o[i, 1], o[i, 2]
        cos_in = _dot(d0, d1, d2, n0, n1, n2)
        # hit distance in float64 from the triangle's plane (embree found the triangle in float32)
        if abs(cos_in) < 1e-12:
            t = _dot(centroids[k, 0] - o0, centroids[k, 1] - o1, centroids[k, 2] - o2, d0, d1, d2)
        else:
            t = (plane_d[k] - _dot(n0, n1, n2, o0, o1, o2)) / cos_in
        t_out[i] = t
        cos_out[i] = cos_in
        tc = t if (t > 0.0 or t != t) else 0.0  # np.maximum(t, 0): NaN propagates
        p[i, 0] = o0 + tc * d0
        p[i, 1] = o1 + tc * d1
        p[i, 2] = o2 + tc * d2
        if cos_in < 0:
            nf[i, 0], nf[i, 1], nf[i, 2] = n0, n1, n2
        else:
            nf[i, 0], nf[i, 1], nf[i, 2] = -n0, -n1, -n2
        wi_ = w[i]
        M[r_inc + pt, r] += wi_
        if prev_kind[i] == 0:
            M[r_first + pt, r] += wi_
        if role == _DETECTOR:
            if not (both_sides or cos_in < 0):
                M[r_abs + pt, r] += wi_
                continue
            j = det_of_part[pt]
            M[r_walk + j, r] += wi_
            w_det = wi_
            # a hit straight after a BRDF scatter is shared with NEE by MIS weights (power heuristic)
            if nee and prev_kind[i] == KIND_SCATTER:
                p_n = k_nee * (t * t) / (det_area[j] * abs(cos_in))
                w_det = wi_ * _mis(pdf_prev[i], p_n)
                M[r_nex + prev_part[i], r] += wi_ - w_det
            if w_det > 0:
                M[r_direct + j, r] += w_det
                rec[nr] = i
                rec_w[nr] = w_det
                nr += 1
        elif role == _ABSORBER:
            M[r_abs + pt, r] += wi_
        else:
            cont[nc] = i
            nc += 1
    return cont[:nc], p, nf, part, t_out, cos_out, rec[:nr], rec_w[:nr]


@njit(cache=True, nogil=True)
def frames(cont, d, nf, part, part_roles, part_material, U):
    """Local frames (Duff et al. 2017 basis, as straylight.sources.orthonormal_basis) of the surface
    (BRDF) hits among ``cont``: returns (surf: positions into cont, surf_of: row of each cont entry in
    the per-surface arrays or -1 for a mirror, tb, bb, wi_loc, material index, the sampling uniforms U[:, 0:3])"""
    n = len(cont)
    surf = np.empty(n, np.int64)
    surf_of = np.full(n, -1, np.int64)
    ns = 0
    for c in range(n):
        if part_roles[part[cont[c]]] == _SURFACE:
            surf[ns] = c
            surf_of[c] = ns
            ns += 1
    surf = surf[:ns]
    tb = np.empty((ns, 3))
    bb = np.empty((ns, 3))
    wi_loc = np.empty((ns, 3))
    mat = np.empty(ns, np.int64)
    u_s = np.empty((ns, 3))
    for s in range(ns):
        i = cont[surf[s]]
        mat[s] = part_material[part[i]]
        u_s[s, 0], u_s[s, 1], u_s[s, 2] = U[i, 0], U[i, 1], U[i, 2]
        x, y, z = nf[i, 0], nf[i, 1], nf[i, 2]
        sign = 1.0 if z >= 0 else -1.0
        a = -1.0 / (sign + z)
        b = x * y * a
        t0, t1, t2 = 1.0 + sign * x * x * a, sign * b, -sign * x
        b0, b1, b2 = b, sign + y * y * a, -y
        tb[s, 0], tb[s, 1], tb[s, 2] = t0, t1, t2
        bb[s, 0], bb[s, 1], bb[s, 2] = b0, b1, b2
        w0, w1, w2 = -d[i, 0], -d[i, 1], -d[i, 2]
        wi_loc[s, 0] = _dot(w0, w1, w2, t0, t1, t2)
        wi_loc[s, 1] = _dot(w0, w1, w2, b0, b1, b2)
        wi_loc[s, 2] = _dot(w0, w1, w2, x, y, z)
    return surf, surf_of, tb, bb, wi_loc, mat, u_s


@njit(cache=True, nogil=True)
def nee_pairs(cont, surf, tb, bb, p, nf, U, u_col0, n_det, k_nee, det_off, prob, alias, v0, e1, e2, det_normals,
              both_sides, eps):
    """Detector points for next-event estimation: for each surface hit s and each (detector j, sample k),
    a point y uniform over j's area (triangle by Walker alias, then Turk 1990 barycentrics), kept when
    it faces the surface and the detector (cos_s > 0, cos_d > 0, d > 2 eps).

    Returns pairs (s, jk) in s-major order and their y, wo_loc (sample frame), dist2, cos_s, cos_d, wdir.
    """
    ns = len(surf)
    m = ns * n_det * k_nee
    ps = np.empty(m, np.int64)
    pjk = np.empty(m, np.int64)
    y = np.empty((m, 3))
    wo_loc = np.empty((m, 3))
    wdir = np.empty((m, 3))
    dist2 = np.empty(m)
    cos_s = np.empty(m)
    cos_d = np.empty(m)
    q = 0
    two_eps = 2 * eps
    for s in range(ns):
        i = cont[surf[s]]
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
            su = np.sqrt(ub)
            bw1 = su * (1.0 - uc)
            bw2 = su * uc
            y0 = v0[g, 0] + bw1 * e1[g, 0] + bw2 * e2[g, 0]
            y1 = v0[g, 1] + bw1 * e1[g, 1] + bw2 * e2[g, 1]
            y2 = v0[g, 2] + bw1 * e1[g, 2] + bw2 * e2[g, 2]
            v0_, v1_, v2_ = y0 - p0, y1 - p1, y2 - p2
            dd2 = _dot(v0_, v1_, v2_, v0_, v1_, v2_)
            dist = np.sqrt(dd2)
            inv = dist if dist > 0 else 1.0
            a0, a1, a2 = v0_ / inv, v1_ / inv, v2_ / inv
            cs = _dot(a0, a1, a2, f0, f1, f2)
            cd = -_dot(a0, a1, a2, det_normals[g, 0], det_normals[g, 1], det_normals[g, 2])
            if both_sides:
                cd = abs(cd)
            if cs > 0 and cd > 0 and dist > two_eps:
                ps[q] = s
                pjk[q] = jk
                y[q, 0], y[q, 1], y[q, 2] = y0, y1, y2
                wo_loc[q, 0] = _dot(a0, a1, a2, tb[s, 0], tb[s, 1], tb[s, 2])
                wo_loc[q, 1] = _dot(a0, a1, a2, bb[s, 0], bb[s, 1], bb[s, 2])
                wo_loc[q, 2] = cs
                wdir[q, 0], wdir[q, 1], wdir[q, 2] = a0, a1, a2
                dist2[q] = dd2
                cos_s[q] = cs
                cos_d[q] = cd
                q += 1
    return ps[:q], pjk[:q], y[:q], wo_loc[:q], dist2[:q], cos_s[:q], cos_d[:q], wdir[:q]


@njit(cache=True, nogil=True)
def nee_shadow(ps, pjk, y, dist2, cos_s, cos_d, f, p_b, cont, surf, w, p, nf, k_nee, det_area, eps):
    """NEE contributions c = w f cos_s cos_d A / d^2 * m_nee / k (area form, MIS density k d^2 / (A cos_d))
    and the shadow rays of those with c > 0: returns (keep (pair positions), c, origins, dirs, tmax)."""
    m = len(ps)
    keep = np.empty(m, np.int64)
    cc = np.empty(m)
    so = np.empty((m, 3))
    sd = np.empty((m, 3))
    tmax = np.empty(m)
    q = 0
    for a in range(m):
        s = ps[a]
        i = cont[surf[s]]
        j = pjk[a] // k_nee
        area = det_area[j]
        p_n = k_nee * dist2[a] / (area * cos_d[a])
        c = w[i] * f[a] * cos_s[a] * cos_d[a] * area / dist2[a] * _mis(p_n, p_b[a]) / k_nee
        if c > 0:
            oo0 = p[i, 0] + eps * nf[i, 0]
            oo1 = p[i, 1] + eps * nf[i, 1]
            oo2 = p[i, 2] + eps * nf[i, 2]
            v0_, v1_, v2_ = y[a, 0] - oo0, y[a, 1] - oo1, y[a, 2] - oo2
            lo = np.sqrt(_dot(v0_, v1_, v2_, v0_, v1_, v2_))
            keep[q] = a
            cc[q] = c
            so[q, 0], so[q, 1], so[q, 2] = oo0, oo1, oo2
            sd[q, 0], sd[q, 1], sd[q, 2] = v0_ / lo, v1_ / lo, v2_ / lo
            tmax[q] = lo - eps
            q += 1
    return keep[:q], cc[:q], so[:q], sd[:q], tmax[:q]


@njit(cache=True, nogil=True)
def nee_tally(keep, cc, blocked, ps, pjk, cont, surf, idx, part, k_nee, M, r_nee, r_nex):
    """Add unblocked NEE contributions to the detector and (negated) to the NEE exchange of the part."""
    m = len(keep)
    ok = np.empty(m, np.int64)
    q = 0
    for b in range(m):
        if blocked[b]:
            continue
        a = keep[b]
        i = cont[surf[ps[a]]]
        r = idx[i]
        M[r_nee + pjk[a] // k_nee, r] += cc[b]
        M[r_nex + part[i], r] -= cc[b]
        ok[q] = b
        q += 1
    return ok[:q]


@njit(cache=True, nogil=True)
def to_world(wo, weight, pdf, tb, bb, surf, cont, nf):
    """Sampled local directions to world (renormalised); weight zero below the horizon."""
    ns = len(surf)
    out = np.empty((ns, 3))
    wt = np.empty(ns)
    for s in range(ns):
        i = cont[surf[s]]
        a, b, c = wo[s, 0], wo[s, 1], wo[s, 2]
        wt[s] = weight[s] if c > 0 else 0.0
        x0 = a * tb[s, 0] + b * bb[s, 0] + c * nf[i, 0]
        x1 = a * tb[s, 1] + b * bb[s, 1] + c * nf[i, 1]
        x2 = a * tb[s, 2] + b * bb[s, 2] + c * nf[i, 2]
        nrm = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        if not nrm > 0:
            nrm = 1.0
        out[s, 0], out[s, 1], out[s, 2] = x0 / nrm, x1 / nrm, x2 / nrm
    return out, wt, pdf


@njit(cache=True, nogil=True)
def advance(cont, surf_of, wo_world, weight, pdf_dir, d, w, p, nf, part, idx, U, hkey, depth, hist, has_hist,
            record_paths, mirror_r, thr, eps, last, M, r_abs, r_rr, r_trunc):
    """Absorption, Russian roulette, truncation and the next state of the rays that go on.

    ``surf_of[c]``: row in the sampled arrays of continuing ray c, -1 for a mirror hit (specular
    reflection about nf, weight x R). Roulette: a weight below ``thr`` survives with probability
    w / thr at weight thr. Returns the compacted state (idx, o, d, w, prev_kind, pdf_prev, prev_part,
    hkey, depth, hist) of the surviving rays.
    """
    n = len(cont)
    K = hist.shape[1]
    n_idx = np.empty(n, np.int64)
    n_o = np.empty((n, 3))
    n_d = np.empty((n, 3))
    n_w = np.empty(n)
    n_kind = np.empty(n, np.int8)
    n_pdf = np.empty(n)
    n_part = np.empty(n, np.int64)
    n_key = np.empty(n, np.uint64)
    n_depth = np.empty(n, np.int64)
    n_hist = np.empty((n if has_hist else 0, K), np.int16)
    q = 0
    for c in range(n):
        i = cont[c]
        r = idx[i]
        pt = part[i]
        s = surf_of[c]
        if s < 0:
            dn = _dot(d[i, 0], d[i, 1], d[i, 2], nf[i, 0], nf[i, 1], nf[i, 2])
            e0 = d[i, 0] - 2.0 * dn * nf[i, 0]
            e1 = d[i, 1] - 2.0 * dn * nf[i, 1]
            e2 = d[i, 2] - 2.0 * dn * nf[i, 2]
            w_new = w[i] * mirror_r
            pdf_new = 0.0
            kind = KIND_SPECULAR
        else:
            e0, e1, e2 = wo_world[s, 0], wo_world[s, 1], wo_world[s, 2]
            w_new = w[i] * weight[s]
            pdf_new = pdf_dir[s]
            kind = KIND_SCATTER
        M[r_abs + pt, r] += w[i] - w_new
        w_after = w_new
        if w_new < thr and w_new > 0:
            w_after = thr if U[i, 3] * thr < w_new else 0.0
            M[r_rr + pt, r] += w_new - w_after
        if not w_after > 0:
            continue
        if last:
            M[r_trunc + pt, r] += w_after
            continue
        code = pt * 4 + kind
        if has_hist:
            for kk in range(K):
                n_hist[q, kk] = hist[i, kk]
            if depth[i] < K:
                n_hist[q, depth[i]] = code
        n_idx[q] = r
        n_o[q, 0] = p[i, 0] + eps * nf[i, 0]
        n_o[q, 1] = p[i, 1] + eps * nf[i, 1]
        n_o[q, 2] = p[i, 2] + eps * nf[i, 2]
        n_d[q, 0], n_d[q, 1], n_d[q, 2] = e0, e1, e2
        n_w[q] = w_after
        n_kind[q] = kind
        n_pdf[q] = pdf_new
        n_part[q] = pt
        n_key[q] = mix_key1(hkey[i], code) if record_paths else hkey[i]
        n_depth[q] = depth[i] + 1
        q += 1
    return (n_idx[:q], n_o[:q], n_d[:q], n_w[:q], n_kind[:q], n_pdf[:q], n_part[:q], n_key[:q], n_depth[:q],
            n_hist[:q] if has_hist else n_hist[:0])


@njit(cache=True, nogil=True)
def _pairwise_block(x, lo, n):
    """numpy's pairwise sum of x[lo:lo+n] and of its squares for n <= 128 (numpy/_core/src/umath/
    loops_utils.h.src: plain loop below 8, else 8 accumulators then the tail)."""
    if n < 8:
        res = 0.0
        res2 = 0.0
        for i in range(lo, lo + n):
            v = x[i]
            res += v
            res2 += v * v
        return res, res2
    r0, r1, r2, r3 = x[lo], x[lo + 1], x[lo + 2], x[lo + 3]
    r4, r5, r6, r7 = x[lo + 4], x[lo + 5], x[lo + 6], x[lo + 7]
    q0, q1, q2, q3 = r0 * r0, r1 * r1, r2 * r2, r3 * r3
    q4, q5, q6, q7 = r4 * r4, r5 * r5, r6 * r6, r7 * r7
    i = lo + 8
    stop = lo + n - n % 8
    while i < stop:
        v0, v1, v2, v3 = x[i], x[i + 1], x[i + 2], x[i + 3]
        v4, v5, v6, v7 = x[i + 4], x[i + 5], x[i + 6], x[i + 7]
        r0 += v0
        r1 += v1
        r2 += v2
        r3 += v3
        r4 += v4
        r5 += v5
        r6 += v6
        r7 += v7
        q0 += v0 * v0
        q1 += v1 * v1
        q2 += v2 * v2
        q3 += v3 * v3
        q4 += v4 * v4
        q5 += v5 * v5
        q6 += v6 * v6
        q7 += v7 * v7
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    res2 = ((q0 + q1) + (q2 + q3)) + ((q4 + q5) + (q6 + q7))
    while i < lo + n:
        v = x[i]
        res += v
        res2 += v * v
        i += 1
    return res, res2


@njit(cache=True, nogil=True)
def _pairwise2(x, lo, n):
    """numpy's pairwise sums of x[lo:lo+n] and of its squares: blocks of <= 128 combined as a binary
    tree whose splits are halves rounded down to multiples of 8, so that per-chunk sums are
    bit-identical to ``np.add.reduceat(x)`` and ``np.add.reduceat(x * x)``. Written without recursion
    (an explicit post-order stack; numba's on-disk cache and recursion do not mix well)."""
    if n <= 128:
        return _pairwise_block(x, lo, n)
    # stack of (lo, n, state); state 0 = expand, 1 = combine the two results on the value stack
    st_lo = np.empty(64, np.int64)
    st_n = np.empty(64, np.int64)
    st_s = np.empty(64, np.int64)
    v1 = np.empty(64)
    v2 = np.empty(64)
    top = 0
    nv = 0
    st_lo[0], st_n[0], st_s[0] = lo, n, 0
    top = 1
    while top > 0:
        top -= 1
        a, m, state = st_lo[top], st_n[top], st_s[top]
        if state == 1:  # right result on top of left result
            nv -= 1
            v1[nv - 1] = v1[nv - 1] + v1[nv]
            v2[nv - 1] = v2[nv - 1] + v2[nv]
        elif m <= 128:
            s1_, s2_ = _pairwise_block(x, a, m)
            v1[nv] = s1_
            v2[nv] = s2_
            nv += 1
        else:
            m2 = m // 2
            m2 -= m2 % 8
            # push: combine, right, left (left is evaluated first)
            st_lo[top], st_n[top], st_s[top] = a, m, 1
            st_lo[top + 1], st_n[top + 1], st_s[top + 1] = a + m2, m - m2, 0
            st_lo[top + 2], st_n[top + 2], st_s[top + 2] = a, m2, 0
            top += 3
    return v1[0], v2[0]


@njit(cache=True, nogil=True, inline="always")
def _any_nonzero(x, a, b):
    """True if some x[a:b] != 0 (NaN counts), tested 8 at a time."""
    i = a
    while i + 8 <= b:
        if ((x[i] != 0.0) | (x[i + 1] != 0.0) | (x[i + 2] != 0.0) | (x[i + 3] != 0.0)
                | (x[i + 4] != 0.0) | (x[i + 5] != 0.0) | (x[i + 6] != 0.0) | (x[i + 7] != 0.0)):
            return True
        i += 8
    while i < b:
        if x[i] != 0.0:
            return True
        i += 1
    return False


@njit(cache=True, nogil=True)
def chunk_sums(M, chunk, n_parts, n_det, r_abs, r_rr, r_nex, r_trunc, r_nee, r_direct, clear=False):
    """Per-chunk S1 = sum x, S2 = sum x^2 of every tally row of M (n_rows, n) and of the derived rows
    (absorbed ledger ABS + RR + NEX + TRUNC per part, detector total NEE + DIRECT), as
    ``np.add.reduceat`` over chunks of ``chunk`` rays would give them. Returns (s1, s2), (n_chunks, rows).

    Blocks (row, chunk) that hold only zeros are skipped (derived rows: when all their source blocks
    are zero); ``clear=True`` zeroes the non-zero blocks of M afterwards, so that M is all zeros again
    and the caller can reuse it without filling it."""
    n_rows, n = M.shape
    n_ext = n_rows + n_parts + n_det
    nch = (n + chunk - 1) // chunk
    s1 = np.zeros((nch, n_ext))
    s2 = np.zeros((nch, n_ext))
    nz = np.zeros((nch, n_rows), np.bool_)
    buf = np.empty(chunk)
    for r in range(n_ext):
        for c in range(nch):
            a = c * chunk
            b = min(a + chunk, n)
            if r < n_rows:
                x = M[r]
                lo = a
                if not _any_nonzero(x, a, b):
                    continue  # a sum of zeros
                nz[c, r] = True
            elif r < n_rows + n_parts:
                k = r - n_rows
                if not (nz[c, r_abs + k] or nz[c, r_rr + k] or nz[c, r_nex + k] or nz[c, r_trunc + k]):
                    continue
                for i in range(a, b):
                    buf[i - a] = ((M[r_abs + k, i] + M[r_rr + k, i]) + M[r_nex + k, i]) + M[r_trunc + k, i]
                x = buf
                lo = 0
                if not _any_nonzero(x, 0, b - a):
                    continue
            else:
                k = r - n_rows - n_parts
                if not (nz[c, r_nee + k] or nz[c, r_direct + k]):
                    continue
                for i in range(a, b):
                    buf[i - a] = M[r_nee + k, i] + M[r_direct + k, i]
                x = buf
                lo = 0
                if not _any_nonzero(x, 0, b - a):
                    continue
            # reduceat: the first element, then the pairwise sum of the rest
            t1, t2 = _pairwise2(x, lo + 1, b - a - 1)
            s1[c, r] = x[lo] + t1
            s2[c, r] = x[lo] * x[lo] + t2
    if clear:
        for r in range(n_rows):
            for c in range(nch):
                if nz[c, r]:
                    a = c * chunk
                    M[r, a:min(a + chunk, n)] = 0.0
    return s1, s2


# ------------------------------------------------------------------ random streams (straylight.rng)


@njit(cache=True, nogil=True)
def seed_states(words, n_words, out):
    """SeedSequence(entropy words).generate_state(4, uint64) -> PCG64 srandom, one row per chunk.

    words : (m, w) uint32 entropy as uint64 values, n_words (m,) used length; out : (m, 4) uint64
    (state hi, state lo, inc hi, inc lo). Constants and steps of numpy's SeedSequence (pool size 4)."""
    m32 = np.uint64(0xFFFFFFFF)
    mult_a = np.uint64(0x931E8875)
    mult_b = np.uint64(0x58F38DED)
    mix_l = np.uint64(0xCA01F9DD)
    mix_r = np.uint64(0x4973F715)
    s16 = np.uint64(16)
    s32 = np.uint64(32)
    one = np.uint64(1)
    s63 = np.uint64(63)
    mult_hi = np.uint64(2549297995355413924)
    mult_lo = np.uint64(4865540595714422341)
    pool = np.empty(4, np.uint64)
    st = np.empty(8, np.uint64)
    for r in range(words.shape[0]):
        nw = n_words[r]
        h = np.uint64(0x43B0D7E5)
        for i in range(4):  # hashmix of the entropy (0 past its end)
            v = words[r, i] if i < nw else np.uint64(0)
            v = (v ^ h) & m32
            h = (h * mult_a) & m32
            v = (v * h) & m32
            pool[i] = v ^ (v >> s16)
        for i_src in range(4):
            for i_dst in range(4):
                if i_src != i_dst:
                    v = (pool[i_src] ^ h) & m32
                    h = (h * mult_a) & m32
                    v = (v * h) & m32
                    v = v ^ (v >> s16)
                    x = (mix_l * pool[i_dst] - mix_r * v) & m32
                    pool[i_dst] = x ^ (x >> s16)
        for i_src in range(4, nw):
            for i_dst in range(4):
                v = (words[r, i_src] ^ h) & m32
                h = (h * mult_a) & m32
                v = (v * h) & m32
                v = v ^ (v >> s16)
                x = (mix_l * pool[i_dst] - mix_r * v) & m32
                pool[i_dst] = x ^ (x >> s16)
        hb = np.uint64(0x8B51F9DD)
        for i in range(8):  # generate_state(4, uint64): 8 uint32 words, little-endian pairs
            v = (pool[i % 4] ^ hb) & m32
            hb = (hb * mult_b) & m32
            v = (v * hb) & m32
            st[i] = v ^ (v >> s16)
        seed_hi = st[0] | (st[1] << s32)
        seed_lo = st[2] | (st[3] << s32)
        inc_hi0 = st[4] | (st[5] << s32)
        inc_lo0 = st[6] | (st[7] << s32)
        inc_hi = (inc_hi0 << one) | (inc_lo0 >> s63)
        inc_lo = (inc_lo0 << one) | one
        # pcg_setseq_128_srandom_r: state 0, step, add the seed, step
        s_hi, s_lo = _pcg_step(np.uint64(0), np.uint64(0), inc_hi, inc_lo, mult_hi, mult_lo)
        lo = s_lo + seed_lo
        s_hi = s_hi + seed_hi + (one if lo < s_lo else np.uint64(0))
        s_lo = lo
        s_hi, s_lo = _pcg_step(s_hi, s_lo, inc_hi, inc_lo, mult_hi, mult_lo)
        out[r, 0], out[r, 1], out[r, 2], out[r, 3] = s_hi, s_lo, inc_hi, inc_lo
    return out


@intrinsic
def _mulhi(typingctx, a, b):
    """High 64 bits of the 128-bit product of two uint64 (one LLVM i128 multiply: x86-64 ``mul``)."""
    sig = types.uint64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        i128 = ir.IntType(128)
        prod = builder.mul(builder.zext(args[0], i128), builder.zext(args[1], i128))
        return builder.trunc(builder.lshr(prod, ir.Constant(i128, 64)), ir.IntType(64))

    return sig, codegen


@njit(cache=True, nogil=True, inline="always")
def _pcg_step(s_hi, s_lo, inc_hi, inc_lo, mult_hi, mult_lo):
    """state <- state * MULT + inc (mod 2^128)."""
    lo = s_lo * mult_lo
    hi = _mulhi(s_lo, mult_lo) + s_lo * mult_hi + s_hi * mult_lo
    lo2 = lo + inc_lo
    hi = hi + inc_hi + (np.uint64(1) if lo2 < lo else np.uint64(0))
    return hi, lo2


@njit(cache=True, nogil=True)
def fill_uniforms(states, rows, per_chunk, width, out):
    """out[i, :] <- the next ``width`` uniforms of the generator of chunk ``rows[i] // per_chunk``
    (rows of one chunk contiguous and in order, as gen.random((rows, width)) fills them)."""
    mult_hi = np.uint64(2549297995355413924)
    mult_lo = np.uint64(4865540595714422341)
    s11 = np.uint64(11)
    s58 = np.uint64(58)
    s63 = np.uint64(63)
    unit = 1.0 / 9007199254740992.0
    n = out.shape[0]
    i = 0
    while i < n:
        c = rows[i] // per_chunk
        s_hi, s_lo, inc_hi, inc_lo = states[c, 0], states[c, 1], states[c, 2], states[c, 3]
        while i < n and rows[i] // per_chunk == c:
            for k in range(width):
                s_hi, s_lo = _pcg_step(s_hi, s_lo, inc_hi, inc_lo, mult_hi, mult_lo)
                x = s_hi ^ s_lo
                rot = s_hi >> s58
                x = (x >> rot) | (x << ((np.uint64(64) - rot) & s63))  # rotr64
                out[i, k] = np.float64(x >> s11) * unit
            i += 1
        states[c, 0], states[c, 1] = s_hi, s_lo
    return out


@njit(cache=True, nogil=True)
def map_sums(key, pw, nb, n_det, chunk):
    """Irradiance-map sums of one batch from its records sorted by ``key = (ray * D + det) * nb + bin``
    (stable, so each key's powers keep record order): per (ray, det, bin) the ray's power
    x = reduceat(pw) (first element + pairwise rest, as numpy), then per (chunk, det, bin) cell
    S1 = sum x, S2 = sum x^2 in ray order (as np.bincount). Returns cells (chunk, det, bin ascending):
    chunk, det, bin, s1, s2, and the group bounds (start, stop) of each (chunk, det)."""
    m = len(key)
    width = n_det * nb
    acc1 = np.zeros(width)
    acc2 = np.zeros(width)
    touched = np.zeros(width, np.bool_)
    tl = np.empty(width, np.int64)
    nt = 0
    o_chunk = np.empty(m, np.int64)
    o_cell = np.empty(m, np.int64)
    o1 = np.empty(m)
    o2 = np.empty(m)
    q = 0
    cur = -1
    a = 0
    while a <= m:
        if a < m:
            k = key[a]
            ch = (k // width) // chunk
        else:
            ch = -2  # flush the last chunk
        if ch != cur and nt > 0:
            cells = np.sort(tl[:nt])
            for t in range(nt):
                cell = cells[t]
                o_chunk[q] = cur
                o_cell[q] = cell
                o1[q] = acc1[cell]
                o2[q] = acc2[cell]
                acc1[cell] = 0.0
                acc2[cell] = 0.0
                touched[cell] = False
                q += 1
            nt = 0
        if a == m:
            break
        cur = ch
        b = a + 1
        while b < m and key[b] == k:
            b += 1
        if b - a == 1:
            x = pw[a]
        else:
            t1, t2 = _pairwise2(pw, a + 1, b - a - 1)
            x = pw[a] + t1
        cell = k % width
        if not touched[cell]:
            touched[cell] = True
            tl[nt] = cell
            nt += 1
        acc1[cell] += x
        acc2[cell] += x * x
        a = b
    o_chunk, o_cell, o1, o2 = o_chunk[:q], o_cell[:q], o1[:q], o2[:q]
    # groups of equal (chunk, det)
    g_start = np.empty(q, np.int64)
    ng = 0
    for i in range(q):
        if i == 0 or o_chunk[i] != o_chunk[i - 1] or o_cell[i] // nb != o_cell[i - 1] // nb:
            g_start[ng] = i
            ng += 1
    g_stop = np.empty(ng, np.int64)
    for g in range(ng):
        g_stop[g] = g_start[g + 1] if g + 1 < ng else q
    return o_chunk, o_cell // nb, o_cell % nb, o1, o2, g_start[:ng], g_stop


@njit(cache=True, nogil=True)
def lift_origins(o, d, normal, eps):
    """Emitted origins moved eps along the source plane's normal toward each ray's side (in place):
    o + eps sign(d . n) n, with sign(0) = +1."""
    n0, n1, n2 = normal[0], normal[1], normal[2]
    for i in range(o.shape[0]):
        s = eps if _dot(d[i, 0], d[i, 1], d[i, 2], n0, n1, n2) >= 0 else -eps
        o[i, 0] = o[i, 0] + s * n0
        o[i, 1] = o[i, 1] + s * n1
        o[i, 2] = o[i, 2] + s * n2
    return o
