"""numpy's pairwise summation in numba, so that compiled per-chunk sums are bit-identical to
``np.add.reduceat`` (numpy/_core/src/umath/loops_utils.h.src)."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit


@njit(cache=True, nogil=True)
def pairwise_block(x, lo, n):
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
def pairwise_work():
    """Scratch for :func:`pairwise_sums_with`: an explicit stack of (lo, n, state) and of results;
    allocate once per pass, not per sum (the allocations cost more than summing 1000 numbers)."""
    return np.empty((3, 64), np.int64), np.empty((2, 64))


@njit(cache=True, nogil=True)
def pairwise_sums_with(x, lo, n, ist, fst):
    """numpy's pairwise sums of x[lo:lo+n] and of its squares: blocks of <= 128 combined as a binary
    tree whose splits are halves rounded down to multiples of 8, so that per-chunk sums are
    bit-identical to ``np.add.reduceat(x)`` and ``np.add.reduceat(x * x)`` (:func:`_pairwise_tree`;
    ``ist``, ``fst`` from :func:`pairwise_work`)."""
    if n <= 128:
        return pairwise_block(x, lo, n)
    return _pairwise_tree(x, lo, n, ist[0], -1, ist, fst, fst)


@njit(cache=True, nogil=True)
def _pairwise_tree(x, lo, n, pos, n_pos, ist, fst, rq):
    """The tree of :func:`pairwise_sums_with` over x[lo:lo+n], its blocks summed densely
    (``n_pos < 0``) or from the listed non-zero positions ``pos[:n_pos]`` (ascending) alone
    (:func:`_sparse_block`; a subtree with none of them sums to 0.0 without a visit). Written
    without recursion (an explicit post-order stack in ``ist``, values in ``fst``; numba's on-disk
    cache and recursion do not mix well)."""
    p = 0
    while p < n_pos and pos[p] < lo:
        p += 1
    # stack of (lo, n, state); state 0 = expand, 1 = combine the two results on the value stack
    st_lo, st_n, st_s = ist[0], ist[1], ist[2]
    v1, v2 = fst[0], fst[1]
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
        elif n_pos >= 0 and (p >= n_pos or pos[p] >= a + m):  # no listed position here: 0.0
            v1[nv] = 0.0
            v2[nv] = 0.0
            nv += 1
        elif m <= 128:
            if n_pos < 0:
                s1_, s2_ = pairwise_block(x, a, m)
            else:  # blocks come left to right, so one forward pass over pos serves them all
                s1_, s2_, p = _sparse_block(x, a, m, pos, p, n_pos, rq)
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


@njit(cache=True, nogil=True)
def pairwise_sums(x, lo, n):
    """:func:`pairwise_sums_with` with its own scratch (one-off sums)."""
    if n <= 128:
        return pairwise_block(x, lo, n)
    ist, fst = pairwise_work()
    return pairwise_sums_with(x, lo, n, ist, fst)


@njit(cache=True, nogil=True)
def _sparse_block(x, a, m, pos, p, n_pos, rq):
    """:func:`pairwise_block` of x[a:a+m] reading only the listed non-zero positions ``pos[p:]``
    (ascending) that fall below a + m: the zeros numpy adds in between change nothing (x + 0.0 == x),
    so the accumulators, their combination and the tail come out the same to the bit. Returns
    (sum, sum of squares, next p). ``rq``: (2, 8) scratch for the accumulators. (Below 8 numpy adds
    in a plain loop: here the accumulators stay 0.0 and the tail loop is that loop.)"""
    r, q = rq[0], rq[1]
    r[:] = 0.0
    q[:] = 0.0
    stop = a + m - m % 8
    while p < n_pos and pos[p] < stop:
        v = x[pos[p]]
        j = (pos[p] - a) % 8
        r[j] += v
        q[j] += v * v
        p += 1
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    res2 = ((q[0] + q[1]) + (q[2] + q[3])) + ((q[4] + q[5]) + (q[6] + q[7]))
    while p < n_pos and pos[p] < a + m:
        v = x[pos[p]]
        res += v
        res2 += v * v
        p += 1
    return res, res2, p


@njit(cache=True, nogil=True)
def pairwise_sums_sparse(x, lo, n, pos, n_pos, ist, fst, rq):
    """:func:`pairwise_sums_with` of x[lo:lo+n] when x is zero except at ``pos[:n_pos]`` (ascending):
    the same tree of blocks and splits, each block summed from its listed positions only, so the
    result is the same to the bit at a cost that follows the non-zeros, not n. ``rq``: (2, 8) scratch."""
    return _pairwise_tree(x, lo, n, pos, n_pos, ist, fst, rq)
