"""Stage: tallies. Per batch, the per-ray tallies x[row, ray] (rows: :class:`TallyRows`; kept as a
log of writes or a dense matrix, straylight.engine.tally_store) are reduced to per-chunk sums
S1 = sum x, S2 = sum x^2 (chunk order, fixed chunk length: independent of the batch size;
stderr = sqrt(N/(N-1) (S2 - S1^2/N)) over all N rays), irradiance-map sums per (chunk, detector,
bin) and path records (:class:`DetectorRecords` collects them during the walk).
The compiled sums (:func:`log_chunk_sums`) replay numpy's pairwise summation, so they equal
``np.add.reduceat`` on the dense matrix to the bit (:func:`chunk_sums_numpy` is that formulation)."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit

from straylight.engine.pairwise_sums import pairwise_sums_sparse, pairwise_sums_with, pairwise_work
from straylight.rng import CHUNK_RAYS


@njit(cache=True, nogil=True)
def _gather_block(lo, hi, pos_sorted, val_sorted, acc, mark, touched):
    """x = the cells of one (chunk, row) block: acc[pos] += value over the block's sorted log entries
    lo:hi (write order, as the dense matrix adds them), starting from the zeros acc holds. Returns
    how many positions were touched (listed in ``touched``, marked in ``mark``)."""
    nt = 0
    for e in range(lo, hi):
        pos = pos_sorted[e]
        if not mark[pos]:
            mark[pos] = True
            touched[nt] = pos
            nt += 1
        acc[pos] += val_sorted[e]
    return nt


SPARSE_BLOCK_MAX = 96  # blocks with more touched cells are summed densely (about as fast there)


@njit(cache=True, nogil=True)
def _block_sums(acc, touched, nt, length, ist, fst, rq):
    """(non-zero?, S1, S2) of the block acc[0:length] as ``np.add.reduceat`` gives them (its first
    element, then numpy's pairwise sum of the rest); an all-zero block is skipped (0, 0), as the
    dense sums skip it. Few touched cells: summed from them alone (sorted in place), same bits."""
    nz = False
    for t in range(nt):
        if acc[touched[t]] != 0.0:
            nz = True
            break
    if not nz:
        return False, 0.0, 0.0
    if nt <= SPARSE_BLOCK_MAX:
        for t in range(1, nt):  # insertion sort: a few cells, mostly in order already
            v = touched[t]
            u = t - 1
            while u >= 0 and touched[u] > v:
                touched[u + 1] = touched[u]
                u -= 1
            touched[u + 1] = v
        t1, t2 = pairwise_sums_sparse(acc, 1, length - 1, touched, nt, ist, fst, rq)
    else:
        t1, t2 = pairwise_sums_with(acc, 1, length - 1, ist, fst)
    return True, acc[0] + t1, acc[0] * acc[0] + t2


@njit(cache=True, nogil=True)
def _clear_block(acc, mark, touched, nt):
    for t in range(nt):
        pos = touched[t]
        acc[pos] = 0.0
        mark[pos] = False


@njit(cache=True, nogil=True)
def _add_into(acc, touched, nt, dst, dmark, dtouched, nd):
    """dst += acc at the touched positions (the derived rows' per-ray sums, in row order)."""
    for t in range(nt):
        pos = touched[t]
        if not dmark[pos]:
            dmark[pos] = True
            dtouched[nd] = pos
            nd += 1
        dst[pos] += acc[pos]
    return nd


@njit(cache=True, nogil=True)
def log_chunk_sums(row, ray, value, m, n, chunk, rows):
    """Per-chunk S1 = sum x, S2 = sum x^2 of every tally row and of the derived rows
    (``ledger_absorbed`` = ((absorbed + roulette) + nee_exchange) + truncated per part,
    ``detector_total`` = detector_nee + detector_direct; :class:`TallyRows`) from a log of m writes
    x[row, ray] += value (straylight.engine.tally_store), equal to the bit to what
    :func:`chunk_sums_numpy` gives on the dense matrix of the same writes. Returns (s1, s2), (n_chunks, rows).

    The entries are sorted stably by (chunk, row), so each cell adds its values in write order from
    0.0 as the matrix does; each block is rebuilt in a chunk-long scratch (zeros elsewhere) and
    summed by numpy's pairwise order. Only blocks with entries are visited."""
    n_rows = rows.n_per_ray
    n_parts, n_det = rows.n_parts, rows.n_detectors
    n_ext = rows.n_summed
    nch = (n + chunk - 1) // chunk
    nb = nch * n_rows
    # counting sort by bucket (chunk, row), stable; the entries are copied out in bucket order
    chunk_of = np.empty(n, np.int64)  # a lookup, not a division per entry
    for c in range(nch):
        chunk_of[c * chunk:min(c * chunk + chunk, n)] = c
    bucket = np.empty(m, np.int64)
    start = np.zeros(nb + 1, np.int64)
    for e in range(m):
        b = chunk_of[ray[e]] * n_rows + row[e]
        bucket[e] = b
        start[b + 1] += 1
    for b in range(nb):
        start[b + 1] += start[b]
    fill = start[:nb].copy()
    pos_sorted = np.empty(m, np.int32)
    val_sorted = np.empty(m)
    for e in range(m):
        b = bucket[e]
        f = fill[b]
        pos_sorted[f] = ray[e] - chunk_of[ray[e]] * chunk
        val_sorted[f] = value[e]
        fill[b] = f + 1
    s1 = np.zeros((nch, n_ext))
    s2 = np.zeros((nch, n_ext))
    acc = np.zeros(chunk)
    mark = np.zeros(chunk, np.bool_)
    touched = np.empty(chunk, np.int64)
    dacc = np.zeros(chunk)
    dmark = np.zeros(chunk, np.bool_)
    dtouched = np.empty(chunk, np.int64)
    ist, fst = pairwise_work()
    rq = np.empty((2, 8))
    # the source rows of the derived rows, in their order: per part absorbed, roulette, nee_exchange,
    # truncated; per detector nee, direct. Each is summed and added into the derived row's scratch
    # in one visit; the other rows after them.
    n_src_rows = 4 * n_parts + 2 * n_det
    src_row = np.empty(n_src_rows, np.int64)
    is_src = np.zeros(n_rows, np.bool_)
    q = 0
    for k in range(n_parts):
        for r0 in (rows.absorbed, rows.roulette, rows.nee_exchange, rows.truncated):
            src_row[q] = r0 + k
            is_src[r0 + k] = True
            q += 1
    for j in range(n_det):
        for r0 in (rows.detector_nee, rows.detector_direct):
            src_row[q] = r0 + j
            is_src[r0 + j] = True
            q += 1
    for c in range(nch):
        length = min(c * chunk + chunk, n) - c * chunk
        base = c * n_rows
        q = 0
        for k in range(n_parts + n_det):
            nd = 0
            for _ in range(4 if k < n_parts else 2):
                r = src_row[q]
                q += 1
                lo, hi = start[base + r], start[base + r + 1]
                if lo == hi:
                    continue
                nt = _gather_block(lo, hi, pos_sorted, val_sorted, acc, mark, touched)
                nd = _add_into(acc, touched, nt, dacc, dmark, dtouched, nd)
                nz, t1, t2 = _block_sums(acc, touched, nt, length, ist, fst, rq)
                if nz:
                    s1[c, r] = t1
                    s2[c, r] = t2
                _clear_block(acc, mark, touched, nt)
            if nd == 0:
                continue
            nz, t1, t2 = _block_sums(dacc, dtouched, nd, length, ist, fst, rq)
            if nz:
                s1[c, n_rows + k] = t1
                s2[c, n_rows + k] = t2
            _clear_block(dacc, dmark, dtouched, nd)
        for r in range(n_rows):
            lo, hi = start[base + r], start[base + r + 1]
            if is_src[r] or lo == hi:
                continue
            nt = _gather_block(lo, hi, pos_sorted, val_sorted, acc, mark, touched)
            nz, t1, t2 = _block_sums(acc, touched, nt, length, ist, fst, rq)
            if nz:
                s1[c, r] = t1
                s2[c, r] = t2
            _clear_block(acc, mark, touched, nt)
    return s1, s2


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
    ist, fst = pairwise_work()
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
            t1, t2 = pairwise_sums_with(pw, a + 1, b - a - 1, ist, fst)
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


def chunk_sums_numpy(M, chunk, rows):
    """Per-chunk sums S1, S2 of every row of the dense tally matrix M (rows, rays) and of the derived
    rows, as np.add.reduceat gives them (the reference :func:`log_chunk_sums` equals)."""
    p, d = rows.n_parts, rows.n_detectors
    ledger = (M[rows.absorbed:rows.absorbed + p] + M[rows.roulette:rows.roulette + p]
              + M[rows.nee_exchange:rows.nee_exchange + p] + M[rows.truncated:rows.truncated + p])
    det_total = M[rows.detector_nee:rows.detector_nee + d] + M[rows.detector_direct:rows.detector_direct + d]
    ext = np.concatenate([M, ledger, det_total], axis=0)
    starts = np.arange(0, M.shape[1], chunk)
    s1 = np.add.reduceat(ext, starts, axis=1).T.copy()
    s2 = np.add.reduceat(ext * ext, starts, axis=1).T.copy()
    return s1, s2


def chunk_maps(map_rows, nch, C, D, bins):
    """Per chunk and detector: (bin indices, sum of power, sum over rays of (ray's power in bin)^2)."""
    nb = bins[0] * bins[1]
    out = [[None] * D for _ in range(nch)]
    if not map_rows:
        return out
    ray, det, b, pw = (np.concatenate(x) for x in zip(*map_rows))
    # one key per (ray, detector, bin); sorting makes the sums independent of record order
    key = (ray.astype(np.int64) * D + det) * nb + b
    order = np.argsort(key, kind="stable")
    chunk, dj, bins_, s1, s2, g_start, g_stop = map_sums(key[order], np.ascontiguousarray(pw[order], np.float64),
                                                         nb, D, C)
    for a, z in zip(g_start.tolist(), g_stop.tolist()):
        out[int(chunk[a])][int(dj[a])] = (bins_[a:z], s1[a:z], s2[a:z])
    return out


class DetectorRecords:
    """Detector contributions of one batch, for the irradiance maps (always) and the path records
    (``record_paths``)."""

    def __init__(self, detectors, detector_parts, bins, record_paths):
        self.detectors = detectors  # DetectorGeometry per detector
        self.detector_parts = detector_parts
        self.bins = bins
        self.record_paths = record_paths
        self.map_rows = []
        self.path_rows = []
        self.polarization = None  # the batch's PolarizationState, made on first use (engine.interactions.stokes)

    def add(self, j, ray, points_mm, power_w, keys, events, depth):
        """Contributions ``power_w`` of rays ``ray`` (index in the batch) at ``points_mm`` on detector
        ``j``; path hash ``keys``, event codes ``events`` and depth ``depth`` (path records only)."""
        if len(ray) == 0:
            return
        b = self.detectors[j].bin_index(points_mm, self.bins)
        self.map_rows.append((ray, np.full(len(ray), j), b, power_w))
        if self.record_paths:
            self.path_rows.append((ray, np.full(len(ray), self.detector_parts[j], dtype=np.int16), power_w,
                                   depth.astype(np.int16), keys, events))


def batch_sums(tallies, rows, first_chunk, records, segments, shadow_rays, ray_log=None):
    """The result of one batch: per-chunk sums S1, S2 of every tally row (``tallies``: a store of
    straylight.engine.tally_store), irradiance-map sums, path records and the ray log's piece
    (``ray_log``: straylight.engine.ray_log.RayLogger.piece, None when off)."""
    C = CHUNK_RAYS
    n = tallies.n_rays
    nch = -(-n // C)
    s1, s2 = tallies.sums(C, rows)
    maps = chunk_maps(records.map_rows, nch, C, rows.n_detectors, records.bins)
    paths = None
    if records.record_paths and records.path_rows:
        cols = [np.concatenate(x) for x in zip(*records.path_rows)]
        order = np.lexsort((cols[1], cols[3], cols[0]))
        paths = {
            "ray": cols[0][order] + first_chunk * C, "detector": cols[1][order], "power_w": cols[2][order],
            "depth": cols[3][order], "key": cols[4][order], "events": cols[5][order],
        }
    return {"first_chunk": first_chunk, "s1": s1, "s2": s2, "maps": maps, "paths": paths,
            "segments": segments, "shadow_rays": shadow_rays, "ray_log": ray_log}
