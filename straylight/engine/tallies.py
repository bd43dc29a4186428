"""Stage: tallies. Per batch, the per-ray tally matrix M (rows: :class:`TallyRows`) is reduced to
per-chunk sums S1 = sum x, S2 = sum x^2 (chunk order, fixed chunk length: independent of the batch
size; stderr = sqrt(N/(N-1) (S2 - S1^2/N)) over all N rays), irradiance-map sums per (chunk,
detector, bin) and path records (:class:`DetectorRecords` collects them during the walk).
The compiled sums replay numpy's pairwise summation, so they equal ``np.add.reduceat`` to the bit
(:func:`chunk_sums_numpy` is that formulation)."""
from __future__ import annotations

import numpy as np
from numba import njit

from straylight.engine.pairwise_sums import any_nonzero, pairwise_sums_with, pairwise_work
from straylight.rng import CHUNK_RAYS


@njit(cache=True, nogil=True)
def chunk_sums(M, chunk, rows, clear=False, parts_hit=None):
    """Per-chunk S1 = sum x, S2 = sum x^2 of every tally row of M (n_rows, n) and of the derived rows
    (``ledger_absorbed`` = absorbed + roulette + nee_exchange + truncated per part, ``detector_total``
    = detector_nee + detector_direct; :class:`TallyRows`), as
    ``np.add.reduceat`` over chunks of ``chunk`` rays would give them. Returns (s1, s2), (n_chunks, rows).

    Blocks (row, chunk) that hold only zeros are skipped (derived rows: when all their source blocks
    are zero); ``clear=True`` zeroes the non-zero blocks of M afterwards, so that M is all zeros again
    and the caller can reuse it without filling it. ``parts_hit`` (n_chunks, n_parts) bool, if given:
    the per-part rows of part k in chunk c are known to be zero unless ``parts_hit[c, k]`` (the walk
    writes a part's rows only for rays that hit it), so those blocks are not even scanned: with many
    parts most of M is such blocks (0.36M-triangle assembly: 310 rows, 1.3 % non-zero)."""
    n_rows, n = M.shape
    n_parts, n_det = rows.n_parts, rows.n_detectors
    r_abs, r_rr, r_nex, r_trunc = rows.absorbed, rows.roulette, rows.nee_exchange, rows.truncated
    r_nee, r_direct = rows.detector_nee, rows.detector_direct
    n_ext = n_rows + n_parts + n_det
    nch = (n + chunk - 1) // chunk
    s1 = np.zeros((nch, n_ext))
    s2 = np.zeros((nch, n_ext))
    nz = np.zeros((nch, n_rows), np.bool_)
    buf = np.empty(chunk)
    ist, fst = pairwise_work()
    part_rows = rows.truncated + n_parts  # rows 0 .. part_rows-1: blocks of n_parts, one row per part
    for r in range(n_ext):
        for c in range(nch):
            a = c * chunk
            b = min(a + chunk, n)
            if r < n_rows:
                if parts_hit is not None and r < part_rows and not parts_hit[c, (r - rows.incident) % n_parts]:
                    continue  # a part no ray of this chunk hit: zeros
                x = M[r]
                lo = a
                if not any_nonzero(x, a, b):
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
                if not any_nonzero(x, 0, b - a):
                    continue
            else:
                k = r - n_rows - n_parts
                if not (nz[c, r_nee + k] or nz[c, r_direct + k]):
                    continue
                for i in range(a, b):
                    buf[i - a] = M[r_nee + k, i] + M[r_direct + k, i]
                x = buf
                lo = 0
                if not any_nonzero(x, 0, b - a):
                    continue
            # reduceat: the first element, then the pairwise sum of the rest
            t1, t2 = pairwise_sums_with(x, lo + 1, b - a - 1, ist, fst)
            s1[c, r] = x[lo] + t1
            s2[c, r] = x[lo] * x[lo] + t2
    if clear:
        for r in range(n_rows):
            for c in range(nch):
                if nz[c, r]:
                    a = c * chunk
                    M[r, a:min(a + chunk, n)] = 0.0
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


def chunk_sums_numpy(M, chunk, rows, clear=False, parts_hit=None):
    """:func:`chunk_sums` as np.add.reduceat (the reference; ``clear`` zeroes M; every block summed,
    ``parts_hit`` unused)."""
    p, d = rows.n_parts, rows.n_detectors
    ledger = (M[rows.absorbed:rows.absorbed + p] + M[rows.roulette:rows.roulette + p]
              + M[rows.nee_exchange:rows.nee_exchange + p] + M[rows.truncated:rows.truncated + p])
    det_total = M[rows.detector_nee:rows.detector_nee + d] + M[rows.detector_direct:rows.detector_direct + d]
    ext = np.concatenate([M, ledger, det_total], axis=0)
    starts = np.arange(0, M.shape[1], chunk)
    s1 = np.add.reduceat(ext, starts, axis=1).T.copy()
    s2 = np.add.reduceat(ext * ext, starts, axis=1).T.copy()
    if clear:
        M[:] = 0.0
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


def batch_sums(M, rows, first_chunk, records, segments, shadow_rays, chunk_sum, clear=False, parts_hit=None):
    """The result of one batch: per-chunk sums S1, S2 of every tally row (``chunk_sum``: the compiled
    :func:`chunk_sums` or its twin), irradiance-map sums and path records (``clear``: leave M zeros;
    ``parts_hit``: see :func:`chunk_sums`)."""
    C = CHUNK_RAYS
    n = M.shape[1]
    nch = -(-n // C)
    s1, s2 = chunk_sum(M, C, rows, clear, parts_hit)
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
            "segments": segments, "shadow_rays": shadow_rays}
