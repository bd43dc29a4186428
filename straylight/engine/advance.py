"""Stage: after the surface interactions, per continuing ray: absorption (what the interaction's
throughput removed), Russian roulette, truncation at max_events, and the next state of the rays
that go on, compacted into a new :class:`~straylight.engine.ray_batch.RayBatch`.

Russian roulette (unbiased, :func:`straylight.engine.roulette.survivor_weight`): a weight below
``roulette_w`` survives with probability w / roulette_w at weight roulette_w; the difference goes to
the part's ``roulette`` row.
:func:`advance_numpy` is the numpy twin (same bits)."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit

from straylight.engine.ray_batch import RayBatch
from straylight.engine.roulette import survivor_weight
from straylight.engine.tally_store import tally_add
from straylight.paths import mix_key
from straylight.engine.path_keys import mix_key1


ADVANCE_WRITES_PER_RAY = 3  # most tally writes one ray makes in :func:`advance`


@njit(cache=True, nogil=True)
def advance(cont, out, rays, hit, roulette_u, settings, last, log, rows):
    """Tallies absorption, roulette and truncation into ``log`` (straylight.engine.tally_store); returns
    the fields of the surviving rays' RayBatch, then ``kept`` (their positions in ``cont``)."""
    n = len(cont)
    K = rays.history.shape[1]
    has_hist = settings.record_paths
    n_ray = np.empty(n, np.int64)
    n_o = np.empty((n, 3))
    n_d = np.empty((n, 3))
    n_w = np.empty(n)
    n_event = np.empty(n, np.int8)
    n_pdf = np.empty(n)
    n_part = np.empty(n, np.int64)
    n_key = np.empty(n, np.uint64)
    n_depth = np.empty(n, np.int64)
    n_hist = np.empty((n if has_hist else 0, K), np.int16)
    kept = np.empty(n, np.int64)
    w = rays.weight_w
    p, nf = hit.point_mm, hit.facing_normal
    thr = settings.roulette_w
    eps = settings.eps_mm
    q = 0
    for c in range(n):
        i = cont[c]
        r = rays.ray[i]
        pt = hit.part[i]
        w_new = w[i] * out.throughput[c]
        tally_add(log, rows.absorbed + pt, r, w[i] - w_new)
        w_after = survivor_weight(w_new, thr, roulette_u[i])  # the one roulette rule (straylight.engine.roulette)
        if w_new < thr and w_new > 0:  # where it played: what it removed or added
            tally_add(log, rows.roulette + pt, r, w_new - w_after)
        if not w_after > 0:
            continue
        if last:
            tally_add(log, rows.truncated + pt, r, w_after)
            continue
        code = pt * 4 + out.event[c]
        if has_hist:
            for kk in range(K):
                n_hist[q, kk] = rays.history[i, kk]
            if rays.depth[i] < K:
                n_hist[q, rays.depth[i]] = code
        n_ray[q] = r
        s = eps if out.side[c] > 0 else -eps
        n_o[q, 0] = p[i, 0] + s * nf[i, 0]
        n_o[q, 1] = p[i, 1] + s * nf[i, 1]
        n_o[q, 2] = p[i, 2] + s * nf[i, 2]
        n_d[q, 0], n_d[q, 1], n_d[q, 2] = out.direction[c, 0], out.direction[c, 1], out.direction[c, 2]
        n_w[q] = w_after
        n_event[q] = out.event[c]
        n_pdf[q] = out.pdf_per_sr[c]
        n_part[q] = pt
        n_key[q] = mix_key1(rays.path_key[i], code) if settings.record_paths else rays.path_key[i]
        n_depth[q] = rays.depth[i] + 1
        kept[q] = c
        q += 1
    return (n_ray[:q], n_o[:q], n_d[:q], n_w[:q], n_event[:q], n_pdf[:q], n_part[:q], n_key[:q], n_depth[:q],
            n_hist[:q] if has_hist else n_hist[:0], kept[:q])


def advance_numpy(cont, out, rays, hit, roulette_u, settings, last, M, rows):
    """:func:`advance` in vectorised numpy (the reference)."""
    w = rays.weight_w[cont]
    r = rays.ray[cont]
    part = hit.part[cont]
    w_new = w * out.throughput
    M[rows.absorbed + part, r] += w - w_new
    thr = settings.roulette_w
    low = (w_new < thr) & (w_new > 0)
    w_after = w_new.copy()
    if low.any():
        w_after[low] = np.where(roulette_u[cont[low]] * thr < w_new[low], thr, 0.0)
        M[rows.roulette + part[low], r[low]] += w_new[low] - w_after[low]
    alive = w_after > 0
    if last:
        M[rows.truncated + part[alive], r[alive]] += w_after[alive]
        alive[:] = False
    kept = np.flatnonzero(alive)
    i = cont[kept]
    code = part[kept] * 4 + out.event[kept]
    K = rays.history.shape[1]
    if settings.record_paths:
        hist = rays.history[i]
        depth = rays.depth[i]
        inside = np.flatnonzero(depth < K)
        hist[inside, depth[inside]] = code[inside]
        key = mix_key(rays.path_key[i], code)
    else:
        hist = np.zeros((0, K), np.int16)
        key = rays.path_key[i]
    s = np.where(out.side[kept] > 0, settings.eps_mm, -settings.eps_mm)
    origin = hit.point_mm[i] + s[:, None] * hit.facing_normal[i]
    return (r[kept], origin, out.direction[kept], w_after[kept], out.event[kept].astype(np.int8),
            out.pdf_per_sr[kept], part[kept], key, rays.depth[i] + 1, hist, kept)


def next_rays(fields) -> tuple:
    """(RayBatch, kept) from what :func:`advance` returns."""
    return RayBatch(*fields[:10]), fields[10]
