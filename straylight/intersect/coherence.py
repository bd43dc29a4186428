"""Coherent ray order for the embree queries: rays grouped by where they start.

Embree answers each ray on its own (``rtcIntersect1`` per ray in embreex), so the order of the
rays does not change any answer, only how well the BVH nodes and triangles that neighbouring
queries touch stay in cache. The walk's rays come in ray-id order, i.e. scattered all over the
scene; on a 0.36M-triangle assembly the same rays ran 1.4x faster through ``EmbreeScene.run``
once grouped by origin (8^3 cells in Morton order; finer grids added < 5 %), on the 15k-triangle
tube ~4 % (its BVH fits in cache anyway). :func:`coherent_float32` does the grouping as a counting
sort (two O(n) passes) while it converts the arrays to the float32 embree reads, so it costs
about what the conversion alone cost; :func:`scatter_back` puts the answers back in the caller's
order. Morton (Z-order) curve: Morton, IBM report (1966); the cell grid is the origins' bounding box.
"""
from __future__ import annotations

import numpy as np

from materials.jit_cache import njit
from materials.jit_start import start_numba

CELL_BITS = 4  # 16 cells per axis, 4096 in all
MIN_RAYS = 4096  # below this, ordering does not pay: plain conversion
MIN_TRIANGLES = 100_000  # smaller scenes' BVHs stay in cache: no gain (tube, 15k: 3 % slower)
_COMPILED: dict = {}


def _compiled(fn):
    """``fn`` compiled by numba on first use (numba is started only when a large scene casts; startup
    order of materials.jit_start kept)."""
    jit = _COMPILED.get(fn)
    if jit is None:
        start_numba()
        jit = _COMPILED[fn] = njit(cache=True, nogil=True)(fn)
    return jit


def coherent_float32(origins, dirs, extra, bits):
    """float32 copies of ``origins`` (n, 3), ``dirs`` (n, 3) and ``extra`` (n,) (e.g. tmax; length 0
    for none), rows grouped by the Morton cell of their origin on a 2^bits grid over the origins'
    bounding box (stable within a cell); and ``perm``: row k of the copies is row perm[k] of the input.
    Inputs float64, C-contiguous."""
    return _compiled(_coherent_float32)(origins, dirs, extra, bits)


def scatter_back(values, perm):
    """``out[perm[k]] = values[k]``: answers in the caller's row order."""
    return _compiled(_scatter_back)(values, perm)


def _coherent_float32(origins, dirs, extra, bits):
    def spread3(x):  # bits of x (< 2^10) to every third bit: one axis of the Morton interleave
        x = (x | (x << 16)) & 0x030000FF
        x = (x | (x << 8)) & 0x0300F00F
        x = (x | (x << 4)) & 0x030C30C3
        return (x | (x << 2)) & 0x09249249

    n = origins.shape[0]
    lo0, lo1, lo2 = np.inf, np.inf, np.inf
    hi0, hi1, hi2 = -np.inf, -np.inf, -np.inf
    for i in range(n):
        a, b, c = origins[i, 0], origins[i, 1], origins[i, 2]
        lo0, hi0 = min(lo0, a), max(hi0, a)
        lo1, hi1 = min(lo1, b), max(hi1, b)
        lo2, hi2 = min(lo2, c), max(hi2, c)
    g = 1 << bits
    s0 = g / (hi0 - lo0) if hi0 > lo0 else 0.0
    s1 = g / (hi1 - lo1) if hi1 > lo1 else 0.0
    s2 = g / (hi2 - lo2) if hi2 > lo2 else 0.0
    n_cells = g * g * g
    cell = np.empty(n, np.int64)
    count = np.zeros(n_cells + 1, np.int64)
    for i in range(n):
        # NaN or inf origins land in cell 0 (embree reports them as misses whatever their order)
        q0 = (origins[i, 0] - lo0) * s0
        q1 = (origins[i, 1] - lo1) * s1
        q2 = (origins[i, 2] - lo2) * s2
        c0 = min(max(np.int64(q0), 0), g - 1) if q0 == q0 and abs(q0) < 1e18 else 0
        c1 = min(max(np.int64(q1), 0), g - 1) if q1 == q1 and abs(q1) < 1e18 else 0
        c2 = min(max(np.int64(q2), 0), g - 1) if q2 == q2 and abs(q2) < 1e18 else 0
        k = spread3(c0) | (spread3(c1) << 1) | (spread3(c2) << 2)
        cell[i] = k
        count[k + 1] += 1
    for k in range(n_cells):
        count[k + 1] += count[k]
    o32 = np.empty((n, 3), np.float32)
    d32 = np.empty((n, 3), np.float32)
    e32 = np.empty(extra.shape[0], np.float32)
    perm = np.empty(n, np.int64)
    has_extra = extra.shape[0] == n
    for i in range(n):
        k = cell[i]
        p = count[k]
        count[k] = p + 1
        perm[p] = i
        o32[p, 0], o32[p, 1], o32[p, 2] = origins[i, 0], origins[i, 1], origins[i, 2]
        d32[p, 0], d32[p, 1], d32[p, 2] = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        if has_extra:
            e32[p] = extra[i]
    return o32, d32, e32, perm


def _scatter_back(values, perm):
    out = np.empty_like(values)
    for k in range(perm.shape[0]):
        out[perm[k]] = values[k]
    return out
